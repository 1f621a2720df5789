"""Generalized-alpha stepping of a structure with friction contact.

This module holds the integrator itself: the stepper (a Newton solve per
step, condensed onto the contact coordinates, with step cutting); the contact
elements in condensed coordinates are :mod:`jointsim.solvers.contact_map`.  The drivers that
march to a steady state or ring down a free decay, and the runner that writes
the result file, are in :mod:`jointsim.solvers.transient`; the static state
they start from and the linear modes come from :mod:`jointsim.solvers.static`
and :mod:`jointsim.solvers.modes`, as for every solver.

Equation of motion
------------------
With the sign conventions of :mod:`jointsim.model`,

    M x'' + C x' + K x + B^T phi(B x, history) = f(t),

where ``y = B x`` are the *contact coordinates*: the tangential slips
``u_t = Tt x`` and, when the normal load is coupled, the gap changes
``Tn x`` (gap ``g = gap0 + Tn x``).  ``phi`` stacks the tangential forces
``f_t(u_t, N)`` and, for coupled normal load, ``-N(g)``; so that
``f_c = Tt^T f_t - Tn^T N = B^T phi``.  With a fixed normal load ``y = u_t``
and ``N = N0``.

Scheme
------
Generalized-alpha (Chung & Hulbert, J. Appl. Mech. 60, 1993) with the
spectral radius ``rho_inf`` at infinite frequency:
``am = (2 rho - 1)/(rho + 1)``, ``af = rho/(rho + 1)``,
``gamma = 1/2 - am + af``, ``beta = (1 - am + af)^2 / 4``, Newmark updates
for ``x`` and ``v``, and the balance

    M [(1-am) a1 + am a0] + (1-af) [C v1 + K x1 + B^T phi1 - f(t1)]
                          +    af [C v0 + K x0 + B^T phi0 - f(t0)] = 0.

The internal forces are averaged between the ends of the step (the
"generalized trapezoidal" form of Erlicher, Bonaventura & Bursi, Comput.
Mech. 28, 2002), so the contact laws are only evaluated at the step ends,
with the state committed at the end of each converged step; for linear
systems this is the original method.  The scheme is second-order accurate
for any ``rho_inf``; ``rho_inf = 1`` is the trapezoidal rule (no numerical
dissipation).

A unilateral normal contact that opens or closes within a step breaks the
energy identity of the averaged force: with a stiff penalty and steps longer
than the contact lasts, plain averaging pumps energy into the structure
(clapping lap ends blow up).  For those elements the averaged normal load is
replaced by the discrete gradient of the penalty energy plus the
``(1/2 - af)`` dissipative part (``_transient_kernels.gap_correction``): the
normal force then does exactly the work stored in the penalty spring, and
elements that stay closed or open are unaffected.

Newton, condensed on the contact coordinates
--------------------------------------------
The balance is linear in ``x1`` except for ``phi``.  With
``S = (1-am)/(beta h^2) M + (1-af)(gamma/(beta h) C + K)`` (factorised once
per step size), the linear part gives ``x1 = x_p - (1-af) Z phi(y1)`` with
``Z = S^-1 B^T``, and the step reduces to ``n_c`` equations in the contact
coordinates only::

    r(y) = y - B x_p + (1-af) G phi(y) = 0,      G = B Z  (n_c x n_c),

solved by Newton with the consistent tangent ``I + (1-af) G D``, where
``D = dphi/dy`` comes from the same march kernels as harmonic balance
(called with one sample and the committed state: the tangent of the step at
fixed history).  The iteration stops when

    max |r| <= newton_tol * max(max |y|, max |B x_p|, max |B x0|),

a displacement scale of the step alone (its iterate, its linear prediction
and its start ``x0``), so that a step's tolerance does not depend on the
steps marched before it.  ``x1`` is recovered with one product by ``Z``.  A step whose
Newton iteration fails (iteration limit or non-finite values) is cut in half
and retried, recursively, up to ``max_cuts`` times.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..loads import LoadFunction
from ._transient_kernels import single_threaded
from .contact_map import ContactEval, ContactMap, empty_eval
from .newton import NewtonOptions, newton

log = logging.getLogger(__name__)

#: Models up to this many DOFs are handled with dense matrices (reduced models
#: from Craig-Bampton are dense anyway); larger ones stay sparse.
DENSE_MAX_DOF = 1500


def alpha_parameters(rho_inf: float):
    """Generalized-alpha parameters of Chung & Hulbert.

    Parameters
    ----------
    rho_inf : float
        Spectral radius at infinite frequency, in [0, 1].

    Returns
    -------
    am, af, gamma, beta : float
    """
    if not 0.0 <= rho_inf <= 1.0:
        raise ValueError(f"rho_inf must lie in [0, 1], got {rho_inf}")
    am = (2.0 * rho_inf - 1.0) / (rho_inf + 1.0)
    af = rho_inf / (rho_inf + 1.0)
    gamma = 0.5 - am + af
    beta = 0.25 * (1.0 - am + af) ** 2
    return am, af, gamma, beta


# --------------------------------------------------------------------------
# Linear algebra of the linear part
# --------------------------------------------------------------------------
class _LinearSolver:
    """Solver of a non-singular matrix: a dense inverse for small dense
    matrices (one product per solve), a sparse LU otherwise."""

    def __init__(self, A):
        self.dense = not sp.issparse(A)
        if self.dense:
            lu = sla.lu_factor(A, check_finite=True)
            if np.any(np.diag(lu[0]) == 0.0):
                raise sla.LinAlgError("singular matrix")
            self.inv = sla.lu_solve(lu, np.eye(A.shape[0]))
        else:
            self.lu = spla.splu(sp.csc_matrix(A))

    def solve(self, b):
        if self.dense:
            return self.inv @ b
        return self.lu.solve(np.asarray(b, dtype=float))


class _Condensed:
    """``S``, its factorisation, ``Z = S^-1 B^T`` and ``G = B Z`` for one step size.

    Attributes
    ----------
    S : ndarray or scipy.sparse matrix, shape (n_dof, n_dof)
    solver : _LinearSolver
    Sinv : ndarray, shape (n_dof, n_dof), or None
        C-contiguous ``S^-1`` for the fused kernel (dense ``S``; None when sparse).
    Z : ndarray, shape (n_dof, n_c)
    G : ndarray, shape (n_c, n_c)
    """

    def __init__(self, S, cmap: ContactMap, dense: bool):
        self.S = S
        self.solver = _LinearSolver(S)
        self.Sinv = np.ascontiguousarray(self.solver.inv) if self.solver.dense else None
        if cmap.active:
            Bt = cmap.Bt if dense else cmap.Bt.toarray()
            self.Z = np.asarray(self.solver.solve(Bt)).reshape(S.shape[0], cmap.n_c)
            self.G = np.asarray(cmap.B @ self.Z)
        else:
            self.Z = np.zeros((S.shape[0], 0))
            self.G = np.zeros((0, 0))


class NewtonFailure(RuntimeError):
    """A Newton solve did not converge (the caller cuts the step)."""


def condensed_newton(cmap: ContactMap, G, coef, y_p, y0, state, tol, max_iter, scale=0.0,
                     prev=None):
    """Solve ``y - y_p + G (coef phi(y; state) + c(y)) = 0`` by Newton.

    ``c`` is the energy-consistent normal-force correction of
    :meth:`ContactMap.correction` (with ``prev``), else zero.

    Parameters
    ----------
    cmap : ContactMap
    G : ndarray, shape (n_c, n_c)
        Condensed compliance ``B S^-1 B^T`` [m/N].
    coef : float
        Weight of the contact forces (``1 - af`` in a dynamic step, 1 in statics).
    y_p : ndarray, shape (n_c,)
        Contact coordinates of the linear prediction (zero contact force) [m].
    y0 : ndarray, shape (n_c,)
        Starting iterate [m].
    state : ndarray
        Committed law state.
    tol : float
        Tolerance on ``max |r|`` relative to ``max(|y|, |y_p|, scale)``.
    max_iter : int
    scale : float
        Displacement scale of the step added to the relative tolerance (the
        largest contact coordinate at the step's start) [m].
    prev : tuple, optional
        ``(y0, ev0)`` at the start of a dynamic step, for the normal-force
        correction of unilateral contacts.

    Returns
    -------
    y : ndarray, shape (n_c,)
    ev : ContactEval
        Forces, tangent and new state at ``y``.
    iterations : int
        Linear solves taken.
    c : ndarray, shape (n_c,)
        The correction at ``y`` (zeros without ``prev``).

    Raises
    ------
    NewtonFailure
    """
    ref_p = np.abs(y_p).max() if np.size(y_p) else 0.0
    use_c = prev is not None and cmap.unilateral

    def fun(y):
        ev = cmap.evaluate(y, state)
        if use_c:
            c, dc = cmap.correction(prev[0], prev[1], y, ev)
            return y - y_p + G @ (coef * ev.phi + c), (ev, c, dc)
        return y - y_p + coef * (G @ ev.phi), (ev, np.zeros(y.size), None)

    def jacobian(y, r, extra):
        ev, _c, dc = extra
        J = np.eye(y.size) + coef * cmap.times_D(G, ev)
        if dc is not None:
            J += G * dc
        return J

    def threshold(y, _extra):
        return tol * max(np.abs(y).max() if y.size else 0.0, ref_p, scale)

    res = newton(fun, y0, NewtonOptions(tol, max_iter, check_start=True, line_search="none"),
                 jacobian=jacobian, solve=np.linalg.solve, threshold=threshold)
    if not res.success:
        raise NewtonFailure(res.message)
    ev, c, _dc = res.extra
    return res.x, ev, res.iterations, c


# --------------------------------------------------------------------------
# States and the stepper
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class MarchState:
    """The structure and its contacts at one instant.

    Attributes
    ----------
    t : float
        Time [s].
    x, v, a : ndarray, shape (n_dof,)
        Displacement [m], velocity [m/s] and acceleration [m/s^2].
    contact : ContactEval
        Contact forces at ``x``; ``contact.state`` is the committed law state.
    """

    t: float
    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    contact: ContactEval


class StepFailure(RuntimeError):
    """A step failed even at the smallest allowed step size."""


@dataclass
class StepStats:
    """Counters of a march."""

    steps: int = 0
    substeps: int = 0
    newton_iterations: int = 0
    cuts: int = 0
    deepest_cut: int = 0
    factorizations: int = 0

    def as_attrs(self) -> dict:
        return {"steps": self.steps, "substeps": self.substeps,
                "newton_iterations": self.newton_iterations, "step_cuts": self.cuts,
                "deepest_cut": self.deepest_cut, "factorizations": self.factorizations}


class GeneralizedAlpha:
    """Implicit stepper for ``M x'' + C x' + K x + f_c = f(t)`` with contact.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    force : callable
        ``force(t) -> ndarray (n_dof,)``, the total external force [N]
        (loads and ``f_static``).
    rho_inf : float
        Spectral radius at infinite frequency.
    newton_tol : float
        Relative Newton tolerance on the contact coordinates: a step's
        residual ``max |r|`` [m] is compared with ``newton_tol`` times the
        largest contact coordinate of its iterate, its linear prediction and
        its start (see the module docstring), never with earlier steps.
    max_iter : int
        Newton iterations before a step is cut.
    max_cuts : int
        Halvings allowed for a failing step.
    """

    def __init__(self, model, force, rho_inf: float = 0.9, newton_tol: float = 1e-10,
                 max_iter: int = 25, max_cuts: int = 8, fused: bool = True):
        self.model = model
        self.force = force
        self.rho_inf = float(rho_inf)
        self.am, self.af, self.gamma, self.beta = alpha_parameters(rho_inf)
        self.newton_tol = float(newton_tol)
        self.max_iter = int(max_iter)
        self.max_cuts = int(max_cuts)
        n = model.n_dof
        self.dense = n <= DENSE_MAX_DOF
        self.cmap = ContactMap(model.contacts, dense=self.dense)
        conv = (lambda A: np.asarray(sp.csr_matrix(A).toarray())) if self.dense else \
            (lambda A: sp.csr_matrix(A))
        self.M, self.C, self.K = conv(model.M), conv(model.C), conv(model.K)
        self.has_damping = (np.any(self.C) if self.dense else self.C.nnz > 0)
        self._factors: dict[float, _Condensed] = {}
        self._mass_solver = None
        self.stats = StepStats()
        #: March blocks of steps with the fused numba kernel (dense models, anchored or
        #: linear tangential laws, harmonic loads); otherwise step by step in Python.
        self.fused = bool(fused and self.dense and isinstance(force, LoadFunction)
                          and not force.sampled
                          and model.contacts.law.fused_code is not None)

    # -- linear algebra per step size ---------------------------------------
    def snap(self, h: float) -> float:
        """A cached step size within round-off (1e-9 relative) of ``h``, or ``h``."""
        for key in self._factors:
            if abs(h - key) <= 1e-9 * key:
                return key
        return float(h)

    def _factor(self, h: float) -> _Condensed:
        key = float(h)
        fac = self._factors.get(key)
        if fac is None:
            c0 = 1.0 / (self.beta * h * h)
            S = (1.0 - self.am) * c0 * self.M + (1.0 - self.af) * (
                (self.gamma / (self.beta * h)) * self.C + self.K)
            fac = _Condensed(S, self.cmap, self.dense)
            self.stats.factorizations += 1
            if len(self._factors) > 64:  # many different sizes: keep the cache bounded
                self._factors.clear()
            self._factors[key] = fac
        return fac

    def _internal(self, x, v, ev: ContactEval):
        """``C v + K x + B^T phi``."""
        out = self.K @ x + (self.C @ v if self.has_damping else 0.0)
        if self.cmap.active:
            out = out + self.cmap.Bt @ ev.phi
        return out

    # -- start ----------------------------------------------------------------
    def start(self, t0: float, x0, v0, state0, a0=None) -> MarchState:
        """Initial state: contacts evaluated at ``x0`` from ``state0``, and a consistent
        acceleration ``a0 = M^-1 (f(t0) - C v0 - K x0 - f_c)`` unless given.

        Parameters
        ----------
        t0 : float
        x0, v0 : ndarray, shape (n_dof,)
        state0 : ndarray
            Law state of the contacts at ``x0`` (e.g. after a quasi-static
            load path to ``x0``).
        a0 : ndarray, shape (n_dof,), optional
            Initial acceleration (e.g. of a discrete periodic solution).
        """
        x0 = np.array(x0, dtype=float)
        v0 = np.array(v0, dtype=float)
        ev = self.cmap.evaluate(self.cmap.B @ x0, state0) if self.cmap.active else \
            empty_eval(state0)
        if self._mass_solver is None:
            try:
                self._mass_solver = _LinearSolver(self.M)
            except (RuntimeError, ValueError, sla.LinAlgError) as exc:
                raise ValueError(f"the mass matrix cannot be factorised ({exc}); time "
                                 "marching needs a non-singular mass matrix") from None
        if a0 is None:
            a0 = np.asarray(self._mass_solver.solve(self.force(t0)
                                                    - self._internal(x0, v0, ev)))
        a0 = np.array(a0, dtype=float)
        if not np.all(np.isfinite(a0)):
            raise ValueError("the initial acceleration is not finite: is the mass matrix "
                             "singular?")
        return MarchState(float(t0), x0, v0, a0, ev)

    # -- one step ---------------------------------------------------------------
    def predictor(self, s: MarchState, h: float):
        """Linear prediction ``x_p`` (zero contact force at the new time) of a step.

        Returns
        -------
        x_p : ndarray, shape (n_dof,)
        fac : _Condensed
        """
        am, af, g, b = self.am, self.af, self.gamma, self.beta
        fac = self._factor(h)
        a_at = -s.v / (b * h) - (0.5 / b - 1.0) * s.a           # a1 at x1 = x0
        v_at = s.v + h * ((1.0 - g) * s.a + g * a_at)           # v1 at x1 = x0
        R = self.M @ ((1.0 - am) * a_at + am * s.a) + self.K @ s.x
        if self.has_damping:
            R = R + self.C @ ((1.0 - af) * v_at + af * s.v)
        if self.cmap.active:
            R = R + af * (self.cmap.Bt @ s.contact.phi)
        R = R - (1.0 - af) * self.force(s.t + h) - af * self.force(s.t)
        x_p = s.x - np.asarray(fac.solver.solve(R))
        return x_p, fac

    def residual(self, s: MarchState, h: float, x1) -> np.ndarray:
        """Full residual of the step balance at a trial ``x1`` (for tests) [N].

        The contact forces at ``x1`` are evaluated from ``s``'s committed state.
        """
        am, af, g, b = self.am, self.af, self.gamma, self.beta
        a1 = (x1 - s.x - h * s.v) / (b * h * h) - (0.5 / b - 1.0) * s.a
        v1 = s.v + h * ((1.0 - g) * s.a + g * a1)
        y1 = self.cmap.B @ x1
        ev = self.cmap.evaluate(y1, s.contact.state)
        c, _dc = self.cmap.correction(self.cmap.B @ s.x, s.contact, y1, ev)
        return (self.M @ ((1.0 - am) * a1 + am * s.a)
                + (1.0 - af) * (self._internal(x1, v1, ev) - self.force(s.t + h))
                + af * (self._internal(s.x, s.v, s.contact) - self.force(s.t))
                + (self.cmap.Bt @ c if self.cmap.active else 0.0))

    def tangent(self, s: MarchState, h: float, x1) -> np.ndarray:
        """Consistent tangent ``dR/dx1`` of the step at ``x1``, dense (for tests)."""
        fac = self._factor(h)
        S = fac.S.toarray() if sp.issparse(fac.S) else np.array(fac.S)
        y1 = self.cmap.B @ x1
        ev = self.cmap.evaluate(y1, s.contact.state)
        _c, dc = self.cmap.correction(self.cmap.B @ s.x, s.contact, y1, ev)
        B = self.cmap.B.toarray() if sp.issparse(self.cmap.B) else self.cmap.B
        return S + B.T @ ((1.0 - self.af) * self.cmap.D_matrix(ev) + np.diag(dc)) @ B

    def condensed_residual(self, s: MarchState, h: float, y):
        """The condensed step equation ``r(y)`` and its tangent ``dr/dy`` (for tests)."""
        x_p, fac = self.predictor(s, h)
        coef = 1.0 - self.af
        ev = self.cmap.evaluate(y, s.contact.state)
        c, dc = self.cmap.correction(self.cmap.B @ s.x, s.contact, y, ev)
        r = y - self.cmap.B @ x_p + fac.G @ (coef * ev.phi + c)
        J = np.eye(self.cmap.n_c) + coef * self.cmap.times_D(fac.G, ev) + fac.G * dc
        return r, J

    def _attempt(self, s: MarchState, h: float) -> MarchState:
        af, g, b = self.af, self.gamma, self.beta
        x_p, fac = self.predictor(s, h)
        if self.cmap.active:
            coef = 1.0 - af
            x_guess = s.x + h * s.v + 0.5 * h * h * s.a
            B = self.cmap.B
            y, ev, its, c = condensed_newton(
                self.cmap, fac.G, coef, B @ x_p, B @ x_guess, s.contact.state,
                self.newton_tol, self.max_iter, float(np.max(np.abs(B @ s.x))),
                prev=(B @ s.x, s.contact) if self.cmap.unilateral else None)
            self.stats.newton_iterations += its
            x1 = x_p - fac.Z @ (coef * ev.phi + c)
        else:
            x1 = x_p
            ev = s.contact
        if not np.all(np.isfinite(x1)):
            raise NewtonFailure("non-finite displacement")
        a1 = (x1 - s.x - h * s.v) / (b * h * h) - (0.5 / b - 1.0) * s.a
        v1 = s.v + h * ((1.0 - g) * s.a + g * a1)
        return MarchState(s.t + h, x1, v1, a1, ev)

    def _step(self, s: MarchState, t1: float, depth: int) -> MarchState:
        # steps on a grid differ by round-off only: reuse the factorisation
        h = self.snap(t1 - s.t)
        try:
            out = self._attempt(s, h)
            self.stats.substeps += 1
            return MarchState(t1, out.x, out.v, out.a, out.contact)
        except NewtonFailure as exc:
            if depth >= self.max_cuts:
                raise StepFailure(f"step at t = {s.t:.6g} failed after {depth} halvings "
                                  f"(step {h:.3g}): {exc}") from None
            self.stats.cuts += 1
            self.stats.deepest_cut = max(self.stats.deepest_cut, depth + 1)
            log.debug("t = %.6g: %s; halving the step (level %d)", s.t, exc, depth + 1)
            mid = self._step(s, s.t + 0.5 * h, depth + 1)
            return self._step(mid, t1, depth + 1)

    def step(self, s: MarchState, t1: float) -> MarchState:
        """Advance from ``s`` to time ``t1``, cutting the step if Newton fails.

        The law state is committed (carried in the returned state) only at the
        end of each converged (sub)step.

        Raises
        ------
        StepFailure
            When the step fails at the smallest allowed size; ``s`` is intact.
        """
        if not t1 > s.t:
            raise ValueError(f"t1 = {t1} must be after t = {s.t}")
        with single_threaded():  # one-sample kernel calls: no thread-pool launches
            out = self._step(s, float(t1), 0)
        self.stats.steps += 1
        return out

    def march(self, s: MarchState, times):
        """Yield the state at each of ``times`` (increasing, after ``s.t``)."""
        for t1 in times:
            s = self.step(s, t1)
            yield s

    def march_block(self, s: MarchState, times):
        """March from ``s`` (at ``times[0]``) through ``times[1:]``, returning arrays.

        Equal steps are marched by the fused kernel
        :func:`~jointsim.solvers._transient_kernels.march_dense` when
        :attr:`fused`; a step whose Newton solve fails there is redone by
        :meth:`step` (which cuts it) and the kernel resumes after it.

        Parameters
        ----------
        s : MarchState
        times : ndarray, shape (n + 1,)

        Returns
        -------
        s : MarchState
            At ``times[-1]``.
        x, v : ndarray, shape (n + 1, n_dof)
        u, f, N : ndarray, shape (n_e, n + 1)
        """
        times = np.asarray(times, dtype=float)
        n1 = times.size
        ne = self.cmap.n_e
        x = np.empty((n1, self.model.n_dof))
        v = np.empty_like(x)
        u, f, N = (np.zeros((ne, n1)) for _ in range(3))

        def put(j, st):
            x[j], v[j] = st.x, st.v
            if ne:
                u[:, j], f[:, j], N[:, j] = st.contact.u, st.contact.f, st.contact.N

        put(0, s)
        with single_threaded():
            s = self._block(s, times, put, x, v, u, f, N)
        return s, x, v, u, f, N

    def _block(self, s, times, put, x, v, u, f, N):
        """The loop of :meth:`march_block`: fused kernel, Python steps where it stops."""
        n1 = times.size
        j = 0
        while j < n1 - 1:
            if self.fused:
                s, done = self._fused(s, times[j:], x[j:], v[j:], u[:, j:], f[:, j:],
                                      N[:, j:])
                j += done
                if j == n1 - 1:
                    break
            s = self.step(s, times[j + 1])
            j += 1
            put(j, s)
        return s

    def _fused(self, s, times, x, v, u, f, N):
        """Run the fused kernel from ``s`` over ``times``; fill the arrays; return
        the state reached and the number of steps done."""
        from . import _transient_kernels as TK
        h = self.snap(times[1] - times[0])
        fac = self._factor(h)
        c = self.model.contacts
        law = c.law
        tkind, nkind = law.fused_code, c.normal.fused_code
        state = np.ascontiguousarray(s.contact.state, dtype=float)
        if state.ndim != 2 or state.shape[0] != law.n_elements:
            state = np.zeros((law.n_elements, 0))
        B = np.ascontiguousarray(self.cmap.B, dtype=float)
        done, its, X, V, A, PHI, U, F, NN, st = TK.march_dense(
            times, h, s.x, s.v, s.a, np.ascontiguousarray(s.contact.phi, dtype=float), state,
            self.M, self.C, self.K, fac.Sinv, B, np.ascontiguousarray(self.cmap.Bt),
            np.ascontiguousarray(fac.Z), np.ascontiguousarray(fac.G),
            self.am, self.af, self.gamma, self.beta, float(self.force.omega),
            self.force.harmonic_rows, np.ascontiguousarray(self.force.coefficients),
            tkind, nkind, np.ascontiguousarray(law.k), np.ascontiguousarray(law.g),
            np.ascontiguousarray(c.gap0, dtype=float), np.ascontiguousarray(c.kn, dtype=float),
            np.ascontiguousarray(self.cmap.N0, dtype=float), self.newton_tol, self.max_iter)
        self.stats.steps += done
        self.stats.substeps += done
        self.stats.newton_iterations += its
        if done == 0:
            return s, 0
        x[1:done + 1], v[1:done + 1] = X[1:done + 1], V[1:done + 1]
        if self.cmap.n_e:
            u[:, 1:done + 1] = U[:, 1:done + 1]
            f[:, 1:done + 1] = F[:, 1:done + 1]
            N[:, 1:done + 1] = NN[:, 1:done + 1]
        e = np.zeros(self.cmap.n_e)
        ev = ContactEval(PHI[done].copy(), e, e, e, st.copy() if law.has_force
                         else s.contact.state, U[:, done].copy(), F[:, done].copy(),
                         NN[:, done].copy())
        return MarchState(float(times[done]), X[done].copy(), V[done].copy(),
                          A[done].copy(), ev), done
