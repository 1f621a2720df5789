"""Profile one analysis of the default lap-joint scene on a generated mesh (issue 10).

Runs ``[analysis.hbm]`` (one force level, one process) or ``[analysis.epmc]`` of
``models/lap_joint_nodes.toml`` on a lap mesh of ``--pairs`` node-to-node contact pairs
(``meshes/make_meshes.py``, cached like ``benchmarks/scale.py``) under cProfile, and
prints the load, the analysis time, Newton and GMRES iterations, preconditioner
builds and linear solves, then the profile.  ``--root`` runs another checkout of
jointsim (e.g. a ``git worktree`` of the previous commit) in the same session, for
before/after figures measured side by side::

    python benchmarks/profile_case.py epmc --pairs 121 --points 15
    python benchmarks/profile_case.py hbm --force 20 --pairs 121 --points 12 --root ../old
"""
from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("analysis", choices=("hbm", "epmc"))
    p.add_argument("--pairs", type=int, default=121)
    p.add_argument("--points", type=int, default=12, help="max_points of the branch")
    p.add_argument("--force", type=float, default=20.0, help="force scale (hbm)")
    p.add_argument("--solver", default="krylov", choices=("auto", "direct", "krylov"))
    p.add_argument("--root", default=str(ROOT), help="jointsim checkout to run")
    p.add_argument("--top", type=int, default=30, help="profile lines printed")
    p.add_argument("--sort", default="cumulative", help="pstats sort key (cumulative, tottime)")
    p.add_argument("--dump", default=None, help="also write the raw profile (pstats) here")
    a = p.parse_args(argv)
    root = Path(a.root).resolve()
    sys.path.insert(0, str(root))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from scale import _mesh                       # the same cached meshes

    from jointsim import _toml
    from jointsim.run import run_scene
    from jointsim.scene import apply_overrides, parse_scene
    import h5py
    cache = Path(tempfile.gettempdir()) / "jointsim_scale_meshes"
    cache.mkdir(exist_ok=True)
    mesh = _mesh(a.pairs, cache)
    path = root / "models" / "lap_joint_nodes.toml"
    from resolution_study import only_analyses
    text = only_analyses(path.read_text(), ("modes", a.analysis))
    ov = [f"model.mesh='{mesh}'", f"analysis.{a.analysis}.linear_solver='{a.solver}'",
          f"analysis.{a.analysis}.max_points={a.points}"]
    if a.analysis == "hbm":
        ov += [f"analysis.hbm.force_scale=[{a.force}]", "analysis.hbm.refine_peak=false",
               "analysis.hbm.workers=1"]
    else:
        ov += ["analysis.epmc.loop_amplitudes=[]"]
    data = apply_overrides(_toml.loads(text), ov, str(path))
    scene = parse_scene(data, str(path), path.parent)
    import jointsim
    print(f"jointsim from {Path(jointsim.__file__).parent}; load average at start: "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "case.h5"
        prof = cProfile.Profile()
        t0 = time.perf_counter()
        prof.enable()
        try:
            run_scene(scene, out)
        except RuntimeError as exc:              # max_points: the branch "gave up"
            print(f"(branch stopped: {exc})")
        prof.disable()
        wall = time.perf_counter() - t0
        with h5py.File(out, "r") as f:
            g = f[a.analysis]
            print(f"wall {wall:.1f} s, analysis {float(g.attrs['time_s']):.1f} s, "
                  f"{int(g.attrs['n_points'])} points, {int(g.attrs['n_unknowns'])} unknowns "
                  f"({g.attrs['linear_solver']})")
            for k in ("iterations", "krylov_iterations", "preconditioners", "linear_solves"):
                print(f"{k}: {int(f[f'{a.analysis}/{k}'][()].sum())}")
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if a.dump:
        prof.dump_stats(a.dump)
    pstats.Stats(prof).sort_stats(a.sort).print_stats(a.top)


if __name__ == "__main__":
    main()
