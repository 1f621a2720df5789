"""Every harmonic's interface operator ``S_h`` applied through a hierarchical form.

With a damping of low rank (``ReducedLinear.kind == "lowrank"``, the lap joints) and the
welded modes above ``QUASI_STATIC_RATIO nu_max`` summed once
(:meth:`~jointsim.solvers.condensation.ReducedLinear._b_dinv_bp`), the condensed dynamic
stiffness of every harmonic is

    S_h = G(s) + F M_h F^T,      G(s) = sum_p s^p G_p,      s = nu^2 + i nu xi,

* ``G_0 = K_qq - C_0``, ``G_1 = -(M_qq + C_1)``, ``G_p = -C_p`` (``p >= 2``): real,
  ``n_r x n_r`` and independent of the frequency (``C_p`` the quasi-static sums);
* ``F = [W_q, K_low, M_low, P_0 .. P_P]``: a fixed real basis of ``rho`` columns (the
  damping's factor on the contact coordinates; the columns of ``K_qy`` and ``M_qy`` of the
  welded modes below the threshold; the quasi-static sums ``P_p`` of ``B_0 D^-1 W_y``);
* ``M_h``: a small complex ``rho x rho`` matrix per harmonic (:func:`_middles`), the
  terms of :meth:`~jointsim.solvers.condensation.ReducedLinear.schur_low_rank_damping`
  written in that basis.

The ``G_p`` are interface operators. Order the contact coordinates by a recursive
bisection of their positions and the off-diagonal blocks have a numerical rank that
stays bounded as the interface is refined (``benchmarks/interface_compression.py``:
about 25 at ``1e-12`` from 120 to 480 Gauss points). :class:`HODLR` keeps them as
truncated SVDs, so its product's storage and flops grow as ``n log n``, not ``n^2``.

The Krylov path uses it from :data:`HIERARCHICAL_MIN_ROWS` contact coordinates on
(:attr:`~jointsim.solvers.frequency_blocks.FrequencyBlocks.hierarchical`):

* for ``J v`` (:class:`InterfaceProducts`), within ``COMPRESSION_EPS`` of ``||G||``;
* for the harmonic stage of a loose solve's preconditioner (the error indicators'):
  :class:`HierarchicalInverse` factorises ``G(s_h)`` plus the element tangents' harmonic
  projection as a HODLR matrix and adds ``F M_h F^T`` by Woodbury's formula, without an
  ``n_r x n_r`` array or the stuck flexibility's eigen-decomposition (backward error
  3e-9 to 3.5e-6 from 120 to 480 Gauss points, docs/hbm.md "Round 38"; its basis for
  ``F M_h F^T`` is orthonormal, weighted by ``M_h``: in ``F`` itself Woodbury's
  capacitance is singular to round-off).

The residual and its derivatives stay exact (``DynamicProducts``), so these errors only
perturb Newton's directions and GMRES's iterations, not the solution.
"""
from __future__ import annotations

import logging
import weakref

import numpy as np
import scipy.linalg as sla

log = logging.getLogger(__name__)

#: Contact coordinates from which ``J v`` goes through :class:`InterfaceProducts`.
#: Measured (round 38, docs/hbm.md), a product of 8 harmonics: 0.44 against 1.00 ms at
#: 480 coordinates, 0.41 against 0.32 ms at 240 (``DynamicProducts`` is as fast there);
#: the 240-point FRC 62.9 s against 69.2 s.
HIERARCHICAL_MIN_ROWS = 400
#: Largest leaf of the bisection [contact coordinates]; its diagonal block is dense.
LEAF_ROWS = 128
#: Truncation of the off-diagonal blocks, relative to ``||G(s)||_F`` over the split's
#: frequencies.
COMPRESSION_EPS = 1e-12
#: Singular values of the low-rank terms' basis kept by :class:`HierarchicalInverse`,
#: relative to the largest (``F`` with its columns weighted by ``M_h``).
BASIS_EPS = 1e-15


def bisection_tree(positions: np.ndarray, leaf: int = LEAF_ROWS):
    """A recursive coordinate bisection of the contact coordinates.

    Coordinates at one position (an element's slip and gap) stay together. A cluster is
    cut across its widest extent at the position that halves its coordinates.

    Parameters
    ----------
    positions : ndarray, shape (n, d)
        Position of every coordinate [m].
    leaf : int
        Largest cluster that is not cut.

    Returns
    -------
    order : ndarray of int, shape (n,)
        The coordinates in tree order (every cluster is a contiguous range).
    levels : list of list of (lo, mid, hi)
        The cut clusters of each depth, as ranges of ``order``.
    leaves : list of (lo, hi)
    """
    pos = np.asarray(positions, dtype=float).reshape(len(positions), -1)
    uniq, group = np.unique(pos, axis=0, return_inverse=True)
    group = np.ravel(group)
    members = [np.flatnonzero(group == g) for g in range(len(uniq))]
    sizes = np.array([m.size for m in members])
    order, levels, leaves = [], [], []

    def cut(groups, lo, depth):
        n = int(sizes[groups].sum())
        if n <= leaf or groups.size == 1:
            order.extend(np.concatenate([members[g] for g in groups]))
            leaves.append((lo, lo + n))
            return
        p = uniq[groups]
        axis = int(np.argmax(np.ptp(p, axis=0)))
        groups = groups[np.argsort(p[:, axis], kind="stable")]
        csum = np.cumsum(sizes[groups])
        k = int(np.clip(np.searchsorted(csum, n / 2.0), 0, groups.size - 2)) + 1
        mid = lo + int(csum[k - 1])
        while len(levels) <= depth:
            levels.append([])
        levels[depth].append((lo, mid, lo + n))
        cut(groups[:k], lo, depth + 1)
        cut(groups[k:], mid, depth + 1)

    if len(uniq):
        cut(np.arange(len(uniq)), 0, 0)
    return np.asarray(order, dtype=np.int64), levels, leaves


def _padded(ranges, order, n):
    """Index arrays ``(len(ranges), max length)`` into the coordinates, padded with ``n``."""
    m = max(hi - lo for lo, hi in ranges)
    idx = np.full((len(ranges), m), n, dtype=np.int64)
    for i, (lo, hi) in enumerate(ranges):
        idx[i, :hi - lo] = order[lo:hi]
    return idx


class HODLR:
    """``sum_p s_p G_p X`` with the ``G_p`` kept as one hierarchical off-diagonal low-rank
    (HODLR) matrix per part, on one :func:`bisection_tree`.

    Every off-diagonal block of a part is truncated at its absolute tolerance; the
    parts' factors of one block are stacked, so that a product takes two batched
    ``matmul`` per depth of the tree and one for the dense leaves.

    Parameters
    ----------
    parts : sequence of ndarray, shape (n, n), real
    tols : sequence of float
        Absolute truncation of each part (singular values at or below it are dropped).
    tree : tuple
        :func:`bisection_tree`'s ``(order, levels, leaves)``.
    """

    def __init__(self, parts, tols, tree):
        order, levels, leaves = tree
        n = parts[0].shape[0]
        self.n = n
        # a part below its tolerance everywhere adds nothing
        self.powers = [p for p, (G, t) in enumerate(zip(parts, tols))
                       if sla.norm(G) > t]
        parts = [parts[p] for p in self.powers]
        tols = [tols[p] for p in self.powers]
        self.leaf_idx = _padded(leaves, order, n)
        m = self.leaf_idx.shape[1]
        #: the leaf and the place in it of every coordinate, (n, 2)
        self.leaf_of = np.zeros((n, 2), dtype=np.int64)
        for i, (lo, hi) in enumerate(leaves):
            self.leaf_of[order[lo:hi]] = np.column_stack([np.full(hi - lo, i),
                                                          np.arange(hi - lo)])
        #: the place of every coordinate in tree order, (n,); each leaf's and each
        #: off-diagonal block's ranges there, ``(lo, size)`` and ``(row lo, size, column
        #: lo, size)`` (for :meth:`columns`)
        self.tree_pos = np.empty(n, dtype=np.int64)
        self.tree_pos[order] = np.arange(n)
        self.leaf_span = [(lo, hi - lo) for lo, hi in leaves]
        self.block_spans = []
        self._work = None
        self.D = np.zeros((len(leaves), len(parts) * m, m))
        for i, (lo, hi) in enumerate(leaves):
            ix = order[lo:hi]
            for j, G in enumerate(parts):
                self.D[i, j * m:j * m + hi - lo, :hi - lo] = G[np.ix_(ix, ix)]
        self.levels = []
        self.stored = self.D.size
        self.ranks = []
        for nodes in levels:
            blocks = [b for lo, mid, hi in nodes for b in (((lo, mid), (mid, hi)),
                                                           ((mid, hi), (lo, mid)))]
            factors = [self._compress(parts, tols, order, rows, cols) for rows, cols in blocks]
            k = max(1, max(U.shape[1] for U, _, _ in factors))
            rows = _padded([r for r, _ in blocks], order, n)
            cols = _padded([c for _, c in blocks], order, n)
            U = np.zeros((len(blocks), rows.shape[1], k))
            V = np.zeros((len(blocks), k, cols.shape[1]))
            pid = np.zeros((len(blocks), k), dtype=np.int64)
            for b, (Ub, Vb, pb) in enumerate(factors):
                U[b, :Ub.shape[0], :Ub.shape[1]] = Ub
                V[b, :Vb.shape[0], :Vb.shape[1]] = Vb
                pid[b, :pb.size] = pb
            self.levels.append((rows, cols, U, V, pid))
            self.block_spans.append([(r[0], r[1] - r[0], c[0], c[1] - c[0])
                                     for r, c in blocks])
            self.stored += U.size + V.size
            self.ranks.append(int(max(U.shape[1] for U, _, _ in factors)))

    @staticmethod
    def _compress(parts, tols, order, rows, cols):
        """The stacked truncated SVDs of one off-diagonal block of every part:
        ``(U, V, part)``, shapes ``(m_r, k)``, ``(k, m_c)``, ``(k,)``."""
        ir, ic = order[rows[0]:rows[1]], order[cols[0]:cols[1]]
        Us, Vs, pid = [], [], []
        for j, (G, tol) in enumerate(zip(parts, tols)):
            A = G[np.ix_(ir, ic)]
            if sla.norm(A) <= tol:
                continue
            u, s, vt = sla.svd(A, full_matrices=False, check_finite=False)
            k = int(np.count_nonzero(s > tol))
            Us.append(u[:, :k] * s[:k])
            Vs.append(vt[:k])
            pid.append(np.full(k, j))
        if not Us:
            return np.zeros((ir.size, 0)), np.zeros((0, ic.size)), np.zeros(0, np.int64)
        return np.hstack(Us), np.vstack(Vs), np.concatenate(pid)

    def columns(self, cols, spow: np.ndarray, rows=None, add_to=None) -> np.ndarray:
        """Columns of ``sum_p spow[p, h] G_p`` for every ``h``, read from the factors
        (``O(n k)`` a column and ``h``, no product with unit vectors); on ``rows`` only
        when given; added to ``add_to`` (returned) when given.

        The rows and columns are taken in tree order, where every block of the
        hierarchy is a contiguous range of both, so that each block adds one product
        to one slice of the result (no scattered writes: 0.66 -> 0.25 s a call for about
        540 of 960 columns and 16 combinations in a run, round 55).

        Parameters
        ----------
        cols : array_like of int, shape (m,)
        spow : ndarray, shape (len(powers), n_h)
            The factor of each kept part in each of ``n_h`` combinations.
        rows : array_like of int, shape (r,), optional
            The rows wanted (default all, in order).
        add_to : ndarray, shape (n_h, r, m), complex, optional

        Returns
        -------
        ndarray, shape (n_h, r, m), complex (``r = n`` without ``rows``)
        """
        spow = np.asarray(spow, dtype=complex)
        n, n_h = self.n, spow.shape[1]
        cols = np.asarray(cols, dtype=np.int64)
        rows = np.arange(n) if rows is None else np.asarray(rows, dtype=np.int64)
        # the rows and columns in tree order: ``tr`` and ``tc`` their tree positions
        kr = np.argsort(self.tree_pos[rows], kind="stable")
        kc = np.argsort(self.tree_pos[cols], kind="stable")
        tr, tc = self.tree_pos[rows[kr]], self.tree_pos[cols[kc]]
        # two work arrays kept for the next call (fresh ones of 130 MB each cost more in
        # page faults than their use: 0.75 against 0.22 s in a run at 480 points)
        size = n_h * rows.size * cols.size
        if self._work is None or self._work.shape[1] < size:
            self._work = np.empty((2, size), dtype=complex)
        out = self._work[0, :size].reshape(n_h, rows.size, cols.size)
        out.fill(0.0)

        def span(t, lo, width):
            return int(np.searchsorted(t, lo)), int(np.searchsorted(t, lo + width))
        P, m = len(self.powers), self.leaf_idx.shape[1]
        for leaf, (lo, width) in enumerate(self.leaf_span):
            r0, r1 = span(tr, lo, width)
            c0, c1 = span(tc, lo, width)
            if r0 == r1 or c0 == c1:
                continue
            Dl = self.D[leaf].reshape(P, m, m)[:, tr[r0:r1] - lo][:, :, tc[c0:c1] - lo]
            out[:, r0:r1, c0:c1] += np.tensordot(spow, Dl, axes=(0, 0))
        for (_, _, U, V, pid), spans in zip(self.levels, self.block_spans):
            for b, (rlo, rsize, clo, csize) in enumerate(spans):
                r0, r1 = span(tr, rlo, rsize)
                c0, c1 = span(tc, clo, csize)
                if r0 == r1 or c0 == c1:
                    continue
                # (k, n_h, c) complex as real (k, 2 n_h c): one real product
                Vz = np.ascontiguousarray(     # (one harmonic's may come out transposed)
                    V[b][:, tc[c0:c1] - clo][:, None, :] * spow[pid[b]][:, :, None])
                Y = (U[b][tr[r0:r1] - rlo] @ Vz.view(float).reshape(Vz.shape[0], -1))
                out[:, r0:r1, c0:c1] += Y.view(complex).reshape(r1 - r0, n_h, c1 - c0) \
                    .transpose(1, 0, 2)
        # back to the order asked, by one gather along a flat axis (0.05 s, against 0.4 s
        # for a gather along each axis in turn)
        ir, ic = np.empty_like(kr), np.empty_like(kc)
        ir[kr], ic[kc] = np.arange(kr.size), np.arange(kc.size)
        flat = (ir[:, None] * ic.size + ic[None, :]).ravel()
        if add_to is None:
            return np.take(out.reshape(n_h, -1), flat, axis=1).reshape(out.shape)
        back = self._work[1, :size].reshape(n_h, -1)
        np.take(out.reshape(n_h, -1), flat, axis=1, out=back, mode="clip")   # (unbuffered)
        add_to += back.reshape(out.shape)
        return add_to

    @property
    def leaves(self) -> np.ndarray:
        """The parts' dense leaf blocks, shape (n_leaves, len(powers), m, m) (a view)."""
        L, m = self.leaf_idx.shape
        return self.D.reshape(L, len(self.powers), m, m)

    @property
    def compression(self) -> float:
        """Stored numbers over the dense parts' ``len(powers) n^2``."""
        return self.stored / max(len(self.powers) * self.n ** 2, 1)

    def apply(self, X: np.ndarray, spow: np.ndarray) -> np.ndarray:
        """``sum_p spow[p, j] G_p X[:, j]`` for every column ``j``.

        Parameters
        ----------
        X : ndarray, shape (n, c), complex
        spow : ndarray, shape (len(powers), c)
            The factor of each kept part (:attr:`powers`) in each column: ``s_j^p``.

        Returns
        -------
        ndarray, shape (n, c), complex
        """
        n, c = X.shape
        complex_s = np.iscomplexobj(spow)
        s2 = None if complex_s else np.concatenate([spow, spow], axis=1)
        Xe = np.zeros((n + 1, 2 * c))
        Xe[:n, :c], Xe[:n, c:] = X.real, X.imag
        out = np.zeros((n + 1, 2 * c))

        def scaled(T, pid):
            # T (blocks, k, 2c) real: row i of block b times s^pid[b, i] per column
            if not complex_s:
                return T * s2[pid]
            Tz = (T[..., :c] + 1j * T[..., c:]) * spow[pid]
            return np.concatenate([Tz.real, Tz.imag], axis=-1)
        L, m = self.leaf_idx.shape
        Y = (self.D @ Xe[self.leaf_idx]).reshape(L, len(self.powers), m, 2 * c)
        if complex_s:
            Yz = (Y[..., :c] + 1j * Y[..., c:]) * spow[None, :, None, :]
            Yz = Yz.sum(axis=1)
            out[self.leaf_idx] += np.concatenate([Yz.real, Yz.imag], axis=-1)
        else:
            out[self.leaf_idx] += (Y * s2[None, :, None, :]).sum(axis=1)
        for rows, cols, U, V, pid in self.levels:
            out[rows] += U @ scaled(V @ Xe[cols], pid)
        return out[:n, :c] + 1j * out[:n, c:]


class QuasiStaticForm:
    """The frequency-independent pieces of ``S_h`` for one quasi-static split of a
    low-rank condensation: the ``G_p`` as a :class:`HODLR` and the basis ``F``.

    Parameters
    ----------
    lin : ReducedLinear
        ``kind == "lowrank"`` with :attr:`~ReducedLinear.damping_factors`; its current
        split (``lin._quasi``) is the one used.
    tree : tuple
        :func:`bisection_tree` of its contact coordinates.
    """

    def __init__(self, lin, tree):
        nu_max, (low, C), high = lin._quasi
        self.nu_max = nu_max
        self.low = low
        Wq, Wy, c = lin.damping_factors
        self.c, self.Wy = c, Wy
        P = C.shape[0] - 1                    # the order of the quasi-static sums
        self.order = P
        parts = [lin.K["qq"] - C[0], -(lin.M["qq"] + C[1])] + [-C[p] for p in range(2, P + 1)]
        s_ref = nu_max * nu_max
        ref = max(sla.norm(parts[0]), sla.norm(sum(s_ref ** p * G for p, G in enumerate(parts))))
        tols = [COMPRESSION_EPS * ref / s_ref ** p for p in range(P + 1)]
        self.hodlr = HODLR(parts, tols, tree)
        # P_p: the quasi-static sums of B_0 D^-1 W_y over the modes above the split
        lam, a = lin.lam[high], lin.myy[high] / lin.lam[high]
        Kh, Mh, Wh = lin.K["qy"][:, high], lin.M["qy"][:, high], Wy[high]

        def w(p):
            return a ** p / lam if p >= 0 else np.zeros_like(lam)
        Ps = [(Kh * w(p) - Mh * w(p - 1)) @ Wh for p in range(P + 1)]
        self.F = np.hstack([Wq, lin.K["qy"][:, low], lin.M["qy"][:, low]] + Ps)
        self.r, self.n_low = c.size, low.size
        log.debug("hierarchical interface operator: %d contact coordinates, leaves of %d, "
                  "off-diagonal ranks per depth %s, %.0f %% of the dense parts' storage, "
                  "basis of %d columns, parts s^%s (nu_max %.4g rad/s)",
                  lin.n_r, self.hodlr.leaf_idx.shape[1], self.hodlr.ranks,
                  100 * self.hodlr.compression, self.F.shape[1], self.hodlr.powers, nu_max)


def _middles(form: QuasiStaticForm, lin, nus, xi: float) -> np.ndarray:
    """``M_h`` of every harmonic, shape ``(n_h, rho, rho)`` complex: the terms of
    :meth:`~jointsim.solvers.condensation.ReducedLinear.schur_low_rank_damping` beyond
    ``G(s)`` in the basis ``F`` (``F = [W_q, K_low, M_low, P_0 .. P_P]``).

    With ``Pi_h`` the coefficients of ``P_l = B_0 D^-1 W_y = F Pi_h`` and ``E`` the
    selection of ``W_q``: the low modes ``-(k - s m) (k - s m)^T / d``; ``i nu E c E^T``;
    ``-i nu (E c Pi^T + Pi c E^T)``; ``nu^2 E c Q c E^T``; ``Gamma K_c^-1 Gamma^T``
    with ``Gamma = Pi + i nu E c Q``, ``K_c = diag(1 / (i nu c)) + Q``, ``Q = W_y^T D^-1
    W_y``.  At ``nu = 0`` only the low modes (the damping terms vanish)."""
    r, nl, P = form.r, form.n_low, form.order
    rho = form.F.shape[1]
    iW, iK, iM = slice(0, r), slice(r, r + nl), slice(r + nl, r + 2 * nl)
    c, Wy, low = form.c, form.Wy, form.low
    out = np.zeros((len(nus), rho, rho), dtype=complex)
    for j, nu in enumerate(nus):
        s = nu * nu + 1j * nu * xi if xi else nu * nu
        d = lin.welded_stiffness(s)
        M = out[j]
        dl = d[low]
        M[iK, iK] -= np.diag(1.0 / dl)
        M[iK, iM] += np.diag(s / dl)
        M[iM, iK] += np.diag(s / dl)
        M[iM, iM] -= np.diag(s * s / dl)
        if nu == 0.0:
            continue
        Pi = np.zeros((rho, r), dtype=complex)
        Pi[iK] = Wy[low] / dl[:, None]
        Pi[iM] = -s * Wy[low] / dl[:, None]
        for p in range(P + 1):
            Pi[r + 2 * nl + p * r:r + 2 * nl + (p + 1) * r] = s ** p * np.eye(r)
        Q = (Wy.T / d) @ Wy
        M[iW, iW] += np.diag(1j * nu * c) + nu * nu * (c[:, None] * Q * c[None, :])
        M[iW, :] -= 1j * nu * c[:, None] * Pi.T
        M[:, iW] -= 1j * nu * Pi * c[None, :]
        Gam = Pi.copy()
        Gam[iW] += 1j * nu * c[:, None] * Q
        Kc = np.diag(1.0 / (1j * nu * c)) + Q
        M += Gam @ np.linalg.solve(Kc, Gam.T)
    return out


class InterfaceProducts:
    """``S_h x_h`` of every harmonic at one frequency through a :class:`QuasiStaticForm`
    (the same call as :meth:`~jointsim.solvers.condensation.DynamicProducts.apply`).

    Parameters
    ----------
    form : QuasiStaticForm
    lin : ReducedLinear
    nus : ndarray, shape (n_h,)
        Angular frequency of each harmonic [rad/s], at most ``form.nu_max``.
    xi : float
        Self-excitation [1/s].
    """

    def __init__(self, form: QuasiStaticForm, lin, nus, xi: float = 0.0):
        nus = np.asarray(nus, dtype=float)
        self.form = form
        s = nus * nus + 1j * nus * xi if xi else nus * nus
        self.spow = np.stack([s ** p for p in form.hodlr.powers])    # (n_kept, n_h)
        self.Mh = _middles(form, lin, nus, xi)

    def apply(self, X: np.ndarray) -> np.ndarray:
        """``S_h X[:, h, :]`` for every harmonic (``X`` and the result (n_r, n_h, k)
        complex), as :meth:`~jointsim.solvers.condensation.DynamicProducts.apply`: the
        HODLR product of ``G(s_h)`` and ``F M_h F^T`` by two thin products."""
        nr, nh, k = X.shape
        F = self.form.F
        Xc = X.reshape(nr, nh * k)
        Y = self.form.hodlr.apply(Xc, np.repeat(self.spow, k, axis=1))
        T = F.T @ np.concatenate([Xc.real, Xc.imag], axis=1)
        Tz = (T[:, :nh * k] + 1j * T[:, nh * k:]).reshape(-1, nh, k)
        Uz = (self.Mh @ Tz.transpose(1, 0, 2)).transpose(1, 0, 2).reshape(-1, nh * k)
        FU = F @ np.concatenate([Uz.real, Uz.imag], axis=1)
        Y += FU[:, :nh * k] + 1j * FU[:, nh * k:]
        return Y.reshape(nr, nh, k)


def _leaf_places(hodlr: HODLR, rows, cols):
    """``(leaf, row place, column place)`` of the entries ``(rows[k], cols[k])``, each pair
    in one leaf (an element's coordinates share a position, :func:`bisection_tree`)."""
    (lr, jr), (lc, jc) = hodlr.leaf_of[rows].T, hodlr.leaf_of[cols].T
    if np.any(lr != lc):
        raise ValueError("an entry couples two leaves of the bisection")
    return lr, jr, jc


def schur_entries(prod: InterfaceProducts, rows, cols) -> np.ndarray:
    """The entries ``S_h[rows[k], cols[k]]`` of every harmonic, shape (n_h, len(rows))
    complex, without forming ``S_h``: from the leaves of ``G(s)`` and the rows of ``F``
    (each pair within one leaf)."""
    H = prod.form.hodlr
    lf, jr, jc = _leaf_places(H, rows, cols)
    D = H.leaves[lf, :, jr, jc]                                       # (len, n_kept)
    F = prod.form.F
    return (D @ prod.spow).T + np.einsum("ka,hab,kb->hk", F[rows], prod.Mh, F[cols])


class HierarchicalInverse:
    """``P_h^-1`` of every harmonic at one frequency, ``P_h = S_h + T_h`` with ``T_h``
    local to the leaves (the harmonic projection of the element tangents), without an
    ``n_r x n_r`` array: a HODLR factorisation of ``G(s_h) + T_h`` and Woodbury's formula
    for ``F M_h F^T``.

    The HODLR factorisation (recursive Woodbury): a node ``A = diag(A_11, A_22) + W Z^T``
    with ``W = diag(U_12, U_21)`` and ``Z^T = [[0, s V_12], [s V_21, 0]]`` (its
    off-diagonal blocks, ``s`` the parts' powers) has ``A^-1 = D^-1 - D^-1 W K^-1 Z^T
    D^-1``, ``K = I + Z^T D^-1 W`` of twice the block's rank.  Built from the deepest
    level up, every level of every harmonic at once; a solve is the leaves' dense
    inverses and, per level, three batched products.  Storage and a solve's flops grow
    as ``n k log n``, the build as ``n k^2 log^2 n`` (``k`` the off-diagonal rank), not
    as ``n^2`` and ``n^3``.

    Parameters
    ----------
    prod : InterfaceProducts
        ``S_h`` at this frequency.
    entries : sequence of (rows, cols, vals)
        ``T_h``: ``vals`` (n_h, len(rows)) complex added at ``(rows[k], cols[k])``, each
        pair within one leaf.
    """

    def __init__(self, prod: InterfaceProducts, entries=()):
        self.prod, self.F = prod, None
        H = prod.form.hodlr
        spow = prod.spow                                             # (n_kept, n_h)
        nh = spow.shape[1]
        L, m = H.leaf_idx.shape
        n = self.n = H.n
        self.leaf_idx = H.leaf_idx
        A = np.einsum("ph,lpij->hlij", spow, H.leaves).astype(complex)
        pl, pj = np.nonzero(H.leaf_idx == n)                          # padding: identity
        A[:, pl, pj, pj] = 1.0
        for rows, cols, vals in entries:
            lf, jr, jc = _leaf_places(H, rows, cols)
            A[:, lf, jr, jc] += vals
        self.Linv = np.linalg.inv(A)
        self.levels = []                                              # deepest first
        flops = 8.0 * nh * L * m ** 3
        for rows, cols, U, V, pid in reversed(H.levels):
            nb, k = U.shape[0], U.shape[2]
            sV = np.moveaxis(spow[pid], -1, 0)[..., None] * V[None]  # (n_h, nb, k, m_c)
            B = np.zeros((nh, n + 1, k), dtype=complex)
            B[:, rows] = U[None]
            X = np.concatenate([self._solve(B[:, :n]), np.zeros((nh, 1, k))], axis=1)
            Kb = sV @ X[:, cols]                                      # (n_h, nb, k, k)
            Kn = np.zeros((nh, nb // 2, 2 * k, 2 * k), dtype=complex)
            Kn[..., np.arange(2 * k), np.arange(2 * k)] = 1.0
            Kn[:, :, :k, k:] = Kb[:, 0::2]
            Kn[:, :, k:, :k] = Kb[:, 1::2]
            self.levels.append((rows, cols, X[:, rows], sV, np.linalg.inv(Kn)))
            flops += k * self.apply_flops + 64.0 * nh * nb * k ** 3     # B's solve, K^-1
        # F M_h F^T in an orthonormal basis of the weighted F's range: F's columns span
        # fifty decades and depend on each other (the P_p), and Woodbury's capacitance
        # in F itself is singular to round-off (condition 1e42 on the 120-point lap
        # joint, 1e4 to 1e8 in the basis)
        g = np.sqrt(np.abs(prod.Mh).max(axis=(0, 2)))                 # (rho,)
        on = np.flatnonzero(g > 0)
        U, sv, Vt = np.linalg.svd(prod.form.F[:, on] * g[on], full_matrices=False)
        k = sv > BASIS_EPS * sv[0] if sv.size else np.zeros(0, bool)
        F, B = U[:, k], sv[k, None] * Vt[k] / g[on]                 # F[:, on] = U B
        M = B @ prod.Mh[:, on[:, None], on] @ B.T
        self.F = F
        HF = self._solve(np.broadcast_to(F, (nh,) + F.shape))         # (n_h, n, rho)
        rho = F.shape[1]
        self.HF = HF
        # (H + F M F^T)^-1 = H^-1 - H^-1 F (I + M F^T H^-1 F)^-1 M F^T H^-1
        self.CapM = np.linalg.solve(np.eye(rho) + M @ (F.T @ HF), M)
        self.build_flops = flops + rho * self.apply_flops + 8.0 * nh * (2 * n * rho * rho
                                                                        + 2 * rho ** 3)

    @property
    def apply_flops(self) -> float:
        """Real flops of one solve of one column (every harmonic)."""
        nh, L, m = self.Linv.shape[0], self.Linv.shape[1], self.Linv.shape[2]
        per = L * m * m + sum(2 * X.shape[1] * X.shape[2] * X.shape[3]
                              + Ki.shape[1] * Ki.shape[2] ** 2
                              for _, _, X, _, Ki in self.levels)
        if self.F is not None:
            per += 2 * self.n * self.F.shape[1] + self.F.shape[1] ** 2
        return 8.0 * nh * per

    def _solve(self, Y: np.ndarray) -> np.ndarray:
        """``H_h^-1 Y[h]`` (``H_h = G(s_h) + T_h``) by the levels built so far."""
        nh, n, c = Y.shape
        Ye = np.zeros((nh, n + 1, c), dtype=complex)
        Ye[:, :n] = Y
        Ye[:, self.leaf_idx] = self.Linv @ Ye[:, self.leaf_idx]
        for rows, cols, X, sV, Kinv in self.levels:
            T = sV @ Ye[:, cols]                                      # (n_h, nb, k, c)
            nb, k = T.shape[1], T.shape[2]
            u = Kinv @ T.reshape(nh, nb // 2, 2 * k, c)
            Ye[:, rows] -= X @ u.reshape(nh, nb, k, c)
        return Ye[:, :n]

    def solve(self, Y: np.ndarray) -> np.ndarray:
        """``P_h^-1 Y[h]`` for every harmonic; ``Y`` (n_h, n_r, k) complex."""
        out = self._solve(Y)
        out -= self.HF @ (self.CapM @ (self.F.T @ out))
        return out


class InterfaceHierarchy:
    """The hierarchical ``S_h`` of one condensation, kept across frequencies: the
    :func:`bisection_tree` of its coordinates (``lin.positions``) and the
    :class:`QuasiStaticForm` of its current quasi-static split (made again when the
    split changes).  One per condensation, shared by the systems that share it
    (:meth:`of`).

    Parameters
    ----------
    lin : ReducedLinear
    """

    _of = weakref.WeakKeyDictionary()

    def __init__(self, lin):
        self.lin = lin
        self.tree = bisection_tree(lin.positions, LEAF_ROWS)
        self._form = None

    @classmethod
    def of(cls, lin) -> "InterfaceHierarchy | None":
        """The hierarchy of ``lin`` (made on first use), or None where it does not apply:
        no positions, not a low-rank condensation with its damping's factors, or fewer
        than :data:`HIERARCHICAL_MIN_ROWS` contact coordinates."""
        if (lin.positions is None or lin.kind != "lowrank" or not lin.n_y
                or lin.n_r < HIERARCHICAL_MIN_ROWS or lin.damping_factors is None):
            return None
        got = cls._of.get(lin)
        if got is None:
            got = cls._of[lin] = cls(lin)
        return got

    def products(self, nus, xi: float = 0.0):
        """:class:`InterfaceProducts` at the harmonics' frequencies ``nus`` [rad/s], or
        None where the quasi-static split does not apply (fewer than half the welded
        modes far above the highest harmonic)."""
        lin = self.lin
        nus = np.asarray(nus, dtype=float)
        top = float(nus.max(initial=0.0))
        if top == 0.0:
            return None
        if lin._quasi_static(float(np.sqrt(abs(top * top + 1j * top * xi)))) is None:
            return None
        if self._form is None or self._form.nu_max != lin._quasi[0]:
            self._form = QuasiStaticForm(lin, self.tree)
        return InterfaceProducts(self._form, lin, nus, xi)
