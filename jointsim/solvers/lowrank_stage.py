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
    Q_double : dict, or None
        With several groups, ``Q`` of the harmonics whose stage is in double
        (``preconditioner.LOOSE_DOUBLE_HARMONICS``), index -> (nb n_l, n_rb) complex128;
        ``Q`` holds them in single precision too, unused.
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
    Q_double: dict | None = None

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


def capacitance_blocks(jac, PinvR, Lr4, R, blk_el, dtype, coefs=None) -> list:
    """``L_r G`` (``m x m``) of a low-rank stage by harmonics, one block per harmonic group
    (:meth:`~jointsim.solvers.preconditioner.HarmonicPreconditioner._lowrank`).

    ``G = E_c^T P^-1 E_r`` couples the coefficients of one harmonic only: per harmonic
    ``h`` and column element ``l`` it is the complex ``(R, Rrow)`` part ``Q_h`` of
    ``P_h^-1`` (the ``R`` rows of ``PinvR``) in real 2 x 2 form.  So the rows ``(j, r)``
    and the columns (row block ``j'``, cosine / sine of ``h``) of ``L_r G`` are, with
    ``L_c`` and ``L_s`` the cosine and sine columns of ``L_r`` of harmonic ``h``, the real
    and imaginary parts of ``(L_c + i L_s) Q_h``: ``4 (H + 1) / n_c^2`` (about ``1 / (H +
    1)``) of the flops of the product with the dense ``G`` (``m^2 d``), which is never
    formed.  Measured on 120 Gauss points, FRC at force scale 20 (error indicators on,
    one thread): the dense ``G`` and product took about 5 of the 15 s of the low-rank
    stages.  With several harmonic groups (``L_r`` without the terms between them) only
    the diagonal blocks, (rows of a group) x (columns of that group), are nonzero: only
    they are formed.

    Parameters
    ----------
    jac : jointsim.solvers.jacobian.HBMJacobian
        The Jacobian of the stage (its harmonics and their coefficients).
    PinvR : ndarray, shape (n_h, n_r, nrb), complex
        The ``Rrow`` columns of each ``P_h^-1`` [m/N].
    Lr4 : ndarray, shape (nrb, n_c, nb, n_c)
        ``L_r`` by (row block, its coefficient, column kind, column coefficient) [N/m].
    R, blk_el : ndarray of int
        As in :class:`LowRankStage`.
    dtype : numpy dtype
        Of the result (float32 for a single-precision LU).
    coefs : list of ndarray of int, optional
        Each group's coefficients (sorted; ``HarmonicPreconditioner._harmonic_groups``);
        default one group of all.

    Returns
    -------
    list of ndarray, shape (nrb n_g, nrb n_g)
        Per group of ``n_g`` coefficients, its rows and columns ``(j, k)`` of ``L_r G``,
        index ``j n_g + k`` (the whole ``L_r G`` for one group), dimensionless.
    """
    nrb, nc, nb, _ = Lr4.shape
    nl = R.size // nb
    if coefs is None:
        coefs = [np.arange(nc)]
    group = np.empty(nc, dtype=np.intp)
    place = np.empty(nc, dtype=np.intp)          # a coefficient's place in its group
    for g, c in enumerate(coefs):
        group[c], place[c] = g, np.arange(c.size)
    out = [np.empty((nrb, c.size, nrb, c.size), dtype=dtype) for c in coefs]
    rows = [Lr4[:, c] if len(coefs) > 1 else Lr4 for c in coefs]
    for i, h in enumerate(jac.basis.harmonics):
        # (R, Rrow) part of P_h^-1, R index b nl + l -> (l, b, j'), then per row block
        Q = PinvR[i][R].reshape(nb, nl, nrb).transpose(1, 0, 2)
        Qj = Q[blk_el]                                    # (nrb, nb, nrb)
        ic, is_ = jac._ic[i], jac._is[i]
        g = group[ic]
        Lg, Mk = rows[g], out[g]
        if h:
            W = np.matmul(Lg[:, :, :, ic] + 1j * Lg[:, :, :, is_], Qj)
            Mk[:, :, :, place[ic]] = W.real
            Mk[:, :, :, place[is_]] = W.imag
        else:
            Mk[:, :, :, place[ic]] = np.matmul(Lg[:, :, :, ic], Qj.real)
    return [Mk.reshape(nrb * c.size, nrb * c.size) for Mk, c in zip(out, coefs)]
