"""The data of the harmonic preconditioner's low-rank (Woodbury) stage: the row blocks
it may keep and the stage it builds (:class:`~jointsim.solvers.preconditioner.
HarmonicPreconditioner`, whose ``_lowrank`` explains the scheme)."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np


class LowRankStage(NamedTuple):
    """The Woodbury stage of the harmonic preconditioner (:meth:`~jointsim.solvers.
    preconditioner.HarmonicPreconditioner._lowrank`).

    Attributes
    ----------
    R : ndarray of int, shape (nb n_l,)
        Contact coordinates (slip rows, then gap rows) of the ``n_l`` column elements,
        index ``b n_l + l``.
    Rrow : ndarray of int, shape (n_rb,)
        Contact coordinate of each selected row block.
    block_element : ndarray of int, shape (n_rb,)
        Column element (index into the ``n_l``) of each row block.
    Lr : ndarray, shape (n_rb, n_c, nb n_c)
        ``L`` on each row block, over its element's coordinates [N/m] (without the
        terms that couple two harmonic groups, when there are several).
    groups : tuple
        The coordinates (index ``j n_c + k`` into the ``m = n_rb n_c``) of each
        group, one per harmonic (``_lowrank``);
        ``(slice(None),)`` for one group.
    lus : tuple
        With one group, ``scipy.linalg.lu_factor`` of ``I + L_r G`` (single precision
        for a loose solve or a large ``m``: ``SINGLE_LU_RTOL``, ``SINGLE_LU_MIN``);
        else empty.
    nb : int
        Row kinds per element (slip and gap rows: 2; one of them: 1).
    full : ndarray, shape (n_rb, n_c, nb n_c), or None
        With several groups, ``L`` on each row block with the terms between groups
        (``HarmonicPreconditioner.solve_capacitance``); else None.
    Q : ndarray, shape (n_h, nb n_l, n_rb), complex, or None
        With several groups, the ``(R, Rrow)`` part of each ``P_h^-1`` (``G`` by
        harmonics, single precision); else None.
    inverses : tuple of ndarray, or None
        With several groups, the inverse of each group's block of ``I + L_r G``
        (single precision); else None.
    """

    R: np.ndarray
    Rrow: np.ndarray
    block_element: np.ndarray
    Lr: np.ndarray
    groups: tuple
    lus: tuple
    nb: int
    full: np.ndarray | None = None
    Q: np.ndarray | None = None
    inverses: tuple | None = None

    @property
    def sizes(self) -> list[int]:
        """Coordinates of each group (of its LU, or of its inverse)."""
        if self.inverses is not None:
            return [inv.shape[0] for inv in self.inverses]
        return [lu.shape[0] for lu, _ in self.lus]


class RowBlocks(NamedTuple):
    """The row blocks a low-rank stage may keep
    (:meth:`~jointsim.solvers.preconditioner.HarmonicPreconditioner._selection`)."""
    rows: list          # the slip and gap rows of the elements
    nb: int             # row blocks per element (kinds)
    Lb: np.ndarray      # (n_e, nb, n_c, nb n_c) the tangent minus P's projection
    norm: np.ndarray    # (n_e nb,) each row block's norm
    sel: np.ndarray     # the row blocks above LOWRANK_NEGLIGIBLE, index e nb + kind
    most: int           # how many of them are kept at most
    n_groups: int       # harmonic groups of a split correction (1: none)
