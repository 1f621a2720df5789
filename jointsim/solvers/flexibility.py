"""The stuck joint's dynamic flexibility on the contact coordinates.

The harmonic stage of the preconditioner (:mod:`jointsim.solvers.preconditioner`)
inverts, per harmonic, ``S_h`` plus a stiffness on each contact coordinate.  When that
stiffness is the stuck joint's, ``k`` (the tangent at the static state,
:func:`jointsim.solvers.static.stuck_linearisation`: ``kt A`` on the slip and ``kn A``
on the gap of every closed element, 0 on the open ones), ``S_h + diag(k)`` is the
Schur complement, on ``q = T x``, of the stuck structure's dynamic stiffness
``K_s - s M + i nu C`` (``K_s = K + T' diag(k) T``, ``s = nu^2 + i nu xi``), so its
inverse is that structure's flexibility seen from the contact coordinates:

    (S_h + diag(k))^-1 = T (K_s - s M + i nu C)^-1 T' = sum_j psi_j psi_j' / (lam_j - s + i nu c_j)

over the stuck modes (``K_s phi_j = lam_j M phi_j``, M-orthonormal, ``psi_j = T phi_j``)
when ``C`` is diagonal in them (``c_j``): the modal damping of the stuck joint,
:func:`jointsim.model.damping.damping_matrix`, is.  More generally the modes the
damping reaches (at most ``FLEX_DAMPED_MAX``; 12 on the lap joints) enter as one dense
block, ``Psi_d (diag(lam_d - s) + i nu C_d)^-1 Psi_d'``.  The undamped modes far above
the frequency enter by a quasi-static series, ``1 / (lam - s) = sum_p s^p / lam^(p + 1)``,
summed once (``C_p = sum_j psi_j psi_j' / lam_j^(p + 1)``), so that forming the inverse
of every harmonic costs about ``4 n_r^2 n_L`` flops (``n_L`` the modes below
``FLEX_RATIO`` times the highest harmonic frequency: 19 to 33 at 240 Gauss points) and
no ``n_r^3`` inverse and no ``S_h`` (``n_r^2 n_y``).  The modes and the sums are made
once per run (one eigen-decomposition of the reduced structure, ``n^3``).  On a large
interface the sums are kept compressed (:meth:`StuckFlexibility.compressed`, a HODLR on
the bisection tree of the coordinates' positions: the flexibility of an elastic body
between distant points is smooth: 0.19 of the sums' storage at 480 Gauss points), and
the flexibility is applied by solves instead of formed inverses, whose ``n_r^2`` entries
every application reads.

Its accuracy is that of the stuck modes of a structure with stiff contact springs: their
eigenvalues are known to about ``eps lam_max`` absolutely, so it agrees with the
inverted blocks to about 1e-8 relative off resonance, 3e-6 at a stuck resonance, on the
96-point lap joint; GMRES, on the exact Jacobian, absorbs that (docs/hbm.md, "Round 35").
"""
from __future__ import annotations

import logging

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

log = logging.getLogger(__name__)

#: Modes with ``lam >= (FLEX_RATIO nu_max)^2`` (and no damping) enter by the
#: quasi-static series; ``FLEX_ORDER`` terms of it leave a remainder of at most
#: ``FLEX_RATIO^(-2 FLEX_ORDER) / (1 - FLEX_RATIO^-2)`` of their share (1.5e-11 at 8 and
#: 6).
FLEX_RATIO = 8.0
FLEX_ORDER = 6
#: The stiffness the stuck joint adds must be diagonal on the contact coordinates, and
#: the damping diagonal in the stuck modes, to this relative tolerance; otherwise the
#: flexibility is not used (the preconditioner inverts its blocks).
FLEX_DIAGONAL_RTOL = 1e-9
#: At most this many stuck modes may be damped (their damping is a dense block).
FLEX_DAMPED_MAX = 64
#: The stuck modes cost about ``9 n^3`` flops once, a harmonic stage of inverted
#: blocks ``8 n_r^3`` per harmonic and build: above ``FLEX_SMALL_DOF`` structural DOFs
#: (an eigen-decomposition of about a second) the flexibility is made only for at most
#: ``FLEX_DOF_RATIO`` DOFs per contact coordinate (it pays after about ``0.3 (n /
#: n_r)^3`` builds of 4 harmonics; the lap joints have 2.1 to 3.2).
FLEX_SMALL_DOF = 1500
FLEX_DOF_RATIO = 6.0
#: A series made for ``nu_max`` serves every frequency up to it; it is made for this
#: many times the highest frequency that asked for it.
FLEX_MARGIN = 1.5
#: From this many contact coordinates the series' sums ``C_p`` can be kept compressed
#: (:meth:`StuckFlexibility.compressed`: one :class:`~jointsim.solvers.hierarchical.HODLR`
#: on the interface's bisection tree, leaves of ``FLEX_HODLR_LEAF`` coordinates, each
#: part truncated at ``FLEX_HODLR_EPS`` of its Frobenius norm).  Measured at 480 Gauss
#: points (960 coordinates, round 54): 0.19 of the dense sums, made in 0.63 s; the
#: 8 harmonics applied in 1.7 ms against 2.3 ms for the complex64 inverses, with a
#: backward error of 1.1e-5 against their 3.6e-2.
FLEX_HODLR_MIN_ROWS = 800
FLEX_HODLR_LEAF = 64
FLEX_HODLR_EPS = 1e-10
#: Given modes of the stuck structure (the model's, made for its modal damping) are
#: taken where they are the pencil's to this relative residual (:func:`modes_of`).
MODES_RTOL = 1e-8


def modes_of(modes, K, M, rtol: float = MODES_RTOL) -> bool:
    """Whether ``modes = (lam, phi)`` are every mass-normalised mode of ``(K, M)``.

    Checked on four fixed random combinations ``V = phi R``: ``K V = M phi diag(lam) R``
    to ``rtol`` of ``|K V|`` and ``V^T M V = R^T R`` to ``rtol`` of ``|R^T R|`` (``O(n^2)``,
    not the ``n^3`` of the decomposition).

    Parameters
    ----------
    modes : tuple (lam, phi)
        ``lam`` (n,) [rad^2/s^2], ``phi`` (n, n).
    K, M : ndarray or scipy.sparse matrix, shape (n, n)
        Stiffness [N/m] and mass [kg].
    rtol : float

    Returns
    -------
    bool
    """
    lam, phi = (np.asarray(a, dtype=float) for a in modes)
    n = K.shape[0]
    if lam.shape != (n,) or phi.shape != (n, n):
        return False
    R = np.random.default_rng(0).standard_normal((n, 4))
    V = phi @ R
    KV, MV = np.asarray(K @ V), np.asarray(M @ V)
    RR = R.T @ R
    return bool(np.abs(KV - np.asarray(M @ (phi @ (lam[:, None] * R)))).max()
                <= rtol * np.abs(KV).max() and np.abs(V.T @ MV - RR).max()
                <= rtol * np.abs(RR).max())


class StuckFlexibility:
    """``(S_h + diag(k))^-1`` of every harmonic from the stuck joint's modes (module
    docstring).

    Parameters
    ----------
    lam : ndarray, shape (n,)
        Eigenvalues of the stuck structure [1/s^2] (all positive).
    Psi : ndarray, shape (n_r, n)
        Its M-normalised modes on the contact coordinates [m / sqrt(kg)].
    k : ndarray, shape (n_r,)
        Stiffness of the stuck joint on each contact coordinate [N/m].
    damped : ndarray of int, shape (n_d,)
        The modes the damping reaches.
    Cd : ndarray, shape (n_d, n_d)
        The damping in them, ``Phi_d^T C Phi_d`` [1/s] (the others undamped).
    """

    def __init__(self, lam, Psi, k, damped=(), Cd=None):
        self.lam = np.asarray(lam, dtype=float)
        self.Psi = np.asarray(Psi, dtype=float)
        self.k = np.asarray(k, dtype=float)
        self.damped = np.asarray(damped, dtype=np.intp)
        self.Cd = np.zeros((0, 0)) if Cd is None else np.asarray(Cd, dtype=float)
        self.Psi_d = np.ascontiguousarray(self.Psi[:, self.damped])
        self.n_r = self.Psi.shape[0]
        self._series = None        # (nu_max, undamped low modes' Psi and lam, C (P, n_r, n_r))
        self._scaled = {}          # the series' nu_max^(2p) C_p as (P, n_r^2), per real dtype
        self._last = {}            # precision -> ((nus, xi), inverses) of its last call
        #: positions of the contact coordinates [m] (n_r, d), for :meth:`compressed`
        self.positions = None
        self._hodlr = None         # (nu_max, sigma, HODLR of sigma^p C_p) of the series
        self._damped_last = None   # (key, inverses) of _damped_solve's last frequencies

    @property
    def n_summed(self) -> int:
        """Modes summed exactly (damped and low) by the current series."""
        sr = self._series
        return self.damped.size + (0 if sr is None else sr[2].size)

    @classmethod
    def of(cls, lin, dK) -> "StuckFlexibility | None":
        """The flexibility of a condensed structure, or None where it does not apply.

        Parameters
        ----------
        lin : jointsim.solvers.condensation.ReducedLinear
        dK : scipy.sparse matrix, shape (n, n)
            ``K_s - K``: what the stuck joint adds to the stiffness [N/m].

        The stuck modes are the eigen-decomposition of ``(K + dK, M)`` in the
        coordinates ``(q, y)``.

        Returns None (logged) when ``dK`` is not a stiffness on each contact coordinate
        alone (``dK = T' diag(k) T`` to ``FLEX_DIAGONAL_RTOL`` of its largest entry), when
        the damping reaches more than ``FLEX_DAMPED_MAX`` stuck modes, when the
        stuck structure is not positive definite, or when its modes would cost more
        than they save (``FLEX_SMALL_DOF``, ``FLEX_DOF_RATIO``).
        """
        n_r = lin.n_r
        if not n_r:
            return None
        if lin.n > FLEX_SMALL_DOF and lin.n > FLEX_DOF_RATIO * n_r:
            log.debug("stuck flexibility: %d DOFs for %d contact coordinates, its modes "
                      "would cost more than the inverses they save", lin.n, n_r)
            return None
        # the stuck joint's stiffness on each coordinate, dK = T' diag(k) T: k = diag(Psi' dK
        # Psi), checked on dK itself (sparse; round 43: no V' dK V, 0.48 s at 480 points)
        T = lin.T_sparse
        k = np.einsum("ij,ij->j", lin.Psi, np.asarray(dK @ lin.Psi))
        fit = T.T @ sp.diags(k) @ T
        rest = (sp.csr_matrix(dK) - fit).tocsr()
        if float(np.abs(rest.data).max(initial=0.0)) > FLEX_DIAGONAL_RTOL * max(
                float(np.abs(fit.data).max(initial=0.0)), 1e-300):
            log.debug("stuck flexibility: the stuck joint's stiffness couples coordinates")
            return None

        def whole(X):
            return np.block([[X["qq"], X["qy"]], [X["yq"], X["yy"]]]) if lin.n_y else X["qq"]
        if lin.stuck_modes is not None and lin.damping_low_rank is not None:
            # the model's modes of the stuck structure (checked to be those of K + dK),
            # in the coordinates x: their contact coordinates are q = T x
            lam, Phi = lin.stuck_modes
            Phi_q = np.asarray(T @ Phi)
            PW = Phi.T @ lin.damping_low_rank[0]                  # C = W diag(c) W^T
            Cm = (PW * lin.damping_low_rank[1]) @ PW.T
        else:
            Ks = np.array(whole(lin.K))              # (a copy: whole() may return a block)
            Ks[np.arange(n_r), np.arange(n_r)] += k
            M = whole(lin.M)
            try:
                lam, Phi = sla.eigh(0.5 * (Ks + Ks.T), 0.5 * (M + M.T), check_finite=False)
            except (np.linalg.LinAlgError, ValueError):
                return None
            Phi_q = Phi[:n_r]
            factors = lin.damping_factors
            if factors is not None:                           # C = W diag(c) W^T
                Wq, Wy, cw = factors
                PW = Phi.T @ np.vstack([Wq, Wy])
                Cm = (PW * cw) @ PW.T
            else:
                Cm = Phi.T @ whole(lin.C) @ Phi
        if not lam.min(initial=1.0) > 0.0:
            log.debug("stuck flexibility: the stuck structure is not positive definite")
            return None
        # the damped modes: those the damping reaches (the stuck modes it was defined on;
        # the nearly rigid ones among them are known to about eps lam_max / lam, so the
        # damping couples them a little: kept as a block)
        reach = np.abs(Cm).max(axis=1, initial=0.0)
        damped = np.flatnonzero(reach > FLEX_DIAGONAL_RTOL * max(float(reach.max(initial=0.0)),
                                                                 1e-300))
        if damped.size > FLEX_DAMPED_MAX:
            log.debug("stuck flexibility: the damping reaches %d stuck modes", damped.size)
            return None
        flex = cls(lam, Phi_q, k, damped, Cm[np.ix_(damped, damped)])
        flex.positions = lin.positions
        return flex

    def prepare(self, nu: float) -> None:
        """Make the series for every frequency up to ``nu`` [rad/s] now (before workers
        fork, :meth:`jointsim.solvers.hbm.HBMSystem.prepare_forks`), instead of on first
        use and again each time a higher frequency asks for it."""
        self._made_for(float(nu))

    def _made_for(self, nu: float):
        """The series valid up to ``nu`` (made when the kept one is not)."""
        sr = self._series
        if sr is not None and nu <= sr[0]:
            return sr
        nu_max = FLEX_MARGIN * nu
        free = np.ones(self.lam.size, dtype=bool)
        free[self.damped] = False
        high = (self.lam >= (FLEX_RATIO * nu_max) ** 2) & free
        PsiH, lamH = self.Psi[:, high], self.lam[high]
        C = np.empty((FLEX_ORDER, self.n_r, self.n_r))
        for p in range(FLEX_ORDER):
            C[p] = (PsiH * lamH ** -(p + 1)) @ PsiH.T
        low = ~high & free
        sr = (nu_max, np.ascontiguousarray(self.Psi[:, low]), self.lam[low], C)
        self._series = sr
        self._scaled = {}
        log.debug("stuck flexibility: %d damped modes, %d undamped summed, %d quasi-static, "
                  "up to %g rad/s", self.damped.size, int(low.sum()), int(high.sum()), nu_max)
        return sr

    def compressed(self, nu: float):
        """The series valid up to ``nu`` with its sums kept as one HODLR
        (``FLEX_HODLR_*``), made now if needed; None below ``FLEX_HODLR_MIN_ROWS``
        coordinates or without their positions.  :meth:`solve` and :meth:`columns` use
        it once made (for that series)."""
        if self.n_r < FLEX_HODLR_MIN_ROWS or self.positions is None:
            return None
        nu_max, _, _, C = self._made_for(float(nu))
        if self._hodlr is None or self._hodlr[0] != nu_max:
            from .hierarchical import HODLR, bisection_tree
            sigma = nu_max ** 2
            parts = [C[p] * sigma ** p for p in range(FLEX_ORDER)]
            H = HODLR(parts, [FLEX_HODLR_EPS * float(np.linalg.norm(G)) for G in parts],
                      bisection_tree(self.positions, FLEX_HODLR_LEAF))
            self._hodlr = (nu_max, sigma, H)
            log.debug("stuck flexibility: its series as a HODLR, %.3f of the dense sums",
                      H.compression)
        return self._hodlr

    def _series_hodlr(self, s=None):
        """``(sigma, HODLR)`` of the current series when it is kept compressed, else None;
        with ``s`` (n_h,) (``nu^2 + i nu xi`` of each frequency), ``(HODLR, spow)``
        instead, ``spow`` (parts, n_h) the factor ``(s / sigma)^p`` of each kept part."""
        hz = self._hodlr
        if hz is None or self._series is None or hz[0] != self._series[0]:
            return None
        if s is None:
            return hz[1:]
        sigma, H = hz[1:]
        return H, ((s / sigma)[None, :] ** np.arange(FLEX_ORDER)[:, None])[H.powers]

    @staticmethod
    def _low_factors(lamL, s, regular) -> np.ndarray:
        """``1 / (lam_L - s_h)`` of the low modes at each frequency, (n_h, n_L); at the
        ``regular`` ones (boolean (n_h,)) the mode nearest ``s_h`` left out (0;
        :class:`ShiftedBlock`)."""
        d = 1.0 / (lamL[None, :] - s[:, None])
        if regular.any() and lamL.size:
            h = np.flatnonzero(regular)
            d[h, np.abs(lamL[None, :] - s[h, None]).argmin(axis=1)] = 0.0
        return d

    def columns(self, nus, cols, xi: float = 0.0, rows=None, regular=False) -> np.ndarray:
        """The columns ``cols`` of ``(S_h + diag(k))^-1`` at each frequency, shape
        (n_h, n_r, len(cols)), complex [m/N], without forming the inverses (the series'
        columns read from its HODLR when :meth:`compressed` made one, else sliced); on
        ``rows`` only (shape (n_h, len(rows), len(cols))) when given.  At the frequencies
        ``regular`` (bool, or boolean (n_h,)), of its regular part only: without the damped
        modes and the low mode nearest that frequency (:class:`ShiftedBlock`)."""
        nus = np.asarray(nus, dtype=float)
        cols = np.asarray(cols, dtype=np.int64)
        rsel = slice(None) if rows is None else np.asarray(rows, dtype=np.int64)
        _, PsiL, lamL, C = self._made_for(float(np.abs(nus).max(initial=0.0)))
        s = nus ** 2 + 1j * nus * xi
        regular = np.broadcast_to(np.asarray(regular, dtype=bool), nus.shape)
        d = self._low_factors(lamL, s, regular)                   # (n_h, n_L)
        # the low and the damped modes in one product, (n_h, rows, n_L + n_d) (n_L + n_d, m)
        n_h, n_l = nus.size, lamL.size
        n_rows = self.n_r if rows is None else rsel.size
        A = np.empty((n_h, n_rows, n_l + self.damped.size), dtype=complex)
        A[:, :, :n_l] = PsiL[rsel] * d[:, None, :]
        A[:, :, n_l:] = self.Psi_d[rsel]
        B = np.empty((n_h, A.shape[2], cols.size), dtype=complex)
        B[:, :n_l] = PsiL[cols].T
        if self.damped.size:
            B[:, n_l:] = self._damped_solve(nus, s, self.Psi_d[cols].T)
            B[regular, n_l:] = 0.0
        out = np.matmul(A, B)                                        # (n_h, rows, m)
        hz = self._series_hodlr(s)
        if hz is not None:
            hz[0].columns(cols, hz[1], rows, add_to=out)
        else:
            powers = s[:, None] ** np.arange(FLEX_ORDER)[None, :]
            out += np.einsum("hp,prm->hrm", powers, C[:, rsel][:, :, cols])
        return out

    def _damped_inverses(self, nus, s) -> np.ndarray:
        """``(diag(lam_d - s_h) + i nu_h C_d)^-1`` of the damped modes for every harmonic,
        (n_h, n_d, n_d); those of the last frequencies asked are kept (a stage's solves
        repeat them)."""
        key = (nus.tobytes(), s.tobytes())
        if self._damped_last is None or self._damped_last[0] != key:
            lamd = self.lam[self.damped]
            G = (1j * nus)[:, None, None] * self.Cd[None].astype(complex)
            G[:, np.arange(lamd.size), np.arange(lamd.size)] += lamd[None, :] - s[:, None]
            self._damped_last = (key, np.linalg.inv(G))
        return self._damped_last[1]

    def _damped_solve(self, nus, s, B) -> np.ndarray:
        """:meth:`_damped_inverses` times ``B`` (n_d, m) or (n_h, n_d, m): (n_h, n_d, m)."""
        return np.matmul(self._damped_inverses(nus, s), B)

    def inverses(self, nus, xi: float = 0.0, single: bool = False) -> np.ndarray:
        """``(S_h + diag(k))^-1`` at each frequency.

        The quasi-static series of every harmonic is one real product
        ``(n_h, P) x (P, n_r^2)`` over ``nu_max^(2p) C_p`` (scaled so that single
        precision neither overflows nor underflows), written once into the result; the
        low and the damped modes are added per harmonic, ``A_h B^T`` with ``B = [Psi_L,
        Psi_d]`` (``n_r x (n_L + n_d)``).  No temporary of the result's size but the
        series' (round 41, 480 Gauss points, 16 harmonics: 0.13 to 1.0 s -> 0.09 s, and
        0.05 s in single precision, where the old one's 236 MB of temporaries had to be
        paged in).

        Parameters
        ----------
        nus : array_like, shape (n_h,)
            Angular frequencies of the harmonics [rad/s] (``h omega``).
        xi : float
            Self-excitation (damping ``C - xi M``) [1/s].
        single : bool
            Form them in single precision (complex64; a loose solve's preconditioner,
            about 1e-6 relative as an operator) instead of double.

        Returns
        -------
        ndarray, shape (n_h, n_r, n_r), complex128 or complex64 [m/N]
            Read-only: the last call's array of each precision is kept and returned
            again for the same ``nus`` and ``xi`` (the solves at one frequency, e.g. a
            Newton solve's preconditioners, share it).  A zero frequency's block is real.
        """
        nus = np.asarray(nus, dtype=float)
        key = (nus.tobytes(), float(xi))
        last = self._last.get(bool(single))
        if last is not None and last[0] == key:
            return last[1]
        nu_max, PsiL, lamL, C = self._made_for(float(np.abs(nus).max(initial=0.0)))
        real, cplx = (np.float32, np.complex64) if single else (np.float64, np.complex128)
        sigma = nu_max ** 2
        Cs = self._scaled.get(real)
        if Cs is None:
            Cs = (C * (sigma ** np.arange(FLEX_ORDER))[:, None, None]).reshape(
                FLEX_ORDER, -1).astype(real)
            self._scaled[real] = Cs
        s = nus ** 2 + 1j * nus * xi
        n_h, n_r = nus.size, self.n_r
        # the quasi-static modes: sum_p (s / sigma)^p (sigma^p C_p)
        powers = (s / sigma)[:, None] ** np.arange(FLEX_ORDER)[None, :]
        out = np.empty((n_h, n_r, n_r), dtype=cplx)
        out.real = (powers.real.astype(real) @ Cs).reshape(n_h, n_r, n_r)
        if xi:
            out.imag = (powers.imag.astype(real) @ Cs).reshape(n_h, n_r, n_r)
        else:
            out.imag = 0.0
        # the low modes, Psi_L diag(1 / (lam_L - s)) Psi_L^T, and the damped ones,
        # Psi_d (diag(lam_d - s) + i nu C_d)^-1 Psi_d^T
        B = np.hstack([PsiL, self.Psi_d]).astype(real)
        if B.shape[1]:
            Gd = self._damped_inverses(nus, s) if self.damped.size else None
            for i, si in enumerate(s):
                A = np.empty((n_r, B.shape[1]), dtype=complex)
                A[:, :lamL.size] = PsiL / (lamL - si)
                if Gd is not None:
                    A[:, lamL.size:] = self.Psi_d @ Gd[i]
                out[i].real += A.real.astype(real) @ B.T
                out[i].imag += A.imag.astype(real) @ B.T
        out[nus == 0.0] = out[nus == 0.0].real
        out.flags.writeable = False
        self._last[bool(single)] = (key, out)
        return out

    def solve_flops(self, n_h: int) -> float:
        """Real flops of :meth:`solve` of one column at ``n_h`` frequencies: the low modes,
        the quasi-static series (its HODLR where kept so) and the damped modes."""
        hz = self._series_hodlr()
        series = 4.0 * (hz[1].stored if hz is not None else FLEX_ORDER * self.n_r ** 2)
        return n_h * (8.0 * self.n_r * (self._series[1].shape[1] + self.damped.size) + series)

    def solve(self, nus, B, xi: float = 0.0, regular=False) -> np.ndarray:
        """``(S_h + diag(k))^-1 b_h`` at each frequency, without forming the inverses
        (at the frequencies ``regular``, its regular part's: :meth:`columns`).

        Parameters
        ----------
        nus : array_like, shape (n_h,)
            Angular frequencies [rad/s].
        B : ndarray, shape (n_h, n_r) or (n_h, n_r, m), complex
            Right-hand sides [N].
        xi : float
            Self-excitation [1/s].

        Returns
        -------
        ndarray, the shape of ``B``, complex [m]
            About ``2 n_r n_L + FLEX_ORDER n_r^2`` flops per harmonic and column; as
            accurate as :meth:`inverses` (module docstring).
        """
        nus = np.asarray(nus, dtype=float)
        B = np.asarray(B, dtype=complex)
        B3 = B if B.ndim == 3 else B[:, :, None]
        _, PsiL, lamL, C = self._made_for(float(np.abs(nus).max(initial=0.0)))
        s = nus ** 2 + 1j * nus * xi
        regular = np.broadcast_to(np.asarray(regular, dtype=bool), nus.shape)
        d = self._low_factors(lamL, s, regular)                  # (n_h, n_L)
        # the low modes: Psi_L diag(d_h) Psi_L^T b_h
        Y = np.matmul(PsiL, d[:, :, None] * np.matmul(PsiL.T, B3))
        # the quasi-static modes: sum_p s^p C_p b_h (C_p real: applied to the real and
        # imaginary parts as one real product, no complex copy of C; or its HODLR)
        n_h, n_r, m = B3.shape
        hz = self._series_hodlr(s)
        if hz is not None:
            H, spow = hz
            Bt = np.ascontiguousarray(B3.transpose(1, 0, 2)).reshape(n_r, n_h * m)
            Yq = H.apply(Bt, np.repeat(spow, m, axis=1)).reshape(n_r, n_h, m)
            Y += Yq.transpose(1, 0, 2)
        else:
            Bt = np.ascontiguousarray(B3.transpose(1, 0, 2)).reshape(n_r, -1).view(float)
            CB = (C.reshape(-1, n_r) @ Bt).view(complex).reshape(FLEX_ORDER, n_r, n_h, m)
            powers = s[:, None] ** np.arange(FLEX_ORDER)[None, :]      # (n_h, P)
            Y += np.einsum("hp,prhm->hrm", powers, CB)
        if self.damped.size and not regular.all():
            W = self._damped_solve(nus, s, np.matmul(self.Psi_d.T, B3))
            W[regular] = 0.0
            Y += np.matmul(self.Psi_d, W)
        return Y.reshape(B.shape)


class ShiftedBlock:
    """``(S_h + diag(k) + u ell^T)^-1`` of one harmonic from the stuck flexibility, where
    ``S_h + diag(k)`` itself may be singular: the shifted block of the EPMC's bordered
    solves (:class:`~jointsim.solvers.jacobian.BorderedJacobian`), singular in the linear
    range, where the stuck mode is its null vector.

    Split the flexibility ``F = R + Psi_b G_b^-1 Psi_b'`` into its regular part ``R``
    (:meth:`StuckFlexibility.solve` with ``regular``) and the modes that may be resonant:
    the damped ones (``G_d = diag(lam_d - s) + i nu C_d``) and the low mode nearest ``s``
    (``lam_j - s``).  With ``alpha = ell' x``, ``(S_h + diag(k)) x = y - u alpha`` gives
    ``x = R (y - u alpha) + Psi_b w`` and the bordered system, regular wherever the
    shifted block is, even where ``G_b`` is singular::

        [ G_b           Psi_b' u     ] [ w     ]   [ Psi_b' y ]
        [ -ell' Psi_b   1 + ell' R u ] [ alpha ] = [ ell' R y ]

    (``n_d + 2`` unknowns).  A solve costs one of ``R`` (about one harmonic's
    :meth:`StuckFlexibility.solve`), a build two: no ``S_h`` and no ``n_r^3`` inverse
    (round 57; it was 0.17 s a build at 480 Gauss points, 34 builds of the EPMC's 25
    points).  As accurate as the flexibility off resonance (module docstring).

    Parameters
    ----------
    flex : StuckFlexibility
    nu : float
        Angular frequency of the harmonic [rad/s].
    xi : float
        Self-excitation [1/s].
    u, ell : ndarray, shape (n_r,), complex
        The shift ``u ell'`` [N/m, with ``ell`` dimensionless].
    """

    def __init__(self, flex: StuckFlexibility, nu: float, xi: float, u, ell):
        self.flex, self.nus, self.xi = flex, np.array([float(nu)]), float(xi)
        u, ell = np.asarray(u, dtype=complex), np.asarray(ell, dtype=complex)
        s = nu ** 2 + 1j * nu * xi
        _, PsiL, lamL, _ = flex._made_for(abs(float(nu)))
        nd = flex.damped.size
        G = np.zeros((nd + 1, nd + 1), dtype=complex)
        G[:nd, :nd] = (1j * nu) * flex.Cd
        G[np.arange(nd), np.arange(nd)] += flex.lam[flex.damped] - s
        if lamL.size:                      # the low mode the regular part leaves out
            j = int(np.abs(lamL - s).argmin())
            self.Psi_b = np.hstack([flex.Psi_d, PsiL[:, j:j + 1]])
            G[nd, nd] = lamL[j] - s
        else:
            self.Psi_b, G = flex.Psi_d, G[:nd, :nd]
        nb = self.Psi_b.shape[1]
        RU = self._regular(np.column_stack([u, ell]))
        self.Ru, self.Rl, self.ell = RU[:, 0], RU[:, 1], ell
        K = np.empty((nb + 1, nb + 1), dtype=complex)
        K[:nb, :nb] = G
        K[:nb, nb] = self.Psi_b.T @ u
        K[nb, :nb] = -(ell @ self.Psi_b)
        K[nb, nb] = 1.0 + ell @ self.Ru
        self.Kinv = np.linalg.inv(K)

    def _regular(self, Y) -> np.ndarray:
        """``R Y``, ``Y`` (n_r, m) complex."""
        return self.flex.solve(self.nus, Y[None], self.xi, regular=True)[0]

    def _finish(self, RY, rhs_b, rhs_l, rows=slice(None)) -> np.ndarray:
        """``x = R y - R u alpha + Psi_b w`` on ``rows`` from ``R y`` there and the
        right-hand sides of the bordered system (``Psi_b' y``, ``ell' R y``)."""
        wa = self.Kinv @ np.vstack([rhs_b, rhs_l[None, :]])
        return RY - np.outer(self.Ru[rows], wa[-1]) + self.Psi_b[rows] @ wa[:-1]

    def finish_solve(self, RY, Y) -> np.ndarray:
        """The inverse times ``Y`` (n_r, m) from ``R Y`` (made by the caller: with the
        other harmonics' solves, :class:`FlexibilitySolve`)."""
        return self._finish(RY, self.Psi_b.T @ Y, self.ell @ RY)

    def finish_columns(self, RC, cols, rows=None) -> np.ndarray:
        """The columns ``cols`` of the inverse (on ``rows``) from those of ``R``
        (``ell' R e_c = (R ell)_c``: ``R`` is symmetric)."""
        cols = np.asarray(cols, dtype=np.int64)
        rsel = slice(None) if rows is None else np.asarray(rows, dtype=np.int64)
        return self._finish(RC, self.Psi_b[cols].T, self.Rl[cols], rsel)

    def solve(self, Y) -> np.ndarray:
        """The inverse times ``Y`` (n_r, m) complex [N]: (n_r, m) [m]."""
        return self.finish_solve(self._regular(Y), Y)

    def columns(self, cols, rows=None) -> np.ndarray:
        """The columns ``cols`` of the inverse, (n_r, len(cols)), or their ``rows`` only."""
        RC = self.flex.columns(self.nus, cols, self.xi, rows, regular=True)[0]
        return self.finish_columns(RC, cols, rows)

    @property
    def apply_flops(self) -> float:
        """Real flops of one solve of one column (about one harmonic's flexibility solve)."""
        return self.flex.solve_flops(1) + self.finish_flops

    @property
    def finish_flops(self) -> float:
        """Real flops of :meth:`finish_solve` for one column."""
        return 16.0 * self.flex.n_r * (self.Psi_b.shape[1] + 1)


class FlexibilitySolve:
    """The stuck flexibility at fixed frequencies as a harmonic stage applied by solves
    (:meth:`StuckFlexibility.solve`): no ``n_r x n_r`` inverse is formed (for a loose
    solve whose low-rank stage needs few columns of ``P_h^-1``,
    :data:`jointsim.solvers.preconditioner.SOLVED_STAGE_COLUMNS`, and for any solve
    where the series is compressed, :meth:`StuckFlexibility.compressed`, but a
    tight shifted one); the columns of ``P_h^-1`` are read (:meth:`columns`).

    Parameters
    ----------
    flex : StuckFlexibility
    nus : array_like, shape (n_h,)
        Angular frequencies of the harmonics [rad/s].
    xi : float
        Self-excitation [1/s].
    shifted : tuple (i, ShiftedBlock), optional
        The ``i``-th harmonic's block replaced by this one's inverse (a shifted block: the
        EPMC's bordered solves, :class:`~jointsim.solvers.preconditioner.HarmonicPreconditioner`).
    """

    def __init__(self, flex: StuckFlexibility, nus, xi: float = 0.0, shifted=None):
        self.flex, self.nus, self.xi = flex, np.asarray(nus, dtype=float), float(xi)
        self.shifted = shifted
        # the shifted harmonic's regular part is solved with the others (one pass over
        # the series' HODLR, whose reading is most of a solve's cost)
        self._regular = np.zeros(self.nus.size, dtype=bool)
        if shifted is not None:
            self._regular[shifted[0]] = True
        flex._made_for(float(np.abs(self.nus).max(initial=0.0)))

    @property
    def build_flops(self) -> float:
        """Real flops of making it: the shifted block's two solves, if any."""
        return 2.0 * self.shifted[1].apply_flops if self.shifted is not None else 0.0

    @property
    def apply_flops(self) -> float:
        """Real flops of one solve of one column (every harmonic): the low modes, the
        quasi-static series and the damped modes (and the shifted block's bordering)."""
        return self.flex.solve_flops(self.nus.size) \
            + (self.shifted[1].finish_flops if self.shifted is not None else 0.0)

    def solve(self, Y: np.ndarray) -> np.ndarray:
        """``(S_h + diag(k))^-1 Y[h]`` for every harmonic; ``Y`` (n_h, n_r, k) complex."""
        out = self.flex.solve(self.nus, Y, self.xi, regular=self._regular)
        if self.shifted is not None:
            i, block = self.shifted
            out[i] = block.finish_solve(out[i], Y[i])
        return out

    def columns(self, cols, rows=None) -> np.ndarray:
        """The columns ``cols`` of every ``(S_h + diag(k))^-1``, (n_h, n_r, len(cols)), or
        their ``rows`` only, (n_h, len(rows), len(cols))."""
        out = self.flex.columns(self.nus, cols, self.xi, rows, regular=self._regular)
        if self.shifted is not None:
            i, block = self.shifted
            out[i] = block.finish_columns(out[i], cols, rows)
        return out
