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

The Krylov path uses it for ``J v`` from :data:`HIERARCHICAL_MIN_ROWS` contact
coordinates on (:attr:`~jointsim.solvers.frequency_blocks.FrequencyBlocks.hierarchical`).
``J v`` is then the only approximate quantity, within ``COMPRESSION_EPS`` of ``||G||``.
The residual and its derivatives stay exact (``DynamicProducts``), and the
preconditioner stays formed, so the error only perturbs Newton's direction.
"""
from __future__ import annotations

import logging
import weakref

import numpy as np
import scipy.linalg as sla

log = logging.getLogger(__name__)

#: Contact coordinates from which ``J v`` goes through :class:`InterfaceProducts`
#: (measured in ``benchmarks/scale.py``, round 38; below it :class:`DynamicProducts`,
#: which reads every array once, is as fast).
HIERARCHICAL_MIN_ROWS = 400
#: Largest leaf of the bisection [contact coordinates]; its diagonal block is dense.
LEAF_ROWS = 128
#: Truncation of the off-diagonal blocks, relative to ``||G(s)||_F`` over the split's
#: frequencies.
COMPRESSION_EPS = 1e-12


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
        """``S_h X[:, h, :]`` for every harmonic ``h``.

        Parameters
        ----------
        X : ndarray, shape (n_r, n_h, k), complex

        Returns
        -------
        ndarray, shape (n_r, n_h, k), complex
        """
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
