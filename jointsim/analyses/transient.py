"""Runner of ``[analysis.transient]``: time marching, written to ``/transient``.

A forced steady state (``omega > 0``, :func:`jointsim.solvers.transient.march_steady`)
writes its last period, harmonics, loops and their Masing check, and, when the
scene also ran harmonic balance, the cross-check against it
(:mod:`jointsim.analyses.crosscheck`, with the HBM result in memory); a free
decay (:func:`jointsim.solvers.transient.free_decay`) writes the
amplitude-dependent frequency and damping.  The time history of chosen DOFs is
written as the march goes (:class:`_History`).

Resume (issue 11): a forced march commits, with each period's history rows
and period change, a checkpoint row ``/transient/checkpoint/state`` holding
the exact march state at the start of that period (displacement, velocity,
acceleration, contact forces and law state, time, step counters:
:class:`_Checkpoints`).  ``--resume`` marches the last stored period again
from its row (the last ``history_periods`` periods, when only those are
kept) without writing it, then goes on: the resumed file equals the
uninterrupted one (the same arithmetic from the same state).  A free decay
keeps no checkpoint: ``--resume`` marches it again from the start.
"""
from __future__ import annotations

import collections
import dataclasses
import logging

import numpy as np

from ..io.hdf5 import unit
from ..io.loops import write_loops
from ..masing import check_loops
from ..results import INTERRUPTED, Convergence
from ..solvers.contact_map import ContactEval
from ..solvers.generalized_alpha import MarchState, StepStats
from ..solvers.march_accuracy import undamped_modes, with_mode_damping
from ..solvers.transient import MarchResume, PeriodData, free_decay, march_steady
from .crosscheck import write_cross_check

log = logging.getLogger(__name__)


def output_dofs(scene, model, settings):
    """DOFs whose time history is stored, with their labels.

    ``output_dofs`` plus the DOFs of ``output_points``; by default the loaded
    DOFs and the model's named points, or every DOF of a model with at most
    16 DOFs when there is neither.

    Returns
    -------
    dofs : ndarray of int, shape (n_out,)
    labels : list of str
    """
    dofs = [int(d) for d in settings.output_dofs]
    for i, name in enumerate(settings.output_points):
        if name not in model.points:
            known = ", ".join(sorted(model.points)) or "none"
            raise ValueError(f"{scene.path if scene is not None else '<scene>'}: "
                             f"analysis.transient.output_points[{i}] = {name!r} is not a "
                             f"point of the model (known: {known})")
        dofs.append(int(model.points[name]))
    for i, d in enumerate(dofs):
        if not 0 <= d < model.n_dof:
            raise ValueError(f"analysis.transient.output_dofs[{i}] = {d} is not a DOF of the "
                             f"model ({model.n_dof} DOFs)")
    if not dofs:
        dofs = [int(d) for d in model.load_dofs] + [int(d) for d in model.points.values()]
    if not dofs and model.n_dof <= 16:
        dofs = list(range(model.n_dof))
    dofs = list(dict.fromkeys(dofs))  # unique, in order
    labels = [model.dof_labels[d] if d < len(model.dof_labels) else f"x{d}" for d in dofs]
    return np.asarray(dofs, dtype=np.int64), labels


class _History:
    """Decimated time history of chosen DOFs, written period by period.

    With ``keep_periods > 0`` only the last periods are kept, in memory, and
    written by :meth:`close`.
    """

    def __init__(self, writer, dofs, decimate: int, keep_periods: int, units: str):
        self.writer, self.dofs, self.decimate = writer, dofs, decimate
        self.keep = keep_periods
        self.blocks = collections.deque(maxlen=keep_periods if keep_periods else None)
        self.units = {"t": unit("time", units), "x": unit("displacement", units)}
        self.step = 0

    def add(self, t, x, extra=None):
        """Rows of ``n`` new steps: ``t`` (n,), ``x`` (n, n_dof), ``extra`` (n,) or None."""
        idx = (self.step + np.arange(t.size)) % self.decimate == 0
        self.step += t.size
        block = (t[idx], x[idx][:, self.dofs], None if extra is None else extra[idx])
        if self.keep:
            self.blocks.append(block)
        else:
            self._write(block)

    def _write(self, block):
        t, x, extra = block
        if t.size == 0:
            return
        w = self.writer
        with w.commit():  # the rows of a block: all or nothing
            w.append_rows("transient/x", np.asarray(x, dtype=float), self.units["x"],
                          "time history of the output DOFs (transient/dofs)")
            if extra is not None:
                w.append_rows("transient/q", np.asarray(extra, dtype=float),
                              "m kg^0.5" if self.units["t"] == "s" else "length mass^0.5",
                              "modal coordinate phi^T M (x - x_static)")
            w.append_rows("transient/t", np.asarray(t, dtype=float), self.units["t"],
                          "time of each history sample")

    def close(self):
        for block in self.blocks:
            self._write(block)
        self.blocks.clear()


class _Checkpoints:
    """The march state at the start of every stored period: ``/transient/checkpoint/state``.

    One row per period (row ``k``: the start of period ``k``), appended in the
    commit of that period's history rows and period change, so that the last
    committed row always belongs to the last committed period.  A row is the
    concatenation of :data:`FIELDS` (sizes in the attribute ``sizes``, the
    law state's shape in ``state_shape``) and the step counters
    (:class:`~jointsim.solvers.generalized_alpha.StepStats`, attribute
    ``stats``).
    """

    NAME = "transient/checkpoint/state"
    FIELDS = ("t", "x", "v", "a", "phi", "duu", "dug", "dgg", "u", "f", "N", "state")
    STATS = tuple(f.name for f in dataclasses.fields(StepStats))

    def __init__(self, writer):
        self.writer = writer

    @property
    def rows(self) -> int:
        return self.writer.rows(self.NAME)

    def append(self, s: MarchState, stats: dict) -> None:
        """Append the state ``s`` at the start of the next period (inside a commit)."""
        c = s.contact
        parts = [np.atleast_1d(np.asarray(p, dtype=float)).ravel()
                 for p in (s.t, s.x, s.v, s.a, c.phi, c.duu, c.dug, c.dgg, c.u, c.f, c.N,
                           c.state)]
        row = np.concatenate(parts + [np.array([stats[k] for k in self.STATS], dtype=float)])
        new = self.NAME not in self.writer.h5
        self.writer.append(self.NAME, row, "mixed (SI or nondimensional, per field)",
                           "march state at the start of each period, for --resume")
        if new:
            d = self.writer.h5[self.NAME]
            d.attrs["fields"] = ",".join(self.FIELDS)
            d.attrs["sizes"] = np.array([p.size for p in parts], dtype=np.int64)
            d.attrs["state_shape"] = np.array(np.shape(c.state), dtype=np.int64)
            d.attrs["stats"] = ",".join(self.STATS)

    def load(self, k: int, changes) -> MarchResume:
        """The :class:`MarchResume` at the start of period ``k`` (a committed row)."""
        d = self.writer.h5[self.NAME]
        row = d[k]
        sizes = [int(n) for n in d.attrs["sizes"]]
        vals, i = {}, 0
        for name, n in zip(self.FIELDS, sizes):
            vals[name] = row[i:i + n].copy()
            i += n
        stats = {name: int(v) for name, v in zip(self.STATS, row[i:])}
        state = vals["state"].reshape(tuple(int(n) for n in d.attrs["state_shape"]))
        ev = ContactEval(vals["phi"], vals["duu"], vals["dug"], vals["dgg"], state,
                         vals["u"], vals["f"], vals["N"])
        s = MarchState(float(vals["t"][0]), vals["x"], vals["v"], vals["a"], ev)
        return MarchResume(k, s, stats, tuple(float(c) for c in changes))


def _drop_root_links(h5) -> None:
    """Remove the root ``/loops``, ``/masing`` links when they point into ``/transient``."""
    if h5.attrs.get("loops_of") == "transient":
        for link in ("loops", "masing"):
            if h5.get(link, getlink=True) is not None:
                del h5[link]
        del h5.attrs["loops_of"]


def _drop_transient(h5) -> None:
    """Remove ``/transient`` (and the root loop links into it) to march again."""
    _drop_root_links(h5)
    if "transient" in h5:
        del h5["transient"]


def _stored_march(writer, steady: bool, keep: int):
    """What a resumed file holds of this analysis: ``"complete"``, a number of
    committed periods with checkpoints (steady marches), or None (march from the
    start; whatever was stored of it is removed first).  ``keep``: the scene's
    ``history_periods`` (then the history is written only at the end, so rows of
    it in an unfinished file are of an unfinished ending)."""
    h5 = writer.h5
    if "transient" not in h5:
        return None
    if h5["transient"].attrs.get("complete", False):
        return "complete"
    n = writer.rows(_Checkpoints.NAME)
    if steady and n and writer.rows("transient/period_change") == n:
        _drop_root_links(h5)   # the loops of an unfinished ending are written again
        ending = ["transient/loops", "transient/masing"]
        if keep:
            ending += ["transient/x", "transient/t", "transient/q"]
        for name in ending:
            if name in h5:
                del h5[name]
        return n
    log.info("transient: no checkpoint to resume from; marching again from the start")
    _drop_transient(h5)
    return None


def run_transient(scene, model, writer, results=None) -> None:
    """The ``transient`` analysis of a scene: march, extract, write ``/transient``.

    The runner contract is in :mod:`jointsim.analyses`.  With ``results["hbm"]`` (an
    :class:`~jointsim.solvers.crosscheck.HBMSolutions`) a steady march is
    cross-checked against harmonic balance at its frequency.

    Raises
    ------
    RuntimeError
        After writing what was computed, when the march did not succeed.
    KeyboardInterrupt
        After writing what was computed, when interrupted.
    """
    tr = scene.analysis.transient
    units = model.units
    dofs, labels = output_dofs(scene, model, tr)
    stored = _stored_march(writer, tr.omega > 0.0, tr.history_periods)
    if stored == "complete":
        log.info("transient: already complete in %s", writer.path)
        return
    g = writer.group("transient", kind="steady" if tr.omega > 0 else "free_decay",
                     rho_inf=tr.rho_inf, steps_per_period=tr.steps_per_period,
                     integrator="generalized-alpha (Chung-Hulbert), force-averaged",
                     kernels=f"{model.contacts.law.name}/{model.contacts.normal.name}")
    writer.write("transient/dofs", dofs, "1", "DOF index of each column of transient/x")
    g.attrs["dof_labels"] = ",".join(labels)
    if model.contacts.n_elements and "contacts/area" not in writer.h5:
        writer.write("contacts/area", model.contacts.area, "m^2" if units == "SI"
                     else "length^2", "contact area of each element")
    history = _History(writer, dofs, tr.decimate, tr.history_periods, units)
    if tr.omega > 0.0:
        conv = _run_steady(scene, model, writer, tr, history,
                           (results or {}).get("hbm"), stored or 0)
    else:
        conv = _run_free_decay(scene, model, writer, tr, history)
    history.close()
    writer.group("transient", **conv.as_attrs(), **({"complete": True} if conv.success else {}))
    log.info("transient: %s", conv.message)
    if conv.status == INTERRUPTED:
        raise KeyboardInterrupt(conv.message)
    if not conv.success:
        raise RuntimeError(f"transient: {conv.message}")


def _run_steady(scene, model, writer, tr, history, hbm=None, stored: int = 0) -> Convergence:
    """March to a steady state and write it; cross-check it against ``hbm`` if given.

    ``stored``: periods already committed in a resumed file (with their checkpoints).
    """
    units = model.units
    g = writer.h5["transient"]
    g.attrs["omega"] = tr.omega
    g.attrs["force_scale"] = tr.force_scale
    g.attrs["steady_tol"] = tr.steady_tol
    one = unit("dimensionless", units)
    ckpt = _Checkpoints(writer)
    resume = None
    if stored:
        # march the last stored period again (the kept history's periods, if only
        # the last ones are kept): its state and change are exactly as before
        k0 = max(0, stored - tr.history_periods) if tr.history_periods else stored - 1
        resume = ckpt.load(k0, writer.h5["transient/period_change"][:stored])
        n = tr.steps_per_period
        history.step = 0 if k0 == 0 else (n + 1) + (k0 - 1) * n
        log.info("transient: resuming after %d stored periods (from period %d)", stored, k0)
    start = {}

    def on_state(k, s, stats):
        start["row"] = (s, dataclasses.asdict(stats))

    def on_period(p: PeriodData, change: float):
        t, x = (p.t, p.x) if p.index == 0 else (p.t[1:], p.x[1:])
        if p.index < stored:   # marched again on resume: its rows are in the file
            if history.keep:
                history.add(t, x)
            return
        with writer.commit():   # the period's rows and its checkpoint: all or nothing
            history.add(t, x)
            writer.append("transient/period_change", np.float64(change), one,
                          "largest displacement change between consecutive periods / "
                          "amplitude")
            ckpt.append(*start["row"])

    model, note = _periodic_model(model, tr, g)
    res = march_steady(model, tr, scene=scene, on_period=on_period, on_state=on_state,
                       resume=resume)
    if note and not res.convergence.success:
        c = res.convergence
        res = dataclasses.replace(res, convergence=Convergence(
            c.success, c.status, f"{c.message}; {note}", c.iterations))
    for k, v in res.stats.items():
        g.attrs[k] = v
    g.attrs["wall_time_s"] = res.wall_time
    g.attrs["error_estimate"] = res.error_estimate
    d = unit("displacement", units)
    writer.write("transient/static_x", res.static_x, d, "static equilibrium the march "
                 "started from")
    if res.last is None:
        return res.convergence
    writer.write("transient/harmonics", res.X, d,
                 "harmonic coefficients of the last period, rows [0, 1c, 1s, 2c, 2s, ...] "
                 "(the order of /hbm/X)", harmonics=np.asarray(res.harmonics),
                 omega=res.omega)
    writer.write("transient/harmonic_numbers", np.asarray(res.harmonics, dtype=np.int64), "1",
                 "harmonics of the rows of transient/harmonics")
    n = tr.steps_per_period
    writer.write("transient/period_t", res.last.t[:n], unit("time", units),
                 "times of the last (steady) period")
    writer.write("transient/period_x", res.last.x[:n][:, history.dofs], d,
                 "output DOFs over the last (steady) period")
    if res.energy is not None:
        for k, v in res.energy.as_attrs().items():
            g.attrs[k] = v
    if model.contacts.n_elements:
        last = res.last
        u, f, N = last.u[:, :n], last.f[:, :n], last.N[:, :n]
        report = check_loops(u, f, N, model.contacts.law, scene.analysis.masing.tol)
        write_loops(writer, 0, u, f, N, report, units, prefix="transient")
        loops = writer.h5["transient/loops"]
        loops.attrs["omega"] = res.omega
        loops.attrs["source"] = "transient"
        g.attrs["loops_group"] = "/transient/loops"
        log.info("transient: dev_manifold max %.3e, dev_masing max %.3e",
                 report.dev_manifold.max(), report.dev_masing.max())
    _write_step_error(writer, tr, res, units)
    if hbm is not None:
        write_cross_check(writer, scene, model, res, hbm, tol=tr.crosscheck_tol)
        if "crosscheck" in writer.h5 and "undamped_mode_zeta" in g.attrs:
            cg = writer.h5["crosscheck"]
            cg.attrs["undamped_mode_zeta"] = g.attrs["undamped_mode_zeta"]
            cg.attrs["verdict"] = (f"{cg.attrs['verdict']} (both methods with damping ratio "
                                   f"{g.attrs['undamped_mode_zeta']:g} on the "
                                   f"{int(g.attrs['undamped_modes'])} modes the scene leaves "
                                   "undamped)")
    return res.convergence


def _periodic_model(model, tr, g):
    """The model a steady run marches, and a note on its periodicity.

    Counts the modes of the stuck structure that the scene leaves undamped
    (:func:`~jointsim.solvers.march_accuracy.undamped_modes`; attributes
    ``undamped_modes``, ``undamped_modes_hz``); with
    ``analysis.transient.undamped_mode_zeta > 0`` they get that damping ratio
    (:func:`~jointsim.solvers.march_accuracy.with_mode_damping`).  The note (empty
    when none apply) says why the march may never become periodic.
    """
    modes = undamped_modes(model)
    if modes is None:
        return model, ""
    g.attrs["undamped_modes"] = modes.n
    if modes.n == 0:
        return model, ""
    hz = modes.frequency_hz
    g.attrs["undamped_modes_hz"] = hz
    if tr.undamped_mode_zeta > 0.0:
        g.attrs["undamped_mode_zeta"] = tr.undamped_mode_zeta
        log.info("transient: damping ratio %g on %d undamped modes (%.4g .. %.4g Hz)",
                 tr.undamped_mode_zeta, modes.n, hz.min(), hz.max())
        return with_mode_damping(model, modes, tr.undamped_mode_zeta), ""
    note = (f"{modes.n} modes of the stuck structure ({hz.min():.4g} .. {hz.max():.4g} Hz) "
            "have no damping, so the continuous response is never periodic and the march "
            "settles only by the scheme's numerical dissipation (slower for smaller steps): "
            "set analysis.transient.undamped_mode_zeta (e.g. 0.01) or damp them in [damping]")
    return model, note


def _write_step_error(writer, tr, res, units) -> None:
    """``/transient/error_step*``: the time-step error indicator, and the range warnings."""
    g = writer.h5["transient"]
    if res.range_warnings:
        g.attrs["step_range_warning"] = "; ".join(res.range_warnings)
    e = res.step_error
    if e is None:
        return
    one = unit("dimensionless", units)
    writer.write("transient/error_step", np.float64(e.value), one,
                 "time-step error indicator: estimated |X_1(continuous) - X_1(marched)| / "
                 "|X_1| of the first harmonic, all DOFs (defect of the marched period in "
                 "the continuous equations, solved with the harmonic-balance Jacobian); "
                 "meaningful for a steady period only",
                 tol=tr.error_tol, defect=e.defect, wall_time_s=e.wall_time)
    writer.write("transient/error_step_harmonics", e.rel_harmonics, one,
                 "time-step error indicator per harmonic of transient/harmonic_numbers, "
                 "relative to the first harmonic's norm")
    writer.write("transient/error_step_dX", e.dX, unit("displacement", units),
                 "estimated step-size error of transient/harmonics (continuous minus "
                 "marched), rows [0, 1c, 1s, ...]")
    if e.value > tr.error_tol and res.convergence.success:
        need = int(np.ceil(tr.steps_per_period * np.sqrt(e.value / tr.error_tol)))
        log.warning("transient: the time-step error indicator is %.2e of the first harmonic,"
                    " above analysis.transient.error_tol = %g; about %d steps per period "
                    "would meet it (second order)", e.value, tr.error_tol, need)


def _run_free_decay(scene, model, writer, tr, history) -> Convergence:
    """Ring down from a modal deflection and write the estimates."""
    units = model.units
    g = writer.h5["transient"]
    amp_unit = "m kg^0.5" if units == "SI" else "length mass^0.5"
    fu = unit("frequency", units)
    one = unit("dimensionless", units)

    def on_block(t, x, q):
        history.add(t, x, q)

    def on_estimate(tc, a, f, z):
        writer.append("transient/time", np.float64(tc), unit("time", units),
                      "centre time of each estimate")
        writer.append("transient/amplitude", np.float64(a), amp_unit,
                      "modal amplitude: half peak-to-peak swing of q = phi^T M (x - x_s)")
        writer.append("transient/frequency_hz", np.float64(f), fu,
                      "damped frequency from the time between extrema")
        writer.append("transient/damping_ratio", np.float64(z), one,
                      "from the logarithmic decrement over one cycle")

    res = free_decay(model, tr, scene=scene, on_block=on_block, on_estimate=on_estimate)
    g.attrs.update({"mode": res.mode, "omega_linear": res.omega_linear,
                    "frequency_linear_hz": res.omega_linear / (2.0 * np.pi),
                    "q0": res.q0, "method": "peaks (half swings between extrema)",
                    "wall_time_s": res.wall_time})
    for k, v in res.stats.items():
        g.attrs[k] = v
    d = unit("displacement", units)
    writer.write("transient/phi", res.phi, "kg^-0.5" if units == "SI" else "mass^-0.5",
                 "mass-normalised linear mode of the stuck joint")
    writer.write("transient/static_x", res.static_x, d, "static equilibrium")
    return res.convergence
