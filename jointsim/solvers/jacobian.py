"""Structured Jacobians of the condensed harmonic balance, solved by preconditioned GMRES.

The Jacobian of :class:`jointsim.solvers.hbm.HBMSystem` (``n_z = n_c n_r``
unknowns, harmonic-major) is the sum of

* the condensed dynamic stiffness, block-diagonal over harmonics: per
  harmonic ``h`` the complex ``n_r x n_r`` Schur complement
  ``S_h = A - B E^-1 B'`` (:mod:`jointsim.solvers.condensation`), acting on
  the complex amplitude ``X_c - i X_s``;
* the contact tangent, block-diagonal over elements and dense over the
  ``n_c`` coefficients: the AFT blocks ``Juu``, ``Jug``, ``JNN`` (n_e, n_c, n_c).

:class:`HBMJacobian` keeps these pieces and applies ``J v`` and ``J^T v``
without forming ``J`` (``S_h v = A v - B E^-1 (B' v)``, with a modal or
low-rank condensation for every harmonic at once by real BLAS-3 products,
:class:`~jointsim.solvers.condensation.DynamicProducts`; ``S_h`` is formed only
for a preconditioner or after ``FORM_AFTER`` products), also on a block of
columns; :meth:`HBMJacobian.to_dense` is the reference.  Its preconditioner
(:class:`~jointsim.solvers.preconditioner.HarmonicPreconditioner`) is, per harmonic, ``S_h`` plus the harmonic-
``h`` part of each element's tangent (the complex-form projection of its
``(h, h)`` 2 x 2 coefficient block, coupling the slip and gap rows of one
element), inverted once per harmonic: ``H + 1`` complex ``n_r x n_r`` inverses
instead of one real LU of size ``n_z``.  With a constant contact tangent
(linear contact) it is the exact inverse.  The rest of the tangent lives on
the elements that slip or separate during the period; a Woodbury (low-rank)
stage corrects for it exactly (a dense ``m x m`` LU, ``m`` = all coefficients
of those elements' rows), so that a fresh preconditioner solves in one GMRES
iteration.  When too many elements slip (``m`` above ``LOWRANK_EXACT_FRACTION
n_z``) only the largest corrections are kept and an element-block stage
and GMRES do the rest.  Where the damping is that of the stuck joint's modes (the
lap-joint scenes), the per-harmonic part holds the stuck joint's contact stiffness
instead of the projected tangent, and its inverses are formed from the stuck modes
without ``S_h`` and without an ``n_r^3`` inverse
(:class:`~jointsim.solvers.flexibility.StuckFlexibility`, ``MODAL_STAGE``); the
low-rank stage then corrects for every element whose tangent is not the stuck one.

:class:`BorderedJacobian` is ``[[J, C], [R, D]]`` with a few dense columns
and rows (``dR/domega``, the EPMC unknowns and phase conditions, the
continuation's hyperplane); it is solved by GMRES preconditioned by
bordering the harmonic preconditioner (one extra preconditioner solve per
column and an ``m x m`` Schur complement), which stays regular through
turning points.  A loose solve whose low-rank stage is split (no LU of it: the error
indicators') first solves through its capacitance system, the bordering included
(:func:`_capacitance_refined`), and GMRES finishes.

The preconditioner is reused across Newton iterations and continuation
steps through a :class:`~jointsim.solvers.preconditioner_cache.PreconditionerCache`
owned by the system (an explicit object, not module state) while that pays by its
flop cost model
(:meth:`~jointsim.solvers.preconditioner_cache.PreconditionerCache.threshold`), and
rebuilt when GMRES fails with the old one within that budget.  Every solve is counted in a :class:`LinearStats`.
GMRES stops at the Jacobian's own tolerance (``KRYLOV_RTOL``), or at a looser one a
caller asks for: a Newton step is solved only as far as its residual needs
(:mod:`jointsim.solvers.newton`, ``forcing``; not the EPMC's,
:attr:`BorderedJacobian.inexact_steps`).

:func:`solve`, :func:`append_row`, :func:`drop_last_column` and
:func:`scale_columns` work on dense arrays and on these objects alike; the
Newton loop and the continuation use them.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .gmres import KRYLOV_MAXITER, KRYLOV_RTOL, GMRESResult, gmres, gmres_columns  # noqa: F401
from .preconditioner_cache import PreconditionerCache
from .tangent_projection import add_projected_tangent

log = logging.getLogger(__name__)

#: A reused preconditioner's solve that stopped at the round-off floor
#: (:attr:`GMRESResult.at_floor`) is accepted up to this many times the tolerance
#: instead of building a new preconditioner and going on: the new one reaches the same
#: floor.  Measured on the 96-Gauss-point lap joint's force-0.02 branch (round 13):
#: 58 of 110 solves rebuilt after stopping at 1.4e-11 to 1.5e-10 (rtol 1e-11), and
#: the rebuilt ones stopped at 1.4e-11 to 1.7e-10 after one more iteration.
FLOOR_FACTOR = 1e3
#: The capacitance solves of a split low-rank stage (:func:`_capacitance_refined`):
#: refined to ``CAPACITANCE_MARGIN`` of the tolerance asked (its iterations cost a
#: fraction of one on the system: measured on 21 points of the 240-point FRC's force-2
#: and force-20 branches, indicators at ``INDICATOR_RTOL = 1e-3`` against a solve to
#: 1e-8, one thread: at 0.5 the estimates within 0.43 % in 11.3 s, at 0.1 within
#: 0.12 % in 12.1 s, at 0.02 within 0.055 % (their truncation parts 0.09 %) in 12.4
#: s), in at most ``CAPACITANCE_REFINE`` steps, each to that tolerance or to
#: ``CAPACITANCE_STEP`` of its residual, whichever is looser (its single-precision
#: ``P^-1`` and ``G`` limit what one step gains: one step to 5e-4 left true residuals
#: of 2e-3 to 1.3 at gross-slip points, two to four to 0.03 reach 1e-3).  GMRES on the
#: system finishes what they leave.
CAPACITANCE_REFINE = 6
CAPACITANCE_MARGIN = 0.02
CAPACITANCE_STEP = 0.03
#: ... and they stop at a step that leaves more than this share of its residual (a
#: step that leaves more than all of it is undone): where the element blocks of the
#: capacitance system are weak, its GMRES stagnates and the steps gain little or lose
#: (the 480-point EPMC's indicators in deep gross slip: residual ratios 0.88 to 4.8, six
#: steps of 80 iterations each; round 53, docs/hbm.md).
CAPACITANCE_GAIN = 0.8
#: A bordered solve's capacitance steps (the EPMC indicators') solve ``M^-1`` of the
#: border columns once, to this relative residual (or tighter), since every step's
#: bordering uses them: the EPMC's frequency and damping directions are nearly singular,
#: and at the steps' tolerance they left a step's error at 1e-2 on the four-DOF chain.
BORDER_RTOL = 1e-6
#: :meth:`HBMJacobian.solve_uncoupled` by the stuck flexibility: at most this many
#: refinement steps against ``J`` (each gains about the flexibility's accuracy, 1e-8
#: off a stuck resonance and 3e-6 at one, :mod:`~jointsim.solvers.flexibility`).
UNCOUPLED_REFINE = 3
#: Unknowns ``n_z`` from which ``linear_solver = "auto"`` chooses Krylov.
KRYLOV_MIN_UNKNOWNS = 1200
LINEAR_SOLVERS = ("auto", "direct", "krylov")
#: Unformed products ``A v - B E^-1 (B' v)`` of one Jacobian after which its ``S_h``
#: are formed.  Per-harmonic complex blocks: a product cost about three formed ones and
#: forming (a BLAS-3 product of ``n_r^2 n_y`` per harmonic) ten to twenty, hence 12
#: (round 11).  With :class:`~jointsim.solvers.condensation.DynamicProducts` (round 14)
#: an unformed product costs 1.0 ms against 0.3 to 0.5 ms formed and 21 ms to form (96
#: Gauss points, 15 harmonics): forming pays after about 40.  Measured on the force-2
#: branch (one thread): at 12, 91 formings took 1.8 s; at 24, none happened and the
#: products took 3.8 s against 5.4 s with the formings.
FORM_AFTER = 40

@dataclass
class LinearStats:
    """Counters of the linear solves of one system (read and reset by the runners).

    Attributes
    ----------
    solves : int
        Linear solves.
    krylov_iterations : int
        GMRES iterations summed over the solves.
    factorizations : int
        Preconditioners built (full: ``H + 1`` inverses of ``n_r x n_r`` and the
        low-rank LU; partial, on a shared harmonic stage: the low-rank LU only).
    """

    solves: int = 0
    krylov_iterations: int = 0
    factorizations: int = 0

    def take(self) -> tuple[int, int, int]:
        """``(solves, krylov_iterations, factorizations)`` since the last take; resets."""
        out = (self.solves, self.krylov_iterations, self.factorizations)
        self.solves = self.krylov_iterations = self.factorizations = 0
        return out


# --------------------------------------------------------------------------
# The structured Jacobian
# --------------------------------------------------------------------------
class HBMJacobian:
    """``dR/dz`` of the condensed harmonic balance, kept in its pieces.

    Parameters
    ----------
    basis : jointsim.harmonics.HarmonicBasis
    lin : jointsim.solvers.condensation.ReducedLinear
    freq : jointsim.solvers.frequency_blocks.FrequencyBlocks
        The linear part at the Jacobian's frequency (its blocks, formed on first use,
        and its ``S_h``, shared by every Jacobian at that frequency,
        :meth:`jointsim.solvers.hbm.HBMSystem.harmonic_blocks`).
    t_row, n_row : ndarray of int, shape (n_e,)
        Slip and gap rows of each element among the ``n_r`` contact coordinates.
    Juu, Jug, JNN : ndarray, shape (n_e, n_c, n_c) or None
        AFT blocks (:class:`~jointsim.solvers.aft.AFTResult`).
    col : ndarray, shape (n_z,), optional
        Column scaling: the object is ``J diag(col)``.
    stats : LinearStats, optional
    cache : PreconditionerCache, optional
    rtol : float, optional
        GMRES tolerance of its solves (default ``KRYLOV_RTOL``; the error indicators
        use a looser one).
    """

    #: Newton may solve its steps with it inexactly (:attr:`BorderedJacobian.inexact_steps`)
    inexact_steps = True

    def __init__(self, basis, lin, freq, t_row, n_row, Juu=None, Jug=None, JNN=None,
                 col=None, stats=None, cache=None, rtol=None):
        self.basis, self.lin, self.freq = basis, lin, freq
        self.n_r = lin.n_r
        self.n_c = basis.n_coeff
        self.n_z = self.n_c * self.n_r
        self.shape = (self.n_z, self.n_z)
        self.t_row, self.n_row = t_row, n_row
        self.Juu, self.Jug, self.JNN = Juu, Jug, JNN
        self.col = np.ones(self.n_z) if col is None else np.asarray(col, dtype=float)
        self.stats = stats
        self.cache = cache if cache is not None else PreconditionerCache(reuse=False)
        self.rtol = KRYLOV_RTOL if rtol is None else float(rtol)
        h = list(basis.harmonics)
        self._ic = np.array([basis.index[k][0] for k in h])
        self._is = np.array([basis.index[k][1] if k else basis.index[k][0] for k in h])
        self._h0 = np.array([k == 0 for k in h])
        # S_h once formed (shared by scaled copies and Jacobians at the same frequency)
        self._S = freq.S
        self._products = [0]                  # unformed J v so far (shared by scaled copies)

    # -- pieces -------------------------------------------------------------------
    def scaled(self, col) -> "HBMJacobian":
        """``J diag(col)`` (same pieces, same cache)."""
        out = HBMJacobian(self.basis, self.lin, self.freq, self.t_row, self.n_row,
                          self.Juu, self.Jug, self.JNN, self.col * col, self.stats, self.cache,
                          self.rtol)
        out._products = self._products
        return out

    def form_schur(self) -> None:
        """Form and keep every ``S_h`` (n_r x n_r each), for fast products."""
        for i in range(len(self._S)):
            self.schur(i)

    def schur(self, i: int) -> np.ndarray:
        """``S_h`` (complex, n_r x n_r) of the ``i``-th harmonic (formed once, then kept).

        Returns the kept array itself, read-only (no copy: callers that modify it,
        like the preconditioner's build, copy it into their own storage).
        """
        if self._S[i] is None:
            S = self.freq.schur(i)
            S.flags.writeable = False
            self._S[i] = S
        return self._S[i]

    def _apply_S(self, Xc, herm: bool = False):
        """``S_h x_h`` (or ``S_h^H x_h``) for every harmonic; ``Xc`` (n_h, n_r[, k]) complex."""
        lin = self.lin
        out = np.empty_like(Xc)
        # the hierarchical form is cheaper than even the formed S_h
        products = None if herm else self.freq.hierarchical
        if products is None and all(S is not None for S in self._S):
            for i, S in enumerate(self._S):      # formed (n_r^2 per harmonic)
                out[i] = (S.conj().T @ Xc[i]) if herm else S @ Xc[i]
            return out
        if products is None and not herm:
            products = self.freq.dynamic
        if products is not None:                              # every harmonic at once
            X3 = Xc if Xc.ndim == 3 else Xc[:, :, None]          # (n_h, n_r, k)
            Y3 = products.apply(X3.transpose(1, 0, 2))           # (n_r, n_h, k)
            return Y3.transpose(1, 0, 2).reshape(Xc.shape)
        for i, (A, B, Bp, Ef) in enumerate(self.freq.blocks):
            x = Xc[i]
            if herm:
                # S^H = A^H - B'^H E^-H B^H; E is complex symmetric (E^T = E)
                v = A.conj().T @ x
                if lin.n_y:
                    v = v - Bp.conj().T @ np.conj(lin.solve_E(Ef, np.conj(B.conj().T @ x),
                                                             trans=True))
            else:
                v = A @ x
                if lin.n_y:
                    v = v - B @ lin.solve_E(Ef, Bp @ x)
            out[i] = v
        return out

    def _to_complex(self, V):
        return self.basis.to_complex(V)

    def _from_complex(self, Y, out):
        self.basis.from_complex(Y, out)

    def _elements(self, V, out, transpose: bool):
        """Add the element tangents' product to ``out``; ``V``, ``out`` (n_c, n_r[, k])."""
        sub = "elk,le...->ke..." if transpose else "ekl,le...->ke..."
        if self.Juu is not None:
            out[:, self.t_row] += np.einsum(sub, self.Juu, V[:, self.t_row])
        if self.Jug is not None:
            if transpose:
                out[:, self.n_row] += np.einsum(sub, self.Jug, V[:, self.t_row])
            else:
                out[:, self.t_row] += np.einsum(sub, self.Jug, V[:, self.n_row])
        if self.JNN is not None:
            out[:, self.n_row] -= np.einsum(sub, self.JNN, V[:, self.n_row])

    def matvec(self, v) -> np.ndarray:
        """``J @ v``, shape (n_z,), or ``J @ V`` for ``V`` of shape (n_z, k) (the
        blocks read once for the k columns); ``S_h`` is formed after ``FORM_AFTER``
        unformed products, unless the hierarchical form applies (it is cheaper)."""
        if self._S and self._S[-1] is None and self.freq.hierarchical is None:
            self._products[0] += 1
            if self._products[0] > FORM_AFTER:
                self.form_schur()
        v = np.asarray(v, dtype=float)
        col = self.col if v.ndim == 1 else self.col[:, None]
        V = (v * col).reshape((self.n_c, self.n_r) + v.shape[1:])
        out = np.zeros_like(V)
        self._from_complex(self._apply_S(self._to_complex(V)), out)
        self._elements(V, out, transpose=False)
        return out.reshape(v.shape)

    def rmatvec(self, w) -> np.ndarray:
        """``J^T @ w``, shape (n_z,)."""
        W = np.asarray(w, dtype=float).reshape(self.n_c, self.n_r)
        out = np.zeros_like(W)
        self._from_complex(self._apply_S(self._to_complex(W), herm=True), out)
        self._elements(W, out, transpose=True)
        return out.ravel() * self.col

    __matmul__ = matvec

    def to_dense(self) -> np.ndarray:
        """The dense ``J diag(col)`` (n_z, n_z): the reference path and tests only."""
        nr = self.n_r
        J = np.zeros(self.shape)
        fill_harmonic_blocks(J, np.stack([self.schur(i) for i in range(len(self._ic))]),
                             self.basis)
        add_element_blocks(J, nr, self.n_c, self.t_row, self.n_row, self.Juu, self.Jug,
                           self.JNN)
        return J * self.col[None, :]

    def max_abs(self) -> float:
        """``max |J_ij|`` of the unscaled ``J`` without forming it.

        Per harmonic, the entries of ``S_h`` that no element tangent reaches are read
        in place, and only the reached ones (one per element and tangent kind) are
        summed: the same sums as writing the blocks into a ``2 n_r x 2 n_r`` array, whose
        copies cost 0.27 s at 480 Gauss points (round 48)."""
        parts = [(J, self.t_row, self.t_row, 1.0) for J in (self.Juu,) if J is not None]
        parts += [(J, self.t_row, self.n_row, 1.0) for J in (self.Jug,) if J is not None]
        parts += [(J, self.n_row, self.n_row, -1.0) for J in (self.JNN,) if J is not None]
        m = 0.0
        for i, h in enumerate(self.basis.harmonics):
            cols = [self._ic[i]] + ([self._is[i]] if h else [])
            S = self.schur(i)
            # the cosine/sine sub-blocks: Re S (cc, ss), Im S (cs), -Im S (sc)
            kinds = [np.abs(S.real)] + ([np.abs(S.imag)] if h else [])
            for A in kinds:
                for _, r, c, _ in parts:
                    A[r, c] = 0.0
                m = max(m, float(A.max(initial=0.0)))
            for a, ka in enumerate(cols):
                for b, kb in enumerate(cols):
                    for J, r, c, sign in parts:
                        base = S.real[r, c] if a == b else \
                            (S.imag[r, c] if a < b else -S.imag[r, c])
                        val = base + J[:, ka, kb] if sign > 0 else base - J[:, ka, kb]
                        m = max(m, float(np.abs(val).max(initial=0.0)))
        hk = self.basis.hk
        other = hk[:, None] != hk[None, :]          # coefficient pairs of distinct harmonics
        for Jb in (self.Juu, self.Jug, self.JNN):
            if Jb is not None and other.any():
                m = max(m, float(np.abs(Jb[:, other]).max(initial=0.0)))
        return m

    # -- solves -----------------------------------------------------------------------
    def solve_uncoupled(self, b, tol: float = 1e-8, flexibility=None) -> np.ndarray | None:
        """``J^-1 b`` harmonic by harmonic, for a contact tangent that couples no
        harmonics (every element stuck, or open, over the whole period: the linearised
        joint at its static state).

        Only the harmonics where ``b`` is above ``1e-13`` of its largest entry are
        solved, each by one complex ``n_r`` LU of ``S_h`` plus the harmonic projection
        of the tangent; no other ``S_h`` is formed (a full preconditioner forms and
        inverts every harmonic's).  With the stuck joint's ``flexibility`` given, by
        it first (no ``S_h`` and no LU), refined by up to ``UNCOUPLED_REFINE`` steps
        against ``J``; the LU where that does not meet ``tol`` (a tangent that is not
        the stuck one).

        Parameters
        ----------
        b : ndarray, shape (n_z,)
        tol : float
            Relative residual ``max |J x - b| / max |b|`` the result must meet (a
            coupling tangent misses it by orders of magnitude; at a lightly damped
            resonance the round-off of the products alone reaches about 1e-10).
        flexibility : jointsim.solvers.flexibility.StuckFlexibility, optional
            ``(S_h + diag(k))^-1`` of the model (``self.lin.flexibility``), where it is
            made anyway (it costs an eigen-decomposition).

        Returns
        -------
        ndarray, shape (n_z,), or None
            None when it does not meet ``tol`` (the tangent couples harmonics): solve
            in full then.
        """
        b = np.asarray(b, dtype=float)
        bmax = float(np.abs(b).max(initial=0.0))
        Bc = self._to_complex(b.reshape(self.n_c, self.n_r))
        active = np.flatnonzero(np.abs(Bc).max(axis=1, initial=0.0) > 1e-13 * bmax)
        if flexibility is not None:
            x = self._solve_stuck(flexibility, b, Bc, active, tol * bmax)
            if x is not None:
                return x
        Y = np.zeros_like(Bc)
        for i in active:
            P = np.array(self.schur(i), dtype=complex)
            add_projected_tangent(P, self, i)
            Y[i] = np.linalg.solve(P, Bc[i])
        Y[self._h0] = Y[self._h0].real
        out = np.empty((self.n_c, self.n_r))
        self._from_complex(Y, out)
        x = out.ravel() / self.col
        if not np.all(np.isfinite(x)) \
                or not np.abs(self.matvec(x) - b).max(initial=0.0) <= tol * bmax:
            return None
        return x

    def _solve_stuck(self, flex, b, Bc, active, atol: float):
        """:meth:`solve_uncoupled` by the stuck flexibility (first on the ``active``
        harmonics, then refined on all); None where it does not reach ``max |J x - b| <=
        atol``."""
        nus = np.asarray(self.basis.harmonics, dtype=float) * self.freq.omega
        xi = self.freq.xi
        out = np.empty((self.n_c, self.n_r))

        def step(Rc, rows):
            Y = np.zeros_like(Rc)
            Y[rows] = flex.solve(nus[rows], Rc[rows], xi)
            Y[self._h0] = Y[self._h0].real
            self._from_complex(Y, out)
            return out.ravel() / self.col
        flex.prepare(float(nus.max(initial=0.0)))    # one series for both steps (all harmonics)
        x = step(Bc, active)
        for _ in range(UNCOUPLED_REFINE + 1):
            r = b - self.matvec(x)
            if not np.all(np.isfinite(r)):
                return None
            if np.abs(r).max(initial=0.0) <= atol:
                return x
            x = x + step(self._to_complex(r.reshape(self.n_c, self.n_r)),
                          np.arange(len(nus)))
        return None

    def solve(self, b, rtol=None) -> np.ndarray:
        """``J^-1 b`` by preconditioned GMRES to ``rtol`` (default and least
        :attr:`rtol`; see :func:`krylov_solve`)."""
        b = np.asarray(b, dtype=float)
        col = self.col[:, None] if b.ndim == 2 else self.col

        def capacitance(P):     # J^-1 by the capacitance solves (not of a shifted P)
            def step(r, tau):
                dx, it = P.solve_capacitance(r, tau)
                return dx / col, it
            return step if P.C2 is None else None
        return krylov_solve(self, self.matvec, b, lambda P: (lambda v: P.apply(v, self)),
                            rtol=rtol, capacitance=capacitance)


def fill_harmonic_blocks(J, S, basis) -> None:
    """Write ``S_h`` of every kept harmonic into the dense ``J`` (n_z, n_z), index
    ``k n_r + r``: the real blocks ``[[Re, Im], [-Im, Re]]`` of its cosine and sine
    rows (``Re`` alone for h = 0).

    Parameters
    ----------
    J : ndarray, shape (n_c n_r, n_c n_r)
        Written in place (any other entry is left as it is).
    S : ndarray, shape (n_h, n_r, n_r), complex
    basis : jointsim.harmonics.HarmonicBasis
    """
    nr = S.shape[1]
    r = np.arange(nr)
    rc = (basis.rows_cos * nr)[:, None] + r                              # (n_h, n_r)
    rs = (basis.rows_sin * nr)[:, None] + r
    Sp, rcp = S[basis.has_sine], rc[basis.has_sine]
    J[rc[:, :, None], rc[:, None, :]] = S.real
    J[rcp[:, :, None], rs[:, None, :]] = Sp.imag
    J[rs[:, :, None], rcp[:, None, :]] = -Sp.imag
    J[rs[:, :, None], rs[:, None, :]] = Sp.real


def add_element_blocks(J, nr, nc, t_row, n_row, Juu, Jug, JNN):
    """Add the AFT element blocks into a dense harmonic-major ``J`` (n_c n_r, n_c n_r)."""
    k = np.arange(nc)

    def idx(rows):
        return rows[:, None, None] + nr * k[None, :, None], \
            rows[:, None, None] + nr * k[None, None, :]
    if Juu is not None:
        ri, ci = idx(t_row)
        J[ri, ci] += Juu
    if Jug is not None:
        ri, _ = idx(t_row)
        _, cj = idx(n_row)
        J[ri, cj] += Jug
    if JNN is not None:
        ri, ci = idx(n_row)
        J[ri, ci] -= JNN


def krylov_solve(core: HBMJacobian, matvec, b, make_psolve, shift=None, rtol=None,
                 capacitance=None):
    """GMRES for ``A x = b`` with the preconditioner of ``core`` (cached or rebuilt);
    ``b`` of shape (n,) or (n, k) (the columns in lockstep, :func:`gmres_columns`).

    A reused preconditioner gets :meth:`PreconditionerCache.budget` GMRES
    iterations; when they do not suffice the solve is repeated with one built
    from ``core`` (with ``shift``, see
    :class:`~jointsim.solvers.preconditioner.HarmonicPreconditioner`), except
    when GMRES stopped at the round-off floor within ``FLOOR_FACTOR`` of the
    tolerance (a new preconditioner stops there too).  GMRES stops at
    ``core.rtol`` (or at ``rtol`` when that is looser: an inexact Newton step,
    :mod:`jointsim.solvers.newton`) or when a restart cycle stagnates
    (:func:`gmres`).  Raises ``RuntimeError`` when GMRES does not reach
    ``KRYLOV_RTOL`` and reduces the residual by less than ``1e-6`` (Newton treats
    that as a singular Jacobian).  ``capacitance(P)``, for a fresh preconditioner
    whose low-rank stage is split (:attr:`~.preconditioner.HarmonicPreconditioner.
    capacitance_solves`), gives the step of :func:`_capacitance_refined` (or None),
    which solves first.
    """
    cache, stats = core.cache, core.stats
    rtol = core.rtol if rtol is None else max(core.rtol, float(rtol))
    multi = b.ndim == 2

    def run(P, maxiter=KRYLOV_MAXITER, x0=None):
        """GMRES with ``P``: ``(result, iterations of all columns)``."""
        if not multi:
            res = gmres(matvec, b, make_psolve(P), rtol=rtol, maxiter=maxiter, x0=x0)
            return res, res.iterations
        cols = gmres_columns(matvec, b, make_psolve(P), rtol=rtol, maxiter=maxiter, X0=x0)
        rel = max(r.relres for r in cols)
        # the columns are one solve: iterations (for the reuse policy) and residual of
        # the worst column; at the floor when every column short of rtol is
        res = GMRESResult(np.column_stack([r.x for r in cols]),
                          max(r.iterations for r in cols), rel,
                          all(r.at_floor for r in cols if r.relres > rtol))
        return res, sum(r.iterations for r in cols)
    # S_h is formed (n_r^2 n_y per harmonic) only when a preconditioner is built in full
    # from core; a reused or partial one leaves J v to the unformed products
    # A v - B E^-1 (B' v)
    P, fresh = cache.get(core, shift)
    total, x = 0, None
    step = capacitance(P) if capacitance is not None and fresh and P.capacitance_solves \
        else None
    if step is not None:
        # a split low-rank stage: GMRES on its capacitance system, refined on the
        # system itself (its P^-1 and G are in single precision), then checked below
        x, total = _capacitance_refined(step, matvec, b, rtol)
    while True:
        # a reused preconditioner gets a short budget before it is rebuilt, and so does
        # a partial one (the harmonic stage of an earlier build, SHARE_HARMONIC_STAGE)
        trial = not fresh or P.partial
        maxiter = KRYLOV_MAXITER if not trial else \
            cache.partial_budget() if fresh else cache.budget()
        (x, it, rel, at_floor), more = run(P, maxiter, x0=x)
        total += more
        # on from where it got to with a new one (a full one after a partial one), but
        # not when GMRES stopped at the round-off floor: a new one stops there too
        # (FLOOR_FACTOR)
        if rel <= rtol or not trial or (at_floor and rel <= FLOOR_FACTOR * rtol):
            break
        P, fresh = cache.refresh(core, shift, full=fresh), True
    if stats is not None:
        stats.solves += b.shape[1] if multi else 1
        stats.krylov_iterations += total
    cache.after_solve(it, fresh)
    log.debug("GMRES: %d iterations (%d in the last run, fresh %s, partial %s, truncated %s)",
              total, it, fresh, P.partial, getattr(P, "truncated", None))
    if not np.all(np.isfinite(x)) or rel > max(1e-6, rtol):
        raise RuntimeError(f"GMRES reached only {rel:.1e} relative residual in {total} "
                           f"iterations")
    if rel > rtol:
        log.debug("GMRES stopped at %.1e relative residual after %d iterations", rel, total)
    return x


def _capacitance_refined(step, matvec, b, rtol: float):
    """``x`` with ``|b - A x| <= CAPACITANCE_MARGIN rtol |b|`` per column, or the last of
    ``CAPACITANCE_REFINE`` steps: each, ``step(r, tau) -> (dx, GMRES iterations)``,
    solves the residual's equation by
    :meth:`~jointsim.solvers.preconditioner.HarmonicPreconditioner.solve_capacitance`
    (to ``CAPACITANCE_MARGIN rtol |b|``, or to ``CAPACITANCE_STEP`` of the residual when
    that is looser: a step's gain is limited by its single precision) and the
    residual is recomputed with ``matvec``; it stops after a step that did not bring a
    column's residual below ``CAPACITANCE_GAIN`` of what it was, undone when it raised
    it.  Returns ``(x, GMRES iterations)``."""
    bn = np.linalg.norm(b, axis=0)
    x, r, total = np.zeros_like(b), b, 0
    target = CAPACITANCE_MARGIN * rtol
    for _ in range(CAPACITANCE_REFINE):
        rn = np.linalg.norm(r, axis=0)
        if np.all(rn <= target * bn) or not np.all(np.isfinite(rn)):
            break       # done, or failed (GMRES on the system then starts from zero)
        tau = max(target * float(np.min(bn[rn > 0] / rn[rn > 0])), CAPACITANCE_STEP)
        dx, it = step(r, tau)
        total += it
        r_new = b - matvec(x + dx)
        gain = np.linalg.norm(r_new, axis=0)[rn > 0] / rn[rn > 0]
        if not np.all(gain <= 1.0):         # worse, or not finite: undone
            break
        x, r = x + dx, r_new
        if not np.all(gain <= CAPACITANCE_GAIN):
            break       # too little gained: GMRES on the system finishes
    return x, total


class BorderedJacobian:
    """``[[J, C], [R, D]]``: a structured ``J`` (n_z, n_z) with dense borders.

    Parameters
    ----------
    J : HBMJacobian
    C : ndarray, shape (n_z, k), optional
        Extra columns.
    R : ndarray, shape (m, n_z), optional
        Extra rows (their ``J`` part).
    D : ndarray, shape (m, k), optional
        Corner.
    deflate : tuple (i, ell), optional
        The first two rows of ``R`` are ``Re`` and ``Im`` of ``ell^T (X_c - i X_s)``
        over the ``i``-th harmonic (``ell`` complex (n_r,), unscaled): the EPMC
        amplitude and phase conditions.  The preconditioner is then built for
        ``J + C2 R2`` (a rank-one term in that harmonic's block along the first
        column of ``C``), which stays regular where ``J`` is singular (the mode of
        the linear range), and the bordering is done exactly for that shift
        (:meth:`solve`).
    """

    def __init__(self, J: HBMJacobian, C=None, R=None, D=None, deflate=None):
        nz = J.n_z
        self.J = J
        self.deflate = deflate
        self.C = np.zeros((nz, 0)) if C is None else np.asarray(C, dtype=float).reshape(nz, -1)
        k = self.C.shape[1]
        self.R = np.zeros((0, nz)) if R is None else np.asarray(R, dtype=float).reshape(-1, nz)
        m = self.R.shape[0]
        self.D = np.zeros((m, k)) if D is None else np.asarray(D, dtype=float).reshape(m, k)
        self.shape = (nz + m, nz + k)

    @property
    def inexact_steps(self) -> bool:
        """Whether a Newton step with this Jacobian may be solved inexactly
        (:mod:`jointsim.solvers.newton`, ``forcing``): not for the EPMC's deflated
        systems, whose frequency and damping directions are nearly singular (measured
        on the SDOF Jenkins backbone: a step residual of 0.1 times the Newton
        tolerance moved X by 1.6e-6 relative, against the 1e-8 the Krylov path keeps
        to the dense one)."""
        return self.deflate is None

    def matvec(self, v) -> np.ndarray:
        nz = self.J.n_z
        v = np.asarray(v, dtype=float)
        return np.concatenate([self.J.matvec(v[:nz]) + self.C @ v[nz:],
                               self.R @ v[:nz] + self.D @ v[nz:]])

    __matmul__ = matvec

    def to_dense(self) -> np.ndarray:
        return np.block([[self.J.to_dense(), self.C], [self.R, self.D]])

    def with_row(self, r) -> "BorderedJacobian":
        """The operator with the row ``r`` (n_z + k,) appended."""
        nz = self.J.n_z
        r = np.asarray(r, dtype=float)
        return BorderedJacobian(self.J, self.C, np.vstack([self.R, r[None, :nz]]),
                                np.vstack([self.D, r[None, nz:]]), self.deflate)

    def without_last_column(self) -> "BorderedJacobian":
        return BorderedJacobian(self.J, self.C[:, :-1], self.R, self.D[:, :-1], self.deflate)

    def scaled(self, col) -> "BorderedJacobian":
        """``A diag(col)``."""
        nz = self.J.n_z
        col = np.asarray(col, dtype=float)
        return BorderedJacobian(self.J.scaled(col[:nz]), self.C * col[nz:], self.R * col[:nz],
                                self.D * col[nz:], self.deflate)

    def solve(self, b, rtol=None) -> np.ndarray:
        """``A^-1 b`` (square ``A``) by GMRES preconditioned by bordering, to ``rtol``
        (default and least ``J.rtol``).

        With ``M = J + C2 R2`` (``C2 = 0`` without ``deflate``; ``R2`` the first two
        rows of ``R``, padded with zero rows) the bordered system
        ``J x + C s = v``, ``R x + D s = t`` is exactly
        ``x = M^-1 (v + C2 t_2 - (C + C2 D_2) s)`` with ``s`` from the small system
        ``(D - R M^-1 (C + C2 D_2)) s = t - R M^-1 (v + C2 t_2)``;
        the preconditioner applies it with ``P^-1`` in place of ``M^-1``.
        """
        if self.shape[0] != self.shape[1]:
            raise ValueError(f"cannot solve with a {self.shape} bordered Jacobian")
        J, C, R, D = self.J, self.C, self.R, self.D
        nz = J.n_z
        if C.shape[1] == 0:
            return J.solve(b, rtol=rtol)
        shift = None
        if self.deflate is not None and R.shape[0] >= 2:
            i, ell = self.deflate
            c = C[:, 0].reshape(J.n_c, J.n_r)
            u = c[J._ic[i]] - 1j * (c[J._is[i]] if not J._h0[i] else 0.0)
            shift = (i, u, ell)

        def bordering(P):
            """``C + C2 D_2`` and ``v -> v + C2 t_2`` for ``P``'s shift."""
            C2 = getattr(P, "C2", None)
            if C2 is None or R.shape[0] < 2:
                return C, lambda v: v[:nz]
            return C + C2 @ D[:2], lambda v: v[:nz] + C2 @ v[nz:nz + 2]

        def make_psolve(P):
            def pj(v):
                return P.apply(v, J)
            Ce, lift = bordering(P)
            got = {}

            def psolve(v):
                if not got:     # P^-1 (C + C2 D_2), on the first use (a GMRES run from
                    X = pj(Ce)  # a solution makes none; every column in one application)
                    got.update(X=X, Sinv=np.linalg.pinv(D - R @ X))
                w = pj(lift(v))
                s = got["Sinv"] @ (v[nz:] - R @ w)
                return np.concatenate([w - got["X"] @ s, s])
            return psolve

        def capacitance(P):
            """The bordering's steps with ``M^-1`` by the capacitance solves of a split
            low-rank stage (``M`` holds the shift: the EPMC indicators' loose solves)."""
            Ce, lift = bordering(P)
            col = J.col[:, None]
            got = {}

            def step(r, tau):
                r2 = r.reshape(r.shape[0], -1)
                it = 0
                if "X" not in got:      # M^-1 (C + C2 D_2), once (BORDER_RTOL)
                    X, it = P.solve_capacitance(Ce, min(tau, BORDER_RTOL))
                    got["X"] = X / col
                    got["Sinv"] = np.linalg.pinv(D - R @ got["X"])
                Y, more = P.solve_capacitance(lift(r2), tau)
                Y = Y / col
                s = got["Sinv"] @ (r2[nz:] - R @ Y)
                return np.concatenate([Y - got["X"] @ s, s]).reshape(r.shape), it + more
            return step
        return krylov_solve(J, self.matvec, np.asarray(b, dtype=float), make_psolve, shift,
                            rtol=rtol, capacitance=capacitance)


# --------------------------------------------------------------------------
# Helpers working on dense arrays and structured Jacobians alike
# --------------------------------------------------------------------------
def is_structured(A) -> bool:
    return isinstance(A, (HBMJacobian, BorderedJacobian))


def solve(A, b, rtol=None) -> np.ndarray:
    """``A^-1 b``: dense LU (least squares when singular) or the structured solve (to
    ``rtol``, default its own tolerance; a dense solve is exact)."""
    if is_structured(A):
        return A.solve(b, rtol=rtol)
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, b, rcond=None)[0]


def append_row(A, r):
    """``[A; r^T]``."""
    if isinstance(A, BorderedJacobian):
        return A.with_row(r)
    if isinstance(A, HBMJacobian):
        return BorderedJacobian(A).with_row(r)
    return np.vstack([A, np.asarray(r)[None, :]])


def drop_last_column(A):
    """``A[:, :-1]``."""
    if isinstance(A, BorderedJacobian):
        return A.without_last_column()
    return A[:, :-1]


def scale_columns(A, col):
    """``A diag(col)``."""
    if is_structured(A):
        return A.scaled(col)
    return A * np.asarray(col)[None, :]
