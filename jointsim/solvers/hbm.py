"""AFT harmonic balance with the linear structure condensed onto the contacts.

Formulation
-----------
The structure ``M x'' + C x' + K x + f_c = f_ext`` with
``f_c = Tt^T f_t - Tn^T N`` (see :mod:`jointsim.model`) is sought as
``x(t) = X_0 + sum_h (X_hc cos h w t + X_hs sin h w t)``; coefficient order
``[0, 1c, 1s, 2c, 2s, ...]`` over the kept harmonics.  Per harmonic, with
``nu = h w`` and the complex amplitude ``Xh = X_hc - i X_hs``, the linear part
is the dynamic stiffness ``D_h = K - nu^2 M + i nu C``.

The linear part is condensed onto the contact coordinates ``q = T x`` per
harmonic, ``S_h(w) q_h + phi_h(q) = F_q - B E^-1 F_y`` with ``phi`` the element
forces (:mod:`jointsim.solvers.condensation`), and ``phi`` is evaluated by AFT
(:mod:`jointsim.solvers.aft`).

The frequency derivative of the residual is analytic too:
``dR/dw = A_w q + B_w y + B y_w`` with ``y_w = -E^-1 (B'_w q + E_w y)``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ..harmonics import HarmonicBasis
from .aft import AFT, AFTResult
from .condensation import STACKED_MAX_DOF, WELDED_SINGULAR, ReducedLinear, dense_array
from .frequency_blocks import FrequencyBlocks
from .jacobian import (KRYLOV_MIN_UNKNOWNS, KRYLOV_RTOL, LINEAR_SOLVERS, HBMJacobian, LinearStats,
                       add_element_blocks, fill_harmonic_blocks, solve)
from .preconditioner_cache import PreconditionerCache
from .newton import LINEAR_FORCING, NewtonOptions, newton

log = logging.getLogger(__name__)


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
    J : ndarray, shape (n_c * n_r, n_c * n_r), or HBMJacobian, or None
        ``dR/dz`` (dense on the direct path, structured on the Krylov path).
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
        AFT march periods (see :class:`~jointsim.solvers.aft.AFT`).
    parallel : bool
        Let the AFT kernels use numba threads (see :class:`~jointsim.solvers.aft.AFT`);
        False in worker processes.
    linear_solver : str
        ``"direct"``: dense Jacobians and LU (the reference); ``"krylov"``:
        structured Jacobians (:class:`~jointsim.solvers.jacobian.HBMJacobian`)
        solved by preconditioned GMRES, no ``n_z x n_z`` matrix formed;
        ``"auto"``: Krylov from ``KRYLOV_MIN_UNKNOWNS`` unknowns on.  The
        choice is ``self.linear_solver``; ``self.stats`` counts the solves.
    lin : ReducedLinear, optional
        The condensation of the same model onto the same contact coordinates, to
        share (it does not depend on the harmonics; the error indicators'
        extended system shares the point's); built when not given.
    """

    def __init__(self, model, harmonics, n_samples: int, min_periods: int = 2,
                 max_periods: int = 50, parallel: bool = True, linear_solver: str = "auto",
                 lin: ReducedLinear | None = None):
        self.model = model
        self.basis = HarmonicBasis(harmonics, n_samples)
        c = model.contacts
        self.contacts = c
        self.aft = AFT(c, self.basis, min_periods, max_periods, parallel=parallel)
        ne = c.n_elements
        self.n_e = ne
        self.friction = c.law.has_force
        self.coupled = bool(c.coupled)
        rows = []
        self.t_row = np.full(ne, -1, dtype=np.int64)
        self.n_row = np.full(ne, -1, dtype=np.int64)
        nr = 0
        if self.friction and ne:
            rows.append(dense_array(c.Tt))
            self.t_row = np.arange(ne)
            nr = ne
        if self.coupled and ne:
            rows.append(dense_array(c.Tn))
            self.n_row = nr + np.arange(ne)
            nr += ne
        T = np.vstack(rows) if rows else np.zeros((0, model.n_dof))
        self.T = T
        if lin is not None and (lin.n != model.n_dof or lin.n_r != nr):
            raise ValueError(f"lin condenses {lin.n} DOFs onto {lin.n_r} coordinates, the "
                             f"model needs {model.n_dof} onto {nr}")
        self.lin = lin if lin is not None else ReducedLinear(
            model.M, model.K, model.C, T, K_stuck=model.linearisation.K
            if model.linearisation is not None else None,
            positions=np.vstack([c.position] * (nr // ne)) if nr else None,
            stuck_modes=model.stuck_modes)
        self.n_r = nr
        self.n_c = self.basis.n_coeff
        self.n_z = self.n_c * nr
        self._Tt = dense_array(c.Tt) if ne else np.zeros((0, model.n_dof))
        if linear_solver not in LINEAR_SOLVERS:
            raise ValueError(f"linear_solver must be one of {LINEAR_SOLVERS}, "
                             f"got {linear_solver!r}")
        if linear_solver == "auto":
            linear_solver = "krylov" if self.n_z >= KRYLOV_MIN_UNKNOWNS else "direct"
        self.linear_solver = linear_solver
        self.krylov = linear_solver == "krylov"
        #: a small structure: the direct path's linear part of every harmonic at once
        self.stacked = not self.krylov and model.n_dof <= STACKED_MAX_DOF
        self.stats = LinearStats()
        self.preconditioner = PreconditionerCache()
        #: ``(omega, xi) -> (blocks, S)`` of the last ``OMEGA_CACHE`` frequencies
        #: (:meth:`harmonic_blocks`; an explicit attribute, never shared between systems)
        self.omega_cache = {}
        #: GMRES tolerance of the Krylov path's solves (relative residual)
        self.krylov_rtol = KRYLOV_RTOL
        log.info("HBM system: %d DOFs condensed onto %d contact coordinates x %d "
                 "coefficients = %d unknowns (%s condensation, %s linear solver)",
                 model.n_dof, nr, self.n_c, self.n_z, self.lin.kind, self.linear_solver)

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

    # -- the linear part per frequency ------------------------------------------
    def harmonic_blocks(self, omega: float, xi: float = 0.0) -> FrequencyBlocks:
        """The linear part at ``omega`` (:class:`~.frequency_blocks.FrequencyBlocks`: the
        per-harmonic blocks, formed on first use, the ``S_h`` formed so far and the
        all-harmonic products).

        They depend on ``(omega, xi)`` only, so the last ``OMEGA_CACHE`` frequencies
        are kept in :attr:`omega_cache`: Newton at a fixed frequency (the first point,
        the scale estimate, the corrector closing a branch, peak refinement) and the
        reconstruction of an accepted point form them once, and every structured
        Jacobian at that frequency shares its ``S_h`` (formed once).  Bit-identical to
        forming them again (the same operations).
        """
        key = (float(omega), float(xi))
        cache = self.omega_cache
        got = cache.pop(key, None)
        if got is None:
            got = FrequencyBlocks(self.lin, self.basis.harmonics, omega, xi)
        cache[key] = got                       # most recent last
        while len(cache) > OMEGA_CACHE:
            cache.pop(next(iter(cache)))
        return got

    def prepare_forks(self, omega_max: float, xi: float = 0.0) -> None:
        """Make the condensation's one-time pieces that the Krylov solves use before
        workers are forked, so that the workers share them instead of each making them
        again: the stuck joint's flexibility (an eigen-decomposition, ``n^3``, its
        quasi-static series, ``n_r^2`` per mode, and that series' HODLR on a large
        interface, :meth:`~.flexibility.StuckFlexibility.compressed`) and the
        hierarchical interface operator (its quasi-static split and ``G_p``, ``n_r^2
        n_y``), made for every harmonic up to ``omega_max``.  (Made on first use instead, the series was made twice in each
        worker of the 480-Gauss-point FRC, about 0.4 s each: for the first frequencies
        of ``frc_scales`` and again for the higher harmonics; round 47.)

        Parameters
        ----------
        omega_max : float
            The highest fundamental frequency the workers will meet [rad/s]; the split
            made for it (``2 h_max omega_max``) serves every frequency below.
        xi : float
            Self-excitation [1/s] (EPMC), as in :meth:`harmonic_blocks`.

        Nothing is made on the direct path, nor at a zero frequency.
        """
        if self.krylov and self.lin.n_r and omega_max > 0.0:
            flex = self.lin.flexibility
            h_max = max(self.basis.harmonics)
            if flex is not None and h_max > 0:
                flex.prepare(h_max * float(omega_max))
                flex.compressed(h_max * float(omega_max))   # its HODLR, where kept so
            self.harmonic_blocks(float(omega_max), float(xi)).hierarchical

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
            ``dR/dz``; it is returned as ``J``.  Without it, the Krylov path
            returns a structured :class:`~jointsim.solvers.jacobian.HBMJacobian`.
        """
        nr, nc = self.n_r, self.n_c
        Q = np.asarray(z, dtype=float).reshape(nc, nr)
        R = np.zeros((nc, nr))
        structured = jacobian and self.krylov and J_out is None
        J = (np.zeros((self.n_z, self.n_z)) if J_out is None else J_out) \
            if jacobian and not structured else None
        dR = {p: np.zeros((nc, nr)) for p in wrt} if jacobian else {}
        lin = self.lin
        fb = self.harmonic_blocks(omega, xi)
        # the force in the contact and the other coordinates, every coefficient at once
        # (real products: the complex form of Psi and Z is never made)
        F = np.asarray(F, dtype=float)
        FPsi, FZ = F @ lin.Psi, F @ lin.Z
        if self.krylov and J_out is None and fb.dynamic is not None:
            self._linear_part_all(fb, Q, FPsi, FZ, R, dR)
        elif self.stacked:
            self._linear_part_stacked(fb, Q, FPsi, FZ, R, dR, J, jacobian and not structured)
        else:
            self._linear_part(fb, Q, FPsi, FZ, R, dR, J, jacobian and not structured)
        aft = None
        if self.n_e and nr:
            aft = self.contact_forces(z, jacobian)
            if self.friction:
                R[:, self.t_row] += aft.Ft.T
            if self.coupled:
                R[:, self.n_row] -= aft.Nc.T
            if jacobian and not structured:
                self._add_element_blocks(J, aft)
        if structured:
            J = HBMJacobian(self.basis, self.lin, fb, self.t_row, self.n_row,
                            aft.Juu if (aft is not None and self.friction) else None,
                            aft.Jug if (aft is not None and self.friction and self.coupled)
                            else None,
                            aft.JNN if (aft is not None and self.coupled) else None,
                            stats=self.stats, cache=self.preconditioner, rtol=self.krylov_rtol)
        return Evaluation(R=R.ravel(), J=J, dR={p: v.ravel() for p, v in dR.items()}, aft=aft)

    def _linear_part(self, fb, Q, FPsi, FZ, R, dR, J, dense):
        """Add ``A q + B y - F_q`` (``y = E^-1 (F_y - B' q)``) to ``R``, its derivatives
        to ``dR`` and, when ``dense``, ``S_h`` into ``J``: harmonic by harmonic from the
        blocks (a full ``E``, or the dense Jacobian)."""
        nr, lin = self.n_r, self.lin
        Ss = []
        for h, (A, B, Bp, Ef) in zip(self.basis.harmonics, fb.blocks):
            nu = h * fb.omega
            qh = self._complex(Q, h)
            Fq = self._complex(FPsi, h)
            Fy = self._complex(FZ, h)
            if lin.n_y and dense:
                both = lin.solve_E(Ef, np.column_stack([Fy - Bp @ qh, Bp]))
                y, EinvBp = both[:, 0], both[:, 1:]
            elif lin.n_y:
                y = lin.solve_E(Ef, Fy - Bp @ qh)
            else:
                y, EinvBp = np.zeros(0, complex), np.zeros((0, nr), complex)
            self._store(R, h, A @ qh + B @ y - Fq)
            if dense:
                Ss.append(A - B @ EinvBp)
            for p in dR:
                if h == 0 and p == "omega":
                    continue
                v, dy = lin.dproducts(nu, fb.xi, p, h, qh, y)
                if lin.n_y:
                    v = v + B @ -lin.solve_E(Ef, dy)
                self._store(dR[p], h, v)
        if dense:
            fill_harmonic_blocks(J, np.stack(Ss), self.basis)

    def _linear_part_stacked(self, fb, Q, FPsi, FZ, R, dR, J, dense):
        """:meth:`_linear_part` with the blocks of every harmonic stacked
        (:attr:`~.frequency_blocks.FrequencyBlocks.stacked`, a small structure): a few
        batched products and solves instead of a dozen calls per harmonic."""
        nr, ny = self.n_r, self.lin.n_y
        D = fb.stacked
        A, B, Bp, E = D[:, :nr, :nr], D[:, :nr, nr:], D[:, nr:, :nr], D[:, nr:, nr:]
        b = self.basis
        q = b.to_complex(Q)[..., None]                                   # (n_h, n_r, 1)
        try:
            if ny and dense:
                both = np.linalg.solve(E, np.concatenate([b.to_complex(FZ)[..., None] - Bp @ q,
                                                          Bp], axis=2))
                y, EinvBp = both[..., :1], both[..., 1:]
            elif ny:
                y = np.linalg.solve(E, b.to_complex(FZ)[..., None] - Bp @ q)
            else:
                y = np.zeros((q.shape[0], 0, 1), dtype=complex)
        except np.linalg.LinAlgError:
            raise np.linalg.LinAlgError(WELDED_SINGULAR) from None
        b.from_complex((A @ q + B @ y)[..., 0] - b.to_complex(FPsi), R)
        if dense:
            fill_harmonic_blocks(J, A - B @ EinvBp if ny else A, self.basis)
        if dR:
            _, M, C = self.lin.transformed
            w = np.concatenate([q, y], axis=1)[..., 0]                   # (n_h, n)
            Mw, Cw = w @ M.T, w @ C.T
            h = np.asarray(b.harmonics, dtype=float)
            nu = h * fb.omega
            for p in dR:
                # dD/domega = h (-(2 nu + i xi) M + i C), dD/dxi = -i nu M (0 at h = 0)
                cm, cc = ((-h * (2.0 * nu + 1j * fb.xi), 1j * h) if p == "omega"
                          else (-1j * nu, np.zeros_like(nu)))
                dw = cm[:, None] * Mw + cc[:, None] * Cw
                v = dw[:, :nr]
                if ny:
                    v = v - (B @ np.linalg.solve(E, dw[:, nr:, None]))[..., 0]
                b.from_complex(v, dR[p])

    def _linear_part_all(self, fb, Q, FPsi, FZ, R, dR):
        """:meth:`_linear_part` for every harmonic at once by
        :class:`~.condensation.DynamicProducts` (modal or low-rank condensation): the
        complex per-harmonic blocks are not formed."""
        dyn = fb.dynamic
        H = self.basis.harmonics
        cq = self.basis.to_complex(Q).T                                  # (n_r, n_h)
        cF = self.basis.to_complex(FPsi).T
        cFy = self.basis.to_complex(FZ).T                                # (n_y, n_h)
        lhs, y = dyn.parts(cq, cFy)
        self.basis.from_complex((lhs - cF).T, R)
        for p in dR:
            dq, dy = dyn.derivatives(p, fb.omega, H, cq, y)
            v = dq - dyn.b_einv(dy)
            for j, h in enumerate(H):
                if not (h == 0 and p == "omega"):
                    self._store(dR[p], h, v[:, j])

    def contact_forces(self, z, jacobian: bool = False):
        """The AFT of the contact elements at the coefficients ``z``.

        Parameters
        ----------
        z : ndarray, shape (n_z,)
            Coefficients of the contact coordinates [m].
        jacobian : bool
            Also the element tangents.

        Returns
        -------
        AFTResult
            Force coefficients ``Ft``, ``Nc`` [N] (and tangents [N/m]) of every element.
        """
        Q = np.asarray(z, dtype=float).reshape(self.n_c, self.n_r)
        U = Q[:, self.t_row] if self.friction else np.zeros((self.n_c, self.n_e))
        Gq = Q[:, self.n_row] if self.coupled else None
        return self.aft.evaluate(U, Gq, jacobian)

    def _add_element_blocks(self, J, aft):
        add_element_blocks(J, self.n_r, self.n_c, self.t_row, self.n_row,
                           aft.Juu if self.friction else None,
                           aft.Jug if (self.friction and self.coupled) else None,
                           aft.JNN if self.coupled else None)

    # -- reconstruction ----------------------------------------------------------
    def reconstruct(self, z, omega: float, F, xi: float = 0.0):
        """Full coefficients ``X`` (n_c, n_dof) [m] from the contact coordinates."""
        nr, nc = self.n_r, self.n_c
        Q = np.asarray(z, dtype=float).reshape(nc, nr)
        lin = self.lin
        Y = np.zeros((nc, lin.n_y))            # coefficients of the other coordinates
        FZ = np.asarray(F, dtype=float) @ lin.Z
        dyn = self.harmonic_blocks(omega, xi).dynamic if lin.n_y else None
        if dyn is not None:
            # modal or low-rank condensation: every harmonic at once, no complex block
            # formed (DynamicProducts.parts; B'_h alone is n_y x n_r per harmonic)
            _, y = dyn.parts(self.basis.to_complex(Q).T, self.basis.to_complex(FZ).T)
            self.basis.from_complex(y.T, Y)
        elif lin.n_y:
            for h in self.basis.harmonics:
                _, _, Bp, E = lin.blocks(h * omega, xi, parts="yq")
                self._store(Y, h, lin.solve_E(E, self._complex(FZ, h) - Bp @ self._complex(Q, h)))
        # x = Psi q + Z y, every coefficient at once (real products)
        return Q @ lin.Psi.T + Y @ lin.Z.T

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
                max_iter: int = 30, rscale: float | None = None,
                forcing: float = LINEAR_FORCING) -> PointSolution:
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
    forcing : float
        Inexact Newton steps on the Krylov path (:class:`~.newton.NewtonOptions`; 0:
        every step solved to round-off).
    """
    from ..results import NOT_CONVERGED, SUCCESS, Convergence
    if rscale is None:
        rscale = max(float(np.abs(F).max(initial=0.0)), 1e-300)
    z0 = system.static_coordinates() if z0 is None else np.asarray(z0, dtype=float)

    def fun(z):
        ev = system.evaluate(z, omega, F, wrt=())
        return ev.R, ev.J, ev

    res = newton(fun, z0, NewtonOptions(tol, max_iter, line_search="decrease", max_tries=6,
                                        forcing=forcing),
                 solve=solve, measure=lambda R, _ev: np.abs(R).max(initial=0.0) / rscale)
    z, R, ev, it, ok = res.x, res.R, res.extra, res.iterations, res.success
    rn = float(np.abs(R).max(initial=0.0))
    conv = Convergence(ok, SUCCESS if ok else NOT_CONVERGED,
                       f"Newton {'converged' if ok else 'did not converge'} in {it} iterations "
                       f"(residual {rn / rscale:.1e} of the force scale)", it)
    return PointSolution(z=z, X=system.reconstruct(z, omega, F), omega=float(omega),
                         residual=rn, evaluation=ev, convergence=conv)


#: Frequencies whose harmonic blocks an :class:`HBMSystem` keeps
#: (:meth:`HBMSystem.harmonic_blocks`).
OMEGA_CACHE = 2
