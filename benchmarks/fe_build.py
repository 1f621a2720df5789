"""Cost and accuracy of the FE lap joint versus mesh resolution (not collected by pytest).

For the committed meshes and two finer ones made on the fly, builds the
default scene's model and reports DOF counts, contact elements, the time to
assemble, reduce (Craig-Bampton) and preload, and the first elastic
frequencies of the stuck joint (reduced model) next to the unreduced model's.

    python benchmarks/fe_build.py [--set key=value ...]

Times are wall-clock on whatever the machine is doing; compare rows of one
run, not runs on different days.
"""
from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import numpy as np

from jointsim.fem.generate import RESOLUTIONS, lap_joint_mesh
from jointsim.fem.mesh import write_mesh
from jointsim.model import build_model
from jointsim.scene import load_scene
from jointsim.solvers.modes import eigenmodes, full_stuck_stiffness, stuck_modes

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--set", dest="overrides", action="append", default=[])
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    tmp = Path(tempfile.mkdtemp())
    meshes = {name: ROOT / "meshes" / f"lap_joint_{name}.msh" for name in RESOLUTIONS}
    for name, res in {"fine": (0.005, 0.02, 4), "finer": (0.0025, 0.01, 8)}.items():
        meshes[name] = write_mesh(lap_joint_mesh(*res), tmp / f"{name}.msh")
    print(f"{'mesh':>8} {'FE DOFs':>8} {'ROM DOFs':>8} {'pairs':>5} {'contact':>7} "
          f"{'build s':>8} {'reduce s':>8} {'preload s':>9} {'f1..f3 reduced [Hz]':>28} "
          f"{'max rel err vs full':>19}")
    for name, path in meshes.items():
        scene = load_scene(ROOT / "models" / "lap_joint_nodes.toml",
                           [f"model.mesh='{path}'", *a.overrides])
        t0 = time.perf_counter()
        m = build_model(scene)
        total = time.perf_counter() - t0
        r = stuck_modes(m, 8, 20.0)
        f = r.frequency_hz[r.elastic][:3]
        f_full, _ = eigenmodes(full_stuck_stiffness(m), m.fe.structure.M, 8)
        err = np.abs(r.frequency_hz[r.elastic][:5] / f_full[r.elastic][:5] - 1).max()
        N0 = m.contacts.N0
        print(f"{name:>8} {m.fe.n_full_dof:>8} {m.n_dof:>8} {N0.size:>5} {int((N0 > 0).sum()):>7} "
              f"{m.fe.build_time_s:>8.2f} {m.fe.reduce_time_s:>8.2f} "
              f"{m.preload.time_s:>9.2f} {np.array2string(f, precision=2):>28} "
              f"{err:>19.1e}   (total {total:.2f} s)")
    return 0


if __name__ == "__main__":
    from jointsim.blas import limit_blas_threads
    limit_blas_threads()
    raise SystemExit(main())
