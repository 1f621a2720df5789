"""The linear structure condensed onto the contact coordinates.

The contact forces depend on ``x`` only through ``q = T x``, the stacked
tangential slips ``Tt x`` (when there is friction) and normal gap changes
``Tn x`` (when the normal load is coupled), ``n_r`` rows of full rank.  With ``Psi = T^T (T T^T)^-1`` (so
``T Psi = I``) and ``Z`` an orthonormal basis of the null space of ``T``
(``T Z = 0``), every ``x = Psi q + Z y``, and ``[Psi Z]^T T^T = [I; 0]``, so
that per harmonic

    [A  B ] [q]   [F_q - phi_h(q)]        A = Psi^T D Psi, B = Psi^T D Z,
    [B' E ] [y] = [F_y           ]        B' = Z^T D Psi,  E = Z^T D Z,

with ``phi = (f_t, -N)`` the element forces in the contact coordinates.  The
``y`` equations are linear and are eliminated per harmonic:

    S_h(w) q_h + phi_h(q) = F_q - B E^-1 F_y,     S_h = A - B E^-1 B'

(a dynamic Schur complement; ``y = E^-1 (F_y - B' q)`` rebuilds ``x``).  The
Newton unknowns are the ``n_coeff x n_r`` harmonic coefficients of ``q`` only:
one slip (and one gap) per contact element, whatever the number of structural
DOFs.  ``Z`` is chosen M-orthonormal and K-orthogonal (the modes of the
structure with the contact coordinates held at zero), so ``E`` is diagonal
when the damping is too (Rayleigh, or modal in these modes); when the damping
has low rank (modal damping of a few modes of another basis, e.g. of the
stuck joint) ``E`` is a diagonal plus a rank-r term and is inverted by
Woodbury's formula (an r x r solve); otherwise ``E`` is factorised per
harmonic.  ``E`` is singular only at an undamped resonance of the structure
with the contacts *welded* (``q = 0``); with damping it is not, and the
formulation is exact (the linear FRF is reproduced to round-off).

The coordinates and the blocks of ``K``, ``M`` and ``C`` in them are made once per
model by :mod:`jointsim.solvers.welded`.  The harmonic balance built on it is
:mod:`jointsim.solvers.hbm`.
"""
from __future__ import annotations

import functools
import logging

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from ..linalg import real_times
from .flexibility import modes_of
from .welded import low_rank_factors, orthonormal_factors, welded_coordinates

log = logging.getLogger(__name__)


#: Why ``E`` (the structure with its contact coordinates held) has no inverse.
WELDED_SINGULAR = ("the structure with welded contacts is singular at this frequency (an "
                   "undamped resonance or an unrestrained rigid-body motion)")
#: Above this many structural DOFs the dense condensation is refused.
MAX_DENSE_DOF = 6000
#: In ``S_h`` with a damping of low rank (:meth:`ReducedLinear.schur_low_rank_damping`)
#: the modes of the welded structure above this many times the harmonic's frequency
#: enter by a Taylor expansion in ``s = nu^2`` to ``s^QUASI_STATIC_ORDER``, summed once
#: (:meth:`ReducedLinear._b_dinv_bp`): their relative remainder is of order ``(nu /
#: w)^8``, below 1.5e-12 (measured in docs/hbm.md, round 32).  0: the full ``n_r x n_y
#: x n_r`` product.
QUASI_STATIC_RATIO = 30.0
QUASI_STATIC_ORDER = 3
#: Up to this many structural DOFs the direct path forms the linear part of every
#: harmonic at once (:attr:`~jointsim.solvers.frequency_blocks.FrequencyBlocks.stacked`): the lumped models, whose
#: per-harmonic blocks of a few numbers cost more in calls than in arithmetic.
STACKED_MAX_DOF = 64


def dense_array(A):
    """``A`` (array or sparse matrix) as a dense float array."""
    return np.asarray(A.toarray() if hasattr(A, "toarray") else A, dtype=float)


class ReducedLinear:
    """The linear structure seen from the contact coordinates ``q = T x``.

    Parameters
    ----------
    M, K, C : array or sparse, shape (n, n)
        Mass, stiffness and damping of the linear part.
    T : array or sparse, shape (n_r, n)
        Contact coordinates (full row rank).
    K_stuck : array or sparse, shape (n, n), optional
        The stiffness with the joint stuck at its static state
        (:attr:`jointsim.solvers.static.StuckLinearisation.K`): gives
        :attr:`flexibility`.
    positions : ndarray, shape (n_r, d), optional
        Position of every contact coordinate [m]: orders them for the hierarchical
        form of ``S_h`` (:mod:`jointsim.solvers.hierarchical`).
    stuck_modes : tuple (lam, phi), optional
        Every mode of ``(K_stuck, M)`` if already made (the model's, for its modal
        damping): kept as ``self.stuck_modes`` where they are those modes
        (:func:`~jointsim.solvers.flexibility.modes_of`), and then :attr:`flexibility`
        takes them instead of decomposing the stuck structure again.

    Attributes
    ----------
    T_sparse : scipy.sparse.csr_matrix, shape (n_r, n)
        ``T``.
    damping_low_rank : tuple (W, c) or None
        ``C = W diag(c) W^T`` (``W`` (n, r), ``c`` (r,) [N s/m]) when ``C`` is symmetric
        and of rank ``r < 64`` (modal damping of a few modes, or none) and the structure
        has both kinds of coordinates; the modal and low-rank kinds make C's blocks from
        them (``O(n^2 r)``, not ``n^3``: 0.7 s less at 480 Gauss points, round 43).

    See the module docstring for the formulation.
    """

    def __init__(self, M, K, C, T, K_stuck=None, positions=None, stuck_modes=None):
        self.positions = positions
        self.T_sparse = sp.csr_matrix(T)
        self.stuck_modes = stuck_modes if stuck_modes is not None and K_stuck is not None \
            and modes_of(stuck_modes, K_stuck, M) else None
        if stuck_modes is not None and self.stuck_modes is None:
            log.debug("the given stuck modes are not those of (K_stuck, M): not used")
        # what the stuck joint adds to K (sparse: its contact DOFs; from sparse inputs
        # without a dense copy of K_stuck)
        self._dK = None
        if K_stuck is not None:
            self._dK = (sp.csr_matrix(K_stuck) - sp.csr_matrix(K)) if sp.issparse(K_stuck) \
                and sp.issparse(K) else sp.csr_matrix(dense_array(K_stuck) - dense_array(K))
            self._dK.eliminate_zeros()
        M, K, C, T = dense_array(M), dense_array(K), dense_array(C), dense_array(T)
        n = M.shape[0]
        if n > MAX_DENSE_DOF:
            raise NotImplementedError(
                f"the harmonic balance condenses the structure densely and the model has {n} "
                f"DOFs (> {MAX_DENSE_DOF}); reduce it first (Craig-Bampton)")
        n_r = T.shape[0]
        self.n, self.n_r, self.n_y = n, n_r, n - n_r
        wc = welded_coordinates(M, K, C, T)
        self.kind, self.Psi, self.Z = wc.kind, wc.Psi, wc.Z
        self.K, self.M, self.C = wc.K, wc.M, wc.C
        self.damping_low_rank = wc.damping_low_rank
        self.modal = self.kind == "modal"
        lowrank = wc.lowrank
        if self.kind in ("modal", "lowrank"):
            self.lam = np.diag(self.K["yy"]).copy()
            self.myy = np.diag(self.M["yy"]).copy()
            self.cyy = np.diag(self.C["yy"]).copy() if self.modal else None
        if self.kind == "lowrank":
            self.U, self.cw = lowrank
            self.Cyy = self.C["yy"]
        if self.kind in ("modal", "lowrank") and n_r and self.n_y:
            # K, M, C side by side for the products of every harmonic at once
            # (:class:`DynamicProducts`)
            # rows: K, M, C of the qq blocks, then of the yq blocks (one product gives
            # A X and B' X); columns: K, M, C of the qy blocks.  A damping of low rank
            # enters by its factors instead (KMC_lowc, DynamicProducts): a third fewer
            # flops per product
            lowc = self.damping_factors if self.kind == "lowrank" else None
            kinds = ("K", "M") if lowc is not None else ("K", "M", "C")
            mats = {"K": self.K, "M": self.M, "C": self.C}
            self.KMC_q = np.vstack([mats[m]["qq"] for m in kinds]
                                   + [mats[m]["yq"] for m in kinds])
            self.KMC_qy = np.hstack([mats[m]["qy"] for m in kinds])
            #: the damping's factors ``(W_q, W_y, c)`` when ``KMC_q`` and ``KMC_qy`` leave
            #: it out
            self.KMC_lowc = lowc
        self._Mfull = M
        self._transformed = None
        self._quasi = None       # (nu_max, split, quasi-static modes) of _quasi_static

    # -- blocks of the transformed dynamic stiffness --------------------------
    def blocks(self, nu: float, xi: float = 0.0, parts: str = "qq qy yq"):
        """``A, B, B', E`` at angular frequency ``nu`` with damping ``C - xi M``.

        ``E`` is a 1-D array (its diagonal) when the condensation is modal, a
        :class:`_LowRankE` when the damping is of low rank, else a matrix.
        ``parts`` names the blocks of ``A, B, B'`` that are formed (the others are
        returned as None): rebuilding ``x`` from ``q`` needs only ``B'`` and ``E``.
        """
        def mat(b):
            # (K - nu^2 M) + i nu (C - xi M), written into one complex array: the same
            # numbers as that expression (bit for bit) without its five temporaries
            # (1.8x faster on the 121-pair lap joint's 242 x 282 blocks)
            out = np.empty(self.K[b].shape, dtype=complex)
            re, im = out.real, out.imag
            np.multiply(self.M[b], -nu * nu, out=re)
            re += self.K[b]
            np.multiply(self.M[b], -xi, out=im)
            im += self.C[b]
            im *= nu
            return out
        A, B, Bp = (mat(b) if b in parts else None for b in ("qq", "qy", "yq"))
        if self.kind == "modal":
            E = (self.lam - nu * nu * self.myy) + 1j * nu * (self.cyy - xi * self.myy)
        elif self.kind == "lowrank":
            E = _LowRankE((self.lam - nu * nu * self.myy) - 1j * nu * xi * self.myy,
                          1j * nu * self.cw, self.U)
        else:
            E = mat("yy")
        return A, B, Bp, E

    @functools.cached_property
    def flexibility(self):
        """The stuck joint's flexibility on the contact coordinates
        (:class:`~jointsim.solvers.flexibility.StuckFlexibility`: ``(S_h + diag(k))^-1`` of
        every harmonic without an inverse), or None (no ``K_stuck`` given, or it does not
        apply); made on first use."""
        if self._dK is None:
            return None
        from .flexibility import StuckFlexibility
        return StuckFlexibility.of(self, self._dK)

    @functools.cached_property
    def damping_factors(self):
        """``(W_q, W_y, c)`` with ``C = W diag(c) W^T`` in the coordinates ``(q, y)``
        (``W = [W_q; W_y]``, ``c`` (r,)) for a low-rank condensation with both kinds of
        coordinates, else None (:func:`~.welded.low_rank_factors`; found on first use: only a
        forced response's :meth:`schur_low_rank_damping` needs them)."""
        if self.kind != "lowrank" or not self.n_r or not self.n_y:
            return None
        if self.damping_low_rank is not None:
            W, c = self.damping_low_rank
            Wv, c = orthonormal_factors(np.vstack([self.Psi.T @ W, self.Z.T @ W]), c)
            return np.ascontiguousarray(Wv[:self.n_r]), np.ascontiguousarray(Wv[self.n_r:]), c
        C = self.C
        return low_rank_factors(np.block([[C["qq"], C["qy"]], [C["yq"], C["yy"]]]), self.n_r)

    def schur_low_rank_damping(self, nu: float, xi: float = 0.0) -> np.ndarray:
        """``S_h = A - B E^-1 B'`` at ``nu`` for a damping of low rank
        (:attr:`damping_factors` set).

        With ``s = nu^2 + i nu xi`` (``nu^2`` for a forced response), the damping of rank
        ``r`` (``C = W diag(c) W^T``, ``W = [W_q; W_y]``) is what couples the blocks
        beyond their diagonal in the welded modes: ``B = B_0 + i nu W_q c W_y^T``, ``E =
        D + i nu W_y c W_y^T`` with ``B_0 = K_qy - s M_qy`` and ``D = diag(lam - s m_yy)``.
        Woodbury's formula for ``E^-1`` then gives

            S_h = A_0 + i nu C_qq - B_0 D^-1 B'_0 - i nu (W_q c P_r + P_l c W_q^T)
                  + nu^2 W_q c Q c W_q^T + G_l K_c^-1 G_r,

        ``A_0 = K_qq - s M_qq``, ``P_l = B_0 D^-1 W_y``, ``P_r = W_y^T D^-1 B'_0``, ``Q =
        W_y^T D^-1 W_y``, ``G_l = P_l + i nu W_q c Q``, ``G_r = P_r + i nu Q c W_q^T`` and
        ``K_c = (i nu c)^-1 + Q``: one ``n_r x n_y x n_r`` product ``B_0 D^-1 B'_0`` (real
        for a forced response, a quarter of the flops of the complex one; with its
        quasi-static modes summed once, :meth:`_b_dinv_bp`) and products of rank ``r``.
        Equal to the complex blocks' to round-off (``tests/solvers/test_condensation.py``).
        No complex array of ``B_0``'s size is formed, and the sums are made in place
        (round 42: three (n_r, n_y) and four (n_r, n_r) complex temporaries less; the
        EPMC at 240 Gauss points 40.4 and 41.7 s -> 37.8 and 39.1 s, the same path).

        Parameters
        ----------
        nu : float
            Angular frequency of the harmonic [rad/s].
        xi : float
            Self-excitation (damping ``C - xi M``) [1/s].

        Returns
        -------
        ndarray, shape (n_r, n_r), complex [N/m]
        """
        Wq, Wy, c = self.damping_factors
        s = nu * nu + 1j * nu * xi if xi else nu * nu
        d = self.welded_stiffness(s)
        S = self._b_dinv_bp(s, d).astype(complex, copy=False)
        # S = A_0 + i nu C_qq - B_0 D^-1 B'_0, in place (no (n_r, n_r) temporary of
        # complex numbers: their pages, faulted in on every call, cost more than the sums)
        np.negative(S, out=S)
        S.real += self.K["qq"]
        S.real -= s.real * self.M["qq"]
        if xi:
            S.imag -= s.imag * self.M["qq"]
        S.imag += nu * self.C["qq"]
        if nu == 0.0:
            return S
        # the rank-r terms: P_l = B_0 D^-1 W_y and P_r = W_y^T D^-1 B'_0 from real
        # products with W_y / d, whose real and imaginary parts are the columns of a real
        # view (B_0, B'_0 are never formed: (n_r, n_y) complex arrays)
        Wdy = np.ascontiguousarray(Wy / d[:, None])                 # (n_y, r)
        Pl = real_times(self.K["qy"], Wdy) - s * real_times(self.M["qy"], Wdy)
        Pr = (real_times(self.K["yq"].T, Wdy) - s * real_times(self.M["yq"].T, Wdy)).T
        Q = Wdy.T @ Wy
        Wc = Wq * c                                      # (n_r, r)
        WcQ = Wc @ Q
        Gl = Pl + 1j * nu * WcQ
        Gr = Pr + 1j * nu * WcQ.T
        Kc = np.diag(1.0 / (1j * nu * c)) + Q
        # the rank-r terms as one product: [-i nu Wc, -i nu Pl, nu^2 Wc Q, Gl] times
        # [Pr; Wc^T; Wc^T; Kc^-1 Gr]
        left = np.hstack([-1j * nu * Wc, -1j * nu * Pl, nu * nu * WcQ, Gl])
        right = np.vstack([Pr, Wc.T, Wc.T, np.linalg.solve(Kc, Gr)])
        S += left @ right
        return S

    def welded_stiffness(self, s) -> np.ndarray:
        """``D = lam - s m_yy`` (n_y,) of a modal or low-rank condensation: the diagonal of
        ``E`` without its damping at ``s = nu^2 + i nu xi``; raises ``LinAlgError`` where
        it vanishes (``WELDED_SINGULAR``)."""
        d = self.lam - s * self.myy
        if np.any(d == 0):
            raise np.linalg.LinAlgError(WELDED_SINGULAR)
        return d

    def _b_dinv_bp(self, s, d) -> np.ndarray:
        """``B_0 D^-1 B'_0`` at ``s = nu^2 + i nu xi`` (``n_r x n_r``, real when ``s`` is;
        ``d`` the diagonal of ``D = diag(lam - s m_yy)``, :meth:`welded_stiffness`): a sum
        over the modes ``j`` of the welded structure of ``b_j b'_j / d_j``, with ``b_j = k_j
        - s m_j`` (the columns of ``B_0 = K_qy - s M_qy``, the rows of ``B'_0 = K_yq - s
        M_yq``).

        A mode far above ``nu`` is quasi-static: with ``a_j = m_j / lam_j`` and ``x = s a_j``,
        ``b_j b'_j / d_j = (k k' - s (k m' + m k') + s^2 m m') (1 + x + x^2 + ...) / lam_j``,
        so the modes above ``QUASI_STATIC_RATIO nu`` enter as ``sum_p s^p C_p``, ``p <=
        QUASI_STATIC_ORDER`` (their sums, :meth:`_quasi_static`, formed once), and only the
        others by the product (only their columns of ``B_0`` are formed: 52 of 1,004 at
        480 Gauss points, 16 harmonics): the neglected terms are of order ``x^(P+1)`` of
        the modes' share, ``x <= 1 / QUASI_STATIC_RATIO^2``.  The full product where that
        leaves fewer than half the modes quasi-static (``nu = |s|^(1/2)`` there)."""
        split = self._quasi_static(float(np.sqrt(abs(s))))
        if split is None:
            low, acc = slice(None), None
        else:
            low, C = split
            acc = C[-1].astype(np.result_type(C, s))     # complex when s is
            for Cp in C[-2::-1]:                       # Horner in s
                acc *= s
                acc += Cp
        b = self.K["qy"][:, low] - s * self.M["qy"][:, low]
        bp = self.K["yq"][low] - s * self.M["yq"][low]
        low_part = (b / d[low]) @ bp
        if acc is None:
            return low_part
        acc += low_part
        return acc

    def _quasi_static(self, nu: float):
        """``(low, C)`` for :meth:`_b_dinv_bp` at ``nu``, or None: ``low`` the modes below
        ``QUASI_STATIC_RATIO nu_max``, ``C`` (P + 1, n_r, n_r) the quasi-static sums of the
        others (:meth:`_quasi_sums`).

        Kept for one ``nu_max`` (``2 nu`` when it is made), valid for every frequency up
        to it: a run's first harmonics raise it a few times.  The quasi-static modes
        only become fewer as it rises: the sums lose the modes that leave them (a few
        each time) instead of being formed again."""
        q = self._quasi
        if q is not None and nu <= q[0]:
            return q[1]
        nu_max = 2.0 * nu
        split, high = None, None
        if QUASI_STATIC_RATIO > 0 and self.n_r and self.n_y and nu > 0:
            high = self.lam >= (QUASI_STATIC_RATIO * nu_max) ** 2 * self.myy
            if 2 * np.count_nonzero(high) >= self.n_y:
                if q is not None and q[1] is not None:      # fewer quasi-static modes
                    C = q[1][1]
                    C -= self._quasi_sums(q[2] & ~high)
                else:
                    C = self._quasi_sums(high)
                split = (np.flatnonzero(~high), C)
        self._quasi = (nu_max, split, high)
        return split

    def _quasi_sums(self, modes) -> np.ndarray:
        """``C_p = sum_j (a^p k k' - a^(p-1) (k m' + m k') + a^(p-2) m m') / lam`` over the
        ``modes`` (boolean, (n_y,)), ``p = 0..QUASI_STATIC_ORDER`` (no negative powers;
        ``a = m_yy / lam``, ``k``, ``m`` the columns of ``K_qy``, ``M_qy``, ``k'``, ``m'`` the
        rows of ``K_yq``, ``M_yq``): per ``p`` one product ``[K w_p - M w_(p-1), M w_(p-2) -
        K w_(p-1)] [K'; M']``, shape (P + 1, n_r, n_r)."""
        lam, a = self.lam[modes], self.myy[modes] / self.lam[modes]
        K, M = self.K["qy"][:, modes], self.M["qy"][:, modes]
        right = np.vstack([self.K["yq"][modes], self.M["yq"][modes]])

        def w(p):
            return a ** p / lam if p >= 0 else np.zeros_like(lam)
        C = np.empty((QUASI_STATIC_ORDER + 1, self.n_r, self.n_r))
        for p in range(QUASI_STATIC_ORDER + 1):
            C[p] = np.hstack([K * w(p) - M * w(p - 1), M * w(p - 2) - K * w(p - 1)]) @ right
        return C

    @property
    def transformed(self) -> tuple:
        """``(K, M, C)`` in the coordinates ``(q, y)``, whole, real ``n x n`` (made once:
        the stacked blocks of a small structure, :meth:`~jointsim.solvers.frequency_blocks.FrequencyBlocks.stacked`)."""
        if self._transformed is None:
            self._transformed = tuple(np.block([[X["qq"], X["qy"]], [X["yq"], X["yy"]]])
                                      for X in (self.K, self.M, self.C))
        return self._transformed

    def block_times(self, b: str, nu: float, xi: float, v, transpose: bool = False):
        """``D_b v`` (``D_b^T v`` with ``transpose``) for the block ``b`` (``"qq"``,
        ``"qy"``, ``"yq"`` or ``"yy"``) of ``D = (K - nu^2 M) + i nu (C - xi M)`` and a
        complex vector ``v``, by real products with ``K``, ``M`` and ``C``: the complex
        block (:meth:`blocks`) is not formed.  The EPMC's amplitude condition
        (:meth:`~jointsim.solvers.epmc.EPMCSystem._modal`) at each new frequency: at 480
        Gauss points forming ``A``, ``B``, ``B'`` of harmonic 1 cost 0.07 s an evaluation
        (round 48)."""
        Kv, Mv, Cv = self._real_product(b, v, (self.K, self.M, self.C), transpose)
        return (Kv - nu * nu * Mv) + 1j * nu * (Cv - xi * Mv)

    def _real_product(self, b: str, v, mats=None, transpose: bool = False) -> tuple:
        """``(M_b v, C_b v)`` (or of the blocks ``b`` of ``mats``, transposed with
        ``transpose``) for a complex ``v`` by real products (the complex form of a real
        matrix is never made)."""
        V = np.ascontiguousarray(v, dtype=complex)[:, None]
        return tuple(real_times(X[b].T if transpose else X[b], V)[:, 0]
                     for X in ((self.M, self.C) if mats is None else mats))

    def dproducts(self, nu: float, xi: float, wrt: str, h: int, q, y, parts: str = "q y"):
        """Derivatives of the blocks' products with respect to ``omega`` (``nu = h omega``)
        or ``xi``: ``(dA q + dB y, dB' q + dE y)``.

        ``dD/domega = h (-(2 nu + i xi) M + i C)``, ``dD/dxi = -i nu M``
        (:func:`_dD_coefficients`) applied by real products (cheaper than complex blocks).

        Parameters
        ----------
        nu, xi : float
            Angular frequency of the harmonic [rad/s] and self-excitation [1/s].
        wrt : str
            ``"omega"`` or ``"xi"``.
        h : int
            The harmonic (``nu = h omega``).
        q : ndarray, shape (n_r,), complex
        y : ndarray, shape (n_y,), complex
        parts : str
            ``"q"``: the first product only (None for the second), ``"y"``: the second
            only, ``"q y"``: both.

        Returns
        -------
        dq, dy : ndarray (complex) or None
            Shapes (n_r,) and (n_y,).
        """
        cm, cc = _dD_coefficients(wrt, h, nu, xi)

        def d(b, v):
            Mv, Cv = self._real_product(b, v)
            return cm * Mv + cc * Cv
        dq = dy = None
        if "q" in parts:
            dq = d("qq", q) + (d("qy", y) if self.n_y else 0.0)
        if "y" in parts and self.n_y:
            dy = d("yq", q) + d("yy", y) if self.kind == "direct" else \
                d("yq", q) + self._dE_diag(cm, cc, y)
        return dq, dy

    def _dE_diag(self, cm, cc, y):
        """``dE y`` of a modal or low-rank ``E`` (``cm M_yy + cc C_yy`` applied to ``y``)."""
        out = cm * self.myy * y
        if cc == 0.0:
            return out
        if self.kind == "modal":
            return out + cc * self.cyy * y
        return out + cc * (self.Cyy @ y)

    def solve_E(self, E, rhs, trans: bool = False):
        """``E^-1 rhs`` (``E^-T rhs`` with ``trans``) for diagonal (1-D), low-rank,
        full or factorised (:meth:`factor_E`) ``E``."""
        if isinstance(E, _LowRankE):
            return E.solve(rhs)          # E is complex symmetric: E^T = E
        if isinstance(E, tuple):
            return sla.lu_solve(E, rhs, trans=1 if trans else 0, check_finite=False)
        if trans and E.ndim == 2:
            E = E.T
        if E.ndim == 1:
            if np.any(E == 0):
                raise np.linalg.LinAlgError(WELDED_SINGULAR)
            return rhs / (E[:, None] if rhs.ndim == 2 else E)
        return np.linalg.solve(E, rhs)

    def factor_E(self, E):
        """``E`` prepared for several :meth:`solve_E` calls (LU of a full ``E``)."""
        if isinstance(E, _LowRankE):
            E.factor()
            return E
        if E.ndim == 1 or E.shape[0] == 0:
            return E
        return sla.lu_factor(E, check_finite=False)


class DynamicProducts:
    """``S_h x_h`` for every harmonic at once, without forming ``S_h`` or the complex
    blocks ``A_h``, ``B_h``, ``B'_h``.

    With ``D(nu) = K + c_M M + c_C C`` (``c_M = -nu^2 - i nu xi``, ``c_C = i nu``)
    every block is a combination of the real ``K``, ``M``, ``C`` blocks, shared by the
    harmonics; so ``A X``, ``B' X`` and ``B Y`` for the columns of all harmonics are
    two real BLAS-3 products with the stacked ``K``, ``M``, ``C`` (read once), and
    ``E^-1`` is diagonal (modal) or diagonal plus rank ``r`` (Woodbury, the ``r x r``
    inverse of :class:`_LowRankE` per harmonic, made here once).  Per product this reads
    the real ``K``, ``M`` (and ``C``, or its low-rank factors) once instead of, per
    harmonic, three complex blocks (docs/hbm.md: 1.1 to 1.7 ms against 3.0 ms at 96
    Gauss points).  Only for a modal or low-rank condensation (``ReducedLinear.kind``).

    Parameters
    ----------
    lin : ReducedLinear
    nus : ndarray, shape (n_h,)
        Angular frequency of each harmonic, ``h omega`` [rad/s].
    xi : float
        Self-excitation (damping ``C - xi M``) [1/s].
    """

    def __init__(self, lin: ReducedLinear, nus, xi: float = 0.0):
        if not hasattr(lin, "KMC_q"):
            raise ValueError("DynamicProducts needs a modal or low-rank condensation")
        nus = np.asarray(nus, dtype=float)
        self.lin = lin
        self.cm = -nus * nus - 1j * nus * xi
        self.cc = 1j * nus
        d = lin.lam[:, None] + lin.myy[:, None] * self.cm[None, :]     # (n_y, n_h)
        self.W = None
        if lin.kind == "modal":
            d = d + lin.cyy[:, None] * self.cc[None, :]
            if np.any(d == 0):
                raise np.linalg.LinAlgError(WELDED_SINGULAR)
        else:
            # E_h = diag(d_h) + U diag(s_h) U^T: per harmonic the Woodbury matrix of
            # _LowRankE, inverted once (none for nu = 0: E is diagonal there)
            r = lin.U.shape[1]
            self.W = np.zeros((nus.size, r, r), dtype=complex)
            for j, nu in enumerate(nus):
                E = _LowRankE(d[:, j], 1j * nu * lin.cw, lin.U)
                E.factor()
                if E._small_inv is not None:
                    self.W[j] = E._small_inv
        self.Ed = d
        self.xi = float(xi)

    def derivatives(self, wrt: str, omega: float, harmonics, Q, Y):
        """:meth:`ReducedLinear.dproducts` of every harmonic at once, ``(dA_h q_h + dB_h y_h,
        dB'_h q_h + dE_h y_h)`` by ``omega`` or ``xi``: one real product per block of ``M``
        (and of ``C``, or its low-rank factors) for all the harmonics.

        Parameters
        ----------
        wrt : str
            ``"omega"`` or ``"xi"``.
        omega : float
            Fundamental angular frequency [rad/s] (``nu = h omega``).
        harmonics : array of int, shape (n_h,)
        Q : ndarray, shape (n_r, n_h), complex
        Y : ndarray, shape (n_y, n_h), complex

        Returns
        -------
        dq : ndarray, shape (n_r, n_h), complex
        dy : ndarray, shape (n_y, n_h), complex
        """
        lin = self.lin
        h = np.asarray(harmonics, dtype=float)
        nu = h * omega
        cm, cc = _dD_coefficients(wrt, h, nu, self.xi)

        def prod(A, X):                  # a real matrix times complex columns
            P = A @ np.concatenate([X.real, X.imag], axis=1)
            p = X.shape[1]
            return P[:, :p] + 1j * P[:, p:]
        Mq = prod(lin.M["qq"], Q) + prod(lin.M["qy"], Y)
        My = prod(lin.M["yq"], Q) + lin.myy[:, None] * Y
        if lin.KMC_lowc is not None:     # C = W diag(c) W^T
            Wq, Wy, c = lin.KMC_lowc
            t = c[:, None] * (Wq.T @ Q + Wy.T @ Y)
            Cq, Cy = Wq @ t, Wy @ t
        else:
            Cq = prod(lin.C["qq"], Q) + prod(lin.C["qy"], Y)
            Cy = prod(lin.C["yq"], Q) + (lin.cyy[:, None] * Y if lin.modal
                                         else prod(lin.Cyy, Y))
        return cm * Mq + cc * Cq, cm * My + cc * Cy

    def _from_q(self, X, k):
        """``(A_h X, B'_h X)`` for the columns of ``X`` (n_r, n_h k), harmonic-major: one
        real product with the stacked ``K``, ``M``, ``C`` of the qq and yq blocks (``C``
        by its factors when it is of low rank, ``ReducedLinear.KMC_lowc``)."""
        lin = self.lin
        p = X.shape[1]
        cm, cc = np.repeat(self.cm, k), np.repeat(self.cc, k)
        P = lin.KMC_q @ np.concatenate([X.real, X.imag], axis=1)   # (n_m (n_r + n_y), 2p)
        P = P[:, :p] + 1j * P[:, p:]
        nr, ny = lin.n_r, lin.n_y
        nm = P.shape[0] // (nr + ny)                                # 2 or 3 matrices
        K, M = P[:nr], P[nr:2 * nr]
        Ky, My = P[nm * nr:nm * nr + ny], P[nm * nr + ny:nm * nr + 2 * ny]
        if lin.KMC_lowc is None:
            C, Cy = P[2 * nr:3 * nr], P[3 * nr + 2 * ny:]
        else:
            Wq, Wy, c = lin.KMC_lowc
            t = c[:, None] * (Wq.T @ X)
            C, Cy = Wq @ t, Wy @ t
        return K + cm * M + cc * C, Ky + cm * My + cc * Cy

    def _b(self, Y, k):
        """``B_h Y`` for the columns of ``Y`` (n_y, n_h k): one real product with the
        ``K``, ``M``, ``C`` of the qy blocks side by side (``C`` of low rank by its
        factors)."""
        lin = self.lin
        p = Y.shape[1]
        cm, cc = np.repeat(self.cm, k), np.repeat(self.cc, k)
        parts = [Y, cm * Y] + ([cc * Y] if lin.KMC_lowc is None else [])
        Ys = np.vstack(parts)                                       # (n_m n_y, p)
        P = lin.KMC_qy @ np.concatenate([Ys.real, Ys.imag], axis=1)  # (n_r, 2p)
        out = P[:, :p] + 1j * P[:, p:]
        if lin.KMC_lowc is not None:
            Wq, Wy, c = lin.KMC_lowc
            out += Wq @ (c[:, None] * (Wy.T @ (cc * Y)))
        return out

    def _solve_E(self, Y, k):
        """``E_h^-1`` on the columns of ``Y`` (n_y, n_h k), harmonic-major."""
        Ed = np.repeat(self.Ed, k, axis=1)
        y = Y / Ed
        if self.W is not None:
            U = self.lin.U
            t = np.einsum("jrs,sj->rj", np.repeat(self.W, k, axis=0), U.T @ y)
            y = y - (U @ t) / Ed
        return y

    def apply(self, X):
        """``S_h X[:, h, :]`` for every harmonic ``h``.

        Parameters
        ----------
        X : ndarray, shape (n_r, n_h, k), complex

        Returns
        -------
        ndarray, shape (n_r, n_h, k), complex
        """
        nr, nh, k = X.shape
        AX, BpX = self._from_q(X.reshape(nr, nh * k), k)
        return (AX - self._b(self._solve_E(BpX, k), k)).reshape(nr, nh, k)

    def parts(self, Q, Fy):
        """The residual's linear part of every harmonic: ``y_h = E_h^-1 (F_y,h - B'_h
        q_h)`` and ``A_h q_h + B_h y_h``.

        Parameters
        ----------
        Q : ndarray, shape (n_r, n_h), complex
            Contact coordinates per harmonic [m].
        Fy : ndarray, shape (n_y, n_h), complex
            Force on the other coordinates per harmonic [N].

        Returns
        -------
        Aq_By : ndarray, shape (n_r, n_h), complex [N]
        y : ndarray, shape (n_y, n_h), complex [m]
        """
        AQ, BpQ = self._from_q(Q, 1)
        y = self._solve_E(Fy - BpQ, 1)
        return AQ + self._b(y, 1), y

    def b_einv(self, Y):
        """``B_h E_h^-1 Y[:, h]`` for every harmonic; ``Y`` (n_y, n_h) complex."""
        return self._b(self._solve_E(Y, 1), 1)


class _LowRankE:
    """``E = diag(d) + U diag(s) U^T`` (``U`` real, ``n_y x r``), solved by Woodbury:
    ``E^-1 = D^-1 - D^-1 U (diag(1/s) + U^T D^-1 U)^-1 U^T D^-1``.

    The ``r x r`` matrix (``r`` the damped modes, 12 on the lap joint) is inverted
    once: a solve is then two thin products and an ``r x r`` one, with no LAPACK
    wrapper per call.
    """

    def __init__(self, d, s, U):
        self.d, self.s, self.U = d, s, U
        self._small_inv = None
        self._factored = False

    def factor(self):
        if self._factored:
            return
        if np.any(self.d == 0):
            raise np.linalg.LinAlgError(WELDED_SINGULAR)
        if np.any(self.s != 0):
            small = np.diag(1.0 / self.s) + self.U.T @ (self.U / self.d[:, None])
            self._small_inv = np.linalg.inv(small)
        self._factored = True

    def solve(self, rhs):
        self.factor()
        d = self.d[:, None] if rhs.ndim == 2 else self.d
        x = rhs / d
        if self._small_inv is None:      # no damping term (harmonic 0)
            return x
        return x - (self.U @ (self._small_inv @ (self.U.T @ x))) / d


def _dD_coefficients(wrt: str, h, nu, xi: float):
    """``(c_M, c_C)`` with ``dD/dp = c_M M + c_C C`` for ``D = K - nu^2 M + i nu (C - xi M)``,
    ``nu = h omega``, ``p`` = ``"omega"`` or ``"xi"`` (scalars or arrays over harmonics)."""
    if wrt == "omega":
        return -h * (2.0 * nu + 1j * xi), 1j * h
    return -1j * nu, 0.0 * nu


