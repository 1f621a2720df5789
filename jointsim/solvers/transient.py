"""Time marching: forced steady states and free decays.

The integrator (generalized-alpha with Newton condensed on the contact
coordinates, step cutting, and the consistent tangent of the contact
kernels) is in :mod:`jointsim.solvers.generalized_alpha`.  This module drives it:

* :func:`march_steady` forces the structure at ``omega`` from its static
  equilibrium until the period-to-period change falls below
  ``steady_tol`` (or ``max_periods``), then extracts the last period's
  harmonic coefficients ``[0, 1c, 1s, 2c, 2s, ...]`` (the order of
  ``/hbm/X``), the element loops and the energy balance of that period;
* :func:`free_decay` releases the structure from a deflection along a linear
  mode of the stuck joint and extracts the amplitude-dependent frequency and
  damping from the ring-down by the peak method of
  :func:`~jointsim.solvers.periodic.decay_estimates`.

Accuracy guards (the time-step error of a steady period, the scheme's range,
the modes a scene leaves undamped) are in :mod:`jointsim.solvers.march_accuracy`.

The pure functions of the marched samples (period change, energy balance,
extrema of a ring-down) are in :mod:`jointsim.solvers.periodic`.

The ``transient`` analysis of ``jointsim run`` (writing ``/transient/*``, the
loops, their Masing check and the cross-check against harmonic balance) is
:func:`jointsim.analyses.transient.run_transient`.
"""
from __future__ import annotations

import logging
import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from ..results import (INTERRUPTED, NON_FINITE, NOT_CONVERGED, STEP_TOO_SMALL, SUCCESS,
                       Convergence, interrupt_cause)
from ..harmonics import coefficient_index, dft_matrix, n_coefficients
from ..loads import LoadFunction
from .contact_map import ContactMap
from .generalized_alpha import GeneralizedAlpha, StepFailure, StepStats
from .periodic import (EnergyBalance, ExtremumTracker, PeriodData, decay_estimates,
                       energy_balance, geometric_error, period_change)
from ._transient_kernels import single_threaded
from .march_accuracy import StepError, step_error, step_range_warnings
from .static import StartState, static_start

log = logging.getLogger(__name__)

#: Samples of the quasi-static load path from the static state to the initial
#: deflection of a free decay.
PATH_SAMPLES = 64


# --------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class SteadyResult:
    """A forced steady state found by time marching.

    Attributes
    ----------
    omega : float
        Forcing frequency [rad/s].
    force_scale : float
    harmonics : tuple of int
        Harmonics extracted.
    X : ndarray, shape (n_coeff, n_dof)
        Coefficients of the last period, order ``[0, 1c, 1s, 2c, 2s, ...]`` [m].
    last : PeriodData or None
        The last complete period (None if not even one period was marched).
    energy : EnergyBalance or None
    period_change : ndarray, shape (n_periods,)
        Largest change of the displacements between consecutive periods,
        relative to the vibration amplitude; the first period is compared with its
        initial state held for a period (the change from the start) [-].
    error_estimate : float
        Remaining distance to the steady state estimated from the geometric
        decrease of ``period_change`` (``change * rho / (1 - rho)``, ``inf``
        when the change is not decreasing) [-].
    static_x : ndarray, shape (n_dof,)
        Static equilibrium the march started from [m].
    stats : dict
        Counters of the march (steps, Newton iterations, step cuts...).
    wall_time : float
        Time spent marching [s].
    convergence : Convergence
        ``iterations`` is the number of periods marched.
    step_error : StepError or None
        Time-step error indicator of the last period (:func:`step_error`;
        None without a complete period or when it could not be computed).
    range_warnings : tuple of str
        Why the step is outside the scheme's accurate range
        (:func:`step_range_warnings`), empty when it is inside.
    """

    omega: float
    force_scale: float
    harmonics: tuple
    X: np.ndarray
    last: PeriodData | None
    energy: EnergyBalance | None
    period_change: np.ndarray
    error_estimate: float
    static_x: np.ndarray
    stats: dict
    wall_time: float
    convergence: Convergence = field(repr=False)
    step_error: "StepError | None" = None
    range_warnings: tuple = ()


@dataclass(frozen=True)
class FreeDecayResult:
    """Amplitude-dependent frequency and damping from a ring-down.

    One estimate per half cycle (see :func:`decay_estimates`).

    Attributes
    ----------
    mode : int
        Linear mode deflected along (1-based, counted above the rigid cutoff).
    omega_linear : float
        Its angular frequency with the joint stuck [rad/s].
    phi : ndarray, shape (n_dof,)
        Its mass-normalised shape.
    q0 : float
        Initial modal amplitude.
    time : ndarray, shape (n_est,)
        Centre time of each estimate [s].
    amplitude : ndarray, shape (n_est,)
        Modal amplitude (half peak-to-peak swing of ``q = phi^T M (x - x_s)``).
    frequency_hz : ndarray, shape (n_est,)
        Damped frequency [Hz].
    damping_ratio : ndarray, shape (n_est,)
        From the logarithmic decrement over one cycle [-].
    static_x : ndarray, shape (n_dof,)
    stats : dict
    wall_time : float
    convergence : Convergence
        ``iterations`` is the number of linear periods marched.
    """

    mode: int
    omega_linear: float
    phi: np.ndarray
    q0: float
    time: np.ndarray
    amplitude: np.ndarray
    frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    static_x: np.ndarray
    stats: dict
    wall_time: float
    convergence: Convergence = field(repr=False)


# --------------------------------------------------------------------------
# Drivers
# --------------------------------------------------------------------------
def _frictionless_preload(scene) -> bool:
    m = scene.model if scene is not None else None
    return getattr(m, "preload_tangential", "stuck") == "frictionless"


def _stepper(model, settings, force, fused=True) -> GeneralizedAlpha:
    return GeneralizedAlpha(model, force, rho_inf=settings.rho_inf,
                            newton_tol=settings.newton_tol, max_iter=settings.max_iter,
                            max_cuts=settings.max_cuts, fused=fused)


def _progress(total, desc, enabled):
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit="period", disable=None if enabled else True,
                leave=False)


def _interrupted(exc: BaseException, k: int) -> str:
    """The message of a march stopped by ``exc`` in period ``k`` (SIGINT, SIGTERM...);
    a :class:`SystemError` not caused by an interrupt
    (:func:`~jointsim.results.interrupt_cause`) is re-raised."""
    cause = interrupt_cause(exc)
    if cause is None:
        raise exc
    return f"interrupted in period {k}" + (f" ({cause})" if str(cause) else "")


@dataclass(frozen=True)
class MarchResume:
    """Where a forced march resumes (``--resume`` of a checkpointed run, issue 11).

    Attributes
    ----------
    period : int
        The period that starts at ``state`` (periods are numbered from 0).
    state : MarchState
        The state at the start of that period, exactly as the interrupted
        march had it.
    stats : dict
        The :class:`~jointsim.solvers.generalized_alpha.StepStats` fields at
        that instant.
    changes : tuple of float
        The period changes already known: of periods ``0 .. len - 1``
        (``len > period``); periods up to ``len - 1`` are marched again with
        these changes (their output is already stored) and the march goes on
        after them.
    """

    period: int
    state: object
    stats: dict
    changes: tuple


def march_period(ga: GeneralizedAlpha, s, t, index: int = 0):
    """March from state ``s`` (at ``t[0]``) through the times ``t[1:]``.

    Parameters
    ----------
    ga : GeneralizedAlpha
    s : MarchState
        State at ``t[0]``.
    t : ndarray, shape (n + 1,)
        Times [s].
    index : int
        Period number stored in the result.

    Returns
    -------
    s : MarchState
        State at ``t[-1]``.
    period : PeriodData
        All ``n + 1`` samples, ``s`` included.
    """
    cmap = ga.cmap
    ne = cmap.n_e
    s, x, v, u, f, N = ga.march_block(s, t)
    g = np.zeros((ne, t.size))
    if ne and cmap.coupled:
        g[:] = (cmap.B @ x.T)[ne:]
    return s, PeriodData(index, t, x, v, u, f, N, g)


def march_steady(model, settings, *, scene=None, on_period=None, progress: bool = True,
                 frictionless_preload: bool | None = None, initial=None,
                 fused: bool = True, on_state=None,
                 resume: MarchResume | None = None) -> SteadyResult:
    """March a forced response until it is periodic.

    The structure starts at rest at its static state under the constant
    forces (preload and the loads' constant parts, :func:`static_start`), and
    the harmonic loads are switched on at ``t = 0``; or, with
    ``settings.start = "linear"``, on the discrete steady response of the
    linearised structure (:func:`linear_start`).  Each period of
    ``steps_per_period`` steps is compared with the one before, with the
    rigid-body modes left out (:func:`rigid_modes`, ``rigid_cutoff_hz``);
    the march stops when the change relative to the vibration amplitude
    falls below ``steady_tol`` (after at least ``min_periods``), or after
    ``max_periods``.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    settings : jointsim.scene.TransientAnalysis
        ``omega > 0``, ``force_scale``, ``rho_inf``, ``steps_per_period``,
        ``min_periods``, ``max_periods``, ``steady_tol``, ``harmonics`` and
        the Newton settings are used.
    scene : jointsim.scene.Scene, optional
        For file signals (their folder) and the preload setting.
    on_period : callable, optional
        ``on_period(period: PeriodData, change: float)`` after each period.
    progress : bool
        Show a progress bar (on a terminal).
    frictionless_preload : bool, optional
        Overrides the scene's ``model.preload_tangential``.
    initial : tuple, optional
        ``(x0, v0, state0)`` or ``(x0, v0, state0, a0)``: start from this
        displacement [m], velocity [m/s], law state (and acceleration [m/s^2])
        instead of the static equilibrium at rest (for instance from another
        solution, or with a different slider history).
    fused : bool
        Allow the fused numba march (False: step by step in Python; same
        scheme and results, for tests and comparisons).
    on_state : callable, optional
        ``on_state(k, state: MarchState, stats: StepStats)`` before period
        ``k`` is marched (a checkpoint: :class:`MarchResume` rebuilt from
        it continues the march exactly).
    resume : MarchResume, optional
        Continue an interrupted march from a checkpoint instead of starting.

    Returns
    -------
    SteadyResult
        With ``convergence.success`` False when ``max_periods`` ran out, a
        step failed, or the run was interrupted; what was computed is kept.
    """
    if settings.omega <= 0.0:
        raise ValueError("march_steady needs a forcing frequency omega > 0")
    t_start = time.perf_counter()
    omega = float(settings.omega)
    force = LoadFunction(model, omega, settings.force_scale,
                         scene.base_dir if scene is not None else None)
    if frictionless_preload is None:
        frictionless_preload = _frictionless_preload(scene)
    static = static_start(model, frictionless_preload, settings.newton_tol)
    ga = _stepper(model, settings, force, fused)
    h = 2.0 * np.pi / omega / settings.steps_per_period
    ranges = step_range_warnings(omega * h, settings.rho_inf, max(settings.harmonics),
                                 "the forcing frequency")
    for msg in ranges:
        log.warning("transient: %s", msg)
    s = _steady_initial_state(ga, force, static, h, settings, initial)
    k0, known = 0, ()
    if resume is not None:
        s, k0, known = resume.state, int(resume.period), tuple(resume.changes)
        if k0 > 0:
            # the first factorisation of an uninterrupted march is at exactly h, in
            # period 0 (counted in the stored counters)
            ga._factor(ga.snap(h))
        ga.stats = StepStats(**resume.stats)
    rigid = rigid_modes(model, getattr(settings, "rigid_cutoff_hz", None))
    bar = _progress(settings.max_periods, f"transient w={omega:.4g}", progress)
    try:
        run = _periods_until_steady(ga, s, settings, h, rigid, on_period, bar, k0, known,
                                    on_state)
    finally:
        bar.close()
    if run.status != SUCCESS:
        log.warning("transient: %s", run.message)
    res = _steady_result(model, settings, force, ga, static, rigid, run,
                         time.perf_counter() - t_start)
    err = None
    if res.last is not None and getattr(settings, "error_indicator", True):
        try:
            err = step_error(model, res.last, omega, float(settings.force_scale),
                             settings.harmonics, settings.steps_per_period)
        except (ValueError, np.linalg.LinAlgError) as exc:
            log.warning("transient: no step-size error indicator (%s)", exc)
    if err is not None:
        log.info("transient: step-size error indicator %.2e of the first harmonic "
                 "(%.2f s)", err.value, err.wall_time)
    return dataclasses.replace(res, step_error=err, range_warnings=tuple(ranges))


def _steady_initial_state(ga: GeneralizedAlpha, force: LoadFunction, static: StartState,
                          h: float, settings, initial):
    """The state a forced march starts from (step 1 of :func:`march_steady`).

    ``initial`` when given, else the discrete linear steady response
    (:func:`linear_start`) with ``settings.start = "linear"``, else the static
    state at rest.

    Returns
    -------
    MarchState
    """
    if initial is None and getattr(settings, "start", "rest") == "linear":
        initial = linear_start(ga, force, static, h)
    if initial is None:
        return ga.start(0.0, static.x, np.zeros(ga.model.n_dof), static.contact.state)
    return ga.start(0.0, *initial)


@dataclass(frozen=True)
class _MarchOutcome:
    """How a march loop ended: its status, message and the periods it did.

    Attributes
    ----------
    status : str
        A status of :mod:`jointsim.results`.
    message : str
    periods : int
        Periods marched (the failed one included).
    changes : tuple of float
        Period-to-period changes (forced march; empty for a free decay).
    last : PeriodData or None
        The last complete period (forced march).
    """

    status: str
    message: str
    periods: int
    changes: tuple = ()
    last: PeriodData | None = None


def _periods_until_steady(ga: GeneralizedAlpha, s, settings, h: float, rigid: RigidModes,
                          on_period, bar, k0: int = 0, known: tuple = (),
                          on_state=None) -> _MarchOutcome:
    """March whole periods until the change falls below ``steady_tol`` (step 2 of
    :func:`march_steady`); a failed step or an interrupt ends the loop with
    what was marched.  Resuming, ``s`` is the state at the start of period
    ``k0`` and ``known`` the changes of periods ``0 .. len(known) - 1``."""
    n = settings.steps_per_period
    changes: list[float] = list(known[:k0])
    last: PeriodData | None = None
    status, message = NOT_CONVERGED, ""
    k = k0
    try:
        with single_threaded():
            for k in range(k0, settings.max_periods):
                if on_state is not None:
                    on_state(k, s, ga.stats)
                t = (k * n + np.arange(n + 1)) * h
                s, pd = march_period(ga, s, t, k)
                if not (np.all(np.isfinite(pd.x)) and np.all(np.isfinite(pd.v))):
                    status, message = NON_FINITE, f"non-finite displacement in period {k}"
                    break
                if k < len(known):   # resumed: this period's change is stored
                    c = float(known[k])
                else:
                    before = (last.x[1:] if last is not None
                              else np.broadcast_to(pd.x[0], pd.x[1:].shape))
                    c = period_change(rigid.elastic(pd.x[1:]), rigid.elastic(before))
                changes.append(c)
                last = pd
                bar.update(1)
                bar.set_postfix(change=f"{c:.2e}")
                if on_period is not None:
                    on_period(pd, c)
                if k + 1 >= settings.min_periods and c <= settings.steady_tol:
                    status = SUCCESS
                    message = (f"steady after {k + 1} periods: period-to-period change "
                               f"{c:.2e} <= {settings.steady_tol:g}")
                    break
            else:
                message = (f"not steady after {settings.max_periods} periods: the change "
                           f"between the last two periods is {changes[-1]:.2e} > "
                           f"{settings.steady_tol:g}; raise analysis.transient.max_periods")
    except StepFailure as exc:
        status, message = STEP_TOO_SMALL, f"gave up in period {k}: {exc}"
    except (KeyboardInterrupt, SystemError) as exc:
        status, message = INTERRUPTED, _interrupted(exc, k)
    return _MarchOutcome(status, message, len(changes), tuple(changes), last)


def _steady_result(model, settings, force: LoadFunction, ga: GeneralizedAlpha,
                   static: StartState, rigid: RigidModes, run: _MarchOutcome,
                   wall_time: float) -> SteadyResult:
    """Harmonics and energy balance of the last period (step 3 of :func:`march_steady`)."""
    n = settings.steps_per_period
    last = run.last
    if last is not None:
        E = dft_matrix(settings.harmonics, n, float(settings.omega), last.t[0])
        X = E @ last.x[:n]
        c = model.contacts
        energy = energy_balance(last, force, ga.M, ga.C, ga.K,
                                (c.gap0, c.kn) if ga.cmap.unilateral else None)
    else:
        X = np.full((n_coefficients(settings.harmonics), model.n_dof), np.nan)
        energy = None
    stats = ga.stats.as_attrs()
    stats["static_iterations"] = static.iterations
    stats["rigid_modes_left_out"] = rigid.n
    return SteadyResult(
        omega=float(settings.omega), force_scale=float(settings.force_scale),
        harmonics=tuple(settings.harmonics), X=X, last=last, energy=energy,
        period_change=np.asarray(run.changes, dtype=float),
        error_estimate=geometric_error(run.changes), static_x=static.x, stats=stats,
        wall_time=wall_time,
        convergence=Convergence(run.status == SUCCESS, run.status, run.message,
                                run.periods))


@dataclass(frozen=True)
class RigidModes:
    """Rigid-body (suspension) modes, to leave out of the period-to-period change.

    On a free-free structure hung from soft springs these modes ring at a few
    Hz with little damping long after the elastic response is periodic (the
    suspension of the lap joint: 3.7 Hz at 0.087 %, a decay time of thousands
    of forcing periods).  They do not touch the joint.

    Attributes
    ----------
    shapes : ndarray, shape (n_rigid, n_dof)
        Mass-normalised shapes.
    Mshapes : ndarray, shape (n_dof, n_rigid)
        ``M @ shapes.T``.
    method : str
        How they were told apart (:func:`jointsim.solvers.modes.rigid_body_modes`).
    """

    shapes: np.ndarray
    Mshapes: np.ndarray
    method: str

    @property
    def n(self) -> int:
        return int(self.shapes.shape[0])

    def elastic(self, x):
        """``x`` without its rigid-body part, shape of ``x`` (..., n_dof)."""
        if self.n == 0:
            return x
        return x - (x @ self.Mshapes) @ self.shapes


def rigid_modes(model, cutoff_hz=None) -> RigidModes:
    """The rigid-body modes of the stuck linearisation (none for most lumped models).

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    cutoff_hz : float, optional
        Modes below it are rigid-body modes; default: detected
        (:func:`jointsim.solvers.modes.rigid_body_modes`).
    """
    from .modes import MAX_RIGID, stuck_modes
    res = stuck_modes(model, min(model.n_dof, MAX_RIGID + 1), cutoff_hz)
    shapes = np.ascontiguousarray(res.shapes[~res.elastic])
    M = model.M
    Mshapes = np.asarray(M @ shapes.T) if shapes.size else np.zeros((model.n_dof, 0))
    return RigidModes(shapes, Mshapes, res.rigid_method)


def linear_start(ga: GeneralizedAlpha, force: LoadFunction, static, h: float):
    """Initial state on the discrete steady response of the linearised structure.

    The contacts are linearised at the static state (tangent ``D`` of the laws
    there: stuck sliders).  For every harmonic of the force the periodic
    solution of the *discrete* scheme is solved exactly: with
    ``x_n = X z^n``, ``v_n = V z^n``, ``a_n = A z^n``, ``z = exp(i h w dt)``,
    the Newmark updates give ``V = dt ((1 - gamma) + gamma z) A / (z - 1)`` and
    ``X = (dt V + dt^2 ((1/2 - beta) + beta z) A) / (z - 1)``, and the balance

        [M ((1 - am) z + am) + (K_t X/A + C V/A) ((1 - af) z + af)] A
            = F ((1 - af) z + af)

    gives ``A``.  A linear structure started there is periodic from the first
    step (to round-off); a nonlinear one only has to shed the difference
    between its response and the linearised one.  The contact laws are
    marched along the straight path from the static state to ``x(0)``.

    Parameters
    ----------
    ga : GeneralizedAlpha
        The stepper (its matrices and parameters).
    force : LoadFunction
    static : StartState
    h : float
        Time step [s].

    Returns
    -------
    tuple
        ``(x0, v0, state0, a0)`` for :func:`march_steady`'s ``initial``.
    """
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla
    cmap = ContactMap(ga.model.contacts)
    K = sp.csr_matrix(ga.model.K)
    if cmap.active:
        K = K + cmap.Bt @ sp.csr_matrix(cmap.D_matrix(static.contact)) @ cmap.B
    M, C = sp.csr_matrix(ga.model.M), sp.csr_matrix(ga.model.C)
    n = ga.model.n_dof
    am, af, g, b = ga.am, ga.af, ga.gamma, ga.beta
    hs, coef, w = force.harmonics, force.coefficients, force.omega
    x0 = np.array(static.x, dtype=float)
    v0, a0 = np.zeros(n), np.zeros(n)
    for hh in hs[1:]:
        ic, is_ = coefficient_index(hs, hh)
        F = coef[ic] - 1j * coef[is_]           # f(t) = Re(F e^{i hh w t})
        if not np.any(F):
            continue
        z = np.exp(1j * hh * w * h)
        q = h * ((1.0 - g) + g * z) / (z - 1.0)                      # V = q A
        p = (h * q + h * h * ((0.5 - b) + b * z)) / (z - 1.0)        # X = p A
        wf = (1.0 - af) * z + af
        Z = ((1.0 - am) * z + am) * M + wf * (p * K + q * C)
        rhs = wf * F
        A = np.linalg.solve(Z.toarray(), rhs) if n <= 1500 else \
            spla.spsolve(sp.csc_matrix(Z), rhs)
        x0 += (p * A).real
        v0 += (q * A).real
        a0 += A.real
    state = static.contact.state
    if cmap.active:
        state = loaded_state(cmap, cmap.B @ static.x, cmap.B @ x0, state).state
    return x0, v0, state, a0


def loaded_state(cmap: ContactMap, y0, y1, state, n: int = PATH_SAMPLES):
    """March the contact laws along the straight path from ``y0`` to ``y1``.

    Parameters
    ----------
    cmap : ContactMap
    y0, y1 : ndarray, shape (n_c,)
        Contact coordinates at the start and the end [m].
    state : ndarray
        Law state at ``y0``.
    n : int
        Samples of the path.

    Returns
    -------
    ContactEval
        At ``y1``, with the state after the path.
    """
    ev = None
    for lam in np.linspace(0.0, 1.0, n + 1)[1:]:
        ev = cmap.evaluate(y0 + lam * (y1 - y0), state)
        state = ev.state
    return ev


def free_decay(model, settings, *, scene=None, on_block=None, on_estimate=None,
               progress: bool = True, frictionless_preload: bool | None = None,
               stop_ratio: float = 1e-8, fused: bool = True) -> FreeDecayResult:
    """Ring-down from a deflection along a linear mode of the stuck joint.

    The structure is brought quasi-statically from its static equilibrium
    ``x_s`` to ``x_s + q0 phi`` (the contact laws are marched along the
    straight path), released from rest, and marched for ``max_periods``
    periods of the linear mode with ``steps_per_period`` steps each.  The
    modal coordinate ``q = phi^T M (x - x_s)`` and its rate are tracked for
    extrema, which :func:`decay_estimates` turns into amplitude, frequency
    and damping.  The march stops early when the swing falls below
    ``stop_ratio q0``.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    settings : jointsim.scene.TransientAnalysis
        ``mode``, ``amplitude`` (q0), ``rigid_cutoff_hz``, ``rho_inf``,
        ``steps_per_period``, ``max_periods`` and the Newton settings.
    scene : jointsim.scene.Scene, optional
    on_block : callable, optional
        ``on_block(t, x, q)`` after each linear period, with ``t`` (n,),
        ``x`` (n, n_dof) and ``q`` (n,) of the new steps.
    on_estimate : callable, optional
        ``on_estimate(time, amplitude, frequency_hz, damping_ratio)`` for each
        new estimate.
    progress : bool
    frictionless_preload : bool, optional
    stop_ratio : float
    fused : bool
        Allow the fused numba march.

    Returns
    -------
    FreeDecayResult
    """
    t_start = time.perf_counter()
    force = LoadFunction(model, 0.0, 1.0, scene.base_dir if scene is not None else None)
    if frictionless_preload is None:
        frictionless_preload = _frictionless_preload(scene)
    static = static_start(model, frictionless_preload, settings.newton_tol)
    from .modes import elastic_mode
    em = elastic_mode(model, settings.mode, settings.rigid_cutoff_hz)
    w_lin, phi = em.omega, em.phi
    if w_lin <= 0.0:
        raise ValueError(f"mode {settings.mode} has zero frequency; set "
                         "analysis.transient.rigid_cutoff_hz to skip rigid-body modes")
    ga = _stepper(model, settings, force, fused)
    for msg in step_range_warnings(2.0 * np.pi / settings.steps_per_period,
                                   settings.rho_inf, 1, "the linear mode"):
        log.warning("free decay: %s", msg)
    q0 = float(settings.amplitude)
    s = _deflected_state(ga, static, static.x + q0 * phi)
    h = 2.0 * np.pi / w_lin / settings.steps_per_period
    tracker = ExtremumTracker()
    bar = _progress(settings.max_periods, "free decay", progress)
    try:
        run = _ring_down(ga, s, static.x, np.asarray(ga.M @ phi).ravel(), h, settings,
                         tracker, on_block, on_estimate, stop_ratio * q0, bar)
    finally:
        bar.close()
    tt, amp, fr, zeta = decay_estimates(tracker.t, tracker.q)
    status, message = run.status, run.message
    if status == SUCCESS:
        message += f"; {tt.size} estimates from {len(tracker.t)} extrema"
        if tt.size == 0:
            status = NOT_CONVERGED
            message += " (too few extrema: raise max_periods)"
    if status != SUCCESS:
        log.warning("free decay: %s", message)
    stats = ga.stats.as_attrs()
    return FreeDecayResult(
        mode=settings.mode, omega_linear=w_lin, phi=phi, q0=q0, time=tt, amplitude=amp,
        frequency_hz=fr, damping_ratio=zeta, static_x=static.x, stats=stats,
        wall_time=time.perf_counter() - t_start,
        convergence=Convergence(status == SUCCESS, status, message, run.periods))


def _deflected_state(ga: GeneralizedAlpha, static: StartState, x0):
    """At rest at ``x0``, with the contact laws marched along the straight path
    from the static state (step 1 of :func:`free_decay`).

    Returns
    -------
    MarchState
    """
    cmap = ga.cmap
    zero = np.zeros(ga.model.n_dof)
    if not cmap.active:
        return ga.start(0.0, x0, zero, static.contact.state)
    ev = loaded_state(cmap, cmap.B @ static.x, cmap.B @ x0, static.contact.state)
    # start() evaluates the laws at x0 again from this state; a rate-independent
    # law evaluated twice at the same input is unchanged
    return ga.start(0.0, x0, zero, ev.state)


def _ring_down(ga: GeneralizedAlpha, s, x_static, Mphi, h: float, settings,
               tracker: ExtremumTracker, on_block, on_estimate, stop_swing: float,
               bar) -> _MarchOutcome:
    """March periods of the linear mode, feeding the modal coordinate
    ``q = Mphi^T (x - x_static)`` to ``tracker`` (step 2 of :func:`free_decay`).

    Stops after ``max_periods``, when a period's half swing falls below
    ``stop_swing`` [m], or when a step fails (what was marched is kept).
    """
    n = settings.steps_per_period
    tracker.add(0.0, float(Mphi @ (s.x - x_static)), float(Mphi @ s.v))
    n_done = 0
    status, message = SUCCESS, ""
    k = 0
    try:
        with single_threaded():
            for k in range(settings.max_periods):
                t = (k * n + np.arange(n + 1)) * h
                s, xb, vb, *_ = ga.march_block(s, t)
                t, xb = t[1:], xb[1:]
                qb = (xb - x_static) @ Mphi
                for tj, qj, dj in zip(t, qb, vb[1:] @ Mphi):
                    tracker.add(tj, qj, dj)
                if not np.all(np.isfinite(xb)):
                    status, message = NON_FINITE, f"non-finite displacement in period {k}"
                    break
                if on_block is not None:
                    on_block(t, xb, qb)
                est = decay_estimates(tracker.t, tracker.q)
                if on_estimate is not None:
                    for i in range(n_done, est[0].size):
                        on_estimate(*(a[i] for a in est))
                n_done = est[0].size
                bar.update(1)
                swing = 0.5 * float(np.ptp(qb))
                if swing <= stop_swing:
                    message = f"at rest after {k + 1} periods (swing {swing:.2e})"
                    break
            else:
                message = f"marched {settings.max_periods} periods of the linear mode"
    except StepFailure as exc:
        status, message = STEP_TOO_SMALL, f"gave up in period {k}: {exc}"
    except (KeyboardInterrupt, SystemError) as exc:
        status, message = INTERRUPTED, _interrupted(exc, k)
    return _MarchOutcome(status, message, k + 1)
