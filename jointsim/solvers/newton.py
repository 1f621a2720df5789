"""The one damped Newton iteration of jointsim.

Every nonlinear solve (harmonic balance at a point, the static equilibrium,
the condensed time step, the continuation correctors) is this loop, with
its options:

* ``x_0`` is evaluated; with ``check_start`` the convergence test is applied
  to it already (a converged start takes no iteration), otherwise only after
  the first step.
* The test, at every iterate: a non-finite residual measure or iterate
  fails (``NON_FINITE``); ``measure(R) <= threshold(x)`` succeeds; with
  ``stall`` set, a best measure that has not fallen by 10 % in ``stall``
  iterations fails (Newton cycling across a kink of a piecewise-smooth
  residual); ``max_iter`` iterations fail (``NOT_CONVERGED``).
* The step ``dx = solve(J, -R)``; a solver that raises fails the iteration
  (singular Jacobian); with ``finite_step`` a non-finite ``dx`` fails.
* Inexact steps (``forcing``, structured Jacobians only): the iterative
  solve of a structured Jacobian (:mod:`jointsim.solvers.jacobian`, GMRES)
  is asked for ``solve(J, -R, rtol=eta)``, a linear residual of at most
  ``forcing`` times the Newton tolerance, not the round-off its default
  tolerance gives.  With ``r = measure(R)`` and the measure a multiple of
  ``max |R|``, ``eta = forcing * tol * max|R| / (r * ||R||_2)`` (the 2-norm
  residual GMRES controls bounds the largest entry).  Far from the solution
  the step is then solved to a few digits; the last one still lands the
  residual below ``tol`` (it is at most ``forcing * tol`` plus Newton's
  quadratic term), so a converged point is the one exact steps give up to
  about ``forcing * tol`` in its residual.  Dense Jacobians, and structured
  ones that say no (``J.inexact_steps``: the EPMC's), are solved exactly.
* Damping: the step lengths ``1, 1/2, 1/4, ...`` are tried, at most
  ``max_tries`` of them, until one is accepted (the last one tried is taken
  anyway):

  - ``"none"``: the full step;
  - ``"decrease"``: ``m(x + a dx)`` finite and ``<= m(x)`` or already
    converged;
  - ``"armijo"``: ``m(x + a dx) <= (1 - 1e-4 a) m(x)``.

``iterations`` counts the Newton steps (linear solves) taken.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..results import NON_FINITE, NOT_CONVERGED, SUCCESS, Convergence
from .jacobian import is_structured, solve as linear_solve

LINE_SEARCHES = ("none", "decrease", "armijo")
#: Default ``NewtonOptions.forcing``: the linear residual of a structured Jacobian's
#: Newton step is asked for at most this share of the Newton tolerance (module doc).
#: Measured on 120 Gauss points, the FRC branches (indicators off, one thread, two
#: runs side by side), time / GMRES iterations / preconditioner builds at forcing 0
#: (every solve to ``KRYLOV_RTOL = 1e-11``), 0.01 and 0.03:
#:
#: * force 20: 13.2 s / 1,936 / 72, 11.7 s / 1,611 / 56, 11.1 s / 1,553 / 51;
#: * force 2: 11.6 s / 2,327 / 60, 9.9 s / 2,028 / 59, 9.5 s / 1,975 / 59;
#: * force 0.02: 8.0 s / 1,398 / 12, 7.3 s / 1,202 / 17, 6.8 s / 1,176 / 15.
#:
#: The same points and Newton iterations in all; X equal to the exact steps' to
#: 4.7e-12 .. 9.2e-11 at 0.01 and 1.5e-11 .. 6.9e-11 at 0.03.  But on the default
#: scene's force-0.02 branch (96 Gauss points) one point near the end of the range
#: (omega = 1065.4) moved along the branch by 1.0e-9 in frequency at 0.03, and its X by
#: 1.4e-8, above the 1e-8 the Krylov path keeps to the dense one (3.8e-10 at 0.01,
#: 3.4e-10 at 0.003); at 0.1, 1.9e-8 on the 120-point branch.  Hence 0.01.
LINEAR_FORCING = 0.01


@dataclass(frozen=True)
class NewtonOptions:
    """Options of :func:`newton`.

    Attributes
    ----------
    tol : float
        Tolerance on the residual measure (the default threshold).
    max_iter : int
        Newton steps at most.
    check_start : bool
        Apply the convergence test to the start already.
    line_search : str
        ``"none"``, ``"decrease"`` or ``"armijo"`` (module docstring).
    max_tries : int
        Step lengths ``2^-k`` tried at most (``"none"`` tries one).
    stall : int or None
        Give up when the best measure has not fallen by 10 % in this many steps.
    finite_step : bool
        Fail on a non-finite step before evaluating it.
    forcing : float
        Inexact steps on structured Jacobians: the linear residual asked of the step
        is at most this share of the tolerance (module doc; 0: every step solved to
        the linear solver's own tolerance).
    """

    tol: float
    max_iter: int
    check_start: bool = False
    line_search: str = "decrease"
    max_tries: int = 6
    stall: int | None = None
    finite_step: bool = False
    forcing: float = LINEAR_FORCING

    def __post_init__(self):
        if self.line_search not in LINE_SEARCHES:
            raise ValueError(f"line_search must be one of {LINE_SEARCHES}, "
                             f"got {self.line_search!r}")
        if self.max_tries < 1:
            raise ValueError("max_tries must be >= 1")
        if not 0.0 <= self.forcing < 1.0:
            raise ValueError(f"forcing must be in [0, 1), got {self.forcing!r}")


@dataclass(frozen=True)
class NewtonResult:
    """The end of a Newton iteration.

    Attributes
    ----------
    x : ndarray, shape (n,)
        Last iterate (the converged one on success).
    success : bool
    status : int
        :mod:`jointsim.results` status code.
    message : str
    iterations : int
        Newton steps taken.
    residual : float
        Residual measure at ``x``.
    R : ndarray, shape (n_r,)
        Residual at ``x``.
    J : ndarray or None
        Jacobian at ``x`` when the residual function returns it (else None).
    extra : object
        What the residual function returned besides ``R`` (and ``J``) at ``x``.
    """

    x: np.ndarray
    success: bool
    status: int
    message: str
    iterations: int
    residual: float
    R: np.ndarray
    J: object
    extra: object

    @property
    def convergence(self) -> Convergence:
        """The result as a :class:`~jointsim.results.Convergence`."""
        return Convergence(self.success, self.status, self.message, self.iterations)


def max_norm(R, extra=None) -> float:
    """``max |R|`` (0 for an empty residual)."""
    return float(np.abs(R).max(initial=0.0))


def _forcing_rtol(forcing: float, lim: float, r: float, R) -> float | None:
    """Relative 2-norm residual ``eta`` asked of an inexact step: a linear residual of
    at most ``forcing * lim`` in the measure, when the measure ``r`` is a multiple of
    ``max |R|`` (None when that cannot be said: a zero or non-finite ``R`` or ``r``, or
    no positive limit ``lim``)."""
    R = np.asarray(R)
    n2 = float(np.linalg.norm(R))
    ninf = float(np.abs(R).max(initial=0.0))
    if not (n2 > 0.0 and r > 0.0 and np.isfinite(n2) and np.isfinite(r) and lim > 0.0):
        return None
    # never looser than ``forcing`` (a start already below the tolerance, check_start off)
    return min(forcing * lim * ninf / (r * n2), forcing)


def newton(fun, x0, options: NewtonOptions, *, jacobian=None,
           solve=linear_solve,
           measure=max_norm, threshold=None) -> NewtonResult:
    """Solve ``R(x) = 0`` by damped Newton (module docstring).

    Parameters
    ----------
    fun : callable
        ``fun(x) -> (R, J, extra)``; with ``jacobian`` given,
        ``fun(x) -> (R, extra)``.
    x0 : ndarray, shape (n,)
        Start (copied).
    options : NewtonOptions
    jacobian : callable, optional
        ``jacobian(x, R, extra) -> J``, called only when a step is taken.
    solve : callable
        ``solve(J, b) -> J^-1 b``; may raise ``LinAlgError`` or ``RuntimeError``
        (singular).  Called as ``solve(J, b, rtol=eta)`` for a structured ``J``
        when ``options.forcing > 0`` (module doc).  Default:
        :func:`jointsim.solvers.jacobian.solve` (dense LU with a least-squares
        fallback, or the structured solve).
    measure : callable
        ``measure(R, extra) -> float``, the residual measure (default ``max|R|``).
    threshold : callable, optional
        ``threshold(x, extra) -> float``; converged when ``measure <= threshold``
        (default ``options.tol``).

    Returns
    -------
    NewtonResult
    """
    o = options
    tries = 1 if o.line_search == "none" else o.max_tries

    def evaluate(x):
        if jacobian is None:
            return fun(x)
        R, extra = fun(x)
        return R, None, extra

    def limit(x, extra):
        return o.tol if threshold is None else threshold(x, extra)

    def end(ok, status, message, it):
        return NewtonResult(x, ok, status, message, it, r, R, J, extra)

    x = np.array(x0, dtype=float)
    R, J, extra = evaluate(x)
    r = measure(R, extra)
    best, best_it = r, 0
    first = 0 if o.check_start else 1
    it = 0
    while True:
        if it >= first:
            if not np.isfinite(r) or not np.all(np.isfinite(x)):
                return end(False, NON_FINITE, f"non-finite residual after {it} iterations", it)
            lim = limit(x, extra)
            if r <= lim:
                return end(True, SUCCESS, f"converged in {it} iterations (residual {r:.1e})",
                           it)
            if o.stall is not None:
                if r < 0.9 * best:
                    best, best_it = r, it
                elif it - best_it >= o.stall:
                    return end(False, NOT_CONVERGED,
                               f"stalled at residual {r:.2e} after {it} iterations", it)
            if it == o.max_iter:
                return end(False, NOT_CONVERGED,
                           f"no convergence in {it} iterations (residual {r:.2e}, "
                           f"tolerance {lim:.2e})", it)
        elif it == o.max_iter:
            return end(False, NOT_CONVERGED, f"no convergence in {it} iterations", it)
        if x.size == 0:
            return end(True, SUCCESS, "no unknowns", max(it, first))
        if jacobian is not None:
            J = jacobian(x, R, extra)
        try:
            eta = _forcing_rtol(o.forcing, limit(x, extra), r, R) \
                if o.forcing > 0.0 and is_structured(J) and J.inexact_steps else None
            dx = solve(J, -R) if eta is None else solve(J, -R, rtol=eta)
        except (np.linalg.LinAlgError, RuntimeError) as exc:
            return end(False, NOT_CONVERGED,
                       f"singular Jacobian after {it} iterations ({exc})", it + 1)
        if o.finite_step and not np.all(np.isfinite(dx)):
            return end(False, NON_FINITE,
                       f"non-finite Newton step after {it} iterations (singular Jacobian?)",
                       it + 1)
        a = 1.0
        for _ in range(tries):
            x_try = x + a * dx
            R_try, J_try, e_try = evaluate(x_try)
            r_try = measure(R_try, e_try)
            if o.line_search == "decrease":
                if np.isfinite(r_try) and (r_try <= r or r_try <= limit(x_try, e_try)):
                    break
            elif o.line_search == "armijo":
                if r_try <= (1.0 - 1e-4 * a) * r:
                    break
            a *= 0.5
        x, R, J, extra, r = x_try, R_try, J_try, e_try, r_try
        it += 1
