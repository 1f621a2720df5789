"""Scaling of the harmonic balance with the number of contact elements (issue 10).

For each interface resolution (25, 57, 121, 241, 481 node-to-node pairs: lap
meshes from ``meshes/make_meshes.py`` with ``--dx-lap = 0.03 / k``, ``n = 8 k + 1``
pairs, the spacing having to place nodes at the lap's ends and at +-30 mm), the
default lap-joint scene (coupled N with separation, H = 0..7, Nt = 128) runs

* one FRC branch (force scale 2, the microslip level) for ``--points`` points;
* one EPMC branch of mode 1 for ``--points`` points,

through ``jointsim.run.run_scene`` in a fresh process per case (so the peak
resident memory is that case's), once with ``linear_solver = "krylov"`` and,
while the dense path's estimated time stays below ``--dense-limit`` seconds (the first
size's from the flops of its LUs, the next ones from the last measured),
once with ``"direct"``.  Printed per case: unknowns, Newton iterations (of the accepted
correctors), linear solves (all of them, a failed corrector's too: a corner of a branch
shows here), GMRES
iterations, preconditioner builds, time per point (analysis time / points) of both
paths, the analysis's one-time set-up (the condensation, ``ReducedLinear``, and the
branch's scales: for the FRC ``frc_scales``, the stuck responses and the resonance
solve; for the EPMC the elastic mode, its linear start and ``_scales``) and the time
per point without it, their ratio, the largest
relative difference of ``X`` between the two paths over the points they placed at the
same frequency (FRC) or amplitude (EPMC), with how many those are, and peak memory;
then where each size's set-up went (each piece's own time, :class:`SetupTimer`; e.g.
``StuckFlexibility.of``, the stuck modes' eigen-decomposition), and the fitted exponent
``p`` of time per point ~ n^p (Krylov path, least squares over the sizes from 57 on;
also without the set-up).

``--interface gauss`` runs the default scene's own interface instead (2 Gauss
points per interface edge, pressure-proportional stiffness, washer bolts; the mesh
generated from ``model.dx_lap = 0.24 / n``, ``dx_full = 2 dx_lap``, ``ny_half =
0.02 / dx_lap``: ``n`` a multiple of 8, e.g. 24, 48, 96, 120, 240; the exponent is
fitted from 48 on).

Usage::

    python benchmarks/scale.py                      # all sizes (long)
    python benchmarks/scale.py --elements 25 57 121 --points 6
    python benchmarks/scale.py --quick              # 25, 57, 121 elements, 3 points
    python benchmarks/scale.py --interface gauss --elements 48 96 120 240 --points 4
    python benchmarks/scale.py --interface gauss --elements 48 96 120 240 480 --points 4 \
        --set model.dx_full=0.004 --set model.ny_half=10   # the lap alone refined
    python benchmarks/scale.py --interface gauss --elements 48 96 120 240 480 --points 25 \
        --repeat 2 --dense-limit 0 --set model.dx_full=0.004 --set model.ny_half=10
    python benchmarks/scale.py --elements 25 57 121 241 481 --points 4 4 4 4 2 \
        --numba-cache 121                           # 481 pairs: about 4.4 GB, minutes

A branch's first few points are its stuck start; ``--points 25`` (the issue's own
measure) reaches the FRC's microslip and the EPMC's gross slip, where the growth is
steeper (round 49, from 48 to 480 Gauss points: FRC n^1.45 over 25 points against
n^1.45 over 4, n^1.38 against n^1.06 without the set-up; EPMC n^1.73 against n^1.58,
n^1.72 against n^1.21).  ``--set`` overrides of the analysis a case does not run are
left out of that case, so one list serves both (e.g. both analyses'
``error_indicators=false``).

``--repeat N`` runs every case N times and keeps the fastest (round 48: one slow run of
the 48-point FRC, 0.294 s a point against 0.134 s in the run before, had moved the fitted
exponent from n^1.49 to n^1.12).

``--numba-cache N`` first runs the Krylov case of N elements twice with its own
NUMBA_CACHE_DIR, empty (cold: every kernel compiled) and then filled (warm), and
prints the process wall time of both.
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
import types
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


#: The first size's dense path, with no smaller size to extrapolate from, is estimated
#: from its LUs: about this many of ``n_z`` unknowns per point (Newton steps and the
#: tangent) at this many flop/s (2 cores; 96 Gauss points, 2,880 unknowns: estimated 3.2
#: s a point, measured 4.2 s).
DENSE_LUS_PER_POINT = 4
DENSE_FLOP_RATE = 2e10


def _mesh(n: int, cache: Path, interface: str = "nodes") -> str:
    """The mesh of ``n`` node pairs (a file), or for ``interface = "gauss"`` the
    element length of ``n`` Gauss points (``"gauss:<dx_lap>"``)."""
    if interface == "gauss":
        if n % 8:
            raise SystemExit(f"--interface gauss: {n} Gauss points do not place nodes at "
                             "the bolts (+-30 mm); use a multiple of 8")
        return f"gauss:{0.24 / n:.8g}"
    path = cache / f"lap_{n}.msh"
    if n == 25:
        return ROOT / "meshes" / "lap_joint_default.msh"
    if not path.exists():
        subprocess.run([sys.executable, str(ROOT / "meshes" / "make_meshes.py"), "--dx-lap",
                        f"{0.03 / round((n - 1) / 8):.8g}", "--dx-full", "0.01", "--ny-half", "2",
                        "-o", str(path)], check=True, capture_output=True)
    return path


def _stem(mesh) -> str:
    """A name for the mesh of a case (file stem, or ``gauss_<dx_lap>``)."""
    return str(mesh).replace(":", "_") if str(mesh).startswith("gauss:") else Path(mesh).stem


def _overrides(mesh: str, analysis: str, solver: str, points: int, sets=()) -> list:
    """The scene overrides of one case: the mesh (or the Gauss interface's resolution),
    ``sets`` but those of the other analysis (left out of the case's scene, so that one
    ``--set`` list serves both), the linear solver and the branch's length (FRC: one
    branch at force scale 2, no peak refinement; EPMC: no loops)."""
    if mesh.startswith("gauss:"):   # the resolution study's uniform refinement (washers)
        from resolution_study import resolution_sets
        ov = resolution_sets(float(mesh[6:]), None)
    else:
        ov = [f"model.mesh='{mesh}'"]
    other = "epmc" if analysis == "hbm" else "hbm"
    ov += [s for s in sets if not s.startswith(f"analysis.{other}.")]
    ov += [f"analysis.{analysis}.linear_solver='{solver}'",
           f"analysis.{analysis}.max_points={points}"]
    if analysis == "hbm":
        ov += ["analysis.hbm.force_scale=[2.0]", "analysis.hbm.refine_peak=false"]
    else:
        ov += ["analysis.epmc.loop_amplitudes=[]"]
    return ov


class SetupTimer:
    """The one-time pieces of an analysis, timed where they run (:func:`_case`).

    :meth:`wrap` replaces a function or method by one that times it.  ``total`` is the
    time spent in the outermost of them [s]; ``parts`` each piece's own time [s], a piece
    called inside another counted for the inner one only, so that the parts add up to
    ``total``.
    """

    def __init__(self, clock=time.perf_counter):
        self.clock, self.total, self.parts, self._stack = clock, 0.0, {}, []

    def wrap(self, owner, name: str) -> None:
        """Time ``owner.name`` (a module's function or a class's attribute) from now on;
        nothing when ``owner`` has no such attribute (an older tree, measured side by
        side)."""
        inner = getattr(owner, name, None)
        if inner is None:
            return
        label = name if isinstance(owner, types.ModuleType) else f"{owner.__name__}.{name}"

        def timed(*args, **kw):
            t = self.clock()
            self._stack.append(label)
            try:
                return inner(*args, **kw)
            finally:
                self._stack.pop()
                dt = self.clock() - t
                self.parts[label] = self.parts.get(label, 0.0) + dt
                if self._stack:
                    outer = self._stack[-1]
                    self.parts[outer] = self.parts.get(outer, 0.0) - dt
                else:
                    self.total += dt
        setattr(owner, name, timed)


def _case(mesh: str, analysis: str, solver: str, points: int, out: str,
          sets=()) -> dict:
    """One run in this process; returns its numbers (called in a child process);
    ``sets``: further ``--set`` overrides of the scene."""
    import h5py

    from jointsim import _toml
    from jointsim.run import run_scene
    from jointsim.scene import apply_overrides, parse_scene
    gauss = mesh.startswith("gauss:")
    path = ROOT / "models" / ("lap_joint.toml" if gauss else "lap_joint_nodes.toml")
    from resolution_study import only_analyses
    text = only_analyses(path.read_text(), ("modes", analysis))
    ov = _overrides(mesh, analysis, solver, points, sets)
    data = apply_overrides(_toml.loads(text), ov, str(path))
    scene = parse_scene(data, str(path), path.parent)
    # the one-time work of the analysis, timed apart (once per run or branch, not per
    # point): the condensation onto the contact coordinates (ReducedLinear), the stuck
    # joint's flexibility (StuckFlexibility.of, an eigen-decomposition, made on first
    # use by a preconditioner), the hierarchical interface operator (QuasiStaticForm and
    # the quasi-static sums of its split, ReducedLinear._quasi_static, made on first use
    # and again when a higher harmonic moves the split), both made before workers fork
    # (HBMSystem.prepare_forks), and the branch's scales (FRC: frc_scales, the stuck
    # responses and a Newton solve at the strongest resonance; EPMC: the elastic mode,
    # its linear start and _scales)
    import jointsim.analyses.epmc as ae
    import jointsim.analyses.hbm as ah
    import jointsim.solvers.hbm as sh
    import jointsim.solvers.hierarchical as shi
    from jointsim.solvers.condensation import ReducedLinear
    from jointsim.solvers.flexibility import StuckFlexibility
    setup = SetupTimer()
    for module, name in ((sh, "ReducedLinear"), (StuckFlexibility, "of"),
                         (shi, "QuasiStaticForm"), (ReducedLinear, "_quasi_static"),
                         (sh.HBMSystem, "prepare_forks"), (ah, "frc_scales"),
                         (ae, "elastic_mode"), (ae, "_linear_start"), (ae, "_scales")):
        setup.wrap(module, name)
    t0 = time.perf_counter()
    try:
        run_scene(scene, out)
    except RuntimeError:
        pass                      # max_points reached: the branch "gave up", points kept
    wall = time.perf_counter() - t0
    with h5py.File(out, "r") as f:
        g = f[analysis]
        return dict(n_z=int(g.attrs["n_unknowns"]), solver=str(g.attrs["linear_solver"]),
                    time=float(g.attrs["time_s"]), wall=wall, setup=setup.total,
                    setup_parts=setup.parts,
                    points=int(g.attrs["n_points"]),
                    newton=int(f[f"{analysis}/iterations"][()].sum()),
                    solves=int(f[f"{analysis}/linear_solves"][()].sum()),
                    krylov=int(f[f"{analysis}/krylov_iterations"][()].sum()),
                    builds=int(f[f"{analysis}/preconditioners"][()].sum()),
                    X=f[f"{analysis}/X"][()].tolist(),
                    # the continuation parameter of each point (frequency or amplitude)
                    lam=f[f"{analysis}/{'omega' if analysis == 'hbm' else 'amplitude'}"][()]
                    .tolist(),
                    rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)


def _run_child(mesh, analysis, solver, points, tmp, numba_cache=None, sets=()) -> dict:
    """Run one case in a fresh process; ``process`` is its wall time [s] (imports, numba
    loading or compiling, model build, analysis).  ``numba_cache``: a NUMBA_CACHE_DIR
    for the child (an empty one: a cold cache)."""
    out = Path(tmp) / f"{_stem(mesh)}_{analysis}_{solver}.h5"
    out.unlink(missing_ok=True)
    cmd = [sys.executable, __file__, "--child", str(mesh), analysis, solver, str(points),
           str(out)] + [a for s in sets for a in ("--set", s)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    if numba_cache is not None:
        env["NUMBA_CACHE_DIR"] = str(numba_cache)
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if res.returncode:
        tail = "\n".join(res.stderr.strip().splitlines()[-8:])
        raise SystemExit(f"the {analysis} case of {_stem(mesh)} ({solver}) failed:\n{tail}")
    r = json.loads(res.stdout.strip().splitlines()[-1])
    r["process"] = time.perf_counter() - t0
    return r


def _fastest(repeat: int, *args, **kw) -> dict:
    """The fastest (analysis time) of ``repeat`` runs of :func:`_run_child` (at least one)."""
    return min((_run_child(*args, **kw) for _ in range(max(repeat, 1))),
               key=lambda r: r["time"])


def _numba_cache_case(mesh, analysis, points, tmp) -> None:
    """The same Krylov case with an empty numba cache (cold: every kernel compiled),
    then again with that cache filled (warm)."""
    cache = Path(tmp) / "numba_cache"
    cache.mkdir(exist_ok=True)
    cold = _run_child(mesh, analysis, "krylov", points, tmp, numba_cache=cache)
    warm = _run_child(mesh, analysis, "krylov", points, tmp, numba_cache=cache)
    print(f"numba cache, {analysis.upper()} on {_stem(mesh)} ({cold['n_z']} unknowns, "
          f"{cold['points']} points): process wall cold {cold['process']:.1f} s, warm "
          f"{warm['process']:.1f} s; analysis time cold {cold['time']:.1f} s, warm "
          f"{warm['time']:.1f} s", flush=True)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--elements", type=int, nargs="+", default=[25, 57, 121, 241, 481])
    p.add_argument("--points", type=int, nargs="+", default=[6],
                   help="points per branch: one number, or one per size of --elements")
    p.add_argument("--dense-limit", type=float, default=120.0,
                   help="run the dense path while its estimated time is below this [s] "
                        "(0: never)")
    p.add_argument("--numba-cache", type=int, default=None, metavar="N",
                   help="also run the Krylov case of N elements with a cold and then a warm "
                        "numba cache (an empty NUMBA_CACHE_DIR) and print both times")
    p.add_argument("--repeat", type=int, default=1, metavar="N",
                   help="run each case N times and keep the fastest (analysis time): a "
                        "shared machine only slows a run down, and one slow run of a "
                        "small size moves the fitted exponent by 0.3 or more")
    p.add_argument("--analyses", nargs="+", default=["hbm", "epmc"])
    p.add_argument("--interface", choices=("nodes", "gauss"), default="nodes",
                   help="node pairs on lap meshes (models/lap_joint_nodes.toml), or the "
                        "default scene's Gauss points (models/lap_joint.toml)")
    p.add_argument("--quick", action="store_true",
                   help="25, 57 and 121 elements, 3 points per branch (a few minutes)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a further scene override for every case, e.g. a fixed body mesh "
                        "with --interface gauss: --set model.dx_full=0.004 --set "
                        "model.ny_half=10 (the lap alone refined: the time per point "
                        "depends on the interface, the model build on the whole mesh)")
    p.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.quick and not a.child:
        a.elements = [n for n in a.elements if n <= 121]
        a.points = [min(a.points[0], 3)]
    if a.child:
        mesh, analysis, solver, points, out = a.child
        r = _case(mesh, analysis, solver, int(points), out, a.set)
        print(json.dumps(r))
        return
    if len(a.points) not in (1, len(a.elements)):
        p.error("--points takes one number or one per size of --elements")
    points = dict(zip(a.elements, a.points * len(a.elements) if len(a.points) == 1
                      else a.points))
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if a.repeat > 1:
        print(f"each case run {a.repeat} times, the fastest kept")
    if a.set:
        print(f"scene overrides of every case: {' '.join(a.set)}")
    cache = Path(tempfile.gettempdir()) / "jointsim_scale_meshes"
    cache.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        if a.numba_cache is not None:
            _numba_cache_case(_mesh(a.numba_cache, cache, a.interface), a.analyses[0],
                              points.get(a.numba_cache, a.points[0]), tmp)
        for analysis in a.analyses:
            print(f"\n{analysis.upper()}: points per branch "
                  f"{', '.join(f'{n}: {k}' for n, k in points.items())}")
            print(f"{'n_e':>5} {'n_z':>6} {'pts':>4} {'Newton':>6} {'solves':>6} {'GMRES':>6} "
                  f"{'builds':>6} {'krylov s/pt':>11} {'setup s':>7} {'w/o s/pt':>8} "
                  f"{'dense s/pt':>10} {'ratio':>6} {'max dX':>8} {'MB krylov':>9} "
                  f"{'MB dense':>8}", flush=True)
            sizes, tpp, tpp0, setup_parts = [], [], [], []
            dense_est, measured = None, False
            for n in a.elements:
                mesh = _mesh(n, cache, a.interface)
                k = _fastest(a.repeat, mesh, analysis, "krylov", points[n], tmp, sets=a.set)
                d = None
                if not measured:        # no smaller size measured: from the LUs' flops
                    dense_est = points[n] * DENSE_LUS_PER_POINT * 2 / 3 * k["n_z"] ** 3 \
                        / DENSE_FLOP_RATE
                if a.dense_limit > 0 and dense_est < a.dense_limit:
                    d = _fastest(a.repeat, mesh, analysis, "direct", points[n], tmp,
                                 sets=a.set)
                    dense_est = d["time"] * 10.0      # next size: about n^3, x 2^3
                    measured = True
                kt = k["time"] / max(k["points"], 1)
                kt0 = (k["time"] - k["setup"]) / max(k["points"], 1)    # without the set-up
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
                setup_parts.append((n, k.get("setup_parts", {})))
                tpp.append(kt)
                tpp0.append(kt0)
                print(f"{n:>5} {k['n_z']:>6} {k['points']:>4} {k['newton']:>6} "
                      f"{k['solves']:>6} {k['krylov']:>6} {k['builds']:>6} {kt:>11.3f} "
                      f"{k['setup']:>7.2f} {kt0:>8.3f} {dt:>10.3f} {dt / kt:>6.2f} {dx:>8.1e} "
                      f"{k['rss_mb']:>9.0f} {d['rss_mb'] if d else np.nan:>8.0f}{same}", flush=True)
            # where the set-up went (each piece's own time, s; StuckFlexibility.of: the stuck
            # modes' eigen-decomposition)
            for n, parts in setup_parts:
                print(f"  set-up at {n}: " + ", ".join(
                    f"{name} {t:.2f}" for name, t in sorted(parts.items(), key=lambda x: -x[1])
                    if t >= 0.005))
            sel = [i for i, n in enumerate(sizes) if n >= (48 if a.interface == "gauss" else 57)]
            for label, t in (("", tpp), (" without the set-up", tpp0)):
                if len(sel) < 2:
                    continue
                pfit = np.polyfit(np.log([sizes[i] for i in sel]),
                                  np.log([t[i] for i in sel]), 1)[0]
                print(f"growth of Krylov time per point{label} from {sizes[sel[0]]} to "
                      f"{sizes[sel[-1]]} elements: n^{pfit:.2f}")
                steps = [f"{sizes[i]}->{sizes[j]}: n^"
                         f"{np.log(t[j] / t[i]) / np.log(sizes[j] / sizes[i]):.2f}"
                         for i, j in zip(sel[:-1], sel[1:])]
                print(f"  between consecutive sizes: {', '.join(steps)}")
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
