"""jointsim: nonlinear dynamics of jointed structures.

Data flows one way: scene -> model -> solver -> result -> HDF5 file -> plots.
"""
import os as _os

__version__ = "0.1.0"


def _limit_blas_threads() -> None:
    """Run BLAS on one thread unless ``JOINTSIM_BLAS_THREADS`` says otherwise.

    jointsim's dense algebra is on reduced models (a few hundred DOFs).  At that
    size threaded OpenBLAS only adds synchronisation, and on a loaded machine
    it collapses: a 108 x 108 solve took 139 ms on two threads against 0.16 ms
    on one (2-core machine with other jobs running).  The environment variables
    cover BLAS libraries loaded later; threadpoolctl covers numpy's and
    scipy's, loaded here.
    """
    n = _os.environ.get("JOINTSIM_BLAS_THREADS", "1")
    for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS"):
        _os.environ.setdefault(var, n)
    import numpy  # noqa: F401  (load the BLAS libraries before limiting them)
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits
    threadpool_limits(limits=int(n), user_api="blas")


_limit_blas_threads()

from .scene import Scene, SceneError, load_scene  # noqa: E402

__all__ = ["Scene", "SceneError", "load_scene", "__version__"]
