"""Cost of the per-point error indicators: HBM and EPMC runs with and without them.

Each case runs its scene twice per repeat, ``analysis.<kind>.error_indicators``
true and false, alternating, in this process (numba kernels compiled by a
warm-up run first), and prints the best wall time of each and their ratio.
The indicators cost one evaluation and one linear solve of the extended
harmonic balance per point (:mod:`jointsim.solvers.indicators`).

Cases: ``chain2`` (the 2-DOF Jenkins chain FRC, ``models/hbm/chain2_jenkins.toml``,
branches serial), ``sdof_epmc`` (``models/hbm/sdof_jenkins_epmc.toml``),
``lap_fixed`` (the FE lap joint with fixed normal load on the coarse mesh, one
FRC branch at 200 N over 150-160 Hz), ``lap_epmc`` (the coupled-N lap joint on
the coarse mesh, EPMC from a = 1e-5 to 1e-3).

``lap121_hbm`` and ``lap121_epmc`` are the default scene (``models/lap_joint_nodes.toml``,
coupled N) on the 121-pair lap mesh of ``benchmarks/scale.py`` (generated once and
cached in the temporary directory), Krylov path, one process: the FRC at force
scale 2 (first 20 points) and the EPMC (first 10 points, no loop amplitudes), the
cases of issues 10 and 12; ``lap121_stuck`` the FRC at force scale 0.02 (first 30
points), stuck below the slip limit: its points are linear and their indicators
cost no extended solve (:data:`jointsim.solvers.indicators.LINEAR_FORCE_TOL`).  Their runs stop at ``max_points`` (reported as a
failed branch: the points are kept).  The last column is the indicators' share of
the run, ``(with - without) / with``.

``--root`` measures another checkout (e.g. ``git archive HEAD | tar -x -C /tmp/old``)
with its own scenes; run both checkouts one after the other and compare at the
same load.

EPMC cases also run a third variant, ``linear``: the indicators from the first
Newton step of the extended system only (``analysis.epmc.error_newton_steps = 1``,
the estimate before the extended Newton solve), so that the cost of that solve is
measured side by side.

Usage::

    python benchmarks/indicator_cost.py                 # every case, best of 2
    python benchmarks/indicator_cost.py --cases chain2 --repeat 3
"""
from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

if "--root" in sys.argv:         # the checkout to measure, before jointsim is imported
    ROOT = Path(sys.argv[sys.argv.index("--root") + 1]).resolve()
sys.path.insert(0, str(ROOT))

from jointsim.run import run_scene  # noqa: E402
from jointsim.scene import load_scene  # noqa: E402


def _mesh121() -> str:
    """The 121-pair lap mesh (``benchmarks/scale.py``'s, cached)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from scale import _mesh
    cache = Path(tempfile.gettempdir()) / "jointsim_scale_meshes"
    cache.mkdir(exist_ok=True)
    return str(_mesh(121, cache))


LAP121 = ["analysis.modes.full_model=false", "analysis.modes.monolithic=false"]
CASES = {
    "chain2": ("hbm", ROOT / "models/hbm/chain2_jenkins.toml", ["analysis.hbm.workers=1"]),
    "sdof_epmc": ("epmc", ROOT / "models/hbm/sdof_jenkins_epmc.toml", []),
    "lap_fixed": ("hbm", ROOT / "models/lap_joint_fixed_n_nodes.toml",
                  ["model.mesh='../meshes/lap_joint_coarse.msh'", "analysis.hbm.force_scale=[20.0]",
                   "analysis.hbm.omega_start=942.48", "analysis.hbm.omega_end=1005.3",
                   "analysis.modes.full_model=false", "analysis.modes.monolithic=false"]),
    "lap_epmc": ("epmc", ROOT / "models/lap_joint_nodes.toml",
                 ["model.mesh='../meshes/lap_joint_coarse.msh'",
                  "analysis.epmc.log10_amplitude_end=-3.0",
                  "analysis.modes.full_model=false", "analysis.modes.monolithic=false"]),
    "lap121_hbm": ("hbm", ROOT / "models/lap_joint_nodes.toml",
                   LAP121 + ["analysis.hbm.force_scale=[2.0]", "analysis.hbm.refine_peak=false",
                             "analysis.hbm.workers=1", "analysis.hbm.linear_solver='krylov'",
                             "analysis.hbm.max_points=20"]),
    "lap121_stuck": ("hbm", ROOT / "models/lap_joint_nodes.toml",
                     LAP121 + ["analysis.hbm.force_scale=[0.02]", "analysis.hbm.refine_peak=false",
                               "analysis.hbm.workers=1", "analysis.hbm.linear_solver='krylov'",
                               "analysis.hbm.max_points=30"]),
    "lap121_epmc": ("epmc", ROOT / "models/lap_joint_nodes.toml",
                    LAP121 + ["analysis.epmc.loop_amplitudes=[]",
                              "analysis.epmc.linear_solver='krylov'",
                              "analysis.epmc.max_points=10"]),
}


def _drop_others(path, kind):
    """Overrides are not enough to drop sections: write a copy keeping [analysis.<kind>]."""
    from resolution_study import only_analyses
    tmp = path.parent / f".indicator_cost_{path.name}"
    tmp.write_text(only_analyses(path.read_text(), (kind, "modes")))
    return tmp


def run_once(kind, path, overrides, on, out: Path) -> tuple[float, int]:
    """Wall time and points of one run; ``on``: True, False or ``"linear"`` (EPMC
    indicators from the first step only: ``analysis.epmc.error_newton_steps = 1``)."""
    extra = ["analysis.epmc.error_newton_steps=1"] if on == "linear" else []
    sc = load_scene(path, [*overrides, *extra,
                           f"analysis.{kind}.error_indicators={str(bool(on)).lower()}"])
    t = time.perf_counter()
    try:
        run_scene(sc, out, overwrite=True)
    except RuntimeError as exc:         # max_points reached: the points are written
        if "max_points" not in str(exc):
            raise
    dt = time.perf_counter() - t
    import h5py
    with h5py.File(out, "r") as h5:
        n = int(h5[f"{kind}/omega"].shape[0])
    return dt, n


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--root", default=str(ROOT), help="jointsim checkout to measure")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    import jointsim
    print(f"jointsim from {Path(jointsim.__file__).parent}; load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{'case':11s} {'points':>6s} {'with [s]':>9s} {'without [s]':>11s} {'ratio':>6s} "
          f"{'share':>6s}")
    for name in args.cases:
        kind, path, ov = CASES[name]
        if name.startswith("lap121"):
            ov = [f"model.mesh='{_mesh121()}'", *ov]
        scene_path = _drop_others(path, kind)
        try:
            with tempfile.TemporaryDirectory() as d:
                out = Path(d) / "x.h5"
                run_once(kind, scene_path, ov, True, out)          # warm-up (numba)
                variants = (True, False, "linear") if kind == "epmc" else (True, False)
                best = {v: float("inf") for v in variants}
                n = 0
                for _ in range(args.repeat):
                    for on in variants:
                        dt, n = run_once(kind, scene_path, ov, on, out)
                        best[on] = min(best[on], dt)
            lin = (f"   linear step only {best['linear']:.2f} s "
                   f"(x{best['linear'] / best[False]:.2f})" if "linear" in best else "")
            print(f"{name:11s} {n:6d} {best[True]:9.2f} {best[False]:11.2f} "
                  f"{best[True] / best[False]:6.2f} {1 - best[False] / best[True]:6.1%}{lin}",
                  flush=True)
        finally:
            scene_path.unlink(missing_ok=True)


if __name__ == "__main__":
    main()
