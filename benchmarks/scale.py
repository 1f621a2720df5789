"""Scaling of the harmonic balance with the number of contact elements (issue 10).

For each interface resolution (25, 57, 121, 241, 481 node-to-node pairs: lap
meshes from ``meshes/make_meshes.py`` with ``--dx-lap = 0.03 / k``, ``n = 8 k + 1``
pairs, the spacing having to place nodes at the lap's ends and at +-30 mm), the
default lap-joint scene (coupled N with separation, H = 0..7, Nt = 128) runs

* one FRC branch (force scale 2, the microslip level) for ``--points`` points;
* one EPMC branch of mode 1 for ``--points`` points,

through ``jointsim.run.run_scene`` in a fresh process per case (so the peak
resident memory is that case's), once with ``linear_solver = "krylov"`` and,
while the dense path's estimated time stays below ``--dense-limit`` seconds,
once with ``"direct"``.  Printed per case: unknowns, Newton iterations, GMRES
iterations, preconditioner builds, time per point (analysis time / points) of both paths, their
ratio, the largest relative difference of ``X`` between the two paths over
the points they placed at the same frequency (FRC) or amplitude (EPMC), with
how many those are, and peak memory; then the fitted exponent ``p`` of
time per point ~ n^p (Krylov path, least squares over the sizes from 57 on).

Usage::

    python benchmarks/scale.py                      # all sizes (long)
    python benchmarks/scale.py --elements 25 57 121 --points 6
    python benchmarks/scale.py --quick              # 25, 57, 121 elements, 3 points
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _mesh(n: int, cache: Path) -> Path:
    path = cache / f"lap_{n}.msh"
    if n == 25:
        return ROOT / "meshes" / "lap_joint_default.msh"
    if not path.exists():
        subprocess.run([sys.executable, str(ROOT / "meshes" / "make_meshes.py"), "--dx-lap",
                        f"{0.03 / round((n - 1) / 8):.8g}", "--dx-full", "0.01", "--ny-half", "2",
                        "-o", str(path)], check=True, capture_output=True)
    return path


def _case(mesh: str, analysis: str, solver: str, points: int, out: str) -> dict:
    """One run in this process; returns its numbers (called in a child process)."""
    import h5py

    from jointsim import _toml
    from jointsim.run import run_scene
    from jointsim.scene import apply_overrides, parse_scene
    path = ROOT / "models" / "lap_joint.toml"
    lines, keep = [], True
    for line in path.read_text().splitlines():
        s = line.strip()
        if s.startswith("[") and not s.startswith("[["):
            keep = not s.startswith("[analysis.") or s[10:-1] in ("modes", analysis)
        if keep:
            lines.append(line)
    ov = [f"model.mesh='{mesh}'", f"analysis.{analysis}.linear_solver='{solver}'",
          f"analysis.{analysis}.max_points={points}"]
    if analysis == "hbm":
        ov += ["analysis.hbm.force_scale=[2.0]", "analysis.hbm.refine_peak=false"]
    else:
        ov += ["analysis.epmc.loop_amplitudes=[]"]
    data = apply_overrides(_toml.loads("\n".join(lines)), ov, str(path))
    scene = parse_scene(data, str(path), path.parent)
    t0 = time.perf_counter()
    try:
        run_scene(scene, out)
    except RuntimeError:
        pass                      # max_points reached: the branch "gave up", points kept
    wall = time.perf_counter() - t0
    with h5py.File(out, "r") as f:
        g = f[analysis]
        return dict(n_z=int(g.attrs["n_unknowns"]), solver=str(g.attrs["linear_solver"]),
                    time=float(g.attrs["time_s"]), wall=wall,
                    points=int(g.attrs["n_points"]),
                    newton=int(f[f"{analysis}/iterations"][()].sum()),
                    krylov=int(f[f"{analysis}/krylov_iterations"][()].sum()),
                    builds=int(f[f"{analysis}/preconditioners"][()].sum()),
                    X=f[f"{analysis}/X"][()].tolist(),
                    # the continuation parameter of each point (frequency or amplitude)
                    lam=f[f"{analysis}/{'omega' if analysis == 'hbm' else 'amplitude'}"][()]
                    .tolist(),
                    rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)


def _run_child(mesh, analysis, solver, points, tmp) -> dict:
    out = Path(tmp) / f"{Path(mesh).stem}_{analysis}_{solver}.h5"
    out.unlink(missing_ok=True)
    cmd = [sys.executable, __file__, "--child", str(mesh), analysis, solver, str(points),
           str(out)]
    res = subprocess.run(cmd, check=True, capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--elements", type=int, nargs="+", default=[25, 57, 121, 241, 481])
    p.add_argument("--points", type=int, default=6)
    p.add_argument("--dense-limit", type=float, default=120.0,
                   help="run the dense path while its estimated time is below this [s]")
    p.add_argument("--analyses", nargs="+", default=["hbm", "epmc"])
    p.add_argument("--quick", action="store_true",
                   help="25, 57 and 121 elements, 3 points per branch (a few minutes)")
    p.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.quick and not a.child:
        a.elements = [n for n in a.elements if n <= 121]
        a.points = min(a.points, 3)
    if a.child:
        mesh, analysis, solver, points, out = a.child
        r = _case(mesh, analysis, solver, int(points), out)
        print(json.dumps(r))
        return
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    cache = Path(tempfile.gettempdir()) / "jointsim_scale_meshes"
    cache.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for analysis in a.analyses:
            print(f"\n{analysis.upper()}: {a.points} points per branch")
            print(f"{'n_e':>5} {'n_z':>6} {'pts':>4} {'Newton':>6} {'GMRES':>6} {'builds':>6} "
                  f"{'krylov s/pt':>11} {'dense s/pt':>10} {'ratio':>6} {'max dX':>8} "
                  f"{'MB krylov':>9} {'MB dense':>8}", flush=True)
            sizes, tpp = [], []
            dense_est = None
            for n in a.elements:
                mesh = _mesh(n, cache)
                k = _run_child(mesh, analysis, "krylov", a.points, tmp)
                d = None
                if dense_est is None or dense_est < a.dense_limit:
                    d = _run_child(mesh, analysis, "direct", a.points, tmp)
                    dense_est = d["time"] * 10.0      # next size: about n^3, x 2^3
                kt = k["time"] / max(k["points"], 1)
                dt = d["time"] / max(d["points"], 1) if d else np.nan
                dx, same = np.nan, ""
                if d:
                    # compare the points both paths placed at the same parameter (a failed
                    # step, e.g. a GMRES that did not converge, makes the paths diverge)
                    Xk, Xd = np.asarray(k["X"]), np.asarray(d["X"])
                    lk, ld = np.asarray(k["lam"]), np.asarray(d["lam"])
                    pairs = [(i, int(np.argmin(np.abs(ld - x)))) for i, x in enumerate(lk)]
                    pairs = [(i, j) for i, j in pairs if abs(ld[j] - lk[i]) <= 1e-9 * abs(ld[j])]
                    if pairs:
                        dx = float(max(np.abs(Xk[i] - Xd[j]).max() / np.abs(Xd[j]).max()
                                       for i, j in pairs))
                    same = f" ({len(pairs)}/{len(lk)} points)"
                sizes.append(n)
                tpp.append(kt)
                print(f"{n:>5} {k['n_z']:>6} {k['points']:>4} {k['newton']:>6} "
                      f"{k['krylov']:>6} {k['builds']:>6} {kt:>11.3f} {dt:>10.3f} {dt / kt:>6.2f} {dx:>8.1e} "
                      f"{k['rss_mb']:>9.0f} {d['rss_mb'] if d else np.nan:>8.0f}{same}", flush=True)
            sel = [i for i, n in enumerate(sizes) if n >= 57]
            if len(sel) >= 2:
                pfit = np.polyfit(np.log([sizes[i] for i in sel]),
                                  np.log([tpp[i] for i in sel]), 1)[0]
                print(f"growth of Krylov time per point from {sizes[sel[0]]} to "
                      f"{sizes[sel[-1]]} elements: n^{pfit:.2f}")
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
