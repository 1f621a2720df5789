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
without forming ``J`` (``S_h v = A v - B E^-1 (B' v)``, never formed
either); :meth:`HBMJacobian.to_dense` is the reference.  Its preconditioner
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
and GMRES do the rest.

:class:`BorderedJacobian` is ``[[J, C], [R, D]]`` with a few dense columns
and rows (``dR/domega``, the EPMC unknowns and phase conditions, the
continuation's hyperplane); it is solved by GMRES preconditioned by
bordering the harmonic preconditioner (one extra preconditioner solve per
column and an ``m x m`` Schur complement), which stays regular through
turning points.

The preconditioner is reused across Newton iterations and continuation
steps through a :class:`~jointsim.solvers.preconditioner.PreconditionerCache` owned by the system (an
explicit object, not module state) while that pays by its flop cost model
(:meth:`~jointsim.solvers.preconditioner.PreconditionerCache.threshold`), and
rebuilt when GMRES fails with the old one within that budget.  Every solve is counted in a :class:`LinearStats`.

:func:`solve`, :func:`append_row`, :func:`drop_last_column` and
:func:`scale_columns` work on dense arrays and on these objects alike; the
Newton loop and the continuation use them.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.linalg as sla

from .preconditioner import PreconditionerCache

log = logging.getLogger(__name__)

#: Relative residual ``|b - A x| / |b|`` at which GMRES stops.
KRYLOV_RTOL = 1e-11
#: GMRES restart length and iteration limit.
KRYLOV_RESTART = 80
KRYLOV_MAXITER = 400
#: GMRES stops (stagnation) after a restart cycle that reduced the true residual by
#: less than this factor.
STAGNATION = 0.5
#: A reused preconditioner's solve that stopped at the round-off floor
#: (:attr:`GMRESResult.at_floor`) is accepted up to this many times the tolerance
#: instead of building a new preconditioner and going on: the new one reaches the same
#: floor.  Measured on the 96-Gauss-point lap joint's force-0.02 branch (round 13):
#: 58 of 110 solves rebuilt after stopping at 1.4e-11 to 1.5e-10 (rtol 1e-11), and
#: the rebuilt ones stopped at 1.4e-11 to 1.7e-10 after one more iteration.
FLOOR_FACTOR = 1e3
#: Unknowns ``n_z`` from which ``linear_solver = "auto"`` chooses Krylov.
KRYLOV_MIN_UNKNOWNS = 1200
LINEAR_SOLVERS = ("auto", "direct", "krylov")
#: Unformed products ``A v - B E^-1 (B' v)`` of one Jacobian after which its ``S_h``
#: are formed (a product costs about three formed ones; forming, a BLAS-3 product
#: of ``n_r^2 n_y`` per harmonic, about as much as ten to twenty of them).
FORM_AFTER = 12

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
        Preconditioners built (each ``H + 1`` LUs of ``n_r x n_r``).
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
# GMRES
# --------------------------------------------------------------------------
class GMRESResult(NamedTuple):
    """What :func:`gmres` returns."""

    x: np.ndarray
    iterations: int
    relres: float
    at_floor: bool


def gmres(matvec, b, psolve, rtol: float = KRYLOV_RTOL, restart: int = KRYLOV_RESTART,
          maxiter: int = KRYLOV_MAXITER, x0=None):
    """Right-preconditioned restarted GMRES for ``A x = b`` (real).

    Minimises ``|b - A P^-1 u|`` over the Krylov space of ``A P^-1``, with
    ``x = P^-1 u`` (so the residual it monitors is the true one, up to
    round-off; it is recomputed at every restart and at the end).

    Parameters
    ----------
    matvec : callable
        ``v -> A v``.
    b : ndarray, shape (n,)
    psolve : callable
        ``v -> P^-1 v``.
    rtol : float
        Stop at ``|b - A x| <= rtol |b|``.
    restart, maxiter : int
    x0 : ndarray, shape (n,), optional
        Start (default zero), e.g. the result of an attempt that ran out of
        iterations.

    Returns
    -------
    GMRESResult
        ``(x, iterations, relres, at_floor)``: the solution, shape (n,), the
        iterations, ``|b - A x| / |b|``, and whether GMRES stopped at the
        round-off floor (below).

    Notes
    -----
    Besides ``rtol`` and ``maxiter`` it stops when a restart cycle reduced the
    true residual by less than ``1 / STAGNATION``; ``relres`` then tells the
    caller how far it got.  ``at_floor``: the last cycle's own (Arnoldi)
    residual reached ``rtol`` but the recomputed true one did not: the
    residual floor of an ill-conditioned system (near a lightly damped
    resonance, 1e-11 to 2e-10 at 96 contact points), which no better
    preconditioner lowers (:func:`krylov_solve`).
    """
    n = b.size
    bn = float(np.linalg.norm(b))
    x = np.zeros(n)
    if bn == 0.0 or n == 0:
        return GMRESResult(x, 0, 0.0, False)
    total = 0
    r = b.copy()
    beta = bn
    if x0 is not None and np.all(np.isfinite(x0)):
        r0 = b - matvec(x0)
        if float(np.linalg.norm(r0)) < bn:          # a better start than zero
            x, r, beta = np.array(x0, dtype=float), r0, float(np.linalg.norm(r0))
    while True:
        if beta <= rtol * bn or total >= maxiter:
            return GMRESResult(x, total, beta / bn, False)
        m = min(restart, maxiter - total)
        V = np.zeros((m + 1, n))
        Zp = np.zeros((m, n))
        H = np.zeros((m + 1, m))
        cs, sn = np.zeros(m), np.zeros(m)
        g = np.zeros(m + 1)
        g[0] = beta
        V[0] = r / beta
        j_end = 0
        converged = False
        for j in range(m):
            Zp[j] = psolve(V[j])
            w = matvec(Zp[j])
            for _ in range(2):                      # classical Gram-Schmidt, twice
                hj = V[:j + 1] @ w
                w -= hj @ V[:j + 1]
                H[:j + 1, j] += hj
            hn = float(np.linalg.norm(w))
            H[j + 1, j] = hn
            if hn > 0.0:
                V[j + 1] = w / hn
            for i in range(j):                      # earlier rotations
                t = cs[i] * H[i, j] + sn[i] * H[i + 1, j]
                H[i + 1, j] = -sn[i] * H[i, j] + cs[i] * H[i + 1, j]
                H[i, j] = t
            d = np.hypot(H[j, j], H[j + 1, j])
            cs[j], sn[j] = (1.0, 0.0) if d == 0.0 else (H[j, j] / d, H[j + 1, j] / d)
            H[j, j] = d
            H[j + 1, j] = 0.0
            g[j + 1] = -sn[j] * g[j]
            g[j] = cs[j] * g[j]
            total += 1
            j_end = j + 1
            converged = abs(g[j + 1]) <= 0.5 * rtol * bn
            if converged or hn == 0.0:
                break
        y = sla.solve_triangular(H[:j_end, :j_end], g[:j_end], check_finite=False)
        x = x + y @ Zp[:j_end]
        r = b - matvec(x)
        beta_start, beta = beta, float(np.linalg.norm(r))
        if j_end < m and beta > rtol * bn and hn == 0.0:  # breakdown without convergence
            return GMRESResult(x, total, beta / bn, False)
        if beta > rtol * bn and beta > STAGNATION * beta_start:
            # a whole cycle gained less than 1/STAGNATION: the true residual is at the
            # floor that the conditioning allows (e.g. the bordered EPMC system in the
            # linear range, 2e-11 .. 2e-9 at 121 pairs); the caller judges the result
            return GMRESResult(x, total, beta / bn, converged)


# --------------------------------------------------------------------------
# The structured Jacobian
# --------------------------------------------------------------------------
class HBMJacobian:
    """``dR/dz`` of the condensed harmonic balance, kept in its pieces.

    Parameters
    ----------
    basis : jointsim.harmonics.HarmonicBasis
    lin : jointsim.solvers.condensation.ReducedLinear
    blocks : list of tuple
        Per harmonic of ``basis.harmonics``: ``(A, B, B', Ef)`` of
        :meth:`ReducedLinear.blocks` (``Ef`` prepared by ``factor_E``).
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
    schur : list, optional
        The ``S_h`` list (entries None until formed) shared by every Jacobian at the
        same frequency (:meth:`jointsim.solvers.hbm.HBMSystem.harmonic_blocks`);
        default a list of its own.
    """

    def __init__(self, basis, lin, blocks, t_row, n_row, Juu=None, Jug=None, JNN=None,
                 col=None, stats=None, cache=None, rtol=None, schur=None):
        self.basis, self.lin, self.blocks = basis, lin, blocks
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
        self._S = [None] * len(blocks) if schur is None else schur
        self._products = [0]                  # unformed J v so far (shared likewise)

    # -- pieces -------------------------------------------------------------------
    def scaled(self, col) -> "HBMJacobian":
        """``J diag(col)`` (same pieces, same cache)."""
        out = HBMJacobian(self.basis, self.lin, self.blocks, self.t_row, self.n_row,
                          self.Juu, self.Jug, self.JNN, self.col * col, self.stats, self.cache,
                          self.rtol)
        out._S = self._S
        out._products = self._products
        return out

    def form_schur(self) -> None:
        """Form and keep every ``S_h`` (n_r x n_r each), for fast products."""
        for i in range(len(self.blocks)):
            self.schur(i)

    def schur(self, i: int) -> np.ndarray:
        """``S_h`` (complex, n_r x n_r) of the ``i``-th harmonic (formed once, then kept).

        Returns the kept array itself, read-only (no copy: callers that modify it,
        like the preconditioner's build, copy it into their own storage).
        """
        if self._S[i] is None:
            A, B, Bp, Ef = self.blocks[i]
            S = np.array(A, dtype=complex) if not self.lin.n_y \
                else A - B @ self.lin.solve_E(Ef, Bp)
            S.flags.writeable = False
            self._S[i] = S
        return self._S[i]

    def _apply_S(self, Xc, herm: bool = False):
        """``S_h x_h`` (or ``S_h^H x_h``) for every harmonic; ``Xc`` (n_h, n_r) complex."""
        lin = self.lin
        out = np.empty_like(Xc)
        if all(S is not None for S in self._S):
            for i, S in enumerate(self._S):      # formed (n_r^2 per harmonic)
                out[i] = (S.conj().T @ Xc[i]) if herm else S @ Xc[i]
            return out
        for i, (A, B, Bp, Ef) in enumerate(self.blocks):
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
        X = V[self._ic] - 1j * V[self._is]
        X[self._h0] = V[self._ic[self._h0]]
        return X

    def _from_complex(self, Y, out):
        out[self._ic] = Y.real
        hs = ~self._h0
        out[self._is[hs]] = -Y[hs].imag

    def _elements(self, V, out, transpose: bool):
        sub = "elk,el->ek" if transpose else "ekl,el->ek"
        if self.Juu is not None:
            out[:, self.t_row] += np.einsum(sub, self.Juu, V[:, self.t_row].T).T
        if self.Jug is not None:
            if transpose:
                out[:, self.n_row] += np.einsum(sub, self.Jug, V[:, self.t_row].T).T
            else:
                out[:, self.t_row] += np.einsum(sub, self.Jug, V[:, self.n_row].T).T
        if self.JNN is not None:
            out[:, self.n_row] -= np.einsum(sub, self.JNN, V[:, self.n_row].T).T

    def matvec(self, v) -> np.ndarray:
        """``J @ v``, shape (n_z,) (``S_h`` formed after ``FORM_AFTER`` unformed products)."""
        if self._S and self._S[-1] is None:
            self._products[0] += 1
            if self._products[0] > FORM_AFTER:
                self.form_schur()
        V = (np.asarray(v, dtype=float) * self.col).reshape(self.n_c, self.n_r)
        out = np.zeros_like(V)
        self._from_complex(self._apply_S(self._to_complex(V)), out)
        self._elements(V, out, transpose=False)
        return out.ravel()

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
        for i, h in enumerate(self.basis.harmonics):
            S = self.schur(i)
            rc = self._ic[i] * nr + np.arange(nr)
            J[np.ix_(rc, rc)] = S.real
            if h:
                rs = self._is[i] * nr + np.arange(nr)
                J[np.ix_(rc, rs)] = S.imag
                J[np.ix_(rs, rc)] = -S.imag
                J[np.ix_(rs, rs)] = S.real
        add_element_blocks(J, nr, self.n_c, self.t_row, self.n_row, self.Juu, self.Jug,
                           self.JNN)
        return J * self.col[None, :]

    def max_abs(self) -> float:
        """``max |J_ij|`` of the unscaled ``J`` without forming it."""
        nr = self.n_r
        m = 0.0
        for i, h in enumerate(self.basis.harmonics):
            cols = [self._ic[i]] + ([self._is[i]] if h else [])
            S = self.schur(i)
            blk = np.zeros((len(cols) * nr, len(cols) * nr))
            blk[:nr, :nr] = S.real
            if h:
                blk[:nr, nr:], blk[nr:, :nr], blk[nr:, nr:] = S.imag, -S.imag, S.real
            sub = [(a, b) for a in range(len(cols)) for b in range(len(cols))]
            for a, b in sub:
                ka, kb = cols[a], cols[b]
                r0, c0 = a * nr, b * nr
                if self.Juu is not None:
                    blk[r0 + self.t_row, c0 + self.t_row] += self.Juu[:, ka, kb]
                if self.Jug is not None:
                    blk[r0 + self.t_row, c0 + self.n_row] += self.Jug[:, ka, kb]
                if self.JNN is not None:
                    blk[r0 + self.n_row, c0 + self.n_row] -= self.JNN[:, ka, kb]
            m = max(m, float(np.abs(blk).max(initial=0.0)))
        hk = self.basis.hk
        other = hk[:, None] != hk[None, :]          # coefficient pairs of distinct harmonics
        for Jb in (self.Juu, self.Jug, self.JNN):
            if Jb is not None and other.any():
                m = max(m, float(np.abs(Jb[:, other]).max(initial=0.0)))
        return m

    # -- solves -----------------------------------------------------------------------
    def solve(self, b) -> np.ndarray:
        """``J^-1 b`` by preconditioned GMRES (see :func:`krylov_solve`)."""
        return krylov_solve(self, self.matvec, np.asarray(b, dtype=float),
                            lambda P: (lambda v: P.apply(v, self)))


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


def krylov_solve(core: HBMJacobian, matvec, b, make_psolve, shift=None):
    """GMRES for ``A x = b`` with the preconditioner of ``core`` (cached or rebuilt).

    A reused preconditioner gets :meth:`PreconditionerCache.budget` GMRES
    iterations; when they do not suffice the solve is repeated with one built
    from ``core`` (with ``shift``, see
    :class:`~jointsim.solvers.preconditioner.HarmonicPreconditioner`), except
    when GMRES stopped at the round-off floor within ``FLOOR_FACTOR`` of the
    tolerance (a new preconditioner stops there too).  GMRES stops at
    ``core.rtol`` or when a restart cycle stagnates (:func:`gmres`).  Raises
    ``RuntimeError`` when GMRES does not reach ``KRYLOV_RTOL`` and reduces the
    residual by less than ``1e-6`` (Newton treats that as a singular Jacobian).
    """
    cache, stats = core.cache, core.stats
    # S_h is formed (n_r^2 n_y per harmonic) only when a preconditioner is built from
    # core; a reused one leaves J v to the unformed products A v - B E^-1 (B' v)
    P, fresh = cache.get(core, shift)
    # a reused preconditioner gets a short budget before it is rebuilt
    rtol = core.rtol
    x, it, rel, at_floor = gmres(matvec, b, make_psolve(P), rtol=rtol,
                                 maxiter=KRYLOV_MAXITER if fresh else cache.budget())
    total = it
    # a reused preconditioner is rebuilt when it did not get there, but not when GMRES
    # stopped at the round-off floor: a new one stops there too (FLOOR_FACTOR)
    if rel > rtol and not fresh and not (at_floor and rel <= FLOOR_FACTOR * rtol):
        P, fresh = cache.refresh(core, shift), True
        # on from where the reused preconditioner got to
        x, it, rel, _ = gmres(matvec, b, make_psolve(P), rtol=rtol, x0=x)
        total += it
    if stats is not None:
        stats.solves += 1
        stats.krylov_iterations += total
    cache.after_solve(it, fresh)
    if not np.all(np.isfinite(x)) or rel > max(1e-6, rtol):
        raise RuntimeError(f"GMRES reached only {rel:.1e} relative residual in {total} "
                           f"iterations")
    if rel > rtol:
        log.debug("GMRES stopped at %.1e relative residual after %d iterations", rel, total)
    return x


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

    def solve(self, b) -> np.ndarray:
        """``A^-1 b`` (square ``A``) by GMRES preconditioned by bordering.

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
            return J.solve(b)
        shift = None
        if self.deflate is not None and R.shape[0] >= 2:
            i, ell = self.deflate
            c = C[:, 0].reshape(J.n_c, J.n_r)
            u = c[J._ic[i]] - 1j * (c[J._is[i]] if not J._h0[i] else 0.0)
            shift = (i, u, ell)

        def make_psolve(P):
            def pj(v):
                return P.apply(v, J)
            C2 = getattr(P, "C2", None)
            if C2 is None or R.shape[0] < 2:
                Ce = C
                def lift(v):
                    return v[:nz]
            else:
                Ce = C + C2 @ D[:2]

                def lift(v):
                    return v[:nz] + C2 @ v[nz:nz + 2]
            X = np.column_stack([pj(c) for c in Ce.T])
            Sm = D - R @ X
            Sinv = np.linalg.pinv(Sm)

            def psolve(v):
                w = pj(lift(v))
                s = Sinv @ (v[nz:] - R @ w)
                return np.concatenate([w - X @ s, s])
            return psolve
        return krylov_solve(J, self.matvec, np.asarray(b, dtype=float), make_psolve, shift)


# --------------------------------------------------------------------------
# Helpers working on dense arrays and structured Jacobians alike
# --------------------------------------------------------------------------
def is_structured(A) -> bool:
    return isinstance(A, (HBMJacobian, BorderedJacobian))


def solve(A, b) -> np.ndarray:
    """``A^-1 b``: dense LU (least squares when singular) or the structured solve."""
    if is_structured(A):
        return A.solve(b)
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
