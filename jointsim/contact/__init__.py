"""Contact laws: numba kernels, parameter objects and kernel selection."""
from .laws import TangentialLaw, iwan4_constants, iwan4_sliders, make_tangential_law
from .select import KernelChoice, select_kernels

__all__ = ["TangentialLaw", "iwan4_constants", "iwan4_sliders", "make_tangential_law",
           "KernelChoice", "select_kernels"]
