"""``jointsim converge``: how accurate is a scene, and what does more accuracy cost?

The user's own scene is run at a ladder of settings for each numerical dial
it uses, one dial at a time, every other setting as in the scene; each
ladder's most refined setting is its reference.  The dials (:func:`dials_for`):

============  ===============================================  =====================
dial          scene keys                                        used when
============  ===============================================  =====================
harmonics     ``analysis.hbm.harmonics``, ``analysis.epmc...``  HBM or EPMC runs
samples       ``analysis.hbm.n_samples``, ``analysis.epmc...``  HBM or EPMC runs
tol           ``analysis.hbm.tol``, ``analysis.epmc.tol``       HBM or EPMC runs
dx_lap        ``model.dx_lap``                                  generated FE mesh
steps         ``analysis.transient.steps_per_period``           time marching runs
iwan_rtol     ``joint.iwan_rtol``                               Iwan, default sliders
============  ===============================================  =====================

From every result file the quantities the scene produces are read
(:func:`quantities`): each FRC branch's peak amplitude and frequency, EPMC and
QSMA frequency and damping at the loop amplitudes (or at four amplitudes
inside the computed range), the steady time-marching harmonics or the
free-decay backbone, and the manifold and Masing fractions of every loop set.
Errors are relative for the physical quantities and absolute for the
fractions (they are shares in [0, 1]).

A dial's recommended setting is the least refined one that, together with
every more refined one, is within ``rtol`` of the ladder's reference in every
quantity.  The combined recommendation (every dial at its recommended
setting) is then run against the combined reference (every dial at its most
refined setting); while it misses ``rtol``, the dial whose recommended
setting was worst is refined by one step and the check is repeated.

The runs go through :func:`jointsim.sweep.run_variants` (dask workers; a
``--scheduler`` cluster speeds it up).  Written to the output folder: every
run's result file, ``converge.h5`` (the tables, with units and docs), and
``converge_<dial>.png`` (error against wall time, one per dial).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from .quantities import errors, kind_errors, quantities
from .scene import SceneError, load_scene

log = logging.getLogger(__name__)

#: ladders, least refined first (the last is the reference)
LADDERS = {
    "harmonics": (1, 3, 5, 7, 11, 15),
    "samples": (32, 64, 128, 256, 512),
    "tol": (1e-4, 1e-6, 1e-8, 1e-10),
    "dx_lap": (0.03, 0.015, 0.01, 0.0075),
    "steps": (64, 128, 256, 512),
    "iwan_rtol": (0.1, 0.03, 0.01, 0.003),
}

#: unit and meaning of each dial's setting
DIAL_DOC = {
    "harmonics": ("1", "highest harmonic kept H (the scene's pattern of even/odd and the "
                       "mean kept)"),
    "samples": ("1", "AFT time samples per period Nt"),
    "tol": ("1", "Newton tolerance of the continuation (scaled residual)"),
    "dx_lap": ("m", "element length along the lap of the generated mesh"),
    "steps": ("1", "time steps per period"),
    "iwan_rtol": ("1", "Iwan dissipation accuracy that sets the slider count"),
}


def parse_ladders(items, file: str = "<command line>") -> dict:
    """``["harmonics=3,5,7", ...]`` (from ``--ladder``) as ``{dial: values}``.

    Raises
    ------
    SceneError
        For an unknown dial, a value that is not a number, or fewer than two values.
    """
    out = {}
    for item in items:
        name, _, vals = item.partition("=")
        name = name.strip()
        if name not in LADDERS:
            raise SceneError(file, "--ladder", f"unknown dial {name!r} (one of "
                                               f"{sorted(LADDERS)})")
        try:
            conv = int if name in ("harmonics", "samples", "steps") else float
            values = tuple(conv(v) for v in vals.split(","))
        except ValueError:
            raise SceneError(file, f"--ladder {name}", f"values {vals!r} are not numbers") \
                from None
        if len(values) < 2:
            raise SceneError(file, f"--ladder {name}", "needs at least two values")
        out[name] = values
    return out


@dataclass(frozen=True)
class Dial:
    """One numerical setting and its ladder.

    Attributes
    ----------
    name : str
        Key of :data:`LADDERS`.
    values : tuple
        Ladder, least refined first; the last is the reference.
    scene_value : object
        The scene's own setting (for the table).
    """

    name: str
    values: tuple
    scene_value: object

    def overrides(self, value, scene) -> tuple[str, ...]:
        """``--set`` items that put ``scene`` at ``value`` of this dial."""
        a = scene.analysis
        secs = [n for n in ("hbm", "epmc") if getattr(a, n, None) is not None]
        if self.name == "harmonics":
            return tuple(f"analysis.{n}.harmonics="
                         f"{list(_harmonics(getattr(a, n).harmonics, value))}" for n in secs)
        if self.name == "samples":
            return tuple(f"analysis.{n}.n_samples={int(value)}" for n in secs)
        if self.name == "tol":
            return tuple(f"analysis.{n}.tol={float(value)!r}" for n in secs)
        if self.name == "dx_lap":
            return (f"model.dx_lap={float(value)!r}",)
        if self.name == "steps":
            return (f"analysis.transient.steps_per_period={int(value)}",)
        if self.name == "iwan_rtol":
            return (f"joint.iwan_rtol={float(value)!r}",)
        raise ValueError(f"unknown dial {self.name!r}")


def _harmonics(scene_h, H: int) -> tuple[int, ...]:
    """Harmonics 0..H in the pattern of the scene's list (mean kept or not, odd only or not)."""
    scene_h = tuple(int(h) for h in scene_h)
    odd_only = all(h % 2 == 1 for h in scene_h if h > 0)
    hs = [h for h in range(1, H + 1) if not odd_only or h % 2 == 1]
    return tuple(([0] if 0 in scene_h else []) + hs)


def dials_for(scene, ladders: dict | None = None) -> list[Dial]:
    """The dials a scene uses, with their ladders (see the module docstring).

    ``ladders`` replaces some of :data:`LADDERS` (``{dial: values}``, least
    refined first).
    """
    L = {**LADDERS, **{k: tuple(v) for k, v in (ladders or {}).items()}}
    a = scene.analysis
    out = []
    secs = [getattr(a, n) for n in ("hbm", "epmc") if getattr(a, n, None) is not None]
    if secs:
        h_scene = max(max(s.harmonics) for s in secs)
        nt_scene = max(s.n_samples for s in secs)
        out.append(Dial("harmonics", L["harmonics"], h_scene))
        nts = tuple(n for n in L["samples"] if n > 2 * h_scene)
        out.append(Dial("samples", nts, nt_scene))
        out.append(Dial("tol", L["tol"], max(s.tol for s in secs)))
    m = scene.model
    if m.kind == "fe" and m.dx_lap is not None:
        out.append(Dial("dx_lap", L["dx_lap"], m.dx_lap))
    if getattr(a, "transient", None) is not None:
        out.append(Dial("steps", L["steps"], a.transient.steps_per_period))
    if scene.joint.law == "iwan4" and scene.joint.n_sliders is None:
        out.append(Dial("iwan_rtol", L["iwan_rtol"], scene.joint.iwan_rtol))
    return out


# ---------------------------------------------------------------- quantities

@dataclass
class Ladder:
    """One dial's runs: settings, wall times, errors against its reference."""

    dial: Dial
    files: list[Path]
    status: list[str]
    messages: list[str]
    wall_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    quantity_names: list[str] = field(default_factory=list)
    quantity_units: list[str] = field(default_factory=list)
    reference_values: np.ndarray = field(default_factory=lambda: np.zeros(0))
    error: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # (n_settings, n_q)
    recommended: int = -1
    reference: int = -1  # index of the reference setting (most refined complete run)

    @property
    def worst(self) -> np.ndarray:
        """Largest error over the quantities, per setting (NaN-free quantities)."""
        e = np.where(np.isnan(self.error), 0.0, self.error)
        return e.max(axis=1) if e.size else np.full(len(self.files), np.nan)


@dataclass
class ConvergeResult:
    """Everything ``jointsim converge`` found (see :func:`run_converge`)."""

    scene_path: str
    rtol: float
    ladders: list[Ladder]
    recommendation: dict[str, object]
    recommendation_overrides: tuple[str, ...]
    check_error: np.ndarray
    check_names: list[str]
    check_wall_time_s: float
    reference_wall_time_s: float
    check_ok: bool
    outdir: Path
    check_message: str = ""


def _wall(path: Path) -> float:
    with h5py.File(path, "r") as h5:
        return float(h5.attrs.get("wall_time_s", np.nan))


def _wall_or_nan(path: Path) -> float:
    """Wall time of a result file [s] (also of a failed run); NaN without a file."""
    try:
        return _wall(path)
    except OSError:
        return np.nan


def _pick(worst: np.ndarray, rtol: float, usable: np.ndarray | None = None) -> int:
    """Least refined index whose error and every more refined one's are within rtol.

    ``usable`` (bool per setting, default all) marks the settings that completed;
    a failed setting can be neither recommended nor block a coarser one: the
    chain of "every more refined setting" skips it.  -1 when no setting is usable.
    """
    usable = np.ones(len(worst), bool) if usable is None else np.asarray(usable, bool)
    idx = np.flatnonzero(usable)
    if idx.size == 0:
        return -1
    ok = np.isfinite(worst) & (worst <= rtol)
    j = idx.size - 1
    while j > 0 and ok[idx[j - 1]]:
        j -= 1
    return int(idx[j])


def _quantities_or_none(path: Path, scene):
    """The quantities of a result file, also of a failed run (what it reached; NaN
    where it stopped short), or None when the file is missing or unreadable."""
    if not Path(path).exists():
        return None
    try:
        return quantities(path, scene)
    except (OSError, KeyError, ValueError, IndexError) as exc:
        log.warning("%s: quantities not readable (%s)", Path(path).name, exc)
        return None


def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def run_converge(scene_path, rtol: float = 1e-2, dials: list[str] | None = None,
                 outdir=None, scheduler: str | None = None, n_workers: int = 2,
                 common: list[str] = (), max_rounds: int = 3,
                 ladders: dict | None = None) -> ConvergeResult:
    """Run the ladders of a scene and recommend the cheapest setting within ``rtol``.

    Parameters
    ----------
    scene_path : str or Path
        The user's scene.
    rtol : float
        Requested accuracy (relative; absolute for fractions).
    dials : list of str, optional
        Dials to ladder (default: every one the scene uses).
    outdir : str or Path, optional
        Folder of the runs, ``converge.h5`` and the figures (default
        ``results/<scene>_converge``).
    scheduler, n_workers
        As for :func:`jointsim.sweep.run_sweep`.
    common : list of str
        ``--set`` overrides applied to every run.
    max_rounds : int
        Refinements of the combined recommendation before giving up.
    ladders : dict, optional
        ``{dial: values}`` replacing the default ladders (:data:`LADDERS`).

    Returns
    -------
    ConvergeResult

    Raises
    ------
    SceneError
        For an invalid scene, override or dial (nothing is run).
    """
    from .sweep import Variant, _client
    if not rtol > 0:
        raise SceneError(str(scene_path), "--rtol", f"must be > 0, got {rtol}")
    scene = load_scene(scene_path, list(common))
    avail = dials_for(scene, ladders)
    names = [d.name for d in avail]
    if dials:
        bad = [d for d in dials if d not in names]
        if bad:
            raise SceneError(str(scene_path), "--dials",
                             f"{bad} not used by this scene (it uses {names})")
        avail = [d for d in avail if d.name in dials]
    if not avail:
        raise SceneError(str(scene_path), "[analysis]", "runs nothing with a numerical dial "
                                                         "(hbm, epmc, transient, Iwan, FE mesh)")
    outdir = Path(outdir) if outdir else Path("results") / (Path(scene_path).stem + "_converge")
    variants, ladders, by_text = [], [], {}

    def variant(ov, name) -> Path:
        """The result file of a setting; settings that resolve to the same scene run once."""
        text = load_scene(scene_path, list(ov)).text  # validates before anything runs
        if text not in by_text:
            f = outdir / name
            variants.append(Variant(len(variants), ov, f))
            by_text[text] = f
        return by_text[text]

    for d in avail:
        files = [variant(tuple(common) + d.overrides(v, scene), f"{d.name}_{_fmt(v)}.h5")
                 for v in d.values]
        ladders.append(Ladder(d, files, [], []))
    # the combined reference (every dial at its most refined setting) runs with the ladders
    ref_ov = tuple(common) + tuple(o for lad in ladders
                                   for o in lad.dial.overrides(lad.dial.values[-1], scene))
    ref_file = variant(ref_ov, "combined_reference.h5")
    if not scheduler and n_workers < 1:
        raise ValueError(f"--workers {n_workers}: a local cluster needs at least 1 worker")
    client, cluster = _client(scheduler, n_workers)
    try:
        result = _converge(scene, scene_path, rtol, ladders, variants, by_text, ref_file,
                           outdir, client, common, max_rounds)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    write_h5(result, outdir / "converge.h5")
    return result


def _failed_before(scene_path, variant) -> dict | None:
    """The status of a variant whose result file is a failed run of the same scene.

    Runs are deterministic, so a failed setting is reported again from its
    file (its message and what it reached) instead of being rerun; delete the
    file to retry it.  None when the file is absent, of another scene, or not
    failed.
    """
    from .io.hdf5 import read_attrs
    f = Path(variant.output)
    if not f.exists():
        return None
    try:
        a = read_attrs(f)
    except (OSError, ValueError):
        return None
    if a.get("status") != "failed" or a.get("scene") != load_scene(
            scene_path, list(variant.overrides)).text:
        return None
    return {"index": variant.index, "status": "failed",
            "message": f"kept from an earlier run: {a.get('message', '')}"}


def _run_keeping_failed(scene_path, variants, outdir, client, run_variants) -> list[dict]:
    """:func:`jointsim.sweep.run_variants` for the variants not failed before
    (:func:`_failed_before`); the statuses of all, in the order of ``variants``."""
    before = [_failed_before(scene_path, v) for v in variants]
    todo = [v for v, b in zip(variants, before) if b is None]
    res = iter(run_variants(scene_path, todo, outdir, client=client,
                            index_name="converge_runs.h5", desc="converge")[1]
               if todo else [])
    return [b if b is not None else next(res) for b in before]


def _converge(scene, scene_path, rtol, ladders, variants, by_text, ref_file, outdir, client,
              common, max_rounds) -> ConvergeResult:
    """The runs and the choice of :func:`run_converge`, on an open dask client."""
    from .sweep import Variant, run_variants
    res = _run_keeping_failed(scene_path, variants, outdir, client, run_variants)
    ref_status = next(r for v, r in zip(variants, res) if v.output == ref_file)
    by_file = {v.output: r for v, r in zip(variants, res)}
    for lad in ladders:
        lad.status = [by_file[f]["status"] for f in lad.files]
        lad.messages = [by_file[f]["message"] for f in lad.files]
        ref_k = max((k for k, s in enumerate(lad.status) if s == "complete"), default=None)
        lad.wall_time_s = np.array([_wall_or_nan(f) for f in lad.files])
        if ref_k is None:
            lad.error = np.full((len(lad.files), 0), np.inf)
            continue
        if ref_k != len(lad.files) - 1:
            log.warning("%s: the most refined setting failed; reference is %s",
                        lad.dial.name, _fmt(lad.dial.values[ref_k]))
        ref = quantities(lad.files[ref_k], scene)
        lad.quantity_names = [q.name for q in ref]
        lad.quantity_units = [q.unit for q in ref]
        lad.reference_values = np.array([q.value for q in ref])
        lad.reference = ref_k
        rows = []
        for f in lad.files:  # a failed run keeps what it reached (inf where it stopped)
            q = _quantities_or_none(f, scene)
            rows.append(errors(q, ref) if q is not None else np.full(len(ref), np.inf))
        lad.error = np.array(rows)
        lad.recommended = _pick(lad.worst, rtol,
                                np.array([s == "complete" for s in lad.status]))

    # the combined check: every dial at its pick against every dial at its reference
    # (its most refined complete setting; when one failed, that combination is run)
    check_err, names, ok, t_check, t_ref = np.zeros(0), [], False, np.nan, np.nan
    check_msg = ""
    status_of = {v.output: r for v, r in zip(variants, res)}

    def run_once(ov, name, index_name, desc):
        """Result file and status of a combination (a ladder's run when it is one)."""
        f = by_text.get(load_scene(scene_path, list(ov)).text)
        if f is not None and f in status_of:
            return f, status_of[f]
        f = outdir / name
        v = Variant(0, ov, f)
        r = [_failed_before(scene_path, v)]
        if r[0] is None:
            _, r = run_variants(scene_path, [v], outdir, client=client,
                                index_name=index_name, desc=desc)
        by_text[load_scene(scene_path, list(ov)).text] = f
        status_of[f] = r[0]
        return f, r[0]

    if all(lad.reference == len(lad.files) - 1 for lad in ladders):
        ref_st = ref_status
    else:
        ref_ov = tuple(common) + tuple(
            o for lad in ladders
            for o in lad.dial.overrides(lad.dial.values[max(lad.reference, 0)], scene))
        ref_file, ref_st = run_once(ref_ov, "combined_reference_complete.h5",
                                    "converge_reference.h5", "reference")
    rec_ov: tuple[str, ...] = ()
    for rnd in range(max_rounds + 1):
        if any(lad.recommended < 0 for lad in ladders):
            check_msg = "a dial has no complete setting"
            break
        rec_ov = tuple(common) + tuple(
            o for lad in ladders
            for o in lad.dial.overrides(lad.dial.values[lad.recommended], scene))
        rec_file, r = run_once(rec_ov, f"combined_recommended_{rnd}.h5",
                               "converge_check.h5", "check")
        if r["status"] != "complete" or ref_st["status"] != "complete":
            check_msg = ("recommended run failed: " + r["message"] if r["status"] != "complete"
                         else "combined reference failed: " + ref_st["message"])
            log.warning("combined check did not run: %s", check_msg)
            break
        refq = quantities(ref_file, scene)
        names = [q.name for q in refq]
        check_err = errors(quantities(rec_file, scene), refq)
        t_check, t_ref = _wall(rec_file), _wall(ref_file)
        worst = float(np.nanmax(check_err)) if check_err.size else 0.0
        ok = worst <= rtol
        if ok:
            break
        # refine the dial whose pick is furthest from its reference, to its next
        # complete setting
        cand = [lad for lad in ladders if 0 <= lad.recommended < lad.reference]
        if not cand:
            break
        lad = max(cand, key=lambda L: L.worst[L.recommended])
        log.info("combined setting misses rtol (%.3g > %.3g): refining %s", worst, rtol,
                 lad.dial.name)
        lad.recommended = next(k for k in range(lad.recommended + 1, len(lad.files))
                               if lad.status[k] == "complete")
    rec = {lad.dial.name: lad.dial.values[max(lad.recommended, 0)] for lad in ladders}
    return ConvergeResult(str(scene_path), rtol, ladders, rec, rec_ov, check_err, names,
                          t_check, t_ref, ok, outdir, check_msg)


# ---------------------------------------------------------------- output

#: quantity kinds of :func:`kind_errors`, by a word of the quantity name
def _e(v: float) -> str:
    return "-" if np.isnan(v) else ("not reached" if np.isinf(v) else f"{v:.2e}")


def table_text(r: ConvergeResult) -> str:
    """The terminal table: per dial and setting, wall time, worst error and quantity,
    and the largest frequency and damping errors; a failed run is listed with what it
    reached and its message."""
    lines = [f"convergence of {r.scene_path} (rtol {r.rtol:g}; errors against each "
             f"ladder's most refined complete setting)"]
    for lad in r.ladders:
        d = lad.dial
        lines.append(f"\n  {d.name} ({DIAL_DOC[d.name][1]}; scene: {_fmt(d.scene_value)})")
        lines.append(f"    {'setting':>10} {'wall [s]':>9} {'max error':>10} {'freq.':>9} "
                     f"{'damping':>9}  worst quantity")
        for k, v in enumerate(d.values):
            e = lad.error[k] if lad.error.size else np.zeros(0)
            fin = e[np.isfinite(e)]
            ke = kind_errors(lad.quantity_names, e) if e.size else {}
            t = lad.wall_time_s[k] if k < lad.wall_time_s.size else np.nan
            head = (f"    {_fmt(v):>10} {t:>9.2f} "
                    f"{(fin.max() if fin.size else np.nan):>10.2e} "
                    f"{_e(ke.get('frequency', np.nan)):>9} {_e(ke.get('damping', np.nan)):>9}  ")
            if lad.status[k] != "complete":
                n_miss = int(np.isinf(e).sum())
                lines.append(head + f"FAILED ({n_miss} of {e.size} quantities not reached): "
                                    f"{lad.messages[k][:70]}")
                continue
            e0 = np.where(np.isnan(e), -1.0, e)
            j = int(np.argmax(e0)) if e.size else -1
            mark = " <- recommended" if k == lad.recommended else ""
            ref = " (reference)" if k == lad.reference else ""
            what = lad.quantity_names[j] if j >= 0 and e0[j] > 0 else ""
            lines.append(head + f"{what}{ref}{mark}")
    lines.append("\n  recommendation: " + ", ".join(f"{k} = {_fmt(v)}"
                                                    for k, v in r.recommendation.items()))
    lines.append("    --set " + " --set ".join(r.recommendation_overrides)
                 if r.recommendation_overrides else "    (the scene as it is)")
    if r.check_error.size:
        w = float(np.nanmax(r.check_error))
        ke = kind_errors(r.check_names, r.check_error)
        lines.append(f"    combined check against every dial at its reference: max error "
                     f"{w:.2e} ({'within' if r.check_ok else 'NOT within'} rtol; frequency "
                     f"{_e(ke['frequency'])}, damping {_e(ke['damping'])}), wall "
                     f"{r.check_wall_time_s:.2f} s against {r.reference_wall_time_s:.2f} s")
    else:
        lines.append(f"    combined check: not run ({r.check_message or 'a run failed'})")
    return "\n".join(lines)


def write_h5(r: ConvergeResult, path) -> Path:
    """Write ``converge.h5``: one group per dial and the recommendation, with units and docs."""
    s = h5py.string_dtype()

    def ds(g, name, data, unit, doc):
        d = g.create_dataset(name, data=data)
        d.attrs["unit"] = unit
        d.attrs["doc"] = doc
        return d

    with h5py.File(path, "w", locking=False) as h5:
        h5.attrs["scene_path"] = r.scene_path
        h5.attrs["rtol"] = r.rtol
        h5.attrs["doc"] = ("jointsim converge: errors of the scene's quantities at a ladder "
                           "of settings per dial, against the ladder's most refined setting")
        for lad in r.ladders:
            g = h5.create_group(f"converge/{lad.dial.name}")
            u, doc = DIAL_DOC[lad.dial.name]
            g.attrs["doc"] = doc
            g.attrs["scene_value"] = float(lad.dial.scene_value)
            g.attrs["recommended"] = lad.recommended
            ds(g, "setting", np.asarray(lad.dial.values, dtype=float), u,
               f"{doc}; the last is the reference")
            ds(g, "wall_time_s", lad.wall_time_s, "s", "wall time of the run (result file "
                                                       "attribute wall_time_s)")
            ds(g, "error", lad.error, "1", "error of each quantity (rows: settings), relative "
                                           "(absolute for shares); inf: run or point failed")
            ds(g, "max_error", lad.worst, "1", "largest error over the quantities")
            ds(g, "quantity", np.array(lad.quantity_names, dtype=s), "1", "quantity names")
            ds(g, "quantity_unit", np.array(lad.quantity_units, dtype=s), "1",
               "unit of each quantity")
            ds(g, "reference_value", lad.reference_values, "see quantity_unit",
               "each quantity at the reference setting")
            ds(g, "status", np.array(lad.status, dtype=s), "1",
               "run status (a failed run's errors are of what it reached; inf: not reached)")
            ds(g, "message", np.array([m or "" for m in lad.messages], dtype=s), "1",
               "run message (why a run failed)")
            g.attrs["reference"] = lad.reference
            ds(g, "file", np.array([f.name for f in lad.files], dtype=s), "1",
               "result file of each setting (next to this file)")
        g = h5.create_group("converge/recommendation")
        g.attrs["doc"] = ("cheapest setting per dial within rtol, checked together against "
                          "every dial at its reference")
        g.attrs["overrides"] = np.array(list(r.recommendation_overrides), dtype=s)
        for k, v in r.recommendation.items():
            g.attrs[k] = v
        g.attrs["check_ok"] = bool(r.check_ok)
        g.attrs["check_message"] = r.check_message
        ds(g, "check_error", r.check_error, "1", "error of each quantity of the recommended "
                                                 "setting against the combined reference")
        ds(g, "check_quantity", np.array(r.check_names, dtype=s), "1", "quantity names")
        ds(g, "wall_time_s", np.array([r.check_wall_time_s, r.reference_wall_time_s]), "s",
           "wall time of the recommended and of the combined reference run")
    return Path(path)


def figures(r: ConvergeResult, outdir=None) -> list[Path]:
    """``converge_<dial>.png``: largest error against wall time, one point per setting."""
    from .post.common import pyplot
    plt = pyplot()
    outdir = Path(outdir) if outdir else r.outdir
    paths = []
    for lad in r.ladders:
        fig, ax = plt.subplots(figsize=(5.0, 3.8))
        t, e = lad.wall_time_s, lad.worst
        keep = np.isfinite(t) & np.isfinite(e) & (e > 0)
        ax.loglog(t[keep], e[keep], "o-")
        for k in np.flatnonzero(keep):
            ax.annotate(_fmt(lad.dial.values[k]), (t[k], e[k]), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
        ax.axhline(r.rtol, color="0.5", ls="--", lw=0.8, label=f"rtol {r.rtol:g}")
        if 0 <= lad.recommended < len(t) and np.isfinite(t[lad.recommended]):
            ax.axvline(t[lad.recommended], color="C2", ls=":", lw=0.8, label="recommended")
        ax.set_xlabel("wall time per run [s]")
        ax.set_ylabel("largest error over the quantities")
        ax.set_title(f"{Path(r.scene_path).stem}: {lad.dial.name} "
                     f"(ref. {_fmt(lad.dial.values[-1])})", fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
        fig.tight_layout()
        p = outdir / f"converge_{lad.dial.name}.png"
        fig.savefig(p, dpi=120)
        plt.close(fig)
        paths.append(p)
    return paths
