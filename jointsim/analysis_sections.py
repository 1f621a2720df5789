"""The ``[analysis.*]`` sections of a scene: which analyses run, with their settings.

Part of the scene contract of :mod:`jointsim.scene` (which re-exports these
classes): frozen sections built and validated by :mod:`jointsim._schema`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from ._schema import spec


@dataclass(frozen=True, kw_only=True)
class MasingAnalysis:
    """Masing-manifold check of every element's steady loop."""

    tol: float = spec(0.01, doc="on-manifold tolerance on the normalised deviation", gt=0)
    points: tuple[int, ...] = spec((), doc="solution points whose loops are kept "
                                           "(empty: all)", ge=0)


@dataclass(frozen=True, kw_only=True)
class ModesAnalysis:
    """Linear modes of the preloaded joint with a stuck interface."""

    n_modes: int = spec(10, doc="linear modes of the preloaded, stuck joint", ge=1)
    suspension_hz: Optional[float] = spec(
        None, doc="modes below this frequency are rigid-body (suspension) modes, not elastic "
                  "ones; default: detected (FE: rigid-body share of the modal mass; ROM: "
                  "spectral gap; lumped: none)", unit="Hz", ge=0)
    full_model: bool = spec(False, doc="also solve the unreduced FE model and compare "
                                       "(FE models)")
    monolithic: bool = spec(False, doc="also solve the monolithic beam: the same mesh with "
                                       "coincident nodes glued (FE models)")
    export_rom: str = spec("", doc="write the reduced model to this file (.npz, .mat or "
                                   ".h5; relative to the result file's folder); '' skips it")


@dataclass(frozen=True, kw_only=True)
class HBMAnalysis:
    """Frequency response by AFT harmonic balance with continuation."""

    harmonics: tuple[int, ...] = spec((0, 1, 2, 3, 4, 5, 6, 7), doc="harmonics kept", ge=0)
    n_samples: int = spec(128, doc="AFT time samples per period", ge=4)
    omega_start: float = spec(doc="start of the sweep", unit="rad/s", gt=0)
    omega_end: float = spec(doc="end of the sweep", unit="rad/s", gt=0)
    force_scale: tuple[float, ...] = spec((1.0,), doc="multipliers of the harmonic "
                                                      "excitation; one branch each. Static "
                                                      "loads (the constant part of a force, "
                                                      "bolt preload) are NOT scaled")
    response_dof: int = spec(0, doc="DOF whose amplitude the FRC plots", ge=0)
    response_point: str = spec("", doc="named model point whose amplitude the FRC plots "
                                       "(FE/ROM, e.g. 'response'; overrides response_dof)")
    step: float = spec(0.01, doc="initial arclength step (scaled units)", gt=0)
    step_min: float = spec(1e-6, doc="smallest arclength step before giving up", gt=0)
    step_max: float = spec(0.1, doc="largest arclength step", gt=0)
    max_points: int = spec(2000, doc="maximum points per branch", ge=2)
    tol: float = spec(1e-8, doc="Newton tolerance on the scaled residual", gt=0)
    max_iter: int = spec(20, doc="Newton iterations per corrector", ge=1)
    min_periods: int = spec(2, doc="AFT: periods the laws are marched at least", ge=2)
    max_periods: int = spec(50, doc="AFT: periods marched at most until the law state "
                                    "repeats", ge=2)
    refine_peak: bool = spec(True, doc="refine each branch's largest amplitude by "
                                       "maximising over frequency (single-valued peaks)")
    workers: int = spec(0, doc="branches (force levels) computed at once in worker "
                               "processes; 0: one per core, up to the number of branches; "
                               "1: one after the other in this process; when the branches "
                               "run in this process (one branch), their error indicators "
                               "go to that many workers beside the continuation (with 0, "
                               "none below 200 unknowns: computed here); once no "
                               "branch is left to start and a core is free, the workers "
                               "still running leave their points' indicators to this process",
                      ge=0)
    loops: str = spec("auto", choices=("auto", "peaks", "all", "masing.points"),
                      doc="points whose element loops and Masing checks are kept: 'auto' "
                          "(default): those of analysis.masing.points when it is set, else "
                          "'peaks'; 'peaks': each branch's largest-amplitude point (cheap); "
                          "'all': every point (costly: on small FRCs the loops and checks "
                          "take about 40% of the run, e.g. 6.2 s against 3.7 s); "
                          "'masing.points': those of analysis.masing.points (empty: every "
                          "point)")
    amplitude: str = spec("fundamental", choices=("fundamental", "rms", "peak_to_peak"),
                          doc="measure of /hbm/amplitude and the refined peak at the response "
                              "DOF: 'fundamental' sqrt(X_1c^2 + X_1s^2), 'rms' the RMS of "
                              "x(t) over all harmonics kept (the mean included), "
                              "'peak_to_peak' max x(t) - min x(t) over the AFT samples")
    linear_solver: str = spec("auto", choices=("auto", "direct", "krylov"),
                              doc="Newton linear solves: dense LU ('direct', the reference), "
                                  "preconditioned GMRES on the structured Jacobian without "
                                  "forming it ('krylov'), or 'auto' (Krylov from 1200 "
                                  "unknowns on); see docs/hbm.md")
    error_indicators: bool = spec(True, doc="compute the error indicators /hbm/error_* of "
                                            "every point (one extra linear solve each; "
                                            "jointsim.solvers.indicators)")
    error_tol: float = spec(1e-2, doc="tolerance on /hbm/error_curve (estimated relative "
                                      "error of the retained harmonics across the branch, "
                                      "solved where /hbm/error_estimate exceeds it): points "
                                      "above it are marked on the FRC figure and warned about "
                                      "once per branch; 0: never", ge=0)

    def check(self):
        if not self.force_scale:
            return [("force_scale", "must hold at least one force level (one branch each)")]
        for i, fs in enumerate(self.force_scale):
            if fs == 0.0:
                return [(f"force_scale[{i}]", "must not be 0 (a branch without forcing has "
                                              "no response)")]
        if self.omega_end == self.omega_start:
            return [("omega_end", "must differ from omega_start")]
        return []


@dataclass(frozen=True, kw_only=True)
class EPMCAnalysis:
    """Nonlinear mode by the extended periodic motion concept (Krack 2015).

    The amplitude is the modal amplitude of the fundamental harmonic,
    ``a = |phi^T M (X_1c - i X_1s)|`` with ``phi`` the mass-normalised mode of
    the structure with every contact at its rest tangent (stuck).
    """

    mode: int = spec(1, doc="elastic mode followed (1-based; rigid-body/suspension modes "
                            "are not counted)", ge=1)
    rigid_cutoff_hz: Optional[float] = spec(
        None, doc="modes below this frequency count as rigid-body modes; default: detected "
                  "like analysis.modes.suspension_hz", unit="Hz", ge=0)
    harmonics: tuple[int, ...] = spec((0, 1, 2, 3, 4, 5, 6, 7), doc="harmonics kept", ge=0)
    n_samples: int = spec(128, doc="AFT time samples per period", ge=4)
    log10_amplitude_start: float = spec(doc="log10 of the starting modal amplitude")
    log10_amplitude_end: float = spec(doc="log10 of the final modal amplitude")
    step: float = spec(0.05, doc="initial arclength step", gt=0)
    step_min: float = spec(1e-6, doc="smallest arclength step before giving up", gt=0)
    step_max: float = spec(0.2, doc="largest arclength step", gt=0)
    max_points: int = spec(500, doc="maximum points", ge=2)
    tol: float = spec(1e-8, doc="Newton tolerance", gt=0)
    max_iter: int = spec(20, doc="Newton iterations per corrector", ge=1)
    min_periods: int = spec(2, doc="AFT: periods the laws are marched at least", ge=2)
    max_periods: int = spec(50, doc="AFT: periods marched at most", ge=2)
    linear_solver: str = spec("auto", choices=("auto", "direct", "krylov"),
                              doc="as analysis.hbm.linear_solver")
    error_indicators: bool = spec(True, doc="compute the error indicators /epmc/error_* of "
                                            "every point (one extended solve each)")
    error_tol: float = spec(1e-2, doc="tolerance on /epmc/error_estimate: points above it are "
                                      "marked on the backbone figure and warned about once; "
                                      "0: never", ge=0)
    error_newton_steps: int = spec(8, doc="Newton steps at most of the extended EPMC solve "
                                          "behind the indicators; 1: its first step only (about "
                                          "2.4x cheaper, but on the FE joint up to 18x too high)",
                                   ge=1)
    workers: int = spec(0, doc="worker processes computing the error indicators beside the "
                               "continuation (each point's are written when they come back); "
                               "0: one per core (none below 200 unknowns: each point's "
                               "cost less than a worker's round trip); 1: each point's at "
                               "once, in this process",
                        ge=0)
    loop_amplitudes: tuple[float, ...] = spec(
        (), doc="modal amplitudes at which the element loops and Masing checks are kept "
                "(the first point at or past each; the mode is also solved exactly there, "
                "as for analysis.epmc.amplitudes); empty: the points of "
                "analysis.masing.points (every point when that is empty too)", gt=0)
    amplitudes: tuple[float, ...] = spec(
        (), doc="modal amplitudes at which the mode is also solved exactly (Newton at fixed "
                "amplitude from the neighbouring branch points), written to "
                "/epmc/at_amplitudes; each within 10^log10_amplitude_start .. "
                "10^log10_amplitude_end", unit="m kg^0.5", gt=0)
    max_damping_change: float = spec(
        0.002, doc="step control: largest change of the damping ratio from one point to "
                   "the next (a step that changes it more is shrunk; resolves the slip "
                   "onset); 0: no limit", ge=0)
    max_frequency_change: float = spec(
        0.01, doc="step control: largest relative change of the frequency from one point "
                  "to the next; 0: no limit", ge=0)
    max_excess_damping_growth: float = spec(
        0.0, doc="step control: largest factor by which the damping ratio's excess over "
                 "the linear mode's (viscous) value may grow from one point to the next, "
                 "counted from 0.1 % of the viscous value: the step across the onset of "
                 "friction dissipation lands just past it (the corner of the damping "
                 "backbone on a log axis); 0: no limit, else > 1", ge=0)

    def check(self):
        if 0.0 < self.max_excess_damping_growth <= 1.0:
            return [("max_excess_damping_growth", "must be 0 (no limit) or > 1 (a factor), "
                                                  f"got {self.max_excess_damping_growth:g}")]
        return []


@dataclass(frozen=True, kw_only=True)
class TransientAnalysis:
    """Implicit time marching (generalized-alpha, Chung-Hulbert).

    Two runs exist.  With ``omega > 0`` the structure is forced by the scene's
    loads at ``omega`` until the period-to-period change falls below
    ``steady_tol`` (a *steady* run: harmonics, loops, energy balance).  With
    ``omega = 0`` it is released from a deflection of amplitude ``amplitude``
    along a linear mode and rings down (a *free-decay* run: amplitude-dependent
    frequency and damping).
    """

    rho_inf: float = spec(0.9, doc="spectral radius at infinite frequency (1: no numerical "
                                   "damping, 0: asymptotic annihilation)", ge=0, le=1)
    omega: float = spec(0.0, doc="forcing frequency (0: free decay)", unit="rad/s", ge=0)
    force_scale: float = spec(1.0, doc="multiplier of the harmonic loads (as "
                                       "analysis.hbm.force_scale)")
    steps_per_period: int = spec(256, doc="time steps per forcing period (free decay: per "
                                          "period of the linear mode)", ge=8)
    max_periods: int = spec(2000, doc="periods marched at most", ge=1)
    min_periods: int = spec(3, doc="periods marched at least (steady runs)", ge=2)
    steady_tol: float = spec(1e-6, doc="period-to-period change, relative to the vibration "
                                       "amplitude, that counts as steady", gt=0)
    start: str = spec("rest", choices=("rest", "linear"),
                      doc="steady runs: start at rest at the static equilibrium, or on the "
                          "steady response of the structure linearised with the joint stuck "
                          "(far less transient to wait for, e.g. in lightly damped or "
                          "free-free structures)")
    harmonics: tuple[int, ...] = spec((0, 1, 2, 3, 4, 5, 6, 7),
                                      doc="harmonics extracted from the last period "
                                          "(same order as /hbm/X)", ge=0)
    crosscheck_tol: float = spec(1e-3, doc="steady runs of a scene that also runs "
                                           "analysis.hbm: largest difference of a harmonic, "
                                           "relative to the first harmonic, that counts as "
                                           "agreement with HBM at the same frequency", gt=0)
    newton_tol: float = spec(1e-10, doc="Newton tolerance on the contact displacements, "
                                        "relative to their scale", gt=0)
    max_iter: int = spec(25, doc="Newton iterations per step before the step is cut", ge=1)
    max_cuts: int = spec(8, doc="times a failed step may be halved", ge=0, le=30)
    output_dofs: tuple[int, ...] = spec((), doc="DOFs whose time history is stored "
                                                "(default: the loaded DOFs and the model's "
                                                "named points)", ge=0)
    output_points: tuple[str, ...] = spec((), doc="named model points whose time history "
                                                  "is stored (FE models)")
    decimate: int = spec(1, doc="store every n-th step of the time history", ge=1)
    history_periods: int = spec(0, doc="store the time history of the last n periods "
                                       "only (0: all)", ge=0)
    mode: int = spec(1, doc="free decay: linear mode of the stuck joint to deflect along "
                            "(1-based, counted above rigid_cutoff_hz)", ge=1)
    amplitude: float = spec(0.0, doc="free decay: initial modal amplitude q0 = phi^T M x0 "
                                     "(phi mass-normalised)", unit="m kg^0.5", ge=0)
    rigid_cutoff_hz: Optional[float] = spec(
        None, doc="modes below this frequency are rigid-body (suspension) modes (default: "
                  "detected like analysis.modes.suspension_hz): a free decay does not count "
                  "them in `mode`, and a steady run leaves them out of the period-to-period "
                  "change", unit="Hz", ge=0)
    error_indicator: bool = spec(True, doc="steady runs: estimate the time-step error of "
                                           "the steady period (/transient/error_step: one "
                                           "linear solve of the harmonic-balance Jacobian)")
    error_tol: float = spec(1e-2, doc="steady runs: step-size error indicator (first "
                                      "harmonic, relative) above which a warning asks for "
                                      "more steps per period", gt=0)
    undamped_mode_zeta: float = spec(
        0.0, doc="steady runs: viscous damping ratio given to every mode of the stuck "
                 "structure that the scene's damping leaves undamped (their free vibration "
                 "otherwise decays only by the scheme's numerical dissipation and the march "
                 "is never periodic when the step is refined); HBM in the cross-check gets "
                 "the same damping. 0: off", ge=0, le=1)

    def check(self):
        if 1 not in self.harmonics:
            return [("harmonics", "must include harmonic 1")]
        if len(set(self.harmonics)) != len(self.harmonics):
            return [("harmonics", "must not repeat a harmonic")]
        hmax = max(self.harmonics)
        if self.steps_per_period < 2 * hmax + 1:
            return [("steps_per_period", f"must be >= 2*max(harmonics)+1 = {2 * hmax + 1}, "
                                         f"got {self.steps_per_period}")]
        if self.min_periods > self.max_periods:
            return [("min_periods", "must not exceed max_periods")]
        if self.omega == 0.0 and self.amplitude <= 0.0:
            return [("amplitude", "must be > 0 for a free decay (omega = 0)")]
        if self.omega > 0.0 and self.force_scale == 0.0:
            return [("force_scale", "must not be 0 for a forced run (omega > 0)")]
        return []


@dataclass(frozen=True, kw_only=True)
class QSMAAnalysis:
    """Quasi-static modal analysis (Lacayo and Allen)."""

    mode: int = spec(1, doc="elastic mode index (1-based; modes below rigid_cutoff_hz "
                            "are skipped)", ge=1)
    rigid_cutoff_hz: float = spec(20.0, doc="modes below this frequency are rigid-body "
                                            "(suspension) modes", unit="Hz", ge=0)
    log10_amplitude_start: float = spec(doc="log10 of the smallest modal amplitude")
    log10_amplitude_end: float = spec(doc="log10 of the largest modal amplitude")
    n_steps: int = spec(60, doc="load increments (geometric in the load factor)", ge=2)
    tol: float = spec(1e-10, doc="relative residual tolerance of each static solve", gt=0)


@dataclass(frozen=True, kw_only=True)
class Analyses:
    """The analyses a scene runs: each table present is one analysis."""

    masing: MasingAnalysis = spec(default_factory=MasingAnalysis)
    modes: Optional[ModesAnalysis] = spec(None)
    hbm: Optional[HBMAnalysis] = spec(None)
    epmc: Optional[EPMCAnalysis] = spec(None)
    transient: Optional[TransientAnalysis] = spec(None)
    qsma: Optional[QSMAAnalysis] = spec(None)
