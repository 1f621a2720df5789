"""AFT harmonic balance with the linear structure condensed onto the contacts.

Formulation
-----------
The structure ``M x'' + C x' + K x + f_c = f_ext`` with
``f_c = Tt^T f_t - Tn^T N`` (see :mod:`jointsim.model`) is sought as
``x(t) = X_0 + sum_h (X_hc cos h w t + X_hs sin h w t)``; coefficient order
``[0, 1c, 1s, 2c, 2s, ...]`` over the kept harmonics.  Per harmonic, with
``nu = h w`` and the complex amplitude ``Xh = X_hc - i X_hs``, the linear part
is the dynamic stiffness ``D_h = K - nu^2 M + i nu C``.

*Condensation onto the contact coordinates.*  The contact forces depend on
``x`` only through ``q = T x``, the stacked tangential slips ``Tt x`` (when
there is friction) and normal gap changes ``Tn x`` (when the normal load is
coupled), ``n_r`` rows of full rank.  With ``Psi = T^T (T T^T)^-1`` (so
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

*AFT.*  The coefficients of ``q`` are turned into ``n_t`` samples per period
(``u = Gam U``), the element laws are marched over the samples from rest,
period after period, until their state repeats (at least two periods), and
the last period's forces are transformed back (``F = P f``).  The Jacobian is
analytic: the instantaneous tangents plus the history terms carried
forward through the march (see :mod:`jointsim.contact._aft_kernels`).  With
``effects.normal = "fixed"`` the normal load is ``N0`` and no gap is
evaluated; with ``"coupled"``, ``N = kn A max(0, -g)`` (or bilateral).

The frequency derivative of the residual is analytic too:
``dR/dw = A_w q + B_w y + B y_w`` with ``y_w = -E^-1 (B'_w q + E_w y)``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

from ..harmonics import HarmonicBasis, harmonic_amplitude
from .newton import NewtonOptions, newton

log = logging.getLogger(__name__)

#: Above this many structural DOFs the dense condensation is refused.
MAX_DENSE_DOF = 6000


# --------------------------------------------------------------------------
# AFT evaluation of the contact elements
# --------------------------------------------------------------------------
@dataclass
class AFTResult:
    """Element forces and their derivatives for one set of coefficients.

    Attributes
    ----------
    Ft, Nc : ndarray, shape (n_e, n_c)
        Coefficients of the tangential force and the normal load [N].
    Juu, Jug, JNN : ndarray, shape (n_e, n_c, n_c) or None
        ``dFt/dU``, ``dFt/dG`` and ``dNc/dG`` (None when not computed or not
        applicable).
    u, f, N : ndarray, shape (n_e, n_t)
        Slip, tangential force and normal load over the last period.
    periods : ndarray of int, shape (n_e,)
        Periods marched until the state repeated.
    change : ndarray, shape (n_e,)
        Relative state change over the last period (0 when periodic).
    """

    Ft: np.ndarray
    Nc: np.ndarray
    Juu: np.ndarray | None
    Jug: np.ndarray | None
    JNN: np.ndarray | None
    u: np.ndarray
    f: np.ndarray
    N: np.ndarray
    periods: np.ndarray
    change: np.ndarray


class AFT:
    """Alternating frequency-time evaluation of a :class:`~jointsim.model.ContactSet`.

    Parameters
    ----------
    contacts : jointsim.model.ContactSet
    basis : HarmonicBasis
    min_periods, max_periods : int
        Periods marched at least / at most until the law's state repeats.
    periodic_tol : float
        Relative state change below which a period counts as periodic.
    """

    def __init__(self, contacts, basis: HarmonicBasis, min_periods: int = 2,
                 max_periods: int = 50, periodic_tol: float = 1e-10):
        self.contacts = contacts
        self.basis = basis
        self.law = contacts.law
        self.coupled = bool(contacts.coupled)
        self.min_periods = int(min_periods)
        self.max_periods = int(max(max_periods, min_periods))
        self.periodic_tol = float(periodic_tol)
        self.n_e = contacts.n_elements

    def evaluate(self, U, G=None, jacobian: bool = True) -> AFTResult:
        """Forces of all elements from slip (and gap-change) coefficients.

        Parameters
        ----------
        U : ndarray, shape (n_c, n_e)
            Coefficients of the tangential slip [m].
        G : ndarray, shape (n_c, n_e), optional
            Coefficients of ``Tn x`` (the gap minus ``gap0``) [m]; required
            when the normal load is coupled.
        jacobian : bool
            Compute the derivative blocks.
        """
        b = self.basis
        c = self.contacts
        ne, nt = self.n_e, b.n_samples
        u = np.ascontiguousarray((b.Gam @ U).T)
        if self.coupled:
            g = c.gap0[:, None] + (b.Gam @ G).T
            N, dNdg = c.normal.load(g)
        else:
            N = np.ascontiguousarray(np.broadcast_to(c.N0[:, None], (ne, nt)), dtype=float)
            dNdg = np.zeros((ne, nt))
        f, au, ag, Juu, Jug, periods, change = self.law.aft(
            u, N, dNdg, b, self.min_periods, self.max_periods, self.periodic_tol, self.coupled)
        Ft = f @ b.P.T
        Nc = N @ b.P.T
        JNN = None
        if jacobian:
            nc = b.n_coeff
            if Juu is None:
                Juu = np.zeros((ne, nc, nc))
            if au is not None:
                b.add_diag_product(Juu, au)
            if self.coupled:
                if Jug is None:
                    Jug = np.zeros((ne, nc, nc))
                if ag is not None:
                    b.add_diag_product(Jug, ag)
                JNN = b.diag_product(dNdg)
            else:
                Jug = None
        if np.any(periods >= self.max_periods) and np.any(change > self.periodic_tol):
            log.debug("AFT: %d elements not periodic after %d periods (largest change %.1e)",
                      int(np.sum(change > self.periodic_tol)), self.max_periods, change.max())
        return AFTResult(Ft=Ft, Nc=Nc, Juu=Juu, Jug=Jug, JNN=JNN, u=u, f=f, N=N,
                         periods=periods, change=change)


# --------------------------------------------------------------------------
# Linear part condensed onto the contact coordinates
# --------------------------------------------------------------------------
def _dense(A):
    return np.asarray(A.toarray() if hasattr(A, "toarray") else A, dtype=float)


class ReducedLinear:
    """The linear structure seen from the contact coordinates ``q = T x``.

    Parameters
    ----------
    M, K, C : array or sparse, shape (n, n)
        Mass, stiffness and damping of the linear part.
    T : array or sparse, shape (n_r, n)
        Contact coordinates (full row rank).

    See the module docstring for the formulation.
    """

    def __init__(self, M, K, C, T):
        M, K, C, T = _dense(M), _dense(K), _dense(C), _dense(T)
        n = M.shape[0]
        if n > MAX_DENSE_DOF:
            raise NotImplementedError(
                f"the harmonic balance condenses the structure densely and the model has {n} "
                f"DOFs (> {MAX_DENSE_DOF}); reduce it first (Craig-Bampton)")
        n_r = T.shape[0]
        self.n, self.n_r, self.n_y = n, n_r, n - n_r
        if n_r:
            sv = np.linalg.svd(T, compute_uv=False)
            if n_r > n or sv.min() <= 1e-10 * sv.max():
                raise ValueError(
                    "the contact coordinates are linearly dependent (two contact elements "
                    "measure the same relative motion, or an element's slip and gap coincide); "
                    "merge such elements or give them distinct DOFs")
            Psi = np.linalg.solve(T @ T.T, T).T
            Qf, _ = np.linalg.qr(T.T, mode="complete")
            Z0 = Qf[:, n_r:]
        else:
            Psi = np.zeros((n, 0))
            Z0 = np.eye(n)
        self.kind = "direct"
        Z = Z0
        lowrank = None
        if self.n_y:
            Kyy = Z0.T @ K @ Z0
            Myy = Z0.T @ M @ Z0
            try:
                lam, Phi = sla.eigh(0.5 * (Kyy + Kyy.T), 0.5 * (Myy + Myy.T))
                Zm = Z0 @ Phi
                Cyy = Zm.T @ C @ Zm
                off = Cyy - np.diag(np.diag(Cyy))
                ref = max(np.abs(Cyy).max(), 1e-300)
                sym = (np.allclose(K, K.T, rtol=0, atol=1e-12 * np.abs(K).max())
                       and np.allclose(M, M.T, rtol=0, atol=1e-12 * np.abs(M).max()))
                csym = np.allclose(C, C.T, rtol=0, atol=1e-12 * max(np.abs(C).max(), 1e-300))
                if sym and np.abs(off).max() <= 1e-11 * ref:
                    Z = Zm
                    self.kind = "modal"
                elif sym and csym:
                    # modal damping of a few modes is a low-rank C: E is then a
                    # diagonal plus a rank-r term, inverted by Woodbury's formula
                    c, U = np.linalg.eigh(0.5 * (Cyy + Cyy.T))
                    keep = np.abs(c) > 1e-12 * max(np.abs(c).max(), 1e-300)
                    if keep.sum() <= self.n_y // 3:
                        Z = Zm
                        self.kind = "lowrank"
                        lowrank = (U[:, keep], c[keep])
            except (np.linalg.LinAlgError, ValueError):
                pass
        self.modal = self.kind == "modal"
        self.Psi, self.Z = Psi, Z
        V = np.hstack([Psi, Z])
        Kt, Mt, Ct = V.T @ K @ V, V.T @ M @ V, V.T @ C @ V
        r = slice(0, n_r)
        y = slice(n_r, n)
        self.K = {b: Kt[i, j] for b, (i, j) in _blocks(r, y).items()}
        self.M = {b: Mt[i, j] for b, (i, j) in _blocks(r, y).items()}
        self.C = {b: Ct[i, j] for b, (i, j) in _blocks(r, y).items()}
        if self.kind in ("modal", "lowrank"):
            self.lam = np.diag(self.K["yy"]).copy()
            self.myy = np.diag(self.M["yy"]).copy()
            self.cyy = np.diag(self.C["yy"]).copy() if self.modal else None
        if self.kind == "lowrank":
            self.U, self.cw = lowrank
            self.Cyy = self.C["yy"]
        self._Mfull = M

    # -- blocks of the transformed dynamic stiffness --------------------------
    def blocks(self, nu: float, xi: float = 0.0):
        """``A, B, B', E`` at angular frequency ``nu`` with damping ``C - xi M``.

        ``E`` is a 1-D array (its diagonal) when the condensation is modal, a
        :class:`_LowRankE` when the damping is of low rank, else a matrix.
        """
        def mat(b):
            return (self.K[b] - nu * nu * self.M[b]) + 1j * nu * (self.C[b] - xi * self.M[b])
        A, B, Bp = mat("qq"), mat("qy"), mat("yq")
        if self.kind == "modal":
            E = (self.lam - nu * nu * self.myy) + 1j * nu * (self.cyy - xi * self.myy)
        elif self.kind == "lowrank":
            E = _LowRankE((self.lam - nu * nu * self.myy) - 1j * nu * xi * self.myy,
                          1j * nu * self.cw, self.U, self.Cyy, 1j * nu)
        else:
            E = mat("yy")
        return A, B, Bp, E

    def dblocks(self, nu: float, xi: float, wrt: str, h: int):
        """Derivatives of ``A, B, B', E`` with respect to ``omega`` (``nu = h omega``) or
        ``xi``; apply ``dE`` with :meth:`apply_dE`."""
        if wrt == "omega":
            def d(b):
                return h * (-2.0 * nu * self.M[b] + 1j * (self.C[b] - xi * self.M[b]))
            if self.kind == "modal":
                dE = h * (-2.0 * nu * self.myy + 1j * (self.cyy - xi * self.myy))
            elif self.kind == "lowrank":
                dE = (h * (-2.0 * nu - 1j * xi) * self.myy, 1j * h)
            else:
                dE = d("yy")
        else:
            def d(b):
                return -1j * nu * self.M[b]
            if self.kind == "direct":
                dE = d("yy")
            elif self.kind == "lowrank":
                dE = (-1j * nu * self.myy, 0.0)
            else:
                dE = -1j * nu * self.myy
        return d("qq"), d("qy"), d("yq"), dE

    def apply_dE(self, dE, y):
        """``dE @ y`` for a ``dE`` from :meth:`dblocks`."""
        if isinstance(dE, tuple):        # low rank: diagonal + coefficient * Cyy
            diag, coef = dE
            out = diag * y
            if coef != 0.0:
                out = out + coef * (self.Cyy @ y)
            return out
        return dE * y if dE.ndim == 1 else dE @ y

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
                raise np.linalg.LinAlgError("the structure with welded contacts is singular "
                                            "at this frequency (an undamped resonance or an "
                                            "unrestrained rigid-body motion)")
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


class _LowRankE:
    """``E = diag(d) + U diag(s) U^T`` (``U`` real, ``n_y x r``), solved by Woodbury:
    ``E^-1 = D^-1 - D^-1 U (diag(1/s) + U^T D^-1 U)^-1 U^T D^-1``."""

    def __init__(self, d, s, U, Cyy, coef):
        self.d, self.s, self.U = d, s, U
        self.Cyy, self.coef = Cyy, coef
        self._small = None

    def factor(self):
        if np.any(self.d == 0):
            raise np.linalg.LinAlgError("the structure with welded contacts is singular at "
                                        "this frequency (an undamped resonance or an "
                                        "unrestrained rigid-body motion)")
        if self._small is None and np.any(self.s != 0):
            small = np.diag(1.0 / self.s) + self.U.T @ (self.U / self.d[:, None])
            self._small = sla.lu_factor(small, check_finite=False)

    def solve(self, rhs):
        self.factor()
        d = self.d[:, None] if rhs.ndim == 2 else self.d
        x = rhs / d
        if self._small is None:          # no damping term (harmonic 0)
            return x
        return x - (self.U @ sla.lu_solve(self._small, self.U.T @ x, check_finite=False)) / d


def _blocks(r, y):
    return {"qq": (r, r), "qy": (r, y), "yq": (y, r), "yy": (y, y)}


# --------------------------------------------------------------------------
# The harmonic-balance system
# --------------------------------------------------------------------------
@dataclass
class Evaluation:
    """Residual and derivatives of the condensed HBM equations at one point.

    Attributes
    ----------
    R : ndarray, shape (n_c * n_r,)
        Residual [N] (harmonic-major: index ``k * n_r + r``).
    J : ndarray, shape (n_c * n_r, n_c * n_r) or None
        ``dR/dz``.
    dR : dict of str -> ndarray, shape (n_c * n_r,)
        Derivatives with respect to ``omega`` and/or ``xi``.
    aft : AFTResult or None
    """

    R: np.ndarray
    J: np.ndarray | None
    dR: dict = field(default_factory=dict)
    aft: AFTResult | None = None


class HBMSystem:
    """Condensed AFT harmonic-balance equations of a :class:`~jointsim.model.StructuralModel`.

    The unknown ``z`` holds the harmonic coefficients of the contact
    coordinates ``q`` (``n_c x n_r``, harmonic-major, flattened).  For element
    ``e``, ``q[t_row[e]]`` is its slip and ``q[n_row[e]]`` its gap change.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    harmonics : sequence of int
    n_samples : int
    min_periods, max_periods : int
        AFT march periods (see :class:`AFT`).
    """

    def __init__(self, model, harmonics, n_samples: int, min_periods: int = 2,
                 max_periods: int = 50):
        self.model = model
        self.basis = HarmonicBasis(harmonics, n_samples)
        c = model.contacts
        self.contacts = c
        self.aft = AFT(c, self.basis, min_periods, max_periods)
        ne = c.n_elements
        self.n_e = ne
        self.friction = c.law.has_force
        self.coupled = bool(c.coupled)
        rows = []
        self.t_row = np.full(ne, -1, dtype=np.int64)
        self.n_row = np.full(ne, -1, dtype=np.int64)
        nr = 0
        if self.friction and ne:
            rows.append(_dense(c.Tt))
            self.t_row = np.arange(ne)
            nr = ne
        if self.coupled and ne:
            rows.append(_dense(c.Tn))
            self.n_row = nr + np.arange(ne)
            nr += ne
        T = np.vstack(rows) if rows else np.zeros((0, model.n_dof))
        self.T = T
        self.lin = ReducedLinear(model.M, model.K, model.C, T)
        self.n_r = nr
        self.n_c = self.basis.n_coeff
        self.n_z = self.n_c * nr
        self._Tt = _dense(c.Tt) if ne else np.zeros((0, model.n_dof))
        log.debug("HBM system: %d DOFs condensed onto %d contact coordinates x %d "
                  "coefficients (%s condensation)", model.n_dof, nr, self.n_c,
                  self.lin.kind)

    # -- static state ----------------------------------------------------------
    def static_coordinates(self):
        """``z`` of the static state ``x0``: ``T x0`` in harmonic 0, zero elsewhere.

        ``x0`` is :func:`jointsim.solvers.static.stuck_linearisation`'s (for
        the lap joint the bolt preload).  It solves the harmonic-0 balance at
        vanishing amplitude, so it is where every branch starts; without
        harmonic 0 the result is zero.

        Returns
        -------
        ndarray, shape (n_z,) [m]
        """
        z = np.zeros((self.n_c, self.n_r))
        if 0 in self.basis.harmonics and self.n_r:
            x0 = self.model.linearisation.x0
            z[self.basis.index[0][0]] = self.T @ x0
        return z.ravel()

    # -- forcing -------------------------------------------------------------
    def force_coefficients(self, scale: float = 1.0):
        """External force coefficients, shape (n_c, n_dof) [N] (see StructuralModel)."""
        return self.model.force_coefficients(self.basis.harmonics, scale)

    def _complex(self, X, h):
        """Complex amplitude of harmonic ``h`` from coefficient rows of ``X``."""
        ic, is_ = self.basis.index[h]
        if h == 0:
            return X[ic].astype(complex)
        return X[ic] - 1j * X[is_]

    def _store(self, out, h, v):
        ic, is_ = self.basis.index[h]
        if h == 0:
            out[ic] = v.real
        else:
            out[ic] = v.real
            out[is_] = -v.imag

    # -- residual --------------------------------------------------------------
    def evaluate(self, z, omega: float, F, xi: float = 0.0, jacobian: bool = True,
                 wrt=("omega",), J_out=None) -> Evaluation:
        """Residual ``S(w) q + phi(q) - F_red`` and its analytic derivatives.

        Parameters
        ----------
        z : ndarray, shape (n_z,)
            Coefficients of the contact coordinates [m].
        omega : float
            Base angular frequency [rad/s].
        F : ndarray, shape (n_c, n_dof)
            External force coefficients [N].
        xi : float
            Self-excitation of the EPMC (damping ``C - xi M``) [1/s].
        jacobian : bool
            Also compute ``dR/dz`` and the derivatives named in ``wrt``.
        wrt : tuple of str
            Parameters to differentiate by: ``"omega"``, ``"xi"``.
        J_out : ndarray, shape (n_z, n_z), optional
            Zero-filled array (e.g. a block of a bordered matrix) that receives
            ``dR/dz``; it is returned as ``J``.
        """
        nr, nc = self.n_r, self.n_c
        Q = np.asarray(z, dtype=float).reshape(nc, nr)
        R = np.zeros((nc, nr))
        J = (np.zeros((self.n_z, self.n_z)) if J_out is None else J_out) if jacobian else None
        dR = {p: np.zeros((nc, nr)) for p in wrt} if jacobian else {}
        lin = self.lin
        for h in self.basis.harmonics:
            nu = h * omega
            A, B, Bp, E = lin.blocks(nu, xi)
            Ef = lin.factor_E(E) if lin.n_y else E
            qh = self._complex(Q, h)
            Fh = self._complex(F, h)
            Fq = lin.Psi.T @ Fh
            Fy = lin.Z.T @ Fh
            if lin.n_y and jacobian:
                both = lin.solve_E(Ef, np.column_stack([Fy - Bp @ qh, Bp]))
                y, EinvBp = both[:, 0], both[:, 1:]
            elif lin.n_y:
                y = lin.solve_E(Ef, Fy - Bp @ qh)
            else:
                y, EinvBp = np.zeros(0, complex), np.zeros((0, nr), complex)
            self._store(R, h, A @ qh + B @ y - Fq)
            if not jacobian:
                continue
            S = A - B @ EinvBp
            ic, is_ = self.basis.index[h]
            rc = ic * nr + np.arange(nr)
            if h == 0:
                J[np.ix_(rc, rc)] = S.real
            else:
                rs = is_ * nr + np.arange(nr)
                J[np.ix_(rc, rc)] = S.real
                J[np.ix_(rc, rs)] = S.imag
                J[np.ix_(rs, rc)] = -S.imag
                J[np.ix_(rs, rs)] = S.real
            for p in wrt:
                if h == 0 and p == "omega":
                    continue
                dA, dB, dBp, dE = lin.dblocks(nu, xi, p, h)
                v = dA @ qh
                if lin.n_y:
                    y_p = -lin.solve_E(Ef, dBp @ qh + lin.apply_dE(dE, y))
                    v = v + dB @ y + B @ y_p
                self._store(dR[p], h, v)
        aft = None
        if self.n_e and nr:
            U = Q[:, self.t_row] if self.friction else None
            Gq = Q[:, self.n_row] if self.coupled else None
            if U is None:
                U = np.zeros((nc, self.n_e))
            aft = self.aft.evaluate(U, Gq, jacobian)
            if self.friction:
                R[:, self.t_row] += aft.Ft.T
            if self.coupled:
                R[:, self.n_row] -= aft.Nc.T
            if jacobian:
                self._add_element_blocks(J, aft)
        return Evaluation(R=R.ravel(), J=J, dR={p: v.ravel() for p, v in dR.items()}, aft=aft)

    def _add_element_blocks(self, J, aft):
        nr, nc = self.n_r, self.n_c
        k = np.arange(nc)
        def idx(rows):
            return rows[:, None, None] + nr * k[None, :, None], \
                rows[:, None, None] + nr * k[None, None, :]
        if self.friction:
            ri, ci = idx(self.t_row)
            J[ri, ci] += aft.Juu
            if self.coupled:
                ri2, _ = idx(self.t_row)
                _, cj = idx(self.n_row)
                J[ri2, cj] += aft.Jug
        if self.coupled:
            ri, ci = idx(self.n_row)
            J[ri, ci] -= aft.JNN

    # -- reconstruction ----------------------------------------------------------
    def reconstruct(self, z, omega: float, F, xi: float = 0.0):
        """Full coefficients ``X`` (n_c, n_dof) [m] from the contact coordinates."""
        nr, nc = self.n_r, self.n_c
        Q = np.asarray(z, dtype=float).reshape(nc, nr)
        X = np.zeros((nc, self.model.n_dof))
        lin = self.lin
        for h in self.basis.harmonics:
            A, B, Bp, E = lin.blocks(h * omega, xi)
            qh = self._complex(Q, h)
            Fy = lin.Z.T @ self._complex(F, h)
            y = lin.solve_E(E, Fy - Bp @ qh) if lin.n_y else np.zeros(0, complex)
            self._store(X, h, lin.Psi @ qh + lin.Z @ y)
        return X

    def contact_coordinates(self, X):
        """``z`` from full coefficients ``X`` (n_c, n_dof)."""
        return (np.asarray(X) @ self.T.T).ravel()

    def slips(self, X):
        """Tangential slip samples (n_e, n_t) from full coefficients."""
        return (self.basis.Gam @ (np.asarray(X) @ self._Tt.T)).T


# --------------------------------------------------------------------------
# Newton at a fixed frequency
# --------------------------------------------------------------------------
@dataclass
class PointSolution:
    """A harmonic-balance solution at one frequency.

    Attributes
    ----------
    z : ndarray, shape (n_z,)
        Contact-coordinate coefficients [m].
    X : ndarray, shape (n_c, n_dof)
        Full coefficients [m].
    omega : float
    residual : float
        Largest residual entry [N].
    evaluation : Evaluation
    convergence : jointsim.results.Convergence
    """

    z: np.ndarray
    X: np.ndarray
    omega: float
    residual: float
    evaluation: Evaluation
    convergence: object


def solve_point(system: HBMSystem, omega: float, F, z0=None, tol: float = 1e-10,
                max_iter: int = 30, rscale: float | None = None) -> PointSolution:
    """Solve the harmonic balance at a fixed frequency by Newton's method.

    Parameters
    ----------
    system : HBMSystem
    omega : float
        Angular frequency [rad/s].
    F : ndarray, shape (n_c, n_dof)
        Force coefficients [N].
    z0 : ndarray, optional
        Start (default: the static state, :meth:`HBMSystem.static_coordinates`,
        whose first step is the stuck linear response).
    tol : float
        Tolerance on ``max|R| / rscale``.
    rscale : float, optional
        Residual scale (default: the largest force coefficient).
    """
    from ..results import NOT_CONVERGED, SUCCESS, Convergence
    if rscale is None:
        rscale = max(float(np.abs(F).max(initial=0.0)), 1e-300)
    z0 = system.static_coordinates() if z0 is None else np.asarray(z0, dtype=float)

    def fun(z):
        ev = system.evaluate(z, omega, F, wrt=())
        return ev.R, ev.J, ev

    res = newton(fun, z0, NewtonOptions(tol, max_iter, line_search="decrease", max_tries=6),
                 measure=lambda R, _ev: np.abs(R).max(initial=0.0) / rscale)
    z, R, ev, it, ok = res.x, res.R, res.extra, res.iterations, res.success
    rn = float(np.abs(R).max(initial=0.0))
    conv = Convergence(ok, SUCCESS if ok else NOT_CONVERGED,
                       f"Newton {'converged' if ok else 'did not converge'} in {it} iterations "
                       f"(residual {rn / rscale:.1e} of the force scale)", it)
    return PointSolution(z=z, X=system.reconstruct(z, omega, F), omega=float(omega),
                         residual=rn, evaluation=ev, convergence=conv)


# --------------------------------------------------------------------------
# Frequency-response curves
# --------------------------------------------------------------------------
def frc_scales(system: HBMSystem, F, omega_start: float, omega_end: float, n: int = 9,
               tol: float = 1e-6):
    """Variable and residual scales of an FRC branch.

    The displacement scale ``q_ref`` is the largest ``max |z - z0|`` of

    * the response of the joint stuck at its static state ``z0`` (one Newton
      step from ``z0``) at ``n`` frequencies of the range and at every stuck
      linear resonance inside it;
    * and, when a resonance lies in the range, the nonlinear response at the
      strongest of them (a Newton solve from the stuck response; skipped if
      it does not converge), so that a branch whose friction damping keeps it
      far below the linear peak is still resolved.

    The residual scale is the largest condensed force ``max |R(z0)|``.

    Returns
    -------
    scale : ndarray, shape (n_z + 1,)
        ``q_ref`` for every coefficient, ``|omega_end - omega_start|`` for omega.
    rscale : float
    """
    from .modes import stuck_modes
    lo, hi = sorted((omega_start, omega_end))
    z0 = system.static_coordinates()
    ws = list(np.linspace(omega_start, omega_end, n))
    res = []
    if system.model.n_dof:
        f_hz = stuck_modes(system.model, min(system.model.n_dof, 40)).frequency_hz
        res = [2 * np.pi * f for f in f_hz if lo < 2 * np.pi * f < hi]
    q_off, q_res, rref, best = 0.0, 0.0, 0.0, (0.0, None, None)
    for w in ws + res:
        ev = system.evaluate(z0, w, F, wrt=())
        rref = max(rref, float(np.abs(ev.R).max(initial=0.0)))
        if not system.n_z:
            continue
        try:
            dz = np.linalg.solve(ev.J, -ev.R)
        except np.linalg.LinAlgError:
            continue
        d = float(np.abs(dz).max())
        if w in res:
            q_res = max(q_res, d)
            if d > best[0]:
                best = (d, w, z0 + dz)
        else:
            q_off = max(q_off, d)
    if not rref > 0.0:
        rref = 1.0
    qref = max(q_off, q_res)
    if best[1] is not None:
        sol = solve_point(system, best[1], F, z0=best[2], tol=tol, max_iter=15, rscale=rref)
        if sol.convergence.success:
            qref = max(q_off, float(np.abs(sol.z - z0).max()))
    if not qref > 0.0:
        qref = 1.0
    scale = np.full(system.n_z + 1, qref)
    scale[-1] = max(abs(omega_end - omega_start), 1e-12 * abs(omega_start), 1e-300)
    return scale, rref


def refine_peak(system: HBMSystem, F, omega, Z, amplitude, dof: int, tol: float):
    """Refine the largest amplitude of a branch by maximising over frequency.

    Only where the branch is single-valued around its largest point (the
    frequency increases through it); at a fold the largest computed point is
    returned unrefined.

    Returns
    -------
    omega_peak, amplitude_peak : float
    refined : bool
    """
    from scipy.optimize import minimize_scalar
    i = int(np.argmax(amplitude))
    n = len(omega)
    if i == 0 or i == n - 1 or not (omega[i - 1] < omega[i] < omega[i + 1]):
        return float(omega[i]), float(amplitude[i]), False
    zs = {"z": Z[i]}

    def neg_amp(w):
        sol = solve_point(system, w, F, z0=zs["z"], tol=tol)
        if not sol.convergence.success:
            return -float(amplitude[i])
        zs["z"] = sol.z
        return -float(harmonic_amplitude(system.basis, sol.X[:, dof]))

    lo, hi = float(omega[i - 1]), float(omega[i + 1])
    res = minimize_scalar(neg_amp, bounds=(lo, hi), method="bounded",
                          options={"xatol": 1e-10 * max(abs(hi), 1.0), "maxiter": 25})
    a = -float(res.fun)
    if a < amplitude[i]:
        return float(omega[i]), float(amplitude[i]), False
    return float(res.x), a, True
