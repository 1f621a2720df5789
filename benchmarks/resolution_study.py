"""The interface resolution study of issue 10 (item 4), from ``jointsim run`` (not collected by pytest).

For each lap resolution ``dx_lap`` (uniform refinement: ``dx_full = 2 dx_lap``,
``ny_half = 0.02 / dx_lap``) and each of the two committed lap-joint scenes,
runs ``jointsim run`` on the committed scene with ``--set`` overrides (the
generated mesh, washer bolts, ``--workers``-free, one process) and the FRC
analysis (``[analysis.hbm]``) removed, since none of the study's numbers needs
it: the scene text is copied to a temporary file without that table.  The
modes analysis is kept without its full-model and monolithic comparisons.
Prints per run the wall time and the load average, and a Markdown table of:
stuck f1, the EPMC frequency and damping and the QSMA values at the EPMC loop
amplitudes, and the area-weighted fractions on the manifold and on classical
Masing (:func:`jointsim.post.study_tables.results_rows`).

    python benchmarks/resolution_study.py --dx 0.01 0.005 0.0025 -o results/resolution \\
        [--washer 0.01] [--set key=value ...]

Existing result files in the output folder are read, not recomputed (delete
them to rerun).  Times are wall-clock on whatever the machine is doing: the
load average before and after each run is printed next to it.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENES = {"coupled N": ROOT / "models" / "lap_joint_nodes.toml",
          "fixed N": ROOT / "models" / "lap_joint_fixed_n_nodes.toml"}


def without_frc(text: str) -> str:
    """The scene text without its ``[analysis.hbm]`` table (up to the next table)."""
    return re.sub(r"(?ms)^\[analysis\.hbm\]\n.*?(?=^\[|\Z)", "", text)


def only_analyses(text: str, keep) -> str:
    """The scene text without the ``[analysis.<name>]`` tables whose name is not in
    ``keep`` (each with its ``[[...]]`` arrays, up to the next table)."""
    out, kept = [], True
    for line in text.splitlines():
        s = line.strip()
        if s.startswith("[") and not s.startswith("[["):
            kept = not s.startswith("[analysis.") or s[len("[analysis."):-1] in keep
        if kept:
            out.append(line)
    return "\n".join(out) + "\n"


def resolution_sets(dx: float, washer: float | None) -> list[str]:
    """``--set`` items of one uniform-refinement level."""
    ny = max(1, int(round(0.02 / dx)))
    out = ["model.mesh=''", f"model.dx_lap={dx:g}", f"model.dx_full={2 * dx:g}",
           f"model.ny_half={ny}", "analysis.modes.full_model=false",
           "analysis.modes.monolithic=false"]
    if washer:
        out.append(f"model.bolt_washer_radius={washer:g}")
    return out


def run_one(scene: Path, dx: float, washer, extra, out: Path) -> dict:
    """Run one scene at one resolution (unless its file exists); wall time and load."""
    info = {"file": out, "time_s": np.nan, "load": ""}
    if out.exists():
        return info
    tmp = out.with_suffix(".toml")
    tmp.write_text(without_frc(scene.read_text()))
    # the scene's relative paths (mesh) are overridden; keep the folder anyway
    sets = resolution_sets(dx, washer) + list(extra)
    cmd = [sys.executable, "-c", "import sys; from jointsim.cli import main; "
           "sys.argv = ['jointsim'] + sys.argv[1:]; main()", "run", str(tmp), "-o", str(out),
           "-q"]
    for s in sets:
        cmd += ["--set", s]
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    info["time_s"] = time.perf_counter() - t0
    info["load"] = f"{load0:.1f}-{os.getloadavg()[0]:.1f}"
    (out.with_suffix(".log")).write_text(
        f"{' '.join(cmd)}\nrc={proc.returncode} time={info['time_s']:.1f} s "
        f"load={info['load']}\n{proc.stdout}\n{proc.stderr}")
    if proc.returncode != 0:
        print(f"FAILED {out.name}: see {out.with_suffix('.log')}", flush=True)
    return info


def summary(h5_path: Path, label: str) -> list[str]:
    """Rows: stuck f1, element count, then the README results rows."""
    from jointsim.post.study_tables import results_rows
    with h5py.File(h5_path, "r") as h5:
        f = h5["modes/frequency_hz"][()]
        el = h5["modes/elastic"][()].astype(bool)
        f1 = float(f[el][0])
        n_e = int(h5["contacts/area"].shape[0])
        rows = results_rows(h5, label)
    return [f"stuck f1 = {f1:.3f} Hz, {n_e} contact elements", *rows]


LOOP_AMPLITUDES = (1e-4, 3e-4, 1e-3, 3e-3)   # the scenes' analysis.epmc.loop_amplitudes


def numbers(h5_path: Path) -> dict:
    """The study's numbers of one run, at the nominal loop amplitudes.

    EPMC frequency and damping at :data:`LOOP_AMPLITUDES` are the run's exact
    solutions there (``/epmc/at_amplitudes``; interpolated in log amplitude in a
    file without them), QSMA's are interpolated, so that runs whose branch
    points differ compare at the same amplitude; the area-weighted fractions
    are those of the loop sets solved at those amplitudes
    (``/epmc/at_amplitudes/loops``; in an older file, of the branch points
    nearest them).
    """
    from jointsim.post import study
    with h5py.File(h5_path, "r") as h5:
        f = h5["modes/frequency_hz"][()]
        f1 = float(f[h5["modes/elastic"][()].astype(bool)][0])
        rows = study.backbone_comparison(h5, LOOP_AMPLITUDES)
        sets = study.loop_points(h5, study.exact_loop_group(h5, "epmc"))
        w = study.fraction_weights(h5, sets.loaded.shape[1])["area"]
        wm, ws, _ = study.weighted_fractions(sets, w)
    return {"f1": f1, "f_epmc": np.array([r.f_epmc for r in rows]),
            "z_epmc": np.array([r.zeta_epmc for r in rows]),
            "f_qsma": np.array([r.f_qsma for r in rows]),
            "z_qsma": np.array([r.zeta_qsma for r in rows]),
            "frac_manifold": np.asarray(wm), "frac_masing": np.asarray(ws),
            "loop_amplitude": np.asarray(sets.parameter)}


def convergence(runs: dict) -> list[str]:
    """Differences of each resolution from the finest, against the issue's criteria.

    ``runs`` maps dx_lap -> :func:`numbers`.  Criteria (issue 10, item 4): f1
    and EPMC frequency within 0.2 %, damping within 5 %, fractions within 0.05
    of the finest.  QSMA values are reported with the same thresholds.
    """
    finest = min(runs)
    ref = runs[finest]
    out = [f"differences from dx_lap = {finest * 1e3:g} mm (max over the loop amplitudes):"]
    for dx in sorted(runs, reverse=True):
        if dx == finest:
            continue
        r = runs[dx]
        d = {"f1": abs(r["f1"] / ref["f1"] - 1),
             "f_epmc": np.nanmax(np.abs(r["f_epmc"] / ref["f_epmc"] - 1)),
             "z_epmc": np.nanmax(np.abs(r["z_epmc"] / ref["z_epmc"] - 1)),
             "f_qsma": np.nanmax(np.abs(r["f_qsma"] / ref["f_qsma"] - 1)),
             "z_qsma": np.nanmax(np.abs(r["z_qsma"] / ref["z_qsma"] - 1)),
             "frac": np.nanmax(np.abs(np.concatenate([
                 r["frac_manifold"] - ref["frac_manifold"],
                 r["frac_masing"] - ref["frac_masing"]])))}
        ok = (d["f1"] <= 2e-3 and d["f_epmc"] <= 2e-3 and d["z_epmc"] <= 0.05
              and d["frac"] <= 0.05)
        out.append(f"  {dx * 1e3:g} mm: f1 {100 * d['f1']:.2f} %, f EPMC {100 * d['f_epmc']:.2f} %, "
                   f"zeta EPMC {100 * d['z_epmc']:.1f} %, f QSMA {100 * d['f_qsma']:.2f} %, "
                   f"zeta QSMA {100 * d['z_qsma']:.1f} %, fractions {d['frac']:.2f}: "
                   f"{'converged' if ok else 'not converged'}")
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--dx", type=float, nargs="+", default=[0.01, 0.005, 0.0025])
    p.add_argument("--washer", type=float, default=0.01,
                   help="model.bolt_washer_radius [m]; 0 for point bolts")
    p.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    p.add_argument("--set", dest="extra", action="append", default=[])
    p.add_argument("-o", "--output", type=Path, default=ROOT / "results" / "resolution")
    a = p.parse_args(argv)
    a.output.mkdir(parents=True, exist_ok=True)
    collected = {label: {} for label in a.scenes}
    for dx in a.dx:
        for label in a.scenes:
            stem = f"{SCENES[label].stem}_dx{dx * 1e3:g}mm" + ("_washer" if a.washer else "")
            out = a.output / f"{stem}.h5"
            info = run_one(SCENES[label], dx, a.washer or None, a.extra, out)
            print(f"## {label}, dx_lap = {dx * 1e3:g} mm: {out.name}, wall {info['time_s']:.1f} s "
                  f"(load {info['load']})", flush=True)
            if out.exists():
                try:
                    for row in summary(out, f"{label}, {dx * 1e3:g} mm"):
                        print(row, flush=True)
                    collected[label][dx] = numbers(out)
                except (KeyError, OSError, ValueError) as exc:
                    print(f"(incomplete: {exc})", flush=True)
    for label, runs in collected.items():
        if len(runs) < 2:
            continue
        print(f"## {label}: at the nominal loop amplitudes {LOOP_AMPLITUDES}")
        for dx in sorted(runs, reverse=True):
            r = runs[dx]
            print(f"  {dx * 1e3:g} mm: f1 {r['f1']:.3f} Hz; f EPMC "
                  f"{np.array2string(r['f_epmc'], precision=2)}; zeta EPMC [%] "
                  f"{np.array2string(100 * r['z_epmc'], precision=3)}; f QSMA "
                  f"{np.array2string(r['f_qsma'], precision=2)}; zeta QSMA [%] "
                  f"{np.array2string(100 * r['z_qsma'], precision=3)}; by area on manifold "
                  f"{np.array2string(r['frac_manifold'], precision=2)}, on Masing "
                  f"{np.array2string(r['frac_masing'], precision=2)}")
        for line in convergence(runs):
            print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
