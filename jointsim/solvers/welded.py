"""The coordinates of the condensation, ``x = Psi q + Z y`` (made once per model).

``Psi = T^T (T T^T)^-1`` (so ``T Psi = I``) and ``Z`` a basis of the null space of ``T``:
the modes of the structure with its contact coordinates held at zero (welded), M-
orthonormal and K-orthogonal, when ``K`` and ``M`` are symmetric.  The blocks of ``K``,
``M`` and ``C`` in ``(q, y)`` are what :class:`~jointsim.solvers.condensation.ReducedLinear`
condenses per frequency (the formulation is in :mod:`jointsim.solvers.condensation`).

The kinds, by the damping in the welded modes:

* ``"modal"``: ``Z' C Z`` diagonal (Rayleigh, or no damping);
* ``"lowrank"``: ``Z' C Z`` of rank at most ``n_y / 3`` (modal damping of a few modes of
  another basis, e.g. of the stuck joint): ``E`` is then a diagonal plus a rank-``r``
  term;
* ``"direct"``: anything else (and non-symmetric ``K`` or ``M``): ``Z`` is then an
  orthonormal basis of the null space, and ``E`` a full matrix.

Cost (round 43).  ``K`` and ``M`` are first taken to the coordinates ``(q, y0)`` of the
orthonormal null-space basis ``Z0`` by one congruence each, on :data:`THREADS` threads
(:func:`jointsim.linalg.symmetric_congruence`, both sides of the diagonal formed and
averaged, the steadier rounding: at 480 Gauss points the first stuck frequency of the
condensation came 6.1e-9 from the pivoted shift-invert one, 6.9e-8 with the mirrored
half on blocks of 128 columns, 5.3e-9 and 2.5e-9 on blocks of 64 and 256);
the welded modes ``Phi`` (``Z = Z0 Phi``) then turn the ``y0 q`` blocks into the ``yq``
ones.  A damping of low rank enters by its factors (``C = W diag(c) W^T``, found in
``O(n^2 r)``, :func:`low_rank`), so that no product with ``C`` costs ``n^3``.  ``Psi``,
``Z0`` and the check that ``T``'s rows are independent come from one complete QR of
``T'`` (round 48: ``T' = Q_1 R``, ``Psi = Q_1 R^-T``, ``T``'s singular values ``R``'s).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ..linalg import symmetric_congruence

#: Threads of the congruences of ``K`` and ``M`` (:func:`welded_coordinates`).
THREADS = 2


@dataclass
class WeldedCoordinates:
    """The coordinates ``(q, y)`` of a structure and its matrices in them.

    Attributes
    ----------
    kind : str
        ``"modal"``, ``"lowrank"`` or ``"direct"`` (module docstring).
    Psi : ndarray, shape (n, n_r)
        ``T^T (T T^T)^-1`` [-].
    Z : ndarray, shape (n, n_y)
        The welded modes (M-orthonormal, [1/sqrt(kg)]) for the modal and low-rank kinds,
        else an orthonormal basis of the null space of ``T``.
    K, M, C : dict of ndarray
        Blocks ``"qq"``, ``"qy"``, ``"yq"``, ``"yy"`` of ``V^T A V``, ``V = [Psi, Z]``
        (C-contiguous) [N/m, kg, N s/m].
    lowrank : tuple (U, c) or None
        ``Z' C Z = U diag(c) U^T`` (``U`` (n_y, r) orthonormal) for the low-rank kind.
    damping_low_rank : tuple (W, c) or None
        ``C = W diag(c) W^T`` (``W`` (n, r)) when ``C`` is symmetric and of rank below 64
        and the structure has both kinds of coordinates (:func:`low_rank`).
    """

    kind: str
    Psi: np.ndarray
    Z: np.ndarray
    K: dict
    M: dict
    C: dict
    lowrank: tuple | None
    damping_low_rank: tuple | None


def welded_coordinates(M, K, C, T, threads: int = THREADS) -> WeldedCoordinates:
    """The coordinates ``(q, y)`` of the structure ``(M, K, C)`` with contact coordinates
    ``q = T x``, and its matrices in them.

    Parameters
    ----------
    M, K, C : ndarray, shape (n, n)
        Dense mass [kg], stiffness [N/m] and damping [N s/m].
    T : ndarray, shape (n_r, n)
        Contact coordinates.
    threads : int
        Threads of the congruences of ``K`` and ``M``.

    Returns
    -------
    WeldedCoordinates

    Raises
    ------
    ValueError
        When the rows of ``T`` are linearly dependent.
    """
    n, n_r = M.shape[0], T.shape[0]
    n_y = n - n_r
    if n_r:
        # T' = Q1 R: T's singular values are R's, Psi = Q1 R^-T (no T T' and no SVD of T,
        # 0.36 and 0.13 s at 480 Gauss points, round 48), Z0 the rest of Q
        Q, R = np.linalg.qr(T.T, mode="complete") if n_r <= n else (None, None)
        sv = np.linalg.svd(R[:n_r], compute_uv=False) if R is not None else None
        if sv is None or sv.min() <= 1e-10 * sv.max():
            raise ValueError(
                "the contact coordinates are linearly dependent (two contact elements "
                "measure the same relative motion, or an element's slip and gap coincide); "
                "merge such elements or give them distinct DOFs")
        Psi = sla.solve_triangular(R[:n_r], Q[:, :n_r].T, check_finite=False).T
        Z0 = Q[:, n_r:]
    else:
        Psi, Z0 = np.zeros((n, 0)), np.eye(n)
    V0 = np.hstack([Psi, Z0])
    r, y = slice(0, n_r), slice(n_r, n)
    sym = symmetric(K) and symmetric(M)
    csym = symmetric(C)
    # a symmetric damping of low rank (modal damping of a few stuck modes): its factors
    # stand in for C's n^3 products
    low = low_rank(C) if csym and n_y and n_r else None
    # both sides of the diagonal, each pair of entries the mean of its two roundings
    # (module docstring)
    KV, MV = ((symmetric_congruence(V0, A, threads, both_sides=True) if sym
               else V0.T @ A @ V0) for A in (K, M))
    kind, Z, lowrank, yy = "direct", Z0, None, None
    if n_y and sym:
        try:
            lam, Phi = sla.eigh(KV[y, y], MV[y, y])
            Zm = Z0 @ Phi
            if low is not None:
                WZ = Zm.T @ low[0]
                Cyy = (WZ * low[1]) @ WZ.T
            else:
                Cyy = Zm.T @ C @ Zm
            off = Cyy - np.diag(np.diag(Cyy))
            if np.abs(off).max() <= 1e-11 * max(np.abs(Cyy).max(), 1e-300):
                kind = "modal"
            elif csym:
                # modal damping of a few modes is a low-rank C: E is then a diagonal plus
                # a rank-r term, inverted by Woodbury's formula
                if low is not None:
                    U, c = orthonormal_factors(WZ, low[1])
                else:
                    c, U = np.linalg.eigh(0.5 * (Cyy + Cyy.T))
                    keep = np.abs(c) > 1e-12 * max(np.abs(c).max(), 1e-300)
                    U, c = U[:, keep], c[keep]
                if c.size <= n_y // 3:
                    kind, lowrank = "lowrank", (U, c)
            if kind != "direct":
                Z, yy = Zm, (np.diag(lam), np.eye(n_y), Cyy)
        except (np.linalg.LinAlgError, ValueError):
            pass
    if yy is not None:
        # the qq blocks as they are, the yq ones turned by the welded modes, the yy ones
        # known (diag(lam), the identity, Z' C Z)
        def blocks(AV, Ayy):
            yq = Phi.T @ AV[y, r]
            return {"qq": np.ascontiguousarray(AV[r, r]), "qy": np.ascontiguousarray(yq.T),
                    "yq": yq, "yy": Ayy}
        Kb, Mb = blocks(KV, yy[0]), blocks(MV, yy[1])
        if low is not None:
            Wq, Wy = Psi.T @ low[0], Z.T @ low[0]
            yq = (Wy * low[1]) @ Wq.T
            Cb = {"qq": (Wq * low[1]) @ Wq.T, "qy": np.ascontiguousarray(yq.T), "yq": yq,
                  "yy": yy[2]}
        else:
            CP = C @ Psi
            yq = Z.T @ CP
            Cb = {"qq": Psi.T @ CP, "qy": np.ascontiguousarray(yq.T), "yq": yq, "yy": yy[2]}
    else:
        CV = symmetric_congruence(V0, C, threads, both_sides=True) if csym else V0.T @ C @ V0
        # contiguous copies: the blocks per frequency read them (memory-bound)
        Kb, Mb, Cb = ({b: np.ascontiguousarray(AV[i, j]) for b, (i, j) in
                       {"qq": (r, r), "qy": (r, y), "yq": (y, r), "yy": (y, y)}.items()}
                      for AV in (KV, MV, CV))
    return WeldedCoordinates(kind=kind, Psi=Psi, Z=Z, K=Kb, M=Mb, C=Cb, lowrank=lowrank,
                             damping_low_rank=low)


def symmetric(A, rows: int = 64) -> bool:
    """Whether a dense ``A`` equals its transpose to ``1e-12`` of its largest entry
    (compared by blocks of ``rows`` rows: no ``n x n`` temporary, 0.1 -> 0.03 s at
    1,964 DOFs)."""
    worst = 0.0
    for i in range(0, A.shape[0], rows):
        d = A[i:i + rows] - A[:, i:i + rows].T
        worst = max(worst, float(np.abs(d, out=d).max(initial=0.0)))
    return worst <= 1e-12 * float(np.abs(A).max(initial=0.0))


def low_rank_factors(C, n_r: int, seed: int = 0, max_block: int | None = None):
    """``(W_q, W_y, c)`` with ``C = W diag(c) W^T`` (``W`` (n, r) split after its first
    ``n_r`` rows) for a symmetric ``C`` of rank ``r <= n / 3``, or None when ``C`` is
    not of such a rank to round-off.

    The range of ``C`` from its product with a random block of 64 columns, else of
    ``n / 3`` (a randomised range finder, exact for a rank below the block's), then the
    eigen-decomposition of ``C`` on it: ``O(n^2)`` per column instead of an ``n x n``
    eigen-problem; the reconstruction is checked to ``1e-11`` of ``max |C|``.  With
    ``max_block``, only the first block (a rank below it; a full-rank ``C`` then costs
    ``O(n^2 max_block)`` before None).
    """
    n = C.shape[0]
    ref = float(np.abs(C).max(initial=0.0))
    if ref == 0.0:
        return None
    rng = np.random.default_rng(seed)
    sizes = sorted({min(64, max(n // 3, 1)), max(n // 3, 1)})
    for k in sizes if max_block is None else [b for b in sizes if b <= max_block][:1]:
        Q, _ = np.linalg.qr(C @ rng.standard_normal((n, k)))
        c, V = np.linalg.eigh(Q.T @ C @ Q)
        keep = np.abs(c) > 1e-12 * max(float(np.abs(c).max()), 1e-300)
        if keep.sum() < k:
            W, c = Q @ V[:, keep], c[keep]
            if float(np.abs((W * c) @ W.T - C).max()) > 1e-11 * ref:
                return None
            return np.ascontiguousarray(W[:n_r]), np.ascontiguousarray(W[n_r:]), c
    return None


def low_rank(C, seed: int = 0):
    """``(W, c)`` with ``C = W diag(c) W^T`` (``W`` (n, r), ``r < 64``) for a symmetric
    dense ``C`` of low rank (:func:`low_rank_factors` on one block of 64 columns, so that
    a full-rank damping, Rayleigh's, costs ``O(64 n^2)``; ``r = 0`` for ``C = 0``), or
    None."""
    if not np.any(C):
        return np.zeros((C.shape[0], 0)), np.zeros(0)
    f = low_rank_factors(C, 0, seed, max_block=64)
    return None if f is None else (f[1], f[2])


def orthonormal_factors(U0, c):
    """``(U, w)`` with ``U diag(w) U^T = U0 diag(c) U0^T`` and orthonormal columns ``U``
    (the eigen-decomposition of that rank-``r`` matrix from the QR factors of ``U0``,
    ``O(n r^2)``); eigenvalues at most ``1e-12`` of the largest in magnitude dropped."""
    Q, R = np.linalg.qr(U0)
    w, V = np.linalg.eigh((R * c) @ R.T)
    keep = np.abs(w) > 1e-12 * max(float(np.abs(w).max(initial=0.0)), 1e-300)
    return Q @ V[:, keep], w[keep]
