"""The data of the harmonic preconditioner's low-rank (Woodbury) stage: the row blocks
it may keep and the stage it builds (:class:`~jointsim.solvers.preconditioner.
HarmonicPreconditioner`, whose ``_lowrank`` explains the scheme)."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.linalg as sla

from ..linalg import stacked_inverse


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
        ``L`` on each row block, over its element's coordinates [N/m].
    nb : int
        Row kinds per element (slip and gap rows: 2; one of them: 1).
    lu : tuple, or None
        ``scipy.linalg.lu_factor`` of ``I + L_r G`` (single precision for a loose solve
        or a large ``m``: ``SINGLE_LU_RTOL``, ``SINGLE_LU_MIN``); None when the stage is
        split (``blocks``).
    blocks : tuple of (ndarray, ndarray), or None
        A split stage (solved through its capacitance system, ``HarmonicPreconditioner.
        solve_capacitance``): the inverses of the element blocks of ``I + L_r G``
        (:func:`capacitance_element_blocks`), by block size; else None.
    Q : ndarray, shape (n_h, nb n_l, n_rb), complex, or None
        A split stage's ``(R, Rrow)`` part of each ``P_h^-1`` (``G`` by harmonics,
        single precision); else None.
    Q_double : dict, or None
        A split stage's ``Q`` of the harmonics whose stage is in double
        (``preconditioner.LOOSE_DOUBLE_HARMONICS``), index -> (nb n_l, n_rb) complex128;
        ``Q`` holds them in single precision too, unused.
    """

    R: np.ndarray
    Rrow: np.ndarray
    block_element: np.ndarray
    Lr: np.ndarray
    nb: int
    lu: tuple | None = None
    blocks: tuple | None = None
    Q: np.ndarray | None = None
    Q_double: dict | None = None

    @property
    def split(self) -> bool:
        """Whether ``I + L_r G`` is kept by element blocks (no LU of it)."""
        return self.blocks is not None

    @property
    def sizes(self) -> list[int]:
        """Coordinates of each inverted block of ``I + L_r G``: its LU's, or each
        element block's."""
        if self.blocks is not None:
            return [inv.shape[1] for _, inv in self.blocks for _ in range(inv.shape[0])]
        return [self.lu[0].shape[0]]

    def capacitance_inverse(self, rhs) -> np.ndarray:
        """``(I + L_r G)^-1 rhs`` by its LU, or approximately by its element blocks (a
        split stage); ``rhs`` (m, k)."""
        if self.blocks is None:
            return sla.lu_solve(self.lu, rhs.astype(self.lu[0].dtype, copy=False),
                                check_finite=False)
        s = np.empty(rhs.shape)
        for coords, inv in self.blocks:
            s[coords] = np.matmul(inv, rhs[coords].astype(inv.dtype, copy=False))
        return s


class RowBlocks(NamedTuple):
    """The row blocks a low-rank stage may keep
    (:meth:`~jointsim.solvers.preconditioner.HarmonicPreconditioner._selection`)."""
    rows: list          # the slip and gap rows of the elements
    nb: int             # row blocks per element (kinds)
    Lb: np.ndarray      # (n_e, nb, n_c, nb n_c) the tangent minus P's projection
    norm: np.ndarray    # (n_e nb,) each row block's norm
    sel: np.ndarray     # the row blocks above LOWRANK_NEGLIGIBLE, index e nb + kind
    most: int           # how many of them are kept at most
    split: bool         # every row block kept, I + L_r G by element blocks


def capacitance_blocks(jac, PinvR, Lr4, R, blk_el, dtype) -> np.ndarray:
    """``L_r G`` (``m x m``) of a low-rank stage, formed by harmonics
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
    stages.

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

    Returns
    -------
    ndarray, shape (nrb n_c, nrb n_c)
        ``L_r G``, rows and columns ``(j, k)`` at index ``j n_c + k``, dimensionless.
    """
    nrb, nc, nb, _ = Lr4.shape
    nl = R.size // nb
    out = np.empty((nrb, nc, nrb, nc), dtype=dtype)
    for i, h in enumerate(jac.basis.harmonics):
        # (R, Rrow) part of P_h^-1, R index b nl + l -> (l, b, j'), then per row block
        Q = PinvR[i][R].reshape(nb, nl, nrb).transpose(1, 0, 2)
        Qj = Q[blk_el]                                    # (nrb, nb, nrb)
        ic, is_ = jac._ic[i], jac._is[i]
        if h:
            W = np.matmul(Lr4[:, :, :, ic] + 1j * Lr4[:, :, :, is_], Qj)
            out[:, :, :, ic] = W.real
            out[:, :, :, is_] = W.imag
        else:
            out[:, :, :, ic] = np.matmul(Lr4[:, :, :, ic], Qj.real)
    return out.reshape(nrb * nc, nrb * nc)


def capacitance_element_blocks(jac, PinvR, Lr4, R, blk_el, dtype) -> tuple:
    """The inverses of the element blocks of ``I + L_r G``: for each column element, the
    rows and columns of its own row blocks (``n_c`` or ``nb n_c`` of them), the
    preconditioner of a split stage's capacitance system
    (:meth:`~jointsim.solvers.preconditioner.HarmonicPreconditioner.solve_capacitance`).

    An element block holds the element's whole ``L_r`` (every harmonic coupled with every
    other, which an element's tangent does in slip) times ``G`` between the element's own
    coordinates (its self-flexibility, per harmonic); what it leaves out is ``G`` between
    elements.  Blocks by harmonic (``G`` between all elements, ``L_r`` of one harmonic)
    needed about as many GMRES iterations, and cost ``(H + 1)`` inverses of ``n_rb`` rows
    and twice the memory traffic an application (docs/hbm.md, "Round 52": the whole
    480-point EPMC 25 % faster).  Where ``G`` between elements dominates (the deepest
    gross slip measured, 16,800 coordinates at 480 points) they are weaker: the
    bordering's columns did not converge, and GMRES on the system finished.

    Parameters
    ----------
    jac, PinvR, Lr4, R, blk_el
        As in :func:`capacitance_blocks`.
    dtype : numpy dtype
        Of the inverses (float32 for a loose solve).

    Returns
    -------
    tuple of (ndarray, ndarray)
        Per block size ``c n_c`` (``c`` row blocks of an element): the capacitance
        coordinates of each such element (index ``j n_c + k``), shape (n_e_c, c n_c), and
        the inverses of their blocks, shape (n_e_c, c n_c, c n_c), dimensionless.
    """
    nrb, nc, nb, _ = Lr4.shape
    nl = R.size // nb
    Rl = R.reshape(nb, nl)                               # (kind, column element)
    order = np.argsort(blk_el, kind="stable")
    count = np.bincount(blk_el, minlength=nl)            # row blocks of each element
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    out = []
    for c in np.unique(count[count > 0]):
        els = np.flatnonzero(count == c)
        idx = order[start[els][:, None] + np.arange(c)]            # (n_e_c, c) row blocks
        # q[i, e, b, x]: P_h^-1 at (the element's kind-x coordinate, its row block b)
        q = PinvR[:, Rl[:, els].T[:, None, :], idx[:, :, None]]    # (n_h, n_e_c, c, nb)
        Le = Lr4[idx]                                  # (n_e_c, c, n_c, nb, n_c)
        B = np.zeros((els.size, c, nc, c, nc))
        for i, h in enumerate(jac.basis.harmonics):
            ic, is_ = jac._ic[i], jac._is[i]
            if h:
                W = np.einsum("earx,ebx->earb", Le[..., ic] + 1j * Le[..., is_], q[i])
                B[..., ic], B[..., is_] = W.real, W.imag
            else:
                B[..., ic] = np.einsum("earx,ebx->earb", Le[..., ic], q[i].real)
        B = B.reshape(els.size, c * nc, c * nc)
        B[:, np.arange(c * nc), np.arange(c * nc)] += 1.0
        coords = (idx[:, :, None] * nc + np.arange(nc)).reshape(els.size, c * nc)
        out.append((coords, stacked_inverse(B).astype(dtype, copy=False)))
    return tuple(out)
