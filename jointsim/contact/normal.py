"""The normal contact law: the one home of ``N(g)``.

``N = kn A max(0, -g)`` (unilateral penalty: the gap may open) or
``N = -kn A g`` (bilateral: the element is held in contact), with the gap
``g`` negative in interpenetration; or ``N`` given (``effects.normal =
"fixed"``: the normal load is an input and no gap is evaluated).  Every
solver takes ``N`` and ``dN/dg`` from :meth:`NormalLaw.load`; the time
kernels use the same scalar law (:func:`jointsim.contact._kernels.normal_point`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from . import _kernels as K

#: Codes of the normal laws in the fused time-marching kernel.
FUSED_GIVEN, FUSED_UNILATERAL, FUSED_BILATERAL = 0, 1, 2


@dataclass(frozen=True)
class NormalLaw:
    """Normal law of ``n_e`` elements.

    Attributes
    ----------
    kn : ndarray, shape (n_e,)
        Normal stiffness of each element, ``kn A`` [N/m].

    Class attributes
    ----------------
    name : str
        For logs and result files (never switched on).
    coupled : bool
        True when ``N`` is computed from the gap (False: ``N`` is given).
    can_open : bool
        True when the gap may open (``N = 0`` for ``g > 0``).
    fused_code : int
        Code of the law in the fused time-marching kernel.
    """

    name: ClassVar[str] = ""
    coupled: ClassVar[bool] = True
    can_open: ClassVar[bool] = False
    fused_code: ClassVar[int] = -1

    kn: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "kn", np.ascontiguousarray(self.kn, dtype=float))

    def load(self, g, closed_at_zero: bool = False):
        """Normal load and its derivative from gaps.

        Parameters
        ----------
        g : ndarray, shape (n_e,) or (n_e, n_t)
            Gaps [m]; negative in interpenetration.
        closed_at_zero : bool
            Which side the generalised derivative takes at ``g = 0`` exactly:
            the open one (False, ``dN/dg = 0``; harmonic balance and time
            marching) or the closed one (True, ``dN/dg = -kn``; the static
            solver, so that bodies held only by touching contacts are not
            singular at the first Newton step).

        Returns
        -------
        N, dNdg : ndarray, same shape as ``g``
            Normal load [N] (>= 0 in compression) and ``dN/dg`` [N/m].
        """
        g = np.asarray(g, dtype=float)
        g2 = np.ascontiguousarray(g.reshape(g.shape[0], -1))
        N, dNdg = K.normal_penalty(g2, self.kn, self.can_open, closed_at_zero)
        return N.reshape(g.shape), dNdg.reshape(g.shape)

    def closed(self, g) -> np.ndarray:
        """Where the element is in contact (``g <= 0``), shape of ``g``."""
        return np.asarray(g) <= 0.0


@dataclass(frozen=True)
class GivenNormal(NormalLaw):
    """Normal load given (fixed at ``N0``): no gap is evaluated."""

    name: ClassVar[str] = "given"
    coupled: ClassVar[bool] = False
    fused_code: ClassVar[int] = FUSED_GIVEN

    def load(self, g, closed_at_zero: bool = False):
        raise RuntimeError("normal load is fixed in this scene; no gap is evaluated")


@dataclass(frozen=True)
class UnilateralPenalty(NormalLaw):
    """``N = kn A max(0, -g)``: separation allowed."""

    name: ClassVar[str] = "unilateral"
    can_open: ClassVar[bool] = True
    fused_code: ClassVar[int] = FUSED_UNILATERAL


@dataclass(frozen=True)
class BilateralPenalty(NormalLaw):
    """``N = -kn A g``: the element never separates (tension allowed)."""

    name: ClassVar[str] = "bilateral"
    fused_code: ClassVar[int] = FUSED_BILATERAL
