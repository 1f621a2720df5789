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
(:class:`HarmonicPreconditioner`) is, per harmonic, ``S_h`` plus the harmonic-
``h`` part of each element's tangent (the complex-form projection of its
``(h, h)`` 2 x 2 coefficient block, coupling the slip and gap rows of one
element), inverted once per harmonic: ``H + 1`` complex ``n_r x n_r`` inverses
instead of one real LU of size ``n_z``.  With a constant contact tangent
(linear contact) it is the exact inverse.  The rest of the tangent lives on
the elements that slip or separate during the period; a Woodbury (low-rank)
stage corrects for it exactly (a dense ``m x m`` LU, ``m`` = all coefficients
of those elements' rows), so that a fresh preconditioner solves in one GMRES
iteration.  When too many elements slip (``m`` above ``LOWRANK_MAX_FRACTION
n_z``) only the largest corrections are kept and an element-block stage
and GMRES do the rest.

:class:`BorderedJacobian` is ``[[J, C], [R, D]]`` with a few dense columns
and rows (``dR/domega``, the EPMC unknowns and phase conditions, the
continuation's hyperplane); it is solved by GMRES preconditioned by
bordering the harmonic preconditioner (one extra preconditioner solve per
column and an ``m x m`` Schur complement), which stays regular through
turning points.

The preconditioner is reused across Newton iterations and continuation
steps through a :class:`PreconditionerCache` owned by the system (an
explicit object, not module state): it is rebuilt when a solve needed more
than ``refresh_iterations`` GMRES iterations, or when GMRES fails with the
old one within twice that.  Every solve is counted in a :class:`LinearStats`.

:func:`solve`, :func:`append_row`, :func:`drop_last_column` and
:func:`scale_columns` work on dense arrays and on these objects alike; the
Newton loop and the continuation use them.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

log = logging.getLogger(__name__)

#: Relative residual ``|b - A x| / |b|`` at which GMRES stops.
KRYLOV_RTOL = 1e-11
#: GMRES restart length and iteration limit.
KRYLOV_RESTART = 80
KRYLOV_MAXITER = 400
#: Unknowns ``n_z`` from which ``linear_solver = "auto"`` chooses Krylov.
KRYLOV_MIN_UNKNOWNS = 1200
LINEAR_SOLVERS = ("auto", "direct", "krylov")
#: Unformed products ``A v - B E^-1 (B' v)`` of one Jacobian after which its ``S_h``
#: are formed (a product costs about three formed ones; forming, a BLAS-3 product
#: of ``n_r^2 n_y`` per harmonic, about as much as ten to twenty of them).
FORM_AFTER = 12
#: GMRES iterations above which a reused preconditioner is rebuilt (with the low-rank
#: correction a fresh one is exact: one iteration; a build costs about as much as
#: ten iterations at 120 elements).
REFRESH_ITERATIONS = 10
#: Add the element-block stage to the harmonic preconditioner (when its low-rank
#: correction is truncated or off).
TWO_STAGE = True
#: Correct the harmonic preconditioner exactly on the elements whose tangent couples
#: harmonics (Woodbury, :meth:`HarmonicPreconditioner._lowrank`).
LOWRANK = True
#: Largest low-rank correction: this fraction of ``n_z`` coordinates, and at most
#: ``LOWRANK_MAX`` (its dense ``m x m`` LU costs ``m^3``).
#: ``LOWRANK_MIN`` coordinates are always allowed (small systems).
LOWRANK_MAX_FRACTION = 0.35
LOWRANK_MAX = 3000
LOWRANK_MIN = 600


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


class PreconditionerCache:
    """The harmonic preconditioner in use, shared by successive Jacobians.

    Parameters
    ----------
    refresh_iterations : int
        A solve that needed more GMRES iterations than this drops the cached
        preconditioner (the next solve builds a new one from its Jacobian).  (Keeping
        a truncated one that needed many iterations when fresh was measured worse:
        it is then kept where a new one would be exact.)
    reuse : bool
        False: build a new preconditioner for every Jacobian.
    """

    def __init__(self, refresh_iterations: int = REFRESH_ITERATIONS, reuse: bool = True):
        self.refresh_iterations = int(refresh_iterations)
        self.reuse = bool(reuse)
        self.current = None
        self.owner = None

    def get(self, jac) -> tuple["HarmonicPreconditioner", bool]:
        """A preconditioner for ``jac`` and whether it was built from ``jac`` itself."""
        if self.current is not None and (self.reuse or self.owner is jac):
            return self.current, self.owner is jac
        return self.refresh(jac), True

    def refresh(self, jac) -> "HarmonicPreconditioner":
        """Build the preconditioner of ``jac`` and keep it."""
        self.current = HarmonicPreconditioner(jac)
        self.owner = jac
        if jac.stats is not None:
            jac.stats.factorizations += 1
        return self.current

    def threshold(self) -> int:
        """GMRES iterations above which the preconditioner is dropped."""
        return self.refresh_iterations

    def after_solve(self, iterations: int, fresh: bool) -> None:
        if iterations > self.threshold():
            self.current = None
            self.owner = None


# --------------------------------------------------------------------------
# GMRES
# --------------------------------------------------------------------------
def gmres(matvec, b, psolve, rtol: float = KRYLOV_RTOL, restart: int = KRYLOV_RESTART,
          maxiter: int = KRYLOV_MAXITER):
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

    Returns
    -------
    x : ndarray, shape (n,)
    iterations : int
    relres : float
        ``|b - A x| / |b|``.
    """
    n = b.size
    bn = float(np.linalg.norm(b))
    x = np.zeros(n)
    if bn == 0.0 or n == 0:
        return x, 0, 0.0
    total = 0
    r = b.copy()
    beta = bn
    while True:
        if beta <= rtol * bn or total >= maxiter:
            return x, total, beta / bn
        m = min(restart, maxiter - total)
        V = np.zeros((m + 1, n))
        Zp = np.zeros((m, n))
        H = np.zeros((m + 1, m))
        cs, sn = np.zeros(m), np.zeros(m)
        g = np.zeros(m + 1)
        g[0] = beta
        V[0] = r / beta
        j_end = 0
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
            if abs(g[j + 1]) <= 0.5 * rtol * bn or hn == 0.0:
                break
        y = sla.solve_triangular(H[:j_end, :j_end], g[:j_end], check_finite=False)
        x = x + y @ Zp[:j_end]
        r = b - matvec(x)
        beta = float(np.linalg.norm(r))
        if j_end < m and beta > rtol * bn and hn == 0.0:  # breakdown without convergence
            return x, total, beta / bn


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
    """

    def __init__(self, basis, lin, blocks, t_row, n_row, Juu=None, Jug=None, JNN=None,
                 col=None, stats=None, cache=None):
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
        h = list(basis.harmonics)
        self._ic = np.array([basis.index[k][0] for k in h])
        self._is = np.array([basis.index[k][1] if k else basis.index[k][0] for k in h])
        self._h0 = np.array([k == 0 for k in h])
        self._S = [None] * len(blocks)        # S_h once formed (shared by scaled copies)
        self._products = [0]                  # unformed J v so far (shared likewise)

    # -- pieces -------------------------------------------------------------------
    def scaled(self, col) -> "HBMJacobian":
        """``J diag(col)`` (same pieces, same cache)."""
        out = HBMJacobian(self.basis, self.lin, self.blocks, self.t_row, self.n_row,
                          self.Juu, self.Jug, self.JNN, self.col * col, self.stats, self.cache)
        out._S = self._S
        out._products = self._products
        return out

    def form_schur(self) -> None:
        """Form and keep every ``S_h`` (n_r x n_r each), for fast products."""
        for i in range(len(self.blocks)):
            self.schur(i)

    def schur(self, i: int) -> np.ndarray:
        """``S_h`` (complex, n_r x n_r) of the ``i``-th harmonic (formed once, then kept)."""
        if self._S[i] is None:
            A, B, Bp, Ef = self.blocks[i]
            self._S[i] = np.array(A, dtype=complex) if not self.lin.n_y \
                else A - B @ self.lin.solve_E(Ef, Bp)
        return self._S[i].copy()

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


def _project(Jb, ic, is_, h):
    """Complex-form projection of the ``(h, h)`` coefficient blocks (n_e,) of ``Jb``."""
    if h == 0:
        return Jb[:, ic, ic].astype(complex)
    return 0.5 * (Jb[:, ic, ic] + Jb[:, is_, is_]) + 0.5j * (Jb[:, ic, is_] - Jb[:, is_, ic])


class HarmonicPreconditioner:
    """Per harmonic, the inverse of ``S_h`` plus the harmonic-``h`` element tangent, with an
    exact low-rank correction for the elements whose tangent couples harmonics
    (module docstring, :meth:`_lowrank`).

    Parameters
    ----------
    jac : HBMJacobian
        The Jacobian it is built from (its unscaled pieces).
    """

    def __init__(self, jac: HBMJacobian):
        self.jac = jac
        blocks = []
        t, n = jac.t_row, jac.n_row
        for i, h in enumerate(jac.basis.harmonics):
            ic, is_ = jac._ic[i], jac._is[i]
            P = jac.schur(i)
            if jac.Juu is not None:
                P[t, t] += _project(jac.Juu, ic, is_, h)
            if jac.Jug is not None:
                P[t, n] += _project(jac.Jug, ic, is_, h)
            if jac.JNN is not None:
                P[n, n] -= _project(jac.JNN, ic, is_, h)
            blocks.append(P)
        # explicit inverses, stacked (n_h, n_r, n_r): one batched product per
        # application, and the (R, R) rows and columns the low-rank stage needs
        try:
            self.Pinv = np.linalg.inv(np.array(blocks))
        except np.linalg.LinAlgError:      # a singular block: GMRES then has to cope
            log.debug("harmonic preconditioner: a singular block, pseudo-inverse used")
            self.Pinv = np.linalg.pinv(np.array(blocks))
        self.Pinv[jac._h0] = self.Pinv[jac._h0].real
        self.lowrank = None
        self.truncated = True
        if LOWRANK:
            self._lowrank()
        if TWO_STAGE and self.truncated:
            self._element_blocks()
        else:
            self.Binv = None

    def _element_tangent(self):
        """Each element's own contact tangent (slip and gap rows over all coefficients,
        no ``S_h``): ``rows`` (nb n_e,) and blocks (n_e, nb n_c, nb n_c)."""
        jac = self.jac
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

    def _lowrank(self):
        """Exact correction for the elements whose tangent couples harmonics.

        The preconditioner ``P`` holds ``S_h`` and the harmonic-``h`` projection of
        every element's tangent, so ``J = P + E L E^T`` with ``L`` the rest of the
        element tangents: block-diagonal over elements and zero for an element that
        sticks (and stays closed) over the whole period.  ``E`` selects the
        coordinates (all coefficients of the slip and gap rows) of the ``n_l``
        elements where ``L`` is not negligible.  Woodbury's identity then gives
        ``J^-1 b = y - P^-1 E L x_K`` with ``y = P^-1 b`` and
        ``(I + G L) x_K = y_K``, ``G = E^T P^-1 E`` (m x m, ``m = nb n_c n_l``):
        per harmonic only the ``(R, R)`` rows and columns of ``P_h^-1`` are needed
        (``R`` the selected rows).  When ``m`` would exceed ``LOWRANK_MAX_FRACTION n_z``
        (but at least ``LOWRANK_MIN``) or ``LOWRANK_MAX``, only the elements with the largest ``|L_e|`` are kept
        (``self.truncated``; GMRES and the element-block stage handle the rest).
        """
        jac = self.jac
        nc = jac.n_c
        rows, nb, Tk = self._element_tangent()
        ne = Tk.shape[0]
        if ne == 0:
            self.truncated = False
            return
        Lk = Tk
        # subtract the harmonic projection that P already holds
        pairs = []
        if jac.Juu is not None:
            pairs.append((0, 0, jac.Juu, 1.0))
            if jac.Jug is not None and nb == 2:
                pairs.append((0, 1, jac.Jug, 1.0))
        if jac.JNN is not None:
            pairs.append((nb - 1, nb - 1, jac.JNN, -1.0))
        for a, b, Jb, sgn in pairs:
            for i, h in enumerate(jac.basis.harmonics):
                ic, is_ = jac._ic[i], jac._is[i]
                p = sgn * _project(Jb, ic, is_, h)
                Lk[:, a * nc + ic, b * nc + ic] -= p.real
                if h:
                    Lk[:, a * nc + ic, b * nc + is_] -= p.imag
                    Lk[:, a * nc + is_, b * nc + ic] += p.imag
                    Lk[:, a * nc + is_, b * nc + is_] -= p.real
        norm = np.sqrt(np.einsum("eij,eij->e", Lk, Lk))
        ref = max(float(np.abs(Tk).max(initial=0.0)), 1e-300)
        # 1e-13 of the largest tangent entry: below, the correction is round-off
        sel = np.flatnonzero(norm > 1e-13 * ref)
        cap = int(min(max(LOWRANK_MAX_FRACTION * jac.n_z, LOWRANK_MIN), LOWRANK_MAX)) \
            // (nb * nc)
        self.truncated = sel.size > cap
        if self.truncated:
            sel = sel[np.argsort(norm[sel])[::-1][:cap]]
            sel.sort()
        if sel.size == 0:
            return
        nl = sel.size
        R = np.concatenate([r[sel] for r in rows])           # (nb nl,) selected rows
        nR = R.size
        # K coordinates ordered coefficient-major: index k nR + j (j over R)
        m = nc * nR
        G = np.zeros((m, m))
        for i, h in enumerate(jac.basis.harmonics):
            Q = self.Pinv[i][np.ix_(R, R)]
            ic, is_ = jac._ic[i], jac._is[i]
            c = slice(ic * nR, (ic + 1) * nR)
            if h == 0:
                G[c, c] = Q.real
                continue
            sn = slice(is_ * nR, (is_ + 1) * nR)
            G[c, c] = Q.real
            G[c, sn] = Q.imag
            G[sn, c] = -Q.imag
            G[sn, sn] = Q.real
        # local coordinate (a, k) of selected element l -> K index k nR + a nl + l
        a_k = np.arange(nb * nc)
        loc = (a_k % nc)[None, :] * nR + (a_k // nc)[None, :] * nl + np.arange(nl)[:, None]
        Ls = Lk[sel]                                          # (nl, d, d)
        GL = np.matmul(G[:, loc].transpose(1, 0, 2), Ls)      # G E_l L_l, (nl, m, d)
        Mk = np.eye(m)
        Mk[:, loc] += GL.transpose(1, 0, 2)
        self.lowrank = (R, loc, Ls, sla.lu_factor(Mk, check_finite=False), nR)

    def _harmonic_solve(self, V):
        """``P^-1`` of the harmonic stage; ``V`` (n_c, n_r) real, returns (n_c, n_r)."""
        jac = self.jac
        X = jac._to_complex(V)
        Y = np.matmul(self.Pinv, X[:, :, None])[:, :, 0]
        out = np.empty_like(V)
        jac._from_complex(Y, out)
        return out

    def _element_blocks(self):
        """Inverse of each element's own block of ``J`` (its slip and gap rows over all
        coefficients, contact tangent with its harmonic coupling plus the diagonal of
        ``S_h``): the second stage of the preconditioner."""
        jac = self.jac
        nc, ne = jac.n_c, len(jac.t_row)
        rows = [jac.t_row] + ([jac.n_row] if jac.JNN is not None else [])
        if jac.Juu is None:
            rows = [jac.n_row]
        nb = len(rows)
        Bk = np.zeros((ne, nb * nc, nb * nc))
        for a, ra in enumerate(rows):
            for b, rb in enumerate(rows):
                for i, h in enumerate(jac.basis.harmonics):
                    S = jac._S[i][ra, rb] if jac._S[i] is not None else jac.schur(i)[ra, rb]
                    ic, is_ = jac._ic[i], jac._is[i]
                    Bk[:, a * nc + ic, b * nc + ic] += S.real
                    if h:
                        Bk[:, a * nc + ic, b * nc + is_] += S.imag
                        Bk[:, a * nc + is_, b * nc + ic] -= S.imag
                        Bk[:, a * nc + is_, b * nc + is_] += S.real
        if jac.Juu is not None:
            Bk[:, :nc, :nc] += jac.Juu
            if jac.Jug is not None and nb == 2:
                Bk[:, :nc, nc:] += jac.Jug
        if jac.JNN is not None:
            Bk[:, -nc:, -nc:] -= jac.JNN
        self.rows = np.concatenate(rows)
        self.nb = nb
        self.Binv = np.linalg.inv(Bk)

    def apply(self, v, jac) -> np.ndarray:
        """The preconditioner of the scaled ``jac = J diag(col)``: ``diag(col)^-1 P^-1 v``
        (two-stage when ``TWO_STAGE``)."""
        if self.Binv is not None:
            return self.solve2(v, lambda x: jac.matvec(x / jac.col)) / jac.col
        return self.solve(v) / jac.col

    def solve2(self, v, matvec) -> np.ndarray:
        """Two-stage: ``x = P^-1 v``, then ``x += B^-1 (v - J x)`` (element blocks)."""
        jac = self.jac
        x = self.solve(v)
        r = (v - matvec(x)).reshape(jac.n_c, jac.n_r)
        ne = len(jac.t_row)
        rb = r[:, self.rows].T.reshape(self.nb, ne, jac.n_c).transpose(1, 0, 2) \
            .reshape(ne, -1)
        d = np.einsum("eij,ej->ei", self.Binv, rb)
        d = d.reshape(ne, self.nb, jac.n_c).transpose(1, 0, 2).reshape(-1, jac.n_c).T
        X = x.reshape(jac.n_c, jac.n_r).copy()
        X[:, self.rows] += d
        return X.ravel()

    def solve(self, v) -> np.ndarray:
        """``P^-1 v`` for the unscaled ``J``, shape (n_z,)."""
        jac = self.jac
        V = np.asarray(v, dtype=float).reshape(jac.n_c, jac.n_r)
        Y = self._harmonic_solve(V)
        if self.lowrank is None:
            return Y.ravel()
        R, loc, Ls, Mlu, nR = self.lowrank
        yK = Y[:, R].ravel()                                  # coefficient-major K order
        xK = sla.lu_solve(Mlu, yK, check_finite=False)
        w = np.zeros_like(xK)
        w[loc] = np.matmul(Ls, xK[loc][:, :, None])[:, :, 0]
        W = np.zeros_like(V)
        W[:, R] = w.reshape(jac.n_c, nR)
        return (Y - self._harmonic_solve(W)).ravel()


def krylov_solve(core: HBMJacobian, matvec, b, make_psolve):
    """GMRES for ``A x = b`` with the preconditioner of ``core`` (cached or rebuilt).

    A reused preconditioner gets ``2 threshold`` GMRES iterations
    (:meth:`PreconditionerCache.threshold`); when they do not suffice the solve
    is repeated with one built from ``core``.  Raises ``RuntimeError`` when GMRES
    does not reach
    ``KRYLOV_RTOL`` and reduces the residual by less than ``1e-6`` (Newton
    treats that as a singular Jacobian).
    """
    cache, stats = core.cache, core.stats
    # S_h is formed (n_r^2 n_y per harmonic) only when a preconditioner is built from
    # core; a reused one leaves J v to the unformed products A v - B E^-1 (B' v)
    P, fresh = cache.get(core)
    # a reused preconditioner gets a short budget before it is rebuilt
    x, it, rel = gmres(matvec, b, make_psolve(P),
                       maxiter=KRYLOV_MAXITER if fresh else 2 * cache.threshold())
    total = it
    if rel > KRYLOV_RTOL and not fresh:
        P, fresh = cache.refresh(core), True
        x, it, rel = gmres(matvec, b, make_psolve(P))
        total += it
    if stats is not None:
        stats.solves += 1
        stats.krylov_iterations += total
    cache.after_solve(it, fresh)
    if not np.all(np.isfinite(x)) or rel > 1e-6:
        raise RuntimeError(f"GMRES reached only {rel:.1e} relative residual in {total} "
                           f"iterations")
    if rel > KRYLOV_RTOL:
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
    """

    def __init__(self, J: HBMJacobian, C=None, R=None, D=None):
        nz = J.n_z
        self.J = J
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
                                np.vstack([self.D, r[None, nz:]]))

    def without_last_column(self) -> "BorderedJacobian":
        return BorderedJacobian(self.J, self.C[:, :-1], self.R, self.D[:, :-1])

    def scaled(self, col) -> "BorderedJacobian":
        """``A diag(col)``."""
        nz = self.J.n_z
        col = np.asarray(col, dtype=float)
        return BorderedJacobian(self.J.scaled(col[:nz]), self.C * col[nz:], self.R * col[:nz],
                                self.D * col[nz:])

    def solve(self, b) -> np.ndarray:
        """``A^-1 b`` (square ``A``) by GMRES preconditioned by bordering."""
        if self.shape[0] != self.shape[1]:
            raise ValueError(f"cannot solve with a {self.shape} bordered Jacobian")
        J, C, R, D = self.J, self.C, self.R, self.D
        nz = J.n_z
        if C.shape[1] == 0:
            return J.solve(b)

        def make_psolve(P):
            def pj(v):
                return P.apply(v, J)
            X = np.column_stack([pj(c) for c in C.T])
            Sm = D - R @ X
            Sinv = np.linalg.pinv(Sm)

            def psolve(v):
                w = pj(v[:nz])
                s = Sinv @ (v[nz:] - R @ w)
                return np.concatenate([w - X @ s, s])
            return psolve
        return krylov_solve(J, self.matvec, np.asarray(b, dtype=float), make_psolve)


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
