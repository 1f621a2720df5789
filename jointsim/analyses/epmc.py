"""Runner of ``[analysis.epmc]``: the EPMC backbone of one mode, written point by point.

The formulation is in :mod:`jointsim.solvers.epmc`.  Datasets (per point):
``/epmc/amplitude`` (modal amplitude ``a``), ``/epmc/frequency_hz``,
``/epmc/omega``, ``/epmc/damping_ratio`` (``xi / (2 omega)``), ``/epmc/xi``,
``/epmc/X`` [n_points, n_coeff, n_dof] (coefficients of ``x``, not
normalised), ``/epmc/iterations``, ``/epmc/residual``, ``/epmc/step``,
``/epmc/y`` and ``/epmc/tangent`` (for ``--resume``), ``/epmc/outside_range``
(the point's damping ratio is above :data:`MAX_DAMPING_RATIO`), the error
indicators ``/epmc/error_*`` (:mod:`jointsim.solvers.indicators`; computed beside the
continuation on ``analysis.epmc.workers`` forked workers, :mod:`.indicator_pool`: a
point's rows are NaN until they come back, and ``--resume`` computes rows left NaN); once:
``/epmc/harmonics``, ``/epmc/mode_shape``.  Loops and Masing checks go to
``/epmc/loops`` and ``/epmc/masing``.

The branch is continued in two legs when it starts on the stuck (linear) piece:
up to the stuck onset exactly, then on (:func:`stuck_onset`, :func:`_continue`);
the attribute ``log10_stuck_onset`` holds it (NaN: none).

With ``analysis.epmc.amplitudes`` or ``loop_amplitudes`` the mode is also solved
exactly at those modal amplitudes (:func:`exact_amplitudes`,
:func:`~jointsim.analyses.epmc_exact.solve_at_amplitudes`), in ``/epmc/at_amplitudes/``:
``amplitude``, ``omega``, ``frequency_hz``, ``damping_ratio``, ``xi``, ``X``,
``converged``, ``iterations``, ``residual``; at the ``loop_amplitudes`` also the
element loops and Masing checks of those solutions (``loops/``, ``masing/``).
"""
from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from ..io.hbm_points import write_error_indicators
from ..io.hdf5 import unit
from ..io.loops import write_loops
from ..masing import check_loops
from ..results import SUCCESS, Convergence
from ..solvers.branch_record import Branch, PointInfo
from ..solvers.continuation import TARGET_ITER, continue_branch, next_step
from ..solvers.epmc import EPMCSystem
from ..solvers.condensation import dense_array
from ..solvers.hbm import HBMSystem
from ..solvers.indicators import ErrorEstimator, ToleranceWatch, safe_indicators
from ..solvers.modes import elastic_mode
from .epmc_exact import exact_amplitudes, solve_at_amplitudes

log = logging.getLogger(__name__)

#: Largest damping ratio ``xi / (2 omega)`` at which an EPMC point is taken as within
#: the method's range.  EPMC replaces the dissipation by a mass-proportional
#: self-excitation ``xi M``; the mode it computes is the mode of the damped system only
#: when that term is a small perturbation (light damping, Krack 2015).  Past this
#: limit the frequency and damping are still the EPMC solution, but they no longer
#: describe the free decay of the structure (the free decay of a SDOF Jenkins
#: oscillator at damping ratio 2.8 is not periodic at all).  Points above it are
#: flagged in ``/epmc/outside_range`` and counted in the attribute
#: ``n_outside_range``, with a warning.
MAX_DAMPING_RATIO = 0.1
#: The backbone stops, saying why, when its last ``STALL_POINTS`` points advanced
#: log10 a by less than ``STALL_SHARE`` of the range (a drift at nearly fixed
#: amplitude: :func:`jointsim.solvers.branch_watch.stall_message`).
STALL_POINTS = 20
STALL_SHARE = 1e-4


class _LoopSelection:
    """Which EPMC points keep their element loops.

    With target amplitudes, the first point at or past each target (in the
    direction of the continuation); otherwise the indices of
    ``analysis.masing.points`` (every point when empty).  On resume, targets
    already passed by the stored points are done.
    """

    def __init__(self, amplitudes, points, lam0, lam1, stored):
        self.up = lam1 >= lam0
        targets = sorted(amplitudes, reverse=not self.up)
        if stored.size:
            reached = stored.max() if self.up else stored.min()
            targets = [t for t in targets if (t > reached if self.up else t < reached)]
        self.targets = targets
        self.by_amplitude = bool(amplitudes)
        self.points = set(points)

    def __call__(self, p: int, amp: float) -> bool:
        if not self.by_amplitude:
            return not self.points or p in self.points
        hit = False
        while self.targets and (amp >= self.targets[0] if self.up else amp <= self.targets[0]):
            self.targets.pop(0)
            hit = True
        return hit


def run_epmc_analysis(scene, model, writer, results=None) -> None:
    """Runner of ``[analysis.epmc]``: the backbone of one mode, written point by point.

    The runner contract (arguments, ``results``) is in :mod:`jointsim.analyses`.

    Raises
    ------
    RuntimeError
        After writing what was computed, when the branch gave up.
    """
    t_start = time.perf_counter()
    a = scene.analysis.epmc
    system = HBMSystem(model, a.harmonics, a.n_samples, a.min_periods, a.max_periods,
                        linear_solver=a.linear_solver)
    em = elastic_mode(model, a.mode, a.rigid_cutoff_hz)
    F = system.force_coefficients(0.0)
    ep = EPMCSystem(system, em.phi, F)
    xi0 = float(em.phi @ dense_array(model.C) @ em.phi)
    g = _write_header(writer, a, model, em, xi0)
    with _indicators(writer, a, system, ep, em.omega, xi0) as inds:
        _run(writer, scene, model, a, system, ep, em, F, xi0, g, inds, t_start)


def _indicators(writer, a, system, ep, omega0, xi0):
    """The error indicators of the branch's points (:mod:`.indicator_pool`): on
    ``analysis.epmc.workers`` forked workers, or serially; stored rows left NaN
    (a run killed or a worker lost before they were computed) are computed first.
    ``omega0`` [rad/s] and ``xi0`` [1/s]: the linear mode's, for which the workers'
    shared pieces are made (:meth:`~jointsim.solvers.hbm.HBMSystem.prepare_forks`)."""
    from ..io.hbm_points import missing_error_indicators, pad_error_indicators
    from .indicator_pool import PointIndicators, pool_workers

    if not a.error_indicators:
        return PointIndicators(writer, "epmc", None, None, 1)
    missing = missing_error_indicators(writer.h5, "epmc") if writer.rows("epmc/y") \
        else np.zeros(0, dtype=np.int64)
    done = writer.h5["epmc"].attrs.get("branch_status", "") in ("complete", "gave up")
    n = pool_workers(a.workers, len(missing) if done else None, system.n_z) \
        if system.n_z else 1
    # the workers never start numba threads (a forked process must not): parallel=False
    estimator = ErrorEstimator(system, parallel=n == 1)
    if n > 1:       # shared by the workers: the extended system's first, which serve both
        for s in (estimator, system):
            s.prepare_forks(omega0, xi0)
    steps = a.error_newton_steps
    inds = PointIndicators(writer, "epmc",
                           lambda y: safe_indicators(estimator.epmc, ep, y, steps),
                           ToleranceWatch(a.error_tol, "epmc"), n)
    writer.h5["epmc"].attrs["indicator_workers"] = n
    if missing.size:
        log.info("epmc: computing the error indicators of %d stored point(s)", missing.size)
        with writer.commit():   # rows of a file from before the indicators: NaN first
            pad_error_indicators(writer, "epmc")
        amps = writer.h5["epmc/amplitude"][()]
        for p in missing:
            inds.submit(int(p), (writer.h5["epmc/y"][int(p)],),
                        f"modal amplitude {amps[p]:.3g}")
    return inds


def _run(writer, scene, model, a, system, ep, em, F, xi0, g, inds, t_start) -> None:
    """The branch (:func:`run_epmc_analysis`), its indicators on ``inds``."""
    if g.attrs.get("branch_status", "") in ("complete", "gave up"):
        inds.finish()
        log.info("epmc already %s; skipped", g.attrs["branch_status"])
        return
    y0, t0, h0, solve_first, max_pts = _start(writer, a, system, em, xi0)
    # scales from the linear mode, resumed or not: a resumed branch takes the same steps
    scale, rscale = _scales(ep, _linear_start(a, system, em, xi0), em.omega)
    system.stats.take()
    writer.h5["epmc"].attrs["linear_solver"] = system.linear_solver
    writer.h5["epmc"].attrs["n_unknowns"] = system.n_z
    on_point = _point_writer(writer, scene, model, system, ep, F, solve_first, inds)
    if system.n_z == 0:
        br = _linear_branch(a, ep, em, xi0, on_point, writer.rows("epmc/omega"))
    else:
        onset = stuck_onset(ep, _linear_start(a, system, em, xi0), a.log10_amplitude_start,
                            a.log10_amplitude_end, rscale, a.tol)
        g.attrs["log10_stuck_onset"] = np.nan if onset is None else onset
        br = _continue(a, ep, y0, t0, h0, solve_first, max_pts, scale, rscale, on_point,
                       onset, system.n_z, xi0 / (2.0 * em.omega))
    inds.finish()   # every point's indicators in the file before the branch is marked
    conv = br.convergence
    if not conv.success:
        conv = _explain(conv, model, system, ep, writer, scale)
    if not conv.success and system.n_z and len(br.y):
        cause = stick_resolution(system, ep, br.y[-1], model.contacts.law)
        if cause:
            conv = dataclasses.replace(conv, message=f"{conv.message}; {cause}")
    _report_range(writer)
    writer.group("epmc", time_s=g.attrs.get("time_s", 0.0) + time.perf_counter() - t_start,
                 n_points=writer.rows("epmc/omega"),
                 branch_status="complete" if conv.success else "gave up", **conv.as_attrs())
    log.info("epmc mode %d: %s", a.mode, conv.message)
    exact = exact_amplitudes(a)
    if exact:
        solve_at_amplitudes(writer, a, system, ep, F, scale, rscale, exact,
                            loops=(model.contacts.law, scene.analysis.masing.tol))
    from .study import write_control   # the study's third column (issue 14)
    for group in ("epmc", "epmc/at_amplitudes"):   # the branch's loop sets and the exact ones
        write_control(writer, group, model.contacts.law, scene.analysis.masing.tol, model.units)
    if not conv.success:
        raise RuntimeError(f"epmc: {conv.message}")


#: Stuck onset (:func:`stuck_onset`): scan step [log10 a] and bisection width.
ONSET_SCAN = 0.05
ONSET_WIDTH = 1e-6
#: Stuck onset: the linear mode has stopped solving the equations once its residual
#: moved by this multiple of the Newton tolerance (relative to the residual scale).
#: Not much less: on the stuck piece ``R / a`` still drifts with the static residual
#: ``R(z0) / a`` (the coupled lap joint at H = 0..15, Nt = 512: by 4.8e-12 over
#: log10 a = -5 .. -4.155, against a jump of 7.6e-5 within 0.005 past the onset), and
#: 0.01 tol = 1e-12 put the onset at -4.91 instead of -4.154.
ONSET_TOL = 1.0


def stuck_onset(ep, y_lin, lam_start: float, lam_end: float, rscale: float, tol: float):
    """``log10 a`` at which the stuck (linear) piece of the backbone ends, or None.

    While every contact stays stuck (and no gap opens or closes) the mode is the
    linear one: in the amplitude-normalised unknowns the branch is the straight
    line ``y(lam) = (zh_lin, omega_0, xi_0, lam)``, along which the residual
    ``R / a`` does not change (``R`` is linear in ``z - z0``; up to the drift of the
    static residual ``R(z0) / a``, see :data:`ONSET_TOL`).  The first contact
    event (an element that starts to slip, a gap that opens or closes) makes it
    change: the backbone has a corner there.  Left to itself the continuation
    grows its step to ``step_max`` on the straight piece (one Newton iteration per
    point) and jumps the corner, landing on the nonlinear piece with the piece
    between the corner and the landing point untraced; a corner remedy can then
    send it back down that piece, which no retrace check sees (the coupled lap
    joint at H = 0..15, Nt = 512: a step of 0.2 from log10 a = -4.25 to -4.05 over
    the onset at -4.154; the branch ran back to the onset and down the stuck
    piece, and gave up).  The runner therefore ends the first continuation
    exactly at the onset (:func:`_continue`).

    The onset is the first ``lam`` (scanned from ``lam_start`` towards ``lam_end``
    every :data:`ONSET_SCAN`, then bisected to :data:`ONSET_WIDTH`) at which
    ``max|R(y(lam)) / a - R(y(lam_start)) / a| / rscale`` exceeds
    ``ONSET_TOL * tol``.

    Parameters
    ----------
    ep : jointsim.solvers.epmc.EPMCSystem
    y_lin : ndarray, shape (n_z + 3,)
        The linear mode's point (:func:`_linear_start`; its ``lam`` is replaced).
    lam_start, lam_end : float
        The scene's range of ``log10 a``.
    rscale : float
        Residual scale of the continuation.
    tol : float
        Newton tolerance (on ``max|R| / rscale``).

    Returns
    -------
    float or None
        The last ``lam`` (to :data:`ONSET_WIDTH`) at which the linear mode still
        solves the equations to the tolerance: at or a little past the first
        contact event (on the SDOF Jenkins oracle 7e-7 past it); None when the mode
        is not linear at the start (or the onset lies within :data:`ONSET_SCAN` of
        it), stays linear over the whole range, or its residual is not finite.
    """
    y = np.array(y_lin, dtype=float)

    def residual(lam):
        y[-1] = lam
        return ep.residual(y)   # the amplitude and phase rows do not change with lam

    R0 = residual(lam_start)
    if not np.all(np.isfinite(R0)):
        return None
    thr = ONSET_TOL * tol

    def moved(lam) -> bool:
        d = float(np.abs(residual(lam) - R0).max(initial=0.0)) / rscale
        return not d <= thr   # NaN counts as moved

    sign = 1.0 if lam_end >= lam_start else -1.0
    span = abs(lam_end - lam_start)
    lo = hi = lam_start
    for k in range(1, int(np.ceil(span / ONSET_SCAN)) + 1):
        hi = lam_start + sign * min(k * ONSET_SCAN, span)
        if moved(hi):
            break
        lo = hi
    else:
        return None   # linear over the whole range
    if lo == lam_start:
        return None   # not linear at the start, or the onset is within one scan step
    while abs(hi - lo) > ONSET_WIDTH:
        mid = 0.5 * (lo + hi)
        if moved(mid):
            hi = mid
        else:
            lo = mid
    return float(lo)


def _continue(a, ep, y0, t0, h0, solve_first, max_pts, scale, rscale, on_point, onset, nz,
              zeta0):
    """The continuation of the backbone from ``y0``; in two legs when it starts on the
    stuck piece: up to the stuck onset exactly (:func:`stuck_onset`; the stepper's
    end-of-range rule closes the leg there by a Newton solve at that ``lam``), then
    from there to the end of the range, with first step ``analysis.epmc.step`` (as at
    the start of a branch).  A resumed branch goes on in the leg its last point is in.

    Returns
    -------
    Branch
        The last leg's branch; its ``convergence`` says how the whole branch ended
        (``iterations``: the points of both legs).
    """
    lam_start, lam_end = a.log10_amplitude_start, a.log10_amplitude_end
    direction = 1.0 if lam_end >= lam_start else -1.0
    common = dict(scale=scale, rscale=rscale, step_min=a.step_min, step_max=a.step_max,
                  tol=a.tol, max_iter=a.max_iter, desc=f"epmc mode {a.mode}",
                  monitor=step_monitor(a, nz, zeta0), lam_start=lam_start,
                  lam_stall=(STALL_POINTS, STALL_SHARE))
    n_before = 0
    if onset is not None:
        ahead = (onset - float(y0[-1])) * direction
        if ahead > 1e-12:
            leg = continue_branch(ep.fun, y0, onset, step=h0, max_points=max_pts,
                                  solve_first=solve_first, tangent0=t0, on_point=on_point,
                                  **common)
            if not leg.convergence.success:
                return leg
            n_before = len(leg.y) - 1
            max_pts -= n_before
            y0, t0, h0, solve_first = leg.y[-1], leg.tangents[-1], a.step, False
            log.info("epmc mode %d: the stuck piece ends at log10 a = %.6f; continued "
                     "from there", a.mode, onset)
        elif abs(ahead) <= 1e-12 and not solve_first:
            h0 = a.step   # resumed at the onset point: the second leg's first step
    offset = n_before

    def on_leg(i, y, info):
        if offset and i == 0:
            return   # the onset point, written by the first leg
        on_point(i + offset, y, info)

    br = continue_branch(ep.fun, y0, lam_end, step=h0, max_points=max_pts,
                         solve_first=solve_first, tangent0=t0, on_point=on_leg, **common)
    if n_before:
        conv = br.convergence
        br = dataclasses.replace(br, convergence=dataclasses.replace(
            conv, iterations=conv.iterations + n_before,
            message=f"{conv.message} in its second leg, continued from the stuck onset at "
                    f"log10 a = {onset:.6f} (point {n_before + 1}); {n_before + len(br.y)} "
                    "points in all"))
    return br


#: Points per decade of amplitude of the branch of a joint without contact unknowns.
LINEAR_POINTS_PER_DECADE = 4


def _linear_branch(a, ep, em, xi0, on_point, done: int):
    """The branch of a joint without contact unknowns (fixed N, no friction): the
    linear mode at every amplitude, written point by point from point ``done`` on."""
    lo, hi = a.log10_amplitude_start, a.log10_amplitude_end
    n = max(2, int(np.ceil(abs(hi - lo) * LINEAR_POINTS_PER_DECADE)) + 1)
    lams = np.linspace(lo, hi, n)
    tangent = np.array([0.0, 0.0, 1.0 if hi >= lo else -1.0])
    for i in range(done, n):
        y = ep.linear_point(float(lams[i]), em.omega, xi0)
        info = PointInfo(iterations=0, residual=0.0,
                         step=0.0 if i == 0 else float(abs(lams[i] - lams[i - 1])),
                         tangent=tangent)
        on_point(i, y, info)
    message = (f"no contact unknowns (fixed normal load, no friction): the joint is linear "
               f"and its nonlinear mode is the linear mode; {n} points")
    log.info("epmc mode %d: %s", a.mode, message)
    return Branch(y=np.array([ep.linear_point(float(x), em.omega, xi0) for x in lams]),
                  iterations=np.zeros(n, dtype=np.int64), residual=np.zeros(n),
                  step=np.zeros(n), convergence=Convergence(True, SUCCESS, message, n))


#: Samples per period below which the two stick phases of a slipping element count as
#: unresolved by the AFT sampling (eight per stick phase).  Measured on the coarse FE
#: lap joint with fixed N: at the scene's kt the slipping elements stick for 35 or more
#: of 128 samples at the onset of macroslip and the branch passes; at kt x 1e4 they
#: stick for 6..12 and every corrector past a step of about 0.006 stalls.
MIN_STICK_SAMPLES = 16


def stick_resolution(system, ep, y, law) -> str:
    """Why a branch may have given up with stiff contacts: unresolved stick phases.

    With a contact stiffness that is high against the vibration amplitude, an
    element that slips sticks after each reversal only for a slip of
    ``2 mu N / (kt A)``, which can be shorter than one AFT time sample; the
    stick-slip switches then fall inside a sample, the residual is hardly
    smooth and Newton stalls.  At the point ``y`` this counts the elements
    that slip during part of the period and stick for fewer than
    :data:`MIN_STICK_SAMPLES` of the ``n_samples`` samples (a sample is
    slipping where ``|f| >= mu N (1 - 1e-6)``).

    Parameters
    ----------
    system : jointsim.solvers.hbm.HBMSystem
    ep : jointsim.solvers.epmc.EPMCSystem
    y : ndarray, shape (n_z + 3,)
        A point of the branch (unscaled).
    law : contact law with a friction coefficient ``mu`` (n_e,); other laws
        give an empty answer.

    Returns
    -------
    str
        The cause, naming what the user can change; empty when no slipping
        element is under-resolved (or the point cannot be evaluated).
    """
    mu = getattr(law, "mu", None)
    if mu is None:
        return ""
    _R, _J, ev = ep.fun(np.asarray(y, dtype=float))
    if ev is None or ev.aft is None:
        return ""
    f, N = np.abs(ev.aft.f), ev.aft.N
    nt = f.shape[1]
    limit = np.broadcast_to(np.asarray(mu, dtype=float), (f.shape[0],))[:, None] * N
    slipping = (N > 0.0) & (f >= limit * (1.0 - 1e-6))
    n_slip = slipping.sum(axis=1)
    bad = (n_slip > 0) & (nt - n_slip < MIN_STICK_SAMPLES)
    if not bad.any():
        return ""
    return (f"{int(bad.sum())} of {f.shape[0]} contact elements stick for fewer than "
            f"{MIN_STICK_SAMPLES} of the {nt} samples per period while slipping in the "
            f"rest: the contact stiffness is too high for the time sampling (the "
            f"stick-slip switches fall inside a sample and Newton stalls on them); raise "
            f"analysis.epmc.n_samples or lower joint.kt")


def _report_range(writer) -> int:
    """Count, store and warn about the points outside EPMC's light-damping range.

    Writes the attributes ``n_outside_range`` and ``max_damping_ratio_valid``
    (:data:`MAX_DAMPING_RATIO`) of ``/epmc`` and logs a warning naming the first
    such amplitude and the largest damping ratio.

    Returns
    -------
    int
        Points whose damping ratio is above the limit.
    """
    g = writer.h5["epmc"]
    g.attrs["max_damping_ratio_valid"] = MAX_DAMPING_RATIO
    if "outside_range" not in g:
        g.attrs["n_outside_range"] = 0
        return 0
    out = np.asarray(g["outside_range"][()], dtype=bool)
    n = int(out.sum())
    g.attrs["n_outside_range"] = n
    if n:
        amp = g["amplitude"][()]
        zeta = np.abs(g["damping_ratio"][()])
        log.warning("epmc: %d of %d points are outside the method's light-damping range "
                    "(damping ratio above %g, from modal amplitude %.3g on; largest %.3g): "
                    "there the extended periodic motion concept no longer describes the "
                    "free decay; check with time marching (analysis.transient, free decay)",
                    n, out.size, MAX_DAMPING_RATIO, float(amp[out][0]), float(zeta.max()))
    return n


def _write_header(writer, a, model, em, xi0):
    """The ``/epmc`` group, its attributes and the datasets written once."""
    units = model.units
    w0 = em.omega
    g = writer.group("epmc", mode=a.mode, linear_frequency_hz=w0 / (2 * np.pi),
                     linear_damping_ratio=xi0 / (2 * w0), n_samples=a.n_samples,
                     mode_index=em.index, n_rigid_below=em.n_rigid, error_tol=a.error_tol,
                     amplitude_definition="modal amplitude of the fundamental harmonic, "
                     "|phi^T M (X_1c - i X_1s)|, phi the mass-normalised mode of the "
                     "structure linearised at its static state with the joint stuck")
    if "epmc/harmonics" not in writer.h5:
        writer.write("epmc/harmonics", np.array(a.harmonics, dtype=np.int64), "1",
                     "harmonics kept; coefficient order [0, 1c, 1s, ...]")
        writer.write("epmc/mode_shape", em.phi, "1/sqrt(kg)" if units == "SI" else "1",
                     "mass-normalised stuck mode at the static state (phi^T M phi = 1)")
    if "contacts/area" not in writer.h5 and model.contacts.n_elements:
        writer.write("contacts/area", model.contacts.area, "m^2" if units == "SI" else "length^2",
                     "contact area of each element")
    return g


def _start(writer, a, system, em, xi0):
    """Start of the continuation: the linear mode, or the last stored point on resume.

    Returns
    -------
    y0, tangent0, step, solve_first, max_points
    """
    if writer.rows("epmc/y"):
        ys = writer.h5["epmc/y"]
        y0 = ys[-1]
        t0 = writer.h5["epmc/tangent"][-1]
        # the step the uninterrupted branch takes next (after the first point: a.step),
        # with the monitored change of its last step, as the stepper computes it
        h_last = float(writer.h5["epmc/step"][-1])
        monitor = step_monitor(a, system.n_z, xi0 / (2.0 * em.omega))
        change = 0.0
        if monitor is not None and ys.shape[0] > 1:
            d = np.abs(np.asarray(monitor(ys[-1])) - np.asarray(monitor(ys[-2])))
            change = float(d.max(initial=0.0)) if np.all(np.isfinite(d)) else 0.0
        h0 = next_step(h_last, int(writer.h5["epmc/iterations"][-1]), TARGET_ITER,
                       a.step_min, a.step_max, change) if h_last > 0 else a.step
        return y0, t0, h0, False, a.max_points - writer.rows("epmc/y") + 1
    return _linear_start(a, system, em, xi0), None, a.step, True, a.max_points


def _linear_start(a, system, em, xi0):
    """The first point of the backbone: the linear mode at the start amplitude."""
    Q = np.zeros((system.n_c, system.n_r))
    ic, _ = system.basis.index[1]
    Q[ic] = system.T @ em.phi
    return np.concatenate([Q.ravel(), [em.omega, xi0, a.log10_amplitude_start]])


def _scales(ep, y0, w0):
    """Variable scales (shape coefficients, omega, xi, log10 a) and the residual scale."""
    nz = ep.s.n_z
    zscale = max(float(np.abs(y0[:nz]).max(initial=0.0)), 1e-300) if nz else 1.0
    scale = np.concatenate([np.full(nz, zscale), [w0, w0, 1.0]])
    R0, J0, _ = ep.fun(y0)
    jmax = J0.J.max_abs() if hasattr(J0, "J") else float(np.abs(J0[:nz, :nz]).max(initial=0.0))
    rscale = max(jmax * zscale, 1e-300) if nz else 1.0
    return scale, rscale


def _point_writer(writer, scene, model, system, ep, F, solve_first, inds):
    """``on_point(i, y, info)`` of the continuation: append one point (and its loops);
    its error indicators computed by ``inds`` (:class:`.indicator_pool.PointIndicators`)
    before it is written (serial), or written NaN and handed to its pool."""
    a = scene.analysis.epmc
    units = model.units
    nz = system.n_z
    masing = scene.analysis.masing
    keep = _LoopSelection(a.loop_amplitudes, masing.points, a.log10_amplitude_start,
                          a.log10_amplitude_end,
                          writer.h5["epmc/amplitude"][()] if "epmc/amplitude" in writer.h5
                          else np.zeros(0))
    d_u = unit("displacement", units)
    amp_unit = "m kg^0.5" if units == "SI" else "length mass^0.5"
    law = model.contacts.law

    def on_point(i, y, info):
        if not solve_first and i == 0:
            return
        omega, xi, lam = float(y[nz]), float(y[nz + 1]), float(y[nz + 2])
        amp = 10.0 ** lam
        X = ep.coefficients(y)
        errors = inds.compute(y) if a.error_indicators and inds.serial else None
        with writer.commit():  # the point and its loops: all or nothing
            p = writer.rows("epmc/omega")
            writer.append("epmc/amplitude", amp, amp_unit, "modal amplitude of the fundamental")
            writer.append("epmc/omega", omega, unit("angular_frequency", units), "angular frequency")
            writer.append("epmc/frequency_hz", omega / (2 * np.pi), unit("frequency", units),
                          "frequency of the nonlinear mode")
            writer.append("epmc/damping_ratio", xi / (2 * omega), "1", "xi / (2 omega)")
            writer.append("epmc/xi", xi, unit("angular_frequency", units),
                          "self-excitation (negative mass-proportional damping)")
            writer.append("epmc/X", X, d_u, "harmonic coefficients [n_coeff, n_dof]")
            writer.append("epmc/iterations", np.int64(info.iterations), "1", "Newton iterations")
            writer.append("epmc/residual", info.residual, "1", "max |R| / residual scale")
            writer.append("epmc/step", info.step, "1", "scaled arclength step")
            writer.append("epmc/outside_range", abs(xi / (2 * omega)) > MAX_DAMPING_RATIO, "1",
                          f"damping ratio above {MAX_DAMPING_RATIO:g}: outside EPMC's "
                          "light-damping range")
            writer.append("epmc/y", y, "1", "unknowns (shape, omega, xi, log10 a), for --resume")
            writer.append("epmc/tangent", info.tangent, "1", "unit tangent (scaled)")
            solves, krylov_it, factorizations = system.stats.take()
            writer.append("epmc/linear_solves", np.int64(solves), "1",
                          "linear solves since the previous point")
            writer.append("epmc/krylov_iterations", np.int64(krylov_it), "1",
                          "GMRES iterations summed over those solves (0: direct solver)")
            writer.append("epmc/preconditioners", np.int64(factorizations), "1",
                          "harmonic preconditioners factorised since the previous point")
            if a.error_indicators:
                write_error_indicators(writer, "epmc", p, errors)
                if inds.serial:
                    inds.watch.check(0, errors, p, f"modal amplitude {amp:.3g}")
            ev = info.extra
            if ev is not None and ev.aft is not None and keep(p, amp):
                u = system.slips(X)
                report = check_loops(u, ev.aft.f, ev.aft.N, law, masing.tol)
                write_loops(writer, p, u, ev.aft.f, ev.aft.N, report, units, prefix="epmc")
                writer.h5["epmc/loops"].attrs["analysis"] = "epmc"
        if a.error_indicators and not inds.serial:
            inds.submit(p, (y,), f"modal amplitude {amp:.3g}")

    return on_point


def _explain(conv, model, system, ep, writer, scale=None):
    """The failed branch's convergence, its message extended by the residual jump of a
    law without path continuity (:func:`jointsim.solvers.discontinuity.explain_failure`)."""
    from ..contact.laws import continuation_advice
    from ..solvers.discontinuity import explain_failure

    advice = continuation_advice(model.contacts.law, system.coupled)
    if not advice:
        return conv
    y = writer.h5["epmc/y"][()] if "epmc/y" in writer.h5 else np.zeros((0, 0))
    ahead = None
    if scale is not None and len(y) and "epmc/tangent" in writer.h5:
        # the last predictor: one last step along the last (scaled) tangent
        t, h = writer.h5["epmc/tangent"][-1], float(writer.h5["epmc/step"][-1])
        if h > 0.0 and np.all(np.isfinite(t)):
            ahead = y[-1] + h * np.asarray(scale) * t / max(np.linalg.norm(t), 1e-300)
    def jac(v):
        J = ep.fun(v)[1]
        return J.to_dense() if hasattr(J, "to_dense") else J

    message = explain_failure(conv.message, advice, lambda v: ep.fun(v)[0],
                              y[-2] if len(y) > 1 else None, y[-1] if len(y) else None,
                              n_scan=32, jac=jac, y_ahead=ahead, scale=scale)
    return dataclasses.replace(conv, message=message)


#: The excess damping of :func:`step_monitor` is counted from this share of the linear
#: mode's viscous damping ratio, or from the damping ratio ``EXCESS_DAMPING_MIN`` without
#: viscous damping.
EXCESS_DAMPING_FLOOR = 1e-3
EXCESS_DAMPING_MIN = 1e-6


def step_monitor(a, nz: int, zeta0: float = 0.0):
    """The step-control monitor of the EPMC branch (see
    :class:`~jointsim.solvers.continuation.Continuation`): the damping ratio
    divided by ``analysis.epmc.max_damping_change``, ``log(omega)`` divided
    by ``max_frequency_change``, and ``log(zeta - zeta0 + floor)`` divided by
    ``log(max_excess_damping_growth)`` (``floor``: :data:`EXCESS_DAMPING_FLOOR`
    ``zeta0``, or :data:`EXCESS_DAMPING_MIN` when ``zeta0`` is 0); None when every
    limit is 0.

    The last one places a point just past the onset of friction dissipation: up to
    there the damping ratio is the viscous ``zeta0`` to round-off, and a step whose
    excess damping grows more than the factor from the floor is shrunk.  Measured on
    the coupled lap joint (96 points, steps 0.4 / 0.004): without it the polyline of
    the log-log backbone figure cut that corner by 5.9 % of the figure's height, with
    a factor of 50 it is within 0.95 % (docs/hbm.md, "Round 21").

    Parameters
    ----------
    a : jointsim.scene.EPMCAnalysis
    nz : int
        Number of shape unknowns (``y = (zh, omega, xi, lam)``).
    zeta0 : float
        Damping ratio of the linear mode (its viscous damping) [1].
    """
    dz, dw, gz = a.max_damping_change, a.max_frequency_change, a.max_excess_damping_growth
    if dz <= 0.0 and dw <= 0.0 and gz <= 0.0:
        return None
    floor = EXCESS_DAMPING_FLOOR * zeta0 if zeta0 > 0.0 else EXCESS_DAMPING_MIN

    def monitor(y):
        omega, xi = float(y[nz]), float(y[nz + 1])
        zeta = xi / (2.0 * omega)
        out = []
        if dz > 0.0:
            out.append(zeta / dz)
        if dw > 0.0:
            out.append(np.log(abs(omega)) / dw)
        if gz > 0.0:
            out.append(np.log(max(zeta - zeta0, 0.0) + floor) / np.log(gz))
        return np.array(out)

    return monitor
