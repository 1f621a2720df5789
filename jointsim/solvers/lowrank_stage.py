"""The data of the harmonic preconditioner's low-rank (Woodbury) stage: the row blocks
it may keep and the stage it builds (:class:`~jointsim.solvers.preconditioner.
HarmonicPreconditioner`, whose ``_lowrank`` explains the scheme)."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.linalg as sla

from ..linalg import stacked_inverse
from .hierarchical import bisection_tree

#: A split stage's capacitance system (``I + L_r G`` by element blocks) gets a coarse
#: space: the row blocks of one kind (slip or gap rows) are cut into aggregates of
#: about this many neighbours (a bisection of their positions), and each coefficient's
#: constant over an aggregate is solved exactly beside the element blocks (additive
#: two-level, :func:`capacitance_coarse`).  The element blocks leave ``G`` between
#: elements out, whose smooth part over a slipping region (the elastic body's
#: long-wavelength flexibility against the stuck stiffness) their GMRES needed a number
#: of iterations growing with that region for; docs/hbm.md, "Round 56".  0: none.
COARSE_ROW_BLOCKS = 16


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
    coarse : tuple (ndarray, tuple), or None
        A split stage's coarse space (:func:`capacitance_coarse`): the aggregate
        indicator ``A`` (n_rb, n_a) and the LU of ``Z^T (I + L_r G) Z`` with ``Z = A
        (x) I_nc``; else None.
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
    coarse: tuple | None = None

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
        """``(I + L_r G)^-1 rhs`` by its LU, or approximately by its element blocks plus
        its coarse space (a split stage: ``B^-1 rhs + Z E^-1 Z^T rhs``,
        :func:`capacitance_coarse`); ``rhs`` (m, k)."""
        if self.blocks is None:
            return sla.lu_solve(self.lu, rhs.astype(self.lu[0].dtype, copy=False),
                                check_finite=False)
        s = np.empty(rhs.shape)
        for coords, inv in self.blocks:
            s[coords] = np.matmul(inv, rhs[coords].astype(inv.dtype, copy=False))
        if self.coarse is not None:
            A, lu = self.coarse
            nrb, k = A.shape[0], rhs.shape[1]
            y = sla.lu_solve(lu, (A.T @ rhs.reshape(nrb, -1)).reshape(-1, k),
                             check_finite=False)
            s += (A @ y.reshape(A.shape[1], -1)).reshape(s.shape)
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


def element_tangent(jac) -> tuple:
    """Each element's own contact tangent: its slip and gap rows over all coefficients,
    no ``S_h`` (the row blocks of :class:`RowBlocks` and the element-block stage of the
    harmonic preconditioner).

    Parameters
    ----------
    jac : jointsim.solvers.jacobian.HBMJacobian

    Returns
    -------
    rows : list of ndarray of int
        The slip rows and the gap rows of the elements (those the Jacobian has), each
        (n_e,).
    nb : int
        Row kinds per element (``len(rows)``).
    blocks : ndarray, shape (n_e, nb n_c, nb n_c)
        The tangents [N/m].
    """
    nc, ne = jac.n_c, len(jac.t_row)
    if jac.Juu is None:
        rows = [jac.n_row]
    else:
        rows = [jac.t_row] + ([jac.n_row] if jac.JNN is not None else [])
    nb = len(rows)
    Tk = np.zeros((ne, nb * nc, nb * nc))
    if jac.Juu is not None:
        Tk[:, :nc, :nc] += jac.Juu
        if jac.Jug is not None and nb == 2:
            Tk[:, :nc, nc:] += jac.Jug
    if jac.JNN is not None:
        Tk[:, -nc:, -nc:] -= jac.JNN
    return rows, nb, Tk


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


def coarse_aggregates(positions, kind, size: int) -> np.ndarray:
    """The aggregates of a split stage's coarse space (:func:`capacitance_coarse`): the
    row blocks of each kind cut into neighbours, at most ``size`` of them each, by a
    bisection of their positions (:func:`~jointsim.solvers.hierarchical.bisection_tree`).

    Parameters
    ----------
    positions : ndarray, shape (n_rb, d)
        Position of each row block [m].
    kind : ndarray of int, shape (n_rb,)
        Its kind (the index of its rows in :func:`element_tangent`'s ``rows``: slip rows,
        then gap rows): an aggregate holds one kind.
    size : int
        Row blocks per aggregate at most.

    Returns
    -------
    ndarray of int, shape (n_rb,)
        The aggregate of each row block, ``0 .. n_a - 1``.
    """
    agg = np.empty(len(kind), dtype=np.int64)
    n = 0
    for k in np.unique(kind):
        idx = np.flatnonzero(kind == k)
        order, _, leaves = bisection_tree(positions[idx], max(int(size), 1))
        for lo, hi in leaves:
            agg[idx[order[lo:hi]]] = n
            n += 1
    return agg


def capacitance_coarse(jac, PinvR, Lr4, R, blk_el, Rrow, kind) -> tuple | None:
    """The coarse space of a split stage's capacitance system ``C = I + L_r G``, or None
    with at most ``COARSE_ROW_BLOCKS`` row blocks (or with it 0).

    ``Z = A (x) I_nc`` holds, for each aggregate of row blocks (:func:`coarse_aggregates`
    of the positions of their coordinates, ``jac.lin.positions``, else of their order)
    and each coefficient, the unit constant over the aggregate; ``E = Z^T C Z`` (``n_a
    n_c`` square) is formed by harmonics as :func:`capacitance_blocks` forms ``L_r G``,
    but on the ``n_a`` aggregate sums of ``Q_h``'s columns instead of its ``n_rb``
    columns (a coarse column is one coefficient, so one harmonic: ``Q_h A``).  Its LU is
    applied beside the element blocks, ``B^-1 r + Z E^-1 Z^T r``
    (:meth:`LowRankStage.capacitance_inverse`).

    Parameters
    ----------
    jac, PinvR, Lr4, R, blk_el
        As in :func:`capacitance_blocks`.
    Rrow : ndarray of int, shape (n_rb,)
        Contact coordinate of each row block.
    kind : ndarray of int, shape (n_rb,)
        Kind of each row block (as in :func:`coarse_aggregates`).

    Returns
    -------
    A : ndarray, shape (n_rb, n_a)
        The aggregates' indicator (0 or 1).
    lu : tuple
        ``scipy.linalg.lu_factor`` of ``E``, rows and columns ``(a, c)`` at ``a n_c + c``,
        dimensionless.
    """
    if not COARSE_ROW_BLOCKS or len(Rrow) <= COARSE_ROW_BLOCKS:
        return None
    pos = jac.lin.positions
    agg = coarse_aggregates(np.arange(len(Rrow), dtype=float)[:, None] if pos is None
                            else np.asarray(pos)[Rrow], kind, COARSE_ROW_BLOCKS)
    nrb, nc, nb, _ = Lr4.shape
    nl = R.size // nb
    na = int(agg.max()) + 1
    A = np.zeros((nrb, na))
    A[np.arange(nrb), agg] = 1.0
    # the row blocks in aggregate order, so that Z^T sums contiguous runs of them
    # (np.add.reduceat: a product with A^T cost 20 of a build's 53 ms at 480 points)
    order = np.argsort(agg, kind="stable")
    starts = np.searchsorted(agg[order], np.arange(na))
    Lt = np.ascontiguousarray(np.moveaxis(Lr4[order], 3, 0))     # (n_c, nrb, n_c, nb)
    el = blk_el[order]
    Et = np.zeros((nc, na, nc, na))          # E[a, c, a', c'] at Et[c', a, c, a']
    for i, h in enumerate(jac.basis.harmonics):
        # G's (R, aggregate) part of harmonic h, per row block's element: (nrb, nb, n_a)
        W = (PinvR[i] @ A)[R].reshape(nb, nl, na).transpose(1, 0, 2)[el]
        ic, is_ = jac._ic[i], jac._is[i]
        Lh = Lt[ic] + 1j * Lt[is_] if h else Lt[ic]                # (nrb, n_c, nb)
        W = W if h else W.real
        V = Lh[:, :, 0, None] * W[:, None, 0, :]                   # (nrb, n_c, n_a)
        for x in range(1, nb):
            V += Lh[:, :, x, None] * W[:, None, x, :]
        S = np.add.reduceat(V, starts, axis=0)                     # (n_a, n_c, n_a)
        Et[ic] += S.real
        if h:
            Et[is_] += S.imag
    E = Et.transpose(1, 2, 3, 0).copy()
    a, c = np.meshgrid(np.arange(na), np.arange(nc), indexing="ij")
    E[a, c, a, c] += A.sum(axis=0)[:, None]     # Z^T Z: the aggregates' sizes
    return A, sla.lu_factor(E.reshape(na * nc, na * nc), check_finite=False)
