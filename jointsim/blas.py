"""The number of BLAS threads, set once by each entry point.

``import jointsim`` changes nothing in the process; the entry points (the
command line, :func:`jointsim.run.run_scene`, sweep workers, benchmarks) call
:func:`limit_blas_threads` explicitly.
"""
from __future__ import annotations

import os


def limit_blas_threads(n: int | None = None) -> int:
    """Run BLAS on ``n`` threads (default: ``JOINTSIM_BLAS_THREADS``, else 1).

    jointsim's dense algebra is on reduced models (a few hundred DOFs).  At that
    size threaded OpenBLAS only adds synchronisation, and on a loaded machine
    it collapses: a 108 x 108 solve took 139 ms on two threads against 0.16 ms
    on one (2-core machine with other jobs running).  The environment variables
    cover BLAS libraries loaded later; threadpoolctl covers numpy's and
    scipy's, loaded here.

    Parameters
    ----------
    n : int, optional
        Threads; default ``JOINTSIM_BLAS_THREADS`` or 1.

    Returns
    -------
    int
        The thread count applied.
    """
    n = int(n if n is not None else os.environ.get("JOINTSIM_BLAS_THREADS", "1"))
    for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS"):
        os.environ.setdefault(var, str(n))
    import numpy  # noqa: F401  (load the BLAS libraries before limiting them)
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits
    threadpool_limits(limits=n, user_api="blas")
    return n
