"""Cost and accuracy of the FE lap joint versus mesh resolution (not collected by pytest).

For the committed meshes and two finer ones made on the fly, builds the
default scene's model and reports DOF counts, contact elements, the time to
assemble, reduce (Craig-Bampton) and preload, and the first elastic
frequencies of the stuck joint (reduced model) next to the unreduced model's.

    python benchmarks/fe_build.py [--set key=value ...]
    python benchmarks/fe_build.py --orderings

``--orderings`` compares, on the default scene's interior stiffness ``K_II`` at 96
and 120 Gauss points, SuperLU's default ordering with the one the reduction uses
(:func:`jointsim.fem.reduction.spd_lu`): fill, factorisation, one solve (the
Lanczos iterations), the constraint modes' solve, and how far the constraint modes
of the two factorisations differ.

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


def orderings() -> None:
    """Print the ordering comparison of ``--orderings`` (module docstring)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from jointsim.fem.build import washer_substitution
    from jointsim.fem.reduction import spd_lu

    print(f"{'Gauss pts':>9} {'n_I':>6} {'ordering':>9} {'fill':>9} {'factor s':>8} "
          f"{'1 solve ms':>10} {'n_B solves s':>12} {'Psi rel diff':>12}")
    for label, ov in (("96", []), ("120", ["model.dx_lap=0.002", "model.dx_full=0.004",
                                            "model.ny_half=10"])):
        m = build_model(load_scene(ROOT / "models" / "lap_joint.toml", ov))
        st, B = m.fe.structure, m.fe.cb.retained
        S = washer_substitution(st)
        K = sp.csr_matrix(st.K if S is None else S.T @ st.K @ S)
        inner = np.ones(K.shape[0], bool)
        inner[B] = False
        K_II = sp.csc_matrix(K[inner][:, inner])
        K_IB = np.asfortranarray(K[inner][:, B].toarray())
        psi = {}
        for name, factor in (("COLAMD", spla.splu), ("spd_lu", spd_lu)):
            t0 = time.perf_counter()
            lu = factor(K_II)
            t1 = time.perf_counter()
            for _ in range(10):
                lu.solve(np.ones(K_II.shape[0]))
            t2 = time.perf_counter()
            psi[name] = lu.solve(K_IB)
            t3 = time.perf_counter()
            diff = np.abs(psi[name] - psi["COLAMD"]).max() / np.abs(psi["COLAMD"]).max()
            print(f"{label:>9} {K_II.shape[0]:>6} {name:>9} {lu.L.nnz + lu.U.nnz:>9} "
                  f"{t1 - t0:>8.3f} {(t2 - t1) * 100:>10.1f} {t3 - t2:>12.2f} {diff:>12.1e}",
                  flush=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--set", dest="overrides", action="append", default=[])
    p.add_argument("--orderings", action="store_true",
                   help="compare the sparse LU orderings of the reduction instead")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    if a.orderings:
        orderings()
        return 0
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
