"""jointsim: nonlinear dynamics of jointed structures.

Data flows one way: scene -> model -> solver -> result -> HDF5 file -> plots.
Importing the package has no side effects; the entry points set the BLAS
threads explicitly (:func:`jointsim.blas.limit_blas_threads`).
"""
__version__ = "0.1.0"

from .scene import Scene, SceneError, load_scene  # noqa: E402

__all__ = ["Scene", "SceneError", "load_scene", "__version__"]
