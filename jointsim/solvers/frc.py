"""Frequency-response branches of :class:`~jointsim.solvers.hbm.HBMSystem`: the
scales of a branch's continuation, its first point, and its refined peak.

These are the pieces of an FRC around the continuation
(:func:`jointsim.solvers.continuation.continue_branch`); the harmonic balance
itself (the system, its residual and Jacobian, one point at a fixed frequency) is
:mod:`jointsim.solvers.hbm`.
"""
from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass

import numpy as np

from ..harmonics import harmonic_amplitude
from .hbm import HBMSystem, solve_point
from .jacobian import is_structured, solve
from .newton import NewtonOptions, newton

log = logging.getLogger(__name__)


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

    The scale only needs its order of magnitude, so the nonlinear solve gives
    up early where it cannot succeed (the stuck estimate is then kept, as for
    any failed solve): when its best residual has not fallen by 10 % in
    ``RESONANCE_STALL`` steps, or when an iterate lies farther than
    ``RESONANCE_BOUND`` times the stuck estimate from ``z0`` (in gross slip the
    joint's static position drifts along its nearly free slip, metres away;
    friction only damps and softens, so a converging solve stays below the
    stuck resonance).  A solve that converges is unchanged: the same
    iterations to ``tol``.

    The residual scale is the largest condensed force ``max |R(z0)|``.

    Returns
    -------
    scale : ndarray, shape (n_z + 1,)
        ``q_ref`` for every coefficient, ``|omega_end - omega_start|`` for omega.
    rscale : float
    """
    from .modes import stuck_modes
    from .preconditioner import MODAL_STAGE
    lo, hi = sorted((omega_start, omega_end))
    z0 = system.static_coordinates()
    ws = list(np.linspace(omega_start, omega_end, n))
    res = []
    # the stuck joint's modes on the contact coordinates, where the Krylov path's
    # preconditioners make them anyway: its frequencies and its stuck responses
    flex = system.lin.flexibility if system.krylov and MODAL_STAGE else None
    if system.model.n_dof:
        n_modes = min(system.model.n_dof, 40)
        if flex is not None:
            f_hz = np.sqrt(flex.lam[:n_modes]) / (2 * np.pi)
        else:
            f_hz = stuck_modes(system.model, n_modes).frequency_hz
        res = [2 * np.pi * f for f in f_hz if lo < 2 * np.pi * f < hi]
    q_off, q_res, rref, best = 0.0, 0.0, 0.0, (0.0, None, None)
    for w in ws + res:
        ev = system.evaluate(z0, w, F, wrt=())
        rref = max(rref, float(np.abs(ev.R).max(initial=0.0)))
        if not system.n_z:
            continue
        try:
            # the stuck joint couples no harmonics: only the forced ones are solved
            dz = ev.J.solve_uncoupled(-ev.R, flexibility=flex) if is_structured(ev.J) \
                else None
            dz = solve(ev.J, -ev.R) if dz is None else dz
        except (np.linalg.LinAlgError, RuntimeError):
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
        q_nl = _resonance_response(system, best[1], F, best[2], z0, rref, tol,
                                   RESONANCE_BOUND * qref)
        if q_nl is not None:
            qref = max(q_off, q_nl)
    if not qref > 0.0:
        qref = 1.0
    scale = np.full(system.n_z + 1, qref)
    scale[-1] = max(abs(omega_end - omega_start), 1e-12 * abs(omega_start), 1e-300)
    return scale, rref


#: :func:`frc_scales`: the resonance solve's linear solves (Krylov path) stop at this
#: relative residual, each with its own preconditioner (``PreconditionerCache.single_solve``,
#: as the error indicators' extended solves): a low-rank stage too large for one LU is
#: then kept whole and solved through its capacitance system
#: (``preconditioner.LOOSE_SPLIT_MIN``) instead of truncated.  The scale needs an order of
#: magnitude, and Newton still stops on the true residual at ``tol``.  None: the
#: Jacobian's own tolerance.  Measured at force scale 2 (round 35, one thread, the FRC
#: branch of ``benchmarks/scale.py``): 240 Gauss points 2.18 -> 1.34 s, 480 points 18.4
#: -> 9.8 s (its stage would have been truncated: 4,600 of about 7,400 coordinates, one
#: LU each Newton step), the same Newton iterations, ``max |z - z0|`` equal to 1e-10.
#: 1e-3 instead of 1e-6 (round 47): each solve's capacitance refinement takes about two
#: steps instead of five; at 480 points ``frc_scales`` 4.14 -> 3.51 s (force 2), 4.37 ->
#: 3.82 s (force 20, which gives up in both), the same Newton iterations, and the
#: scales equal to seven digits at 96, 120, 240 and 480 points.
RESONANCE_RTOL = 1e-3
#: :func:`frc_scales`: the resonance solve gives up when its best residual has not
#: fallen by 10 % in this many Newton steps
RESONANCE_STALL = 3
#: :func:`frc_scales`: ... or when an iterate is farther from the static state than
#: this many times the stuck response
RESONANCE_BOUND = 10.0


@contextlib.contextmanager
def loose_solves(system: HBMSystem, rtol: float | None):
    """Within: the Krylov path's linear solves stop at ``rtol`` (or the system's own
    tolerance, if looser), each with its own preconditioner
    (``PreconditionerCache.single_solve``): a low-rank stage too large for one LU is
    then solved through its capacitance system instead of truncated.  For a Newton
    solve at one frequency, which stops on its true residual.  Nothing changes for
    ``rtol = None`` or the direct path."""
    if not system.krylov or rtol is None:
        yield
        return
    cache = system.preconditioner
    saved = system.krylov_rtol, cache.single_solve
    cache.forget()
    system.krylov_rtol, cache.single_solve = max(rtol, saved[0]), True
    try:
        yield
    finally:
        system.krylov_rtol, cache.single_solve = saved
        cache.forget()


class _Implausible(Exception):
    """An iterate of the resonance solve beyond its bound (:func:`_resonance_response`)."""


def _resonance_response(system: HBMSystem, omega: float, F, z_start, z0, rscale: float,
                        tol: float, bound: float):
    """``max |z - z0|`` of the nonlinear response at ``omega`` (for :func:`frc_scales`).

    Newton from ``z_start`` to ``max|R| / rscale <= tol`` (at most 15 steps), given
    up after ``RESONANCE_STALL`` steps without progress or at an iterate with
    ``max |z - z0| > bound``.

    Returns
    -------
    float or None
        None when the solve did not converge.
    """
    def fun(z):
        if not float(np.abs(z - z0).max(initial=0.0)) <= bound:
            raise _Implausible
        ev = system.evaluate(z, omega, F, wrt=())
        return ev.R, ev.J, ev

    try:
        with loose_solves(system, RESONANCE_RTOL):
            res = newton(fun, np.asarray(z_start, dtype=float),
                         NewtonOptions(tol, 15, line_search="decrease", max_tries=6,
                                       stall=RESONANCE_STALL),
                         solve=solve,
                         measure=lambda R, _ev: np.abs(R).max(initial=0.0) / rscale)
    except _Implausible:
        log.debug("frc_scales: the resonance solve at omega = %g left %g of z0; "
                  "the stuck estimate is kept", omega, bound)
        return None
    if not res.success:
        log.debug("frc_scales: the resonance solve at omega = %g: %s; the stuck estimate "
                  "is kept", omega, res.message)
        return None
    return float(np.abs(res.x - z0).max(initial=0.0))


#: :func:`refine_peak`: Newton iterations of a solve from one start before the next
#: start is tried (from a solved neighbour a converging solve takes 1 to 6)
PEAK_MAX_ITER = 10
#: :func:`refine_peak`: a search that solved every frequency it tried and ended within
#: this relative amplitude of the largest computed point confirms that point as the
#: peak (refined); "strictly above" let round-off decide (a 121-pair branch flipped
#: between runs with the same frequency, amplitude and solves)
PEAK_SAME_RTOL = 1e-9
#: :func:`refine_peak`: Brent's relative tolerance on the peak frequency.  The
#: amplitude of a branch that slips is a kinked function of the frequency at the
#: scale of the AFT samples (jagged by about 1e-4 of the peak, docstring), so the
#: search approaches a kink by golden sections: 1e-10 took its 25 iterations on every
#: branch of the lap joint (28 solves), for amplitude changes below 1e-9 after the
#: 16th.  At 1e-7 the amplitude moves by 1.9e-8 (the 2-DOF chain's slipping peak),
#: 5.7e-7 and 1.6e-6 (the peaks of the lumped fold scenes, steep kinks), against a
#: jaggedness of 1e-4; a smooth peak's by about (1e-7 / zeta)^2, zeta the damping ratio.
PEAK_XTOL = 1e-7


def refine_peak(system: HBMSystem, F, omega, Z, amplitude, dof: int, tol: float,
                amplitude_of=None):
    """Refine the largest amplitude of a branch by maximising over frequency.

    ``amplitude_of(X) -> float`` is the measure maximised (default: the
    fundamental amplitude at ``dof``; ``amplitude`` must use the same one).

    Only where the branch is single-valued around its largest point (the
    frequency increases through it); at a fold the largest computed point is
    returned unrefined.  Brent's search from the bracket of the largest point
    and its two neighbours (re-solved to ``tol``; to :data:`PEAK_XTOL` of the
    frequency, 25 iterations at most; the bounded search between the neighbours when the
    re-solved amplitudes no longer bracket a maximum).  Each frequency is solved
    by Newton (:func:`solve_point`, to ``tol``) from the solved points next to
    it: interpolated between the nearest solved frequency on either side, then
    from each of those two alone (at most :data:`PEAK_MAX_ITER` iterations each;
    near a peak where elements begin to slip or separate, Newton from the wrong
    side of that kink cycles).  A frequency where every start fails counts as
    amplitude 0, below every solution (logged), so it is never returned.

    Where elements begin to slip or separate, and in gross slip, the amplitude
    is not smooth near the peak: it is jagged on the scale of the AFT samples
    (measured on the lap joints: by 1e-4 of the peak at the stuck branches'
    peaks, 1e-3 in gross slip), and the search finds one of its local maxima.

    Returns
    -------
    omega_peak, amplitude_peak : float
    refined : bool
        The search ended above the largest computed point, or at it to
        :data:`PEAK_SAME_RTOL` with every frequency solved (then that point is
        returned); False at a fold, when it ended lower, or when solves failed.
    stats : dict
        ``solves`` (Newton solves, failed starts included), ``iterations``
        (Newton iterations summed), ``failed`` (frequencies where every start
        failed).
    """
    from scipy.optimize import minimize_scalar
    stats = {"solves": 0, "iterations": 0, "failed": 0}
    i = int(np.argmax(amplitude))
    n = len(omega)
    if i == 0 or i == n - 1 or not (omega[i - 1] < omega[i] < omega[i + 1]):
        return float(omega[i]), float(amplitude[i]), False, stats
    solved = {float(omega[j]): np.asarray(Z[j], dtype=float) for j in (i - 1, i, i + 1)}

    def starts(w):
        """Starts for a solve at ``w``: interpolated, then the neighbours alone (a
        solved ``w``, re-solved to ``tol``, starts from itself first)."""
        ws = np.array(sorted(solved))
        k = int(np.searchsorted(ws, w))
        sides = [ws[j] for j in (k - 1, k) if 0 <= j < ws.size]
        sides.sort(key=lambda v: abs(v - w))
        if len(sides) == 2 and w not in solved:
            lo, hi = sorted(sides)
            t = (w - lo) / (hi - lo)
            yield (1.0 - t) * solved[lo] + t * solved[hi]
        for v in sides:
            yield solved[v]

    def neg_amp(w):
        for z0 in starts(w):
            sol = solve_point(system, w, F, z0=z0, tol=tol, max_iter=PEAK_MAX_ITER)
            stats["solves"] += 1
            stats["iterations"] += sol.convergence.iterations
            if sol.convergence.success:
                solved[float(w)] = sol.z
                if amplitude_of is not None:
                    return -float(amplitude_of(sol.X))
                return -float(harmonic_amplitude(system.basis, sol.X[:, dof]))
        stats["failed"] += 1
        log.debug("refine_peak: Newton failed at omega = %.10g from every start (%s); "
                  "taken as amplitude 0", w, sol.convergence.message)
        return 0.0

    lo, hi = float(omega[i - 1]), float(omega[i + 1])
    try:
        res = minimize_scalar(neg_amp, bracket=(lo, float(omega[i]), hi), method="brent",
                              options={"xtol": PEAK_XTOL, "maxiter": 25})
    except ValueError:      # the re-solved amplitudes do not bracket a maximum
        res = minimize_scalar(neg_amp, bounds=(lo, hi), method="bounded",
                              options={"xatol": PEAK_XTOL * max(abs(hi), 1.0), "maxiter": 25})
    a = -float(res.fun)
    if a > amplitude[i]:            # above the largest computed point
        return float(res.x), a, True, stats
    # the largest point itself, confirmed to round-off by a search that solved every
    # frequency it tried; else (below it, or failed frequencies) not refined
    confirmed = stats["failed"] == 0 and a >= amplitude[i] * (1.0 - PEAK_SAME_RTOL)
    return float(omega[i]), float(amplitude[i]), confirmed, stats


# --------------------------------------------------------------------------
# The first point of a branch
# --------------------------------------------------------------------------
@dataclass
class FirstPoint:
    """The first point of an FRC branch (:func:`first_point`).

    Attributes
    ----------
    z : ndarray, shape (n_z,)
        Contact-coordinate coefficients [m] (the start when it failed).
    iterations : int
        Newton iterations of the direct solve plus the homotopy's points.
    how : str
        ``"newton"`` (one Newton solve from the static state) or
        ``"force homotopy"`` (continued in the force scale from 0).
    convergence : jointsim.results.Convergence
    """

    z: np.ndarray
    iterations: int
    how: str
    convergence: object


def first_point(system: HBMSystem, omega: float, force_scale: float, *, scale, rscale: float,
                tol: float, max_iter: int = 20, step_min: float = 1e-8,
                max_points: int = 400, desc: str = "hbm") -> FirstPoint:
    """Solve the first point of an FRC branch robustly.

    First one Newton solve at ``omega`` from the static state ``z0`` (the
    first step is the stuck linear response), as before.  When it fails (a
    strongly nonlinear start: slip or separation at the first frequency, where
    Newton from the stuck response cycles across the kinks of the AFT
    residual), the point is reached by a homotopy in the force: the harmonic
    force scale ``s`` is continued from 0, where the static state is the exact
    solution, to ``force_scale`` at fixed ``omega``
    (:func:`~jointsim.solvers.continuation.continue_branch` in ``s``, so folds
    of the response in the force are passed too).  The residual is affine in
    ``s`` (the static loads are not scaled), ``dR/ds = R(z, F(1)) - R(z, F(0))``,
    the same vector at every ``z``.

    Parameters
    ----------
    system : HBMSystem
    omega : float
        Frequency of the first point [rad/s].
    force_scale : float
        Multiplier of the harmonic loads of the branch.
    scale : ndarray, shape (n_z + 1,)
        Variable scales of the branch (:func:`frc_scales`); its ``z`` part is used.
    rscale : float
        Residual scale of the branch.
    tol, max_iter
        Newton tolerance (on ``max|R| / rscale``) and iterations per solve.
    step_min, max_points
        Smallest scaled step and most points of the homotopy.

    Returns
    -------
    FirstPoint
    """
    from ..results import NOT_CONVERGED, SUCCESS, Convergence
    z0 = system.static_coordinates()
    F1 = system.force_coefficients(force_scale)
    opts = NewtonOptions(tol, max_iter, line_search="none")

    def at_fixed(F):
        def fun(z):
            ev = system.evaluate(z, omega, F, wrt=())
            return ev.R, ev.J, ev
        return fun

    def measure(R, _ev):
        return np.abs(R).max(initial=0.0) / rscale

    res = newton(at_fixed(F1), z0, opts, solve=solve, measure=measure)
    if res.success:
        return FirstPoint(res.x, res.iterations, "newton",
                          Convergence(True, SUCCESS, f"Newton converged in {res.iterations} "
                                                     "iterations", res.iterations))
    direct = res.iterations
    log.info("%s: the first point (omega = %g) did not converge in %d Newton iterations "
             "from the static state; continuing in the force scale from 0", desc, omega,
             max_iter)
    br = force_homotopy(system, omega, force_scale, scale=scale, rscale=rscale, tol=tol,
                        max_iter=max_iter, step_min=step_min, max_points=max_points,
                        desc=f"{desc} first point: force homotopy")
    y = br.y[-1]
    it = direct + len(br.y)
    reached = br.convergence.success and \
        abs(y[-1] - force_scale) <= 1e-12 * max(abs(force_scale), 1e-300)
    if br.convergence.success and not reached:   # closed past the end: correct at s exactly
        r2 = newton(at_fixed(F1), y[:-1], opts, solve=solve, measure=measure)
        reached, y, it = r2.success, np.append(r2.x, force_scale), it + r2.iterations
    if reached:
        msg = (f"reached by a force homotopy from 0 in {len(br.y)} points (Newton from "
               f"the static state did not converge in {max_iter} iterations)")
        log.info("%s: first point %s", desc, msg)
        return FirstPoint(y[:-1], it, "force homotopy", Convergence(True, SUCCESS, msg, it))
    msg = (f"the first point (omega = {omega:g}) did not converge: Newton from the static "
           f"state failed in {max_iter} iterations and the force homotopy stopped at "
           f"{y[-1] / force_scale:.3g} of the force ({br.convergence.message})")
    return FirstPoint(z0, it, "force homotopy", Convergence(False, NOT_CONVERGED, msg, it))


def force_homotopy(system: HBMSystem, omega: float, force_scale: float, *, scale,
                   rscale: float, tol: float, max_iter: int = 20, step_min: float = 1e-8,
                   max_points: int = 400, desc: str = "hbm force homotopy"):
    """Continue the harmonic balance at fixed ``omega`` in the force scale, 0 to ``force_scale``.

    At ``s = 0`` the static state is the exact solution.  The residual is
    affine in ``s`` (the static loads are not scaled), so
    ``dR/ds = R(z, F(1)) - R(z, F(0))`` is one vector for every ``z``.

    Parameters
    ----------
    system : HBMSystem
    omega : float
        Frequency [rad/s].
    force_scale : float
        End of the homotopy (multiplier of the harmonic loads).
    scale : ndarray, shape (n_z + 1,)
        Variable scales; the ``z`` part is used, the last entry is replaced by
        ``|force_scale|``.
    rscale, tol, max_iter, step_min, max_points, desc
        As for :func:`~jointsim.solvers.continuation.continue_branch`.

    Returns
    -------
    jointsim.solvers.continuation.Branch
        ``y[:, -1]`` is the force scale; it ends at ``force_scale`` on success.
    """
    from .continuation import continue_branch
    nz = system.n_z
    z0 = system.static_coordinates()
    F0 = system.force_coefficients(0.0)
    Fd = system.force_coefficients(1.0) - F0
    g = system.evaluate(z0, omega, F0 + Fd, jacobian=False).R \
        - system.evaluate(z0, omega, F0, jacobian=False).R   # dR/ds, the same at every z

    def fun(y):
        F = F0 + y[-1] * Fd
        if system.krylov:
            from .jacobian import BorderedJacobian
            ev = system.evaluate(y[:-1], omega, F, wrt=())
            return ev.R, BorderedJacobian(ev.J, g), ev
        J = np.zeros((nz, nz + 1))
        ev = system.evaluate(y[:-1], omega, F, wrt=(), J_out=J[:, :nz])
        J[:, nz] = g
        return ev.R, J, ev

    sc = np.asarray(scale, dtype=float).copy()
    sc[-1] = max(abs(force_scale), 1e-300)
    return continue_branch(fun, np.append(z0, 0.0), force_scale, scale=sc, rscale=rscale,
                           step=0.05, step_min=step_min, step_max=0.25,
                           max_points=max_points, tol=tol, max_iter=max_iter,
                           progress=False, desc=desc, adapt_scale=True, z_origin=z0)
