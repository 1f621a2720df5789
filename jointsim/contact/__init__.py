"""Contact laws: numba kernels, law classes and their selection from a scene."""
from .laws import (AnchoredBank, LinearSpring, ManifoldBank, NoFriction, ScaledBank, TangentialLaw,
                   iwan4_constants, iwan4_sliders)
from .normal import BilateralPenalty, GivenNormal, NormalLaw, UnilateralPenalty
from .select import KernelChoice, law_class, select_kernels, tangential_law

__all__ = ["TangentialLaw", "AnchoredBank", "ScaledBank", "ManifoldBank", "LinearSpring", "NoFriction",
           "NormalLaw", "GivenNormal", "UnilateralPenalty", "BilateralPenalty",
           "iwan4_constants", "iwan4_sliders", "KernelChoice", "law_class", "select_kernels", "tangential_law"]
