"""Runner of ``[analysis.hbm]``: one FRC branch per force scale, written point by point.

File layout (all per solution point unless said otherwise):

* ``/hbm/omega`` [rad/s], ``/hbm/X`` [n_points, n_coeff, n_dof],
  ``/hbm/q`` (contact coordinates, used by ``--resume``), ``/hbm/branch``
  (index into ``/hbm/force_scale``), ``/hbm/amplitude`` (fundamental
  amplitude at the response DOF), ``/hbm/max_abs`` (``max_t |x(t)|`` there),
  ``/hbm/iterations``, ``/hbm/residual``, ``/hbm/step``,
  ``/hbm/aft_periods`` (largest number of periods the laws were marched),
  ``/hbm/linear_solves``, ``/hbm/krylov_iterations``, ``/hbm/preconditioners``
  (linear-algebra counts since the previous point; group attribute
  ``linear_solver``: ``"direct"`` or ``"krylov"``),
  ``/hbm/tangent``, ``/hbm/z_scale`` (the contact-coordinate scale the branch
  continues with, grown with the solution; used by ``--resume``), and the error
  indicators ``/hbm/error_*`` (:mod:`jointsim.solvers.indicators`; group
  attribute ``error_tol``);
* once: ``/hbm/harmonics``, ``/hbm/force_scale`` [n_branches], and per
  branch ``/hbm/peak_omega``, ``/hbm/peak_amplitude``, ``/hbm/peak_refined``;
  group attributes ``branch<b>_status`` / ``branch<b>_message``;
* ``/hbm/loops/*``, ``/hbm/masing/*`` for the points :func:`loop_rule` names:
  each branch's largest-amplitude point (``analysis.hbm.loops = "peaks"``, and
  the default ``"auto"`` when ``analysis.masing.points`` is empty), every
  point (``"all"``), or those listed in ``analysis.masing.points`` (global
  point indices).

``/hbm/amplitude`` and the peak use the measure ``analysis.hbm.amplitude``
(:func:`response_amplitude`), named in the group attribute
``amplitude_measure`` and in ``amplitude_definition``.

Branches run in forked worker processes when there are several (the parent writes
every point as it arrives, and computes the error indicators of the points the
workers still running leave to it once a core is free); a branch computed in the
parent itself sends its error indicators to forked workers instead
(:mod:`.indicator_pool`; the rows are NaN until they come back, ``--resume`` computes
rows left NaN).  The runner returns the solution points
(:class:`~jointsim.solvers.crosscheck.HBMSolutions`) for later analyses.
"""
from __future__ import annotations

import functools
import logging
import os
import time
from dataclasses import dataclass

import numpy as np

from .._schema import SceneError
from ..io.hbm_points import missing_error_indicators, write_error_indicators
from ..io.hdf5 import unit
from ..io.loops import write_loops
from ..masing import check_loops
from ..solvers.continuation import TARGET_ITER, continue_branch, next_step
from ..solvers.crosscheck import HBMSolutions
from ..harmonics import harmonic_amplitude
from ..solvers.frc_diagnosis import closing_advice, explain_branch_failure, sampled_reclosing
from ..solvers.frc import first_point, frc_scales, refine_peak
from ..solvers.hbm import HBMSystem
from ..solvers.indicators import ErrorEstimator, ToleranceWatch, safe_indicators
from ..solvers.jacobian import BorderedJacobian
from .forking import Deferral, _can_fork, _in_daemon, die_with_parent

log = logging.getLogger(__name__)


#: ``_explain_steep``: a residual this many times steeper than its Jacobian names the cause.
STEEP_RATIO = 100.0
#: ``_explain_steep`` forms a dense ``dR/dz``: only up to this many unknowns.
STEEP_MAX_UNKNOWNS = 4000
#: ``_grazing``: an element open over at most this many samples of the period grazes.
GRAZING_SAMPLES = 2


def run_hbm_analysis(scene, model, writer, results=None) -> HBMSolutions:
    """Runner of ``[analysis.hbm]``: one FRC branch per force scale, written point by point.

    The runner contract (arguments, ``results``) is in :mod:`jointsim.analyses`.

    Returns
    -------
    HBMSolutions
        Every solution point of the file's ``/hbm`` (stored ones on resume
        included), in file order.

    Raises
    ------
    RuntimeError
        After writing what was computed, when a branch gave up.
    """
    t_start = time.perf_counter()
    a = scene.analysis.hbm
    system = _system(model, a)
    dof = _response_dof(scene, model)
    g = _write_header(writer, a, model, system, dof)
    out = _Output(writer, scene, model, system, dof)
    todo = _branches_to_run(writer, a, g)
    job_args = dict(system=system, a=a, dof=dof,
                    want_aft=loop_rule(scene) in ("all", "masing.points"),
                    n_branches=len(a.force_scale),
                    keep_orientation=sampled_reclosing(scene.joint, scene.effects))
    n_workers = a.workers or min(len(todo), os.cpu_count() or 1)
    if not (n_workers > 1 and len(todo) > 1 and _can_fork() and not _in_daemon()):
        n_workers = 1
    if n_workers > 1:
        if a.error_indicators and missing_error_indicators(writer.h5, "hbm").size:
            # rows a killed run left NaN, before the branches fork: a serial pool
            # computes and writes each row as it is submitted, i.e. when it is made
            _indicator_pool(writer, a, system, 1).close()
        # the indicators of the points a worker defers once a core is free
        out.inds = _parent_indicators(writer, a, system, out.watch)
        system.prepare_forks(max(a.omega_start, a.omega_end))   # the workers share them
        failures = _run_branches_forked(todo, job_args, min(n_workers, len(todo)),
                                        out.write_point, out.finish_branch)
        if out.deferred:
            log.info("hbm: %d point(s)' error indicators computed here, on a free core",
                     out.deferred)
    else:
        failures = []
        # the branches here, their indicators on forked workers (workers 0: all cores, 1: none)
        with _indicator_pool(writer, a, system, a.workers) as out.inds:
            for job in todo:
                conv = _run_branch(job, on_record=out.write_point, progress=True,
                                   pooled=not out.inds.serial, **job_args)
                fail = out.finish_branch(job.ib, job.fs, conv.success, conv.message)
                if fail:
                    failures.append(fail)
            out.inds.finish()
    g.attrs["workers"] = n_workers if len(todo) > 1 else 1
    g.attrs["time_s"] = g.attrs.get("time_s", 0.0) + time.perf_counter() - t_start
    g.attrs["n_points"] = writer.rows("hbm/omega")
    if failures:
        raise RuntimeError("hbm: " + "; ".join(failures))
    return out.solutions()


#: analysis.hbm.amplitude -> its definition (the ``amplitude_definition`` attribute)
AMPLITUDE_MEASURES = {
    "fundamental": "fundamental harmonic amplitude sqrt(X_1c^2 + X_1s^2) at the response DOF",
    "rms": "RMS of x(t) over one period at the response DOF, all harmonics kept "
           "(sqrt(X_0^2 + sum_h (X_hc^2 + X_hs^2) / 2))",
    "peak_to_peak": "max x(t) - min x(t) at the response DOF over the AFT time samples",
}


def response_amplitude(basis, x, measure: str = "fundamental") -> float:
    """Amplitude of one DOF's periodic response by a named measure.

    Parameters
    ----------
    basis : jointsim.harmonics.HarmonicBasis
    x : ndarray, shape (n_coeff,)
        Harmonic coefficients of the DOF, order ``[0, 1c, 1s, ...]`` [m].
    measure : {'fundamental', 'rms', 'peak_to_peak'}
        See :data:`AMPLITUDE_MEASURES`.

    Returns
    -------
    float
        The amplitude [m].
    """
    x = np.asarray(x, dtype=float)
    if measure == "fundamental":
        return float(harmonic_amplitude(basis, x))
    if measure == "rms":
        w = np.where(np.asarray(basis.hk) == 0, 1.0, 0.5)
        return float(np.sqrt(np.sum(w * x * x)))
    if measure == "peak_to_peak":
        t = basis.samples(x)
        return float(t.max() - t.min())
    raise ValueError(f"unknown amplitude measure {measure!r}; known: "
                     f"{', '.join(AMPLITUDE_MEASURES)}")


def loop_rule(scene) -> str:
    """Which FRC points keep their element loops and Masing checks.

    Returns
    -------
    str
        ``"peaks"`` (each branch's largest point), ``"all"`` or
        ``"masing.points"``; ``analysis.hbm.loops = "auto"`` is
        ``"masing.points"`` when ``analysis.masing.points`` is set, else
        ``"peaks"`` (the loops of every point cost about 40 % of a small FRC).
    """
    rule = scene.analysis.hbm.loops
    if rule == "auto":
        return "masing.points" if scene.analysis.masing.points else "peaks"
    return rule


def _system(model, a, parallel: bool = True, lin=None) -> HBMSystem:
    """The condensed HBM system of ``[analysis.hbm]`` settings ``a`` (the condensation
    ``lin`` of another system of the model when given).

    ``parallel=False`` keeps the AFT kernels off numba threads (worker processes).
    """
    return HBMSystem(model, a.harmonics, a.n_samples, a.min_periods, a.max_periods,
                     parallel=parallel, linear_solver=a.linear_solver, lin=lin)


def _response_dof(scene, model) -> int:
    """The response DOF of the FRC (``response_point`` or ``response_dof``)."""
    a = scene.analysis.hbm
    if a.response_point:
        if a.response_point not in model.points:
            raise SceneError(str(scene.path), "analysis.hbm.response_point",
                             f"{a.response_point!r} is not a named point of the model "
                             f"(named: {sorted(model.points)})")
        return int(model.points[a.response_point])
    if not 0 <= a.response_dof < model.n_dof:
        raise SceneError(str(scene.path), "analysis.hbm.response_dof",
                         f"= {a.response_dof} is out of range (the model has {model.n_dof} "
                         f"DOFs)")
    return a.response_dof


def _write_header(writer, a, model, system, dof):
    """The ``/hbm`` group, its attributes and the datasets written once."""
    units = model.units
    g = writer.group("hbm", n_samples=a.n_samples, response_dof=dof,
                     response_label=str(model.dof_labels[dof]) if model.dof_labels else "",
                     omega_start=a.omega_start, omega_end=a.omega_end,
                     n_contact_coordinates=system.n_r, condensation=system.lin.kind,
                     linear_solver=system.linear_solver, n_unknowns=system.n_z,
                     amplitude_measure=a.amplitude,
                     amplitude_definition=AMPLITUDE_MEASURES[a.amplitude],
                     error_tol=a.error_tol)
    if "hbm/harmonics" not in writer.h5:
        writer.write("hbm/harmonics", np.array(a.harmonics, dtype=np.int64), "1",
                     "harmonics kept; coefficient order [0, 1c, 1s, 2c, 2s, ...]")
        writer.write("hbm/force_scale", np.array(a.force_scale, dtype=float), "1",
                     "multiplier of the excitation of each branch")
        writer.write("hbm/coefficient_harmonic", system.basis.hk, "1",
                     "harmonic of each coefficient")
    if "contacts/area" not in writer.h5 and model.contacts.n_elements:
        writer.write("contacts/area", model.contacts.area, "m^2" if units == "SI" else "length^2",
                     "contact area of each element")
    return g


class _Output:
    """Writes the points and branch summaries of ``/hbm`` and keeps the points in memory.

    On resume the points already stored are loaded first, so that
    :meth:`solutions` holds every point of the file, in file order.
    """

    def __init__(self, writer, scene, model, system, dof):
        a = self.a = scene.analysis.hbm
        self.writer, self.scene, self.model, self.system, self.dof = \
            writer, scene, model, system, dof
        self.units = model.units
        self.rule = loop_rule(scene)
        self.masing_points = set(scene.analysis.masing.points) \
            if self.rule == "masing.points" else set()
        n_br = len(a.force_scale)
        self.peaks = {k: np.full(n_br, np.nan) for k in ("omega", "amplitude")}
        self.refined = np.zeros(n_br, dtype=bool)
        self.watch = ToleranceWatch(a.error_tol, "hbm")
        #: the indicator pool of the points computed in this process (set by the runner),
        #: and the number of points whose indicators a branch worker left to it
        self.inds, self.deferred = None, 0
        h5 = writer.h5
        for name in ("omega", "amplitude"):
            if f"hbm/peak_{name}" in h5:
                self.peaks[name][:] = h5[f"hbm/peak_{name}"][()]
        if "hbm/peak_refined" in h5:
            self.refined[:] = h5["hbm/peak_refined"][()]
        # the points, in memory (stored ones first when resuming)
        self.points = {k: [] for k in ("omega", "X", "q", "branch", "amplitude")}
        if "hbm/omega" in h5:
            for k in self.points:
                self.points[k] = list(h5[f"hbm/{k}"][()])

    def write_point(self, rec) -> None:
        """Append one solution point (a record from :func:`_point_record`)."""
        writer, units = self.writer, self.units
        d_u, w_u = unit("displacement", units), unit("angular_frequency", units)
        with writer.commit():  # every dataset of the point, its loops: all or nothing
            p = writer.rows("hbm/omega")
            writer.append("hbm/omega", rec["omega"], w_u, "angular frequency of the point")
            writer.append("hbm/X", rec["X"], d_u, "harmonic coefficients [n_coeff, n_dof]")
            writer.append("hbm/q", rec["q"], d_u, "coefficients of the contact coordinates")
            writer.append("hbm/branch", np.int64(rec["branch"]), "1",
                          "branch (force level) of the point")
            writer.append("hbm/amplitude", rec["amplitude"], d_u,
                          f"amplitude ({self.a.amplitude}) at the response DOF")
            writer.append("hbm/max_abs", rec["max_abs"], d_u,
                          "max |x(t)| at the response DOF over the AFT samples")
            writer.append("hbm/iterations", np.int64(rec["iterations"]), "1",
                          "Newton iterations of the corrector")
            writer.append("hbm/residual", rec["residual"], "1",
                          "max |R| / residual scale at the point")
            writer.append("hbm/step", rec["step"], "1", "scaled arclength step to the point")
            writer.append("hbm/tangent", rec["tangent"], "1", "unit tangent (scaled variables)")
            writer.append("hbm/z_scale", rec["z_scale"], d_u,
                          "scale of the contact coordinates the branch continues from the "
                          "point with (grows with the solution; used by --resume)")
            writer.append("hbm/aft_periods", np.int64(rec["aft_periods"]), "1",
                          "largest number of periods the laws were marched")
            writer.append("hbm/linear_solves", np.int64(rec["linear_solves"]), "1",
                          "linear solves (Newton steps and tangents) since the previous point")
            writer.append("hbm/krylov_iterations", np.int64(rec["krylov_iterations"]), "1",
                          "GMRES iterations summed over those solves (0: direct solver)")
            writer.append("hbm/preconditioners", np.int64(rec["preconditioners"]), "1",
                          "harmonic preconditioners factorised since the previous point")
            # computed elsewhere: on the pool, or here for a point its worker deferred
            deferred = rec.get("deferred", False)
            self.deferred += deferred
            pooled = self.a.error_indicators and self.inds is not None \
                and (not self.inds.serial or deferred)
            if self.a.error_indicators:
                write_error_indicators(writer, "hbm", p, rec.get("errors"))
                if not pooled:
                    self.watch.check(rec["branch"], rec.get("errors"), p,
                                     f"omega = {rec['omega']:.6g}")
            for k in self.points:
                self.points[k].append(rec[k])
            if rec.get("f") is not None and (not self.masing_points or p in self.masing_points):
                self._write_loops(p, rec["X"], rec["f"], rec["N"])
        if pooled:
            self.inds.submit(p, (rec["q"], rec["omega"], rec["branch"]),
                             f"omega = {rec['omega']:.6g}", branch=rec["branch"])

    def _has_loops(self, p: int) -> bool:
        """Whether the file already holds the element loops of point ``p``."""
        h5 = self.writer.h5
        return "hbm/loops/point" in h5 and bool(np.any(h5["hbm/loops/point"][()] == p))

    def _write_loops(self, p, X, f, N) -> None:
        """Element loops of point ``p`` and their Masing check."""
        u = self.system.slips(X)
        report = check_loops(u, f, N, self.model.contacts.law, self.scene.analysis.masing.tol)
        write_loops(self.writer, p, u, f, N, report, self.units, prefix="hbm")
        self.writer.h5["hbm/loops"].attrs["analysis"] = "hbm"

    def _explain(self, message, F, rows) -> str:
        """A failed branch's message, with the residual jump of a law without path
        continuity (:func:`jointsim.solvers.discontinuity.explain_failure`)."""
        from ..contact.laws import continuation_advice
        from ..solvers.discontinuity import explain_failure

        system = self.system
        advice = continuation_advice(self.model.contacts.law, system.coupled)
        if not advice:
            return self._explain_steep(message, F, rows)
        Z, om = np.asarray(self.points["q"])[rows], np.asarray(self.points["omega"])[rows]
        y = np.column_stack([Z, om])
        return explain_failure(
            message, advice,
            lambda v: system.evaluate(v[:-1], float(v[-1]), F, jacobian=False).R,
            y[-2] if len(y) > 1 else None, y[-1])

    def _explain_steep(self, message, F, rows) -> str:
        """A failed branch of a slipping law with a coupled, separating contact: say when
        the residual is nearly discontinuous one step past the last point (issue 13
        case 5: a huge ``mu`` switches a clapping element between free and stuck within
        a change of ``N`` of about ``kt |u - w| / mu``), measured by
        :func:`jointsim.solvers.discontinuity.steepness` (on the fold scene at
        ``mu = 1e6`` the Jacobian agrees with finite differences at the point; README
        "Hard cases")."""
        from ..solvers.discontinuity import steepness

        system, law, joint = self.system, self.model.contacts.law, self.scene.joint
        if not (system.coupled and law.can_slip and self.scene.effects.separation) \
                or rows.size < 2 or "corrector failed" not in message \
                or system.n_z > STEEP_MAX_UNKNOWNS:
            return message
        Z, om = np.asarray(self.points["q"])[rows], np.asarray(self.points["omega"])[rows]
        y = np.column_stack([Z, om])

        def fun(v):
            return system.evaluate(v[:-1], float(v[-1]), F, jacobian=False).R

        def jac(v):
            ev = system.evaluate(v[:-1], float(v[-1]), F, wrt=("omega",), J_out=np.zeros(
                (system.n_z, system.n_z)))
            return np.column_stack([ev.J, ev.dR["omega"].ravel()])

        ratio = steepness(fun, jac, y[-1], 2.0 * y[-1] - y[-2])
        if ratio < STEEP_RATIO:
            return message
        head = (f"{message}; one secant step past the last point the residual changes "
                f"{ratio:.3g} times faster than the Jacobian at the point predicts: it is "
                f"nearly discontinuous there, and neither Newton nor a smaller step passes.  ")
        if system.aft.closing == "sample":
            return (head + f"At each clap of this separating contact the slip force mu N "
                    f"switches the element from free (N = 0) to stuck within a change of N of "
                    f"kt |u - w| / mu, so with joint.mu = {joint.mu:g} the element sticks "
                    f"within about one time sample of closing and its anchor jumps when the "
                    f"first closed sample of the AFT grid changes (the mu -> infinity limit "
                    f"of a clapping contact: physics of the model, not a numerical defect); "
                    f"set joint.closing = 'interpolated' (the anchor at the closing instant "
                    f"between samples), lower joint.mu so that the element slips over "
                    f"several samples after each closure, or compute this response by time "
                    f"marching")
        return head + self._grazing(F, y, joint.mu)

    def _grazing(self, F, y, mu) -> str:
        """Cause of a nearly discontinuous residual under ``joint.closing =
        'interpolated'`` (closing and opening instants between samples resolved): a
        clap that appears or vanishes (a grazing contact) while the element never slips
        (issue 13 case 5: the fold scene at mu = 1e6 stops at omega = 1.47596, where
        the last clap vanishes)."""
        system = self.system
        fs = []
        for v in (y[-1], 2.0 * y[-1] - y[-2]):
            ev = system.evaluate(v[:-1], float(v[-1]), F, jacobian=False)
            fs.append(ev.aft)
        n_t = fs[0].N.shape[1]
        opens = [np.sum(a.N <= 0.0, axis=1) for a in fs]        # open samples per element
        few = [np.flatnonzero((o > 0) & (o <= GRAZING_SAMPLES)) for o in opens]
        vanish = np.flatnonzero((opens[0] > 0) != (opens[1] > 0))
        lam = float(y[-1][-1])
        if len(few[0]) == 0 and len(few[1]) == 0 and len(vanish) == 0:
            return ("The closing and opening instants of this separating contact are "
                    "interpolated between samples, and the residual is still nearly "
                    "discontinuous here; lower joint.mu, or compute this response by time "
                    "marching")
        e = int((list(vanish) + list(few[0]) + list(few[1]))[0])
        where = (f"at the last point element {e} opens over {int(opens[0][e])} of {n_t} "
                 f"samples, one secant step on over {int(opens[1][e])}")
        width = float(np.abs(fs[0].f[e]).max()) / mu if mu > 0 else float("inf")
        return (f"A clap vanishes (or appears) here: {where} (a grazing contact).  With "
                f"joint.mu = {mu:g} the element never slips while closed, and a contact "
                f"that sticks and never opens keeps whatever anchor it has: every anchor is "
                f"a periodic state.  The branch arrives with the anchor of its last clap; "
                f"where the contact no longer opens, the AFT marches the law from rest (the "
                f"anchor of the static state).  For a finite mu the two join within a change "
                f"of the smallest normal load of about kt |u - w| / mu = {width:.1e}, so the "
                f"response changes almost discontinuously where the last clap vanishes (as "
                f"mu -> infinity it jumps: physics of a contact that never slips, whose "
                f"steady state depends on its history, not a numerical defect).  Run the "
                f"branch from the other end of the range (swap analysis.hbm.omega_start and "
                f"omega_end: a clapping family that ends at lam = {lam:.8g} is often reached "
                f"there from the other side), lower joint.mu so that the element slips "
                f"where its normal load is smallest, or follow the history by time "
                f"marching")

    def finish_branch(self, ib, fs, success, message, failed_truncations=0) -> str | None:
        """Status, peak and peak loops of a finished branch; the failure, if any
        (``failed_truncations``: a worker's, :attr:`.PreconditionerCache.failed_truncations`)."""
        a, system, writer, units = self.a, self.system, self.writer, self.units
        cache = system.preconditioner
        cache.failed_truncations = max(cache.failed_truncations, failed_truncations)
        F = system.force_coefficients(fs)
        rows = np.flatnonzero(np.asarray(self.points["branch"]) == ib) \
            if self.points["branch"] else np.zeros(0, dtype=np.int64)
        if rows.size:
            om = np.asarray(self.points["omega"])[rows]
            amp = np.asarray(self.points["amplitude"])[rows]
            Z = np.asarray(self.points["q"])[rows]
            if a.refine_peak:
                t0 = time.perf_counter()
                pw, pa, ok, st = refine_peak(
                    system, F, om, Z, amp, self.dof, min(a.tol, 1e-10),
                    amplitude_of=lambda X: response_amplitude(system.basis, X[:, self.dof],
                                                              a.amplitude))
                log.info("hbm branch %d: peak %s (%d Newton solves, %d iterations, %d "
                         "frequencies failed; %.1f s): %.6g at omega = %.8g", ib,
                         "refined" if ok else "not refined", st["solves"], st["iterations"],
                         st["failed"], time.perf_counter() - t0, pa, pw)
            else:
                i = int(np.argmax(amp))
                pw, pa, ok = float(om[i]), float(amp[i]), False
            self.peaks["omega"][ib], self.peaks["amplitude"][ib], self.refined[ib] = pw, pa, ok
            with writer.commit():   # the peak loops and tables: all or nothing
                i = int(np.argmax(amp))
                if self.rule == "peaks" and not self._has_loops(int(rows[i])):
                    # the element loops and Masing checks of the branch's largest point
                    # (once: a run stopped after this commit, before the branch's
                    # status, finishes the branch again on --resume)
                    ev = system.evaluate(Z[i], float(om[i]), F, jacobian=False)
                    if ev.aft is not None:   # None: no contact unknowns (a linear joint)
                        X = system.reconstruct(Z[i], float(om[i]), F)
                        self._write_loops(int(rows[i]), X, ev.aft.f, ev.aft.N)
                d_u, w_u = unit("displacement", units), unit("angular_frequency", units)
                writer.write("hbm/peak_omega", self.peaks["omega"], w_u,
                             "frequency of the largest amplitude of each branch")
                writer.write("hbm/peak_amplitude", self.peaks["amplitude"], d_u,
                             f"largest amplitude ({a.amplitude}) of each branch")
                writer.write("hbm/peak_refined", self.refined, "1", "peak refined by "
                             "maximising over frequency (false: largest computed point, "
                             "e.g. at a fold)")
        if not success and rows.size:
            message = closing_advice(self.scene.joint, self.scene.effects,
                                     self._explain(message, F, rows))
        # the status last: a branch marked finished has its peak and loops in the file
        # ("worker died" is not final: --resume computes the branch on)
        writer.group("hbm", **{f"branch{ib}_message": message, f"branch{ib}_status":
                               "complete" if success else ("worker died" if message.startswith(
                                   "worker process ended") else "gave up")})
        log.info("hbm branch %d (force scale %g): %s; peak %.6g at omega = %.6g", ib, fs,
                 message, self.peaks["amplitude"][ib], self.peaks["omega"][ib])
        return None if success else f"branch {ib} (force scale {fs:g}): {message}"

    def solutions(self) -> HBMSolutions:
        """Every point written (and stored before, on resume), in file order."""
        s = self.system
        pts = self.points
        n = len(pts["omega"])
        return HBMSolutions(
            omega=np.asarray(pts["omega"], dtype=float),
            X=np.asarray(pts["X"], dtype=float).reshape(n, s.n_c, s.model.n_dof),
            harmonics=tuple(int(h) for h in self.a.harmonics), n_samples=int(self.a.n_samples),
            q=np.asarray(pts["q"], dtype=float).reshape(n, s.n_z),
            branch=np.asarray(pts["branch"], dtype=np.int64),
            force_scale=np.array(self.a.force_scale, dtype=float))


def _branches_to_run(writer, a, g) -> list:
    """The branches still to compute, with their resume points."""
    todo = []
    for ib, fs in enumerate(a.force_scale):
        status = g.attrs.get(f"branch{ib}_status", "")
        if status in ("complete", "gave up"):
            log.info("hbm branch %d (force scale %g) already %s; skipped", ib, fs, status)
            continue
        rows = np.flatnonzero(writer.h5["hbm/branch"][()] == ib) \
            if "hbm/branch" in writer.h5 else np.zeros(0, dtype=np.int64)
        start = None
        if rows.size:
            last = int(rows[-1])
            # the step the uninterrupted branch takes next (the first point: a.step)
            h_last = float(writer.h5["hbm/step"][last])
            h_next = next_step(h_last, int(writer.h5["hbm/iterations"][last]), TARGET_ITER,
                               a.step_min, a.step_max) if h_last > 0 else a.step
            z_scale = float(writer.h5["hbm/z_scale"][last]) if "hbm/z_scale" in writer.h5 \
                else 0.0
            start = (np.append(writer.h5["hbm/q"][last], writer.h5["hbm/omega"][last]),
                     writer.h5["hbm/tangent"][last], h_next, int(rows.size), z_scale)
            log.info("hbm branch %d: resuming from point %d (omega = %g)", ib, last,
                     start[0][-1])
        todo.append(_BranchJob(ib, fs, start))
    return todo


@dataclass(frozen=True)
class _BranchJob:
    """One FRC branch to compute: its index, force scale and resume point."""

    ib: int
    fs: float
    start: tuple | None  # (y0, tangent, step, rows stored, z scale) when resuming


def _point_record(system, F, y, info, ib, dof, want_aft, measure="fundamental",
                  estimator=None) -> dict:
    """Everything written for one solution point (plain arrays, picklable); with an
    :class:`~jointsim.solvers.indicators.ErrorEstimator`, its indicators (``errors``)."""
    b = system.basis
    w = float(y[-1])
    X = system.reconstruct(y[:-1], w, F)
    errors = safe_indicators(estimator.hbm, y[:-1], w, F, X) if estimator is not None \
        else None
    aft = info.extra.aft if info.extra is not None else None
    solves, krylov_it, factorizations = system.stats.take()
    return dict(errors=errors, linear_solves=solves, krylov_iterations=krylov_it,
                preconditioners=factorizations, omega=w, X=X, q=np.array(y[:-1]), branch=ib,
                amplitude=float(response_amplitude(b, X[:, dof], measure)),
                max_abs=float(np.abs(b.samples(X[:, dof])).max()),
                iterations=int(info.iterations), residual=float(info.residual),
                step=float(info.step), tangent=np.array(info.tangent),
                z_scale=float(info.z_scale),
                aft_periods=int(aft.periods.max()) if aft is not None else 0,
                f=np.array(aft.f) if (want_aft and aft is not None) else None,
                N=np.array(aft.N) if (want_aft and aft is not None) else None)


def _run_branch(job, *, system, a, dof, want_aft, n_branches, on_record, progress,
                keep_orientation=False, pooled=False, defer=None):
    """Follow one FRC branch; every accepted point goes to ``on_record(record)``
    (with its error indicators, unless ``pooled``: the caller's pool computes them;
    or when the :class:`~jointsim.analyses.forking.Deferral` ``defer`` lets it: the
    record is marked ``deferred`` and the parent computes them,
    :func:`_run_branches_forked`).

    Returns
    -------
    Convergence
    """
    t_branch = time.perf_counter()
    system.preconditioner.single_inverses = False    # set for the continuation, below
    F = system.force_coefficients(job.fs)
    scale, rscale = frc_scales(system, F, a.omega_start, a.omega_end)
    system.stats.take()          # the scales' solves are not a point's
    if job.start is not None:
        y0, t0, h0, n_stored, z_scale = job.start
        solve_first, max_pts = False, a.max_points - n_stored + 1
        if z_scale > 0.0:   # the z scale the uninterrupted branch had grown to
            scale = scale.copy()
            scale[:-1] = z_scale
    else:
        # the first point: Newton from the static state, else a force homotopy
        first = first_point(system, a.omega_start, job.fs, scale=scale, rscale=rscale,
                            tol=a.tol, max_iter=a.max_iter, step_min=a.step_min,
                            desc=f"hbm branch {job.ib + 1}/{n_branches} (x{job.fs:g})")
        if not first.convergence.success:
            return first.convergence
        y0 = np.append(first.z, a.omega_start)
        t0, h0, solve_first, max_pts, n_stored = None, a.step, False, a.max_points, 0
    nz = system.n_z
    estimator = _estimator(system, a, system.aft.parallel) \
        if a.error_indicators and not pooled else None
    # the continuation's preconditioners may keep single-precision harmonic inverses
    # (preconditioner.SINGLE_INVERSE_MIN); not the scales' and first point's solves
    system.preconditioner.single_inverses = True

    def fun(y):
        if system.krylov:
            ev = system.evaluate(y[:-1], y[-1], F)
            return ev.R, BorderedJacobian(ev.J, ev.dR["omega"]), ev
        J = np.zeros((nz, nz + 1))
        ev = system.evaluate(y[:-1], y[-1], F, J_out=J[:, :nz])
        J[:, nz] = ev.dR["omega"]
        return ev.R, J, ev

    def on_point(i, y, info):
        if n_stored and i == 0:   # resumed: the first point is the stored last one
            return
        if i == 0 and job.start is None:
            info.iterations = first.iterations
        deferred = estimator is not None and defer is not None and defer.take(job.ib)
        rec = _point_record(system, F, y, info, job.ib, dof, want_aft, a.amplitude,
                            None if deferred else estimator)
        rec["deferred"] = deferred
        on_record(rec)

    try:
        br = continue_branch(
            fun, y0, a.omega_end, scale=scale, rscale=rscale, step=h0, step_min=a.step_min,
            step_max=a.step_max, max_points=max_pts, tol=a.tol, max_iter=a.max_iter,
            solve_first=solve_first, tangent0=t0, on_point=on_point, progress=progress,
            desc=f"hbm branch {job.ib + 1}/{n_branches} (x{job.fs:g})", lam_start=a.omega_start,
            adapt_scale=True, z_origin=system.static_coordinates(),
            keep_orientation=keep_orientation)
    finally:
        system.preconditioner.single_inverses = False
    log.info("hbm branch %d/%d (force scale %g): %d points in %.1f s", job.ib + 1, n_branches,
             job.fs, len(br.y), time.perf_counter() - t_branch)
    if len(br.y) >= max_pts:        # stopped at max_points: no physics to diagnose
        return br.convergence
    return explain_branch_failure(br.convergence, system, F, a.omega_start, a.omega_end,
                                  float(br.y[-1][-1]))


def _estimator(system, a, parallel: bool) -> ErrorEstimator:
    """The error estimator of the FRC points: their error across the branch is solved
    where the fixed-frequency estimate exceeds ``a.error_tol`` (the points it would mark;
    none when the tolerance is 0)."""
    return ErrorEstimator(system, parallel=parallel,
                          curve_above=a.error_tol if a.error_tol > 0 else np.inf)


def _indicator_pool(writer, a, system, workers):
    """The FRC points' error indicators (:class:`~.indicator_pool.PointIndicators`): on
    ``workers`` forked workers (:func:`~.indicator_pool.pool_workers`), or serially when
    that is 1.  Stored rows left NaN (a killed run) are submitted first."""
    from ..io.hbm_points import pad_error_indicators
    from .indicator_pool import PointIndicators, pool_workers

    if not a.error_indicators or not system.n_z:
        return PointIndicators(writer, "hbm", None, ToleranceWatch(a.error_tol, "hbm"), 1)
    missing = missing_error_indicators(writer.h5, "hbm")
    n = pool_workers(workers, n_unknowns=system.n_z)
    writer.h5["hbm"].attrs["indicator_workers"] = n
    if n == 1 and not missing.size:   # serial: each branch computes its own
        return PointIndicators(writer, "hbm", None, ToleranceWatch(a.error_tol, "hbm"), 1)
    estimator = _estimator(system, a, n == 1 and system.aft.parallel)
    for s in (estimator, system):     # before a fork, shared: the extended one serves both
        s.prepare_forks(max(a.omega_start, a.omega_end))
    forces = {ib: system.force_coefficients(fs) for ib, fs in enumerate(a.force_scale)}
    inds = PointIndicators(
        writer, "hbm", lambda z, w, ib: safe_indicators(estimator.hbm, z, w, forces[ib]),
        ToleranceWatch(a.error_tol, "hbm"), n)
    if missing.size:
        log.info("hbm: computing the error indicators of %d stored point(s)", missing.size)
        with writer.commit():
            pad_error_indicators(writer, "hbm")
        h5 = writer.h5
        om, br = h5["hbm/omega"][()], h5["hbm/branch"][()]
        for p in missing:
            inds.submit(int(p), (h5["hbm/q"][int(p)], float(om[p]), int(br[p])),
                        f"omega = {om[p]:.6g}", branch=int(br[p]))
    return inds


def _parent_indicators(writer, a, system, watch):
    """The indicators of the points the branch workers defer (:func:`_run_branches_forked`),
    computed in this process as each point is written, on one thread (a serial copy of
    ``system`` and its estimator, built on the first one); None without indicators."""
    from .indicator_pool import PointIndicators

    if not a.error_indicators:
        return None
    forces = [system.force_coefficients(fs) for fs in a.force_scale]
    est = functools.cache(lambda: _estimator(
        _system(system.model, a, parallel=False, lin=system.lin), a, parallel=False))
    return PointIndicators(writer, "hbm", lambda z, w, ib: safe_indicators(
        est().hbm, z, w, forces[ib]), watch, 1)


def _branch_process(job, job_args, queue, parent_pid, defer=None) -> None:
    """Body of a worker process: compute a branch, send its points to the parent.

    The workers are the parallelism: each builds its own system with ``parallel=False``
    (on the parent's condensation, made before the fork): its AFT kernels stay on one
    thread (no numba thread pool in a forked process, no oversubscribed cores).  Once a
    core is free the worker leaves some of its points' error indicators to the parent
    (``defer``, :class:`~jointsim.analyses.forking.Deferral`).  It dies with its parent
    (:func:`die_with_parent`).
    """
    die_with_parent(parent_pid)
    try:
        serial = _system(job_args["system"].model, job_args["a"], parallel=False,
                         lin=job_args["system"].lin)
        conv = _run_branch(job, on_record=lambda rec: queue.put(("point", job.ib, rec)),
                           progress=False, defer=defer, **dict(job_args, system=serial))
        queue.put(("done", job.ib, (conv.success, conv.message,
                                    serial.preconditioner.failed_truncations)))
    except BaseException as exc:  # reported to the parent, which keeps the file valid
        queue.put(("done", job.ib, (False, f"worker failed: {type(exc).__name__}: {exc}")))


def _run_branches_forked(todo, job_args, n_workers, write_point, finish_branch):
    """Compute branches in forked worker processes; the parent writes every point.

    Points arrive through a queue and are written as they come, so the file
    grows point by point as in a serial run (rows of different branches
    interleave; ``/hbm/branch`` tells them apart).  A worker that dies without
    a word is reported as a failed branch.

    Once no branch is left to start and a worker's core is free, the workers still
    running leave the error indicators of some of their next points to the parent
    (the record's ``deferred``; ``write_point`` computes them on that core; at most
    :data:`~jointsim.analyses.forking.DEFER_BACKLOG` at a time,
    :class:`~jointsim.analyses.forking.Deferral`): with three branches on two workers
    the last one used to run alone, its indicators included.
    A point's indicators do not depend on where or after which point they are
    computed (:data:`~jointsim.solvers.indicators.REUSE_ACROSS_POINTS`), so the file
    is the same.
    """
    import multiprocessing as mp
    import queue as queue_mod

    from tqdm import tqdm
    ctx = mp.get_context("fork")
    q = ctx.Queue()
    defer = Deferral(ctx, 1 + max(job.ib for job in todo))
    # the largest force scale first (longest branch first: gross slip costs the most
    # per point), so that the short ones fill the other workers; the branches and the
    # file's rows do not depend on the order (issue 10)
    pending = sorted(todo, key=lambda job: -abs(float(job.fs)))
    running: dict[int, tuple] = {}
    failures: list[str] = []
    bar = tqdm(desc=f"hbm ({n_workers} workers)", unit="pt", disable=None, leave=False)
    log.info("hbm: %d branches on %d worker processes", len(todo), n_workers)
    try:
        while pending or running:
            while pending and len(running) < n_workers:
                job = pending.pop(0)
                proc = ctx.Process(target=_branch_process,
                                   args=(job, job_args, q, os.getpid(), defer), daemon=True)
                proc.start()
                running[job.ib] = (job, proc)
            if not pending and 0 < len(running) < n_workers and not defer.started:
                defer.start()
                log.info("hbm: a core is free: the error indicators of branch(es) %s are "
                         "computed in this process", sorted(running))
            try:
                kind, ib, payload = q.get(timeout=1.0)
            except queue_mod.Empty:
                for ib, (job, proc) in list(running.items()):
                    if not proc.is_alive() and q.empty():
                        del running[ib]
                        failures.append(finish_branch(
                            ib, job.fs, False, f"worker process ended (exit code "
                                               f"{proc.exitcode}) without finishing"))
                continue
            if kind == "point":
                write_point(payload)
                if payload.get("deferred"):
                    defer.computed()
                bar.update(1)
            else:
                job, proc = running.pop(ib)
                proc.join()
                fail = finish_branch(ib, job.fs, *payload)
                if fail:
                    failures.append(fail)
    finally:
        bar.close()
        for job, proc in running.values():
            proc.terminate()
        for job, proc in running.values():
            # a forked worker shares the result file's descriptor (and its lock)
            # until it is gone
            proc.join(timeout=10)
    return [f for f in failures if f]
