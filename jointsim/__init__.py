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
    on one (2-core machine with other jobs running).
    """
    n = int(_os.environ.get("JOINTSIM_BLAS_THREADS", "1"))
    from threadpoolctl import threadpool_limits
    threadpool_limits(limits=n, user_api="blas")


_limit_blas_threads()

from .scene import Scene, SceneError, load_scene  # noqa: E402

__all__ = ["Scene", "SceneError", "load_scene", "__version__"]
