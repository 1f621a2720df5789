"""Time marching: forced steady states and free decays.

The integrator (generalized-alpha with Newton condensed on the contact
coordinates, step cutting, and the consistent tangent of the contact
kernels) is in :mod:`jointsim.solvers._march`.  This module drives it:

* :func:`march_steady` forces the structure at ``omega`` from its static
  equilibrium until the period-to-period change falls below
  ``steady_tol`` (or ``max_periods``), then extracts the last period's
  harmonic coefficients ``[0, 1c, 1s, 2c, 2s, ...]`` (the order of
  ``/hbm/X``), the element loops and the energy balance of that period;
* :func:`free_decay` releases the structure from a deflection along a linear
  mode of the stuck joint and extracts the amplitude-dependent frequency and
  damping from the ring-down by the peak method of :func:`decay_estimates`;

The ``transient`` analysis of ``jointsim run`` (writing ``/transient/*``, the
loops, their Masing check and the cross-check against harmonic balance) is
:func:`jointsim.analyses.transient.run_transient`.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from ..results import (INTERRUPTED, NON_FINITE, NOT_CONVERGED, STEP_TOO_SMALL, SUCCESS,
                       Convergence)
from ..harmonics import coefficient_index, dft_matrix, n_coefficients
from ..loads import LoadFunction
from ._march import ContactMap, GeneralizedAlpha, StepFailure, empty_eval
from ._transient_kernels import single_threaded

log = logging.getLogger(__name__)

#: Samples of the quasi-static load path from the static state to the initial
#: deflection of a free decay.
PATH_SAMPLES = 64


# --------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class EnergyBalance:
    """Work done over one period, from the marched samples.

    The sums use the trapezoidal rule on the step grid: forces averaged over
    each step times the displacement increment, and ``h vbar^T C vbar`` with
    the mean velocity of the step.  With ``rho_inf = 1`` (the trapezoidal
    rule) the discrete balance is exact up to the Newton tolerance; with
    ``rho_inf < 1`` the imbalance is the numerical dissipation of the scheme.

    Attributes
    ----------
    input : float
        Work of the external force [J].
    viscous : float
        Dissipated by the damping matrix [J].
    friction : float
        Work of the tangential contact forces on the slips (the loop areas) [J].
    normal : float
        Work of the normal contact forces (zero over a period for the
        elastic penalty) [J].
    stored : float
        Change of kinetic plus linear elastic energy over the period [J].
    imbalance : float
        ``input - viscous - friction - normal - stored`` [J].
    relative : float
        ``|imbalance| / max(|input|, viscous + |friction|)`` [-].
    """

    input: float
    viscous: float
    friction: float
    normal: float
    stored: float
    imbalance: float
    relative: float

    def as_attrs(self) -> dict:
        return {f"energy_{k}": float(getattr(self, k)) for k in
                ("input", "viscous", "friction", "normal", "stored", "imbalance", "relative")}


@dataclass(frozen=True)
class PeriodData:
    """The marched samples of one period (``n + 1`` samples, both ends included).

    Attributes
    ----------
    index : int
        Period number (0 is the first).
    t : ndarray, shape (n + 1,)
        Times [s].
    x, v : ndarray, shape (n + 1, n_dof)
        Displacements [m] and velocities [m/s].
    u, f, N : ndarray, shape (n_e, n + 1)
        Tangential slip [m], tangential force [N] and normal load [N].
    g : ndarray, shape (n_e, n + 1)
        Gap changes ``Tn x`` [m] (zeros with a fixed normal load).
    """

    index: int
    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    u: np.ndarray
    f: np.ndarray
    N: np.ndarray
    g: np.ndarray


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
        relative to the vibration amplitude (``nan`` for the first period).
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
# Period analysis (pure functions)
# --------------------------------------------------------------------------
def period_change(x_new, x_old) -> float:
    """Largest change between two periods relative to the vibration amplitude.

    Parameters
    ----------
    x_new, x_old : ndarray, shape (n, n_dof)
        Displacements at the same phases of consecutive periods [m].

    Returns
    -------
    float
        ``max |x_new - x_old| / max_j (max_t x_j - min_t x_j) / 2`` [-].
    """
    amp = 0.5 * float(np.max(np.ptp(x_new, axis=0)))
    diff = float(np.max(np.abs(x_new - x_old)))
    if amp == 0.0:
        return 0.0 if diff == 0.0 else np.inf
    return diff / amp


def energy_balance(p: PeriodData, force, M, C, K, unilateral=None) -> EnergyBalance:
    """Energy balance of one marched period (see :class:`EnergyBalance`).

    Parameters
    ----------
    p : PeriodData
    force : callable
        ``force(t) -> ndarray (n_dof,)`` [N].
    M, C, K : matrix, shape (n_dof, n_dof)
    unilateral : tuple, optional
        ``(gap0, kn)`` of unilateral penalty contacts: the normal work then uses
        the same energy-consistent average as the scheme
        (:func:`~jointsim.solvers._transient_kernels.gap_correction`), i.e. the
        change of the penalty energy.
    """
    F = np.array([force(t) for t in p.t])
    dx = np.diff(p.x, axis=0)
    w_in = float(np.sum(0.5 * (F[1:] + F[:-1]) * dx))
    h = np.diff(p.t)
    vbar = 0.5 * (p.v[1:] + p.v[:-1])
    w_c = float(np.sum(h * np.einsum("ij,ij->i", vbar, (C @ vbar.T).T)))
    w_f = float(np.sum(0.5 * (p.f[:, 1:] + p.f[:, :-1]) * np.diff(p.u, axis=1)))
    Nbar = 0.5 * (p.N[:, 1:] + p.N[:, :-1])
    if unilateral is not None and p.N.shape[0]:
        from ._transient_kernels import gap_correction
        gap0, kn = unilateral
        gaps = gap0[:, None] + p.g
        c, dc = np.empty(gap0.size), np.empty(gap0.size)
        for j in range(p.t.size - 1):
            gap_correction(gaps[:, j], p.N[:, j], gaps[:, j + 1], p.N[:, j + 1], kn, c, dc)
            Nbar[:, j] += c
    w_n = float(np.sum(-Nbar * np.diff(p.g, axis=1)))

    def stored(x, v):
        return 0.5 * float(v @ (M @ v)) + 0.5 * float(x @ (K @ x))

    w_s = stored(p.x[-1], p.v[-1]) - stored(p.x[0], p.v[0])
    imb = w_in - w_c - w_f - w_n - w_s
    ref = max(abs(w_in), w_c + abs(w_f))
    return EnergyBalance(w_in, w_c, w_f, w_n, w_s, imb, abs(imb) / ref if ref > 0 else 0.0)


def geometric_error(changes) -> float:
    """Distance to the limit estimated from a geometrically decreasing sequence.

    With the last two changes ``c1 < c0``, ``rho = c1 / c0`` and the remaining
    distance is ``c1 rho / (1 - rho)``; ``inf`` when the sequence does not
    decrease, ``0`` when the last change is 0.
    """
    c = [v for v in changes if np.isfinite(v)]
    if not c:
        return np.inf
    if c[-1] == 0.0:
        return 0.0
    if len(c) < 2 or not c[-1] < c[-2]:
        return np.inf
    rho = c[-1] / c[-2]
    return c[-1] * rho / (1.0 - rho)


def hermite_extremum(t0, t1, q0, q1, d0, d1):
    """Extremum of the cubic Hermite interpolant of ``q`` on ``[t0, t1]``.

    ``d0`` and ``d1`` (the derivatives at the ends) must differ in sign or
    one of them be 0.

    Returns
    -------
    t, q : float
        Time and value of the extremum.
    """
    dt = t1 - t0
    a = 6.0 * q0 + 3.0 * dt * d0 - 6.0 * q1 + 3.0 * dt * d1
    b = -6.0 * q0 - 4.0 * dt * d0 + 6.0 * q1 - 2.0 * dt * d1
    c = dt * d0
    tau = None
    if abs(a) > 1e-14 * (abs(b) + abs(c)):
        disc = b * b - 4.0 * a * c
        if disc >= 0.0:
            sq = np.sqrt(disc)
            # numerically stable roots of a t^2 + b t + c
            qq = -0.5 * (b + np.copysign(sq, b))
            roots = [qq / a] + ([c / qq] if qq != 0.0 else [])
            inside = [r for r in roots if -1e-12 <= r <= 1.0 + 1e-12]
            if inside:
                tau = min(max(inside[0], 0.0), 1.0)
    elif b != 0.0:
        tau = min(max(-c / b, 0.0), 1.0)
    if tau is None:  # degenerate: linear interpolation of the derivative
        tau = d0 / (d0 - d1) if d0 != d1 else 0.5
    h00 = 2 * tau ** 3 - 3 * tau ** 2 + 1
    h10 = tau ** 3 - 2 * tau ** 2 + tau
    h01 = -2 * tau ** 3 + 3 * tau ** 2
    h11 = tau ** 3 - tau ** 2
    return t0 + tau * dt, h00 * q0 + h10 * dt * d0 + h01 * q1 + h11 * dt * d1


class ExtremumTracker:
    """Alternating extrema of a sampled signal ``q(t)`` with known derivative.

    Feed samples in time order with :meth:`add`; an extremum is found where
    ``dq/dt`` changes sign, and located by cubic Hermite interpolation.
    Consecutive extrema alternate (maximum, minimum, ...): a repeated kind
    (round-off near rest) keeps the more extreme value.
    """

    def __init__(self):
        self.t: list[float] = []
        self.q: list[float] = []
        self.kind: list[int] = []
        self._prev = None

    def add(self, t, q, d) -> None:
        if self._prev is not None:
            t0, q0, d0 = self._prev
            kind = 0
            if d0 > 0.0 and d <= 0.0:
                kind = 1
            elif d0 < 0.0 and d >= 0.0:
                kind = -1
            if kind:
                te, qe = hermite_extremum(t0, t, q0, q, d0, d)
                if self.kind and self.kind[-1] == kind:
                    if kind * qe > kind * self.q[-1]:
                        self.t[-1], self.q[-1] = te, qe
                else:
                    self.t.append(te)
                    self.q.append(qe)
                    self.kind.append(kind)
        self._prev = (t, q, d)


def decay_estimates(t_ext, q_ext):
    """Frequency, damping and amplitude of a ring-down from its extrema.

    With alternating extrema ``(t_j, q_j)`` and half swings
    ``H_j = |q_{j+1} - q_j| / 2``, every three consecutive swings give one
    estimate centred on swing ``j + 1``:

    * amplitude ``A = H_{j+1}``;
    * period ``T = (t_{j+2} - t_j + t_{j+3} - t_{j+1}) / 2``;
    * logarithmic decrement ``delta = ln(H_j / H_{j+2})`` over one cycle and
      ``zeta = delta / sqrt(4 pi^2 + delta^2)``.

    Swings are offset-free: a constant shift of the signal (a slider that
    stays displaced) does not bias them.  For a linear viscously damped
    oscillator the frequency (the damped one) and damping ratio are exact.
    For a nonlinear ring-down each estimate is an average over about 1.5
    cycles, and the amplitude is the peak value, not the first-harmonic
    amplitude of EPMC; both biases grow with the decay per cycle and the
    waveform distortion (see ``docs/transient.md``).

    Parameters
    ----------
    t_ext, q_ext : array_like, shape (n,)
        Times [s] and values of alternating extrema.

    Returns
    -------
    time, amplitude, frequency_hz, damping_ratio : ndarray, shape (max(n - 3, 0),)
    """
    t = np.asarray(t_ext, dtype=float)
    q = np.asarray(q_ext, dtype=float)
    if t.size < 4:
        e = np.zeros(0)
        return e, e, e, e
    H = 0.5 * np.abs(np.diff(q))
    j = np.arange(t.size - 3)
    period = 0.5 * ((t[j + 2] - t[j]) + (t[j + 3] - t[j + 1]))
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where((H[j] > 0) & (H[j + 2] > 0), np.log(H[j] / H[j + 2]), np.nan)
    zeta = delta / np.sqrt(4.0 * np.pi ** 2 + delta ** 2)
    return 0.5 * (t[j + 1] + t[j + 2]), H[j + 1], 1.0 / period, zeta


# --------------------------------------------------------------------------
# Drivers
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class StartState:
    """The static state a march starts from, with the contact laws' state there.

    Attributes
    ----------
    x : ndarray, shape (n_dof,)
        Static displacement [m].
    contact : ContactEval
        Contact forces at ``x``; ``contact.state`` is the law state to start from.
    iterations : int
        Newton iterations of the static solves.
    source : str
        Where ``x`` comes from (the stuck linearisation's ``source``, or
        ``"frictionless"``).
    """

    x: np.ndarray
    contact: object
    iterations: int
    source: str


def static_start(model, frictionless: bool = False, tol: float = 1e-10) -> StartState:
    """The static state under the constant loads, and the laws' state there.

    The state is the one every solver starts from,
    :func:`jointsim.solvers.static.stuck_linearisation` (the model builder's
    preload state when it has one, else solved with the joint stuck), with
    the sliders at rest: anchors at zero slip, so that a stuck slider carries
    ``kt A u_t``.  Where that force exceeds the slip limit, one
    :func:`~jointsim.solvers.static.solve_static` step with the law itself
    (``tangential = "law"``) lets the slider slip to equilibrium.

    With ``frictionless`` (``model.preload_tangential = "frictionless"``) the
    static state carries no tangential force (``solve_static`` with
    ``tangential = "frictionless"``), and the sliders rest, unloaded, at the
    slip it leaves.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    frictionless : bool
    tol : float
        Residual tolerance of the static solves.

    Returns
    -------
    StartState

    Raises
    ------
    RuntimeError
        When a static solve fails (the message says why).
    """
    from ..loads import static_load
    from .static import solve_static
    c = model.contacts
    cmap = ContactMap(c)
    f0 = static_load(model)
    if frictionless and cmap.active:
        x_start = None if model.preload is None else model.preload.x0
        res = solve_static(model.K, f0, c, tangential="frictionless", tol=tol,
                           x_start=x_start, f_start=None if x_start is None else f0)
        if not res.convergence.success:
            raise RuntimeError(f"the static (preload) state, frictionless: "
                               f"{res.convergence.message}")
        state = cmap.state_at(res.u_t, res.N)
        ev = cmap.evaluate(cmap.B @ res.x, state)
        return StartState(res.x, ev, res.convergence.iterations, "frictionless")
    lin = model.linearisation
    if not cmap.active:
        return StartState(lin.x0, empty_eval(c.law.rest_state(np.zeros(0))),
                          lin.convergence.iterations, lin.source)
    rest = c.law.rest_state(lin.N)
    if not c.law.can_slip:   # linear or no friction: no history to solve for
        return StartState(lin.x0, cmap.evaluate(cmap.B @ lin.x0, rest),
                          lin.convergence.iterations, lin.source)
    res = solve_static(model.K, f0, c, tangential="law", state=rest, tol=tol,
                       x_start=lin.x0, f_start=f0)
    if not res.convergence.success:
        raise RuntimeError(f"the static state with the contact law: {res.convergence.message}")
    ev = cmap.evaluate(cmap.B @ res.x, res.state)
    return StartState(res.x, ev, lin.convergence.iterations + res.convergence.iterations,
                      lin.source)


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
                 fused: bool = True) -> SteadyResult:
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
    n = settings.steps_per_period
    period = 2.0 * np.pi / omega
    h = period / n
    if initial is None and getattr(settings, "start", "rest") == "linear":
        initial = linear_start(ga, force, static, h)
    if initial is None:
        s = ga.start(0.0, static.x, np.zeros(model.n_dof), static.contact.state)
    else:
        s = ga.start(0.0, *initial)

    rigid = rigid_modes(model, getattr(settings, "rigid_cutoff_hz", None))
    changes: list[float] = []
    last: PeriodData | None = None
    status, message = NOT_CONVERGED, ""
    k = 0
    bar = _progress(settings.max_periods, f"transient w={omega:.4g}", progress)
    try:
        with single_threaded():
            for k in range(settings.max_periods):
                t = (k * n + np.arange(n + 1)) * h
                s, pd = march_period(ga, s, t, k)
                if not (np.all(np.isfinite(pd.x)) and np.all(np.isfinite(pd.v))):
                    status, message = NON_FINITE, f"non-finite displacement in period {k}"
                    break
                c = period_change(rigid.elastic(pd.x[1:]), rigid.elastic(last.x[1:])) \
                    if last is not None else np.nan
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
    except KeyboardInterrupt:
        status, message = INTERRUPTED, f"interrupted in period {k}"
    finally:
        bar.close()
    if status != SUCCESS:
        log.warning("transient: %s", message)
    n_periods = len(changes)
    if last is not None:
        E = dft_matrix(settings.harmonics, n, omega, last.t[0])
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
        omega=omega, force_scale=float(settings.force_scale),
        harmonics=tuple(settings.harmonics), X=X, last=last, energy=energy,
        period_change=np.asarray(changes, dtype=float),
        error_estimate=geometric_error(changes), static_x=static.x, stats=stats,
        wall_time=time.perf_counter() - t_start,
        convergence=Convergence(status == SUCCESS, status, message, n_periods))


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
    q0 = float(settings.amplitude)
    x0 = static.x + q0 * phi
    cmap = ga.cmap
    if cmap.active:
        ev = loaded_state(cmap, cmap.B @ static.x, cmap.B @ x0, static.contact.state)
        # start() evaluates the laws at x0 again from this state; a rate-independent
        # law evaluated twice at the same input is unchanged
        s = ga.start(0.0, x0, np.zeros(model.n_dof), ev.state)
    else:
        s = ga.start(0.0, x0, np.zeros(model.n_dof), static.contact.state)
    Mphi = np.asarray(ga.M @ phi).ravel()
    n = settings.steps_per_period
    h = 2.0 * np.pi / w_lin / n
    tracker = ExtremumTracker()
    tracker.add(0.0, float(Mphi @ (s.x - static.x)), float(Mphi @ s.v))
    n_done = 0
    status, message = SUCCESS, ""
    bar = _progress(settings.max_periods, "free decay", progress)
    k = 0
    try:
        with single_threaded():
            for k in range(settings.max_periods):
                t = (k * n + np.arange(n + 1)) * h
                s, xb, vb, *_ = ga.march_block(s, t)
                t, xb = t[1:], xb[1:]
                qb = (xb - static.x) @ Mphi
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
                if swing <= stop_ratio * q0:
                    message = f"at rest after {k + 1} periods (swing {swing:.2e})"
                    break
            else:
                message = f"marched {settings.max_periods} periods of the linear mode"
    except StepFailure as exc:
        status, message = STEP_TOO_SMALL, f"gave up in period {k}: {exc}"
    except KeyboardInterrupt:
        status, message = INTERRUPTED, f"interrupted in period {k}"
    finally:
        bar.close()
    tt, amp, fr, zeta = decay_estimates(tracker.t, tracker.q)
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
        convergence=Convergence(status == SUCCESS, status, message, k + 1))
