"""Cost and accuracy of the FE lap joint versus mesh resolution (not collected by pytest).

For the committed meshes and two finer ones made on the fly, builds the
default scene's model and reports DOF counts, contact elements, the time to
assemble, reduce (Craig-Bampton) and preload, and the first elastic
frequencies of the stuck joint (reduced model) next to the unreduced model's.

    python benchmarks/fe_build.py [--set key=value ...]
    python benchmarks/fe_build.py --orderings
    python benchmarks/fe_build.py --projection [--gauss 96 192 480]

``--orderings`` compares, on the default scene's interior stiffness ``K_II`` at 96
and 120 Gauss points, SuperLU's default ordering with the one the reduction uses
(:func:`jointsim.fem.reduction.spd_lu`): fill, factorisation, one solve (the
Lanczos iterations), the constraint modes' solve, and how far the constraint modes
of the two factorisations differ.

``--projection`` reduces the default scene at ``--gauss`` Gauss points (the lap refined
alone from 192 on: ``dx_full = 0.004``, ``ny_half = 10``; ``CB s`` the whole reduction)
and compares its reduced matrices (round 42: each product formed on and above the
diagonal, on two threads) with the whole products ``T^T K T`` and ``T^T M T`` side by
side on two threads (before round 42): their time, their largest difference, the
stuck structure's five lowest elastic frequencies from each against the unreduced
model's, and against each other.

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


def projection(gauss) -> None:
    """Print the comparison of ``--projection`` (module docstring)."""
    from concurrent.futures import ThreadPoolExecutor

    import scipy.sparse as sp

    from jointsim.fem.build import washer_substitution
    from jointsim.fem.reduction import craig_bampton

    def whole(T, A):                         # before round 42, blocks of 256 columns
        out = np.empty((T.shape[1],) * 2)
        for j in range(0, T.shape[1], 256):
            out[:, j:j + 256] = T.T @ (A @ T[:, j:j + 256])
        return 0.5 * (out + out.T)

    print(f"{'Gauss pts':>9} {'FE DOFs':>8} {'n_r':>5} {'CB s':>7} {'whole s':>8} {'now s':>6} "
          f"{'speed-up':>8} {'dK rel':>8} {'dM rel':>8} {'f err whole':>11} {'f err now':>9} "
          f"{'f now/whole':>11}")
    for n in gauss:
        ov = [] if n == 96 else [f"model.dx_lap={0.24 / n:.8g}", "model.dx_full=0.004",
                                 "model.ny_half=10"]
        m = build_model(load_scene(ROOT / "models" / "lap_joint.toml", ov))
        st, n_modes = m.fe.structure, m.fe.cb.n_modes
        S = washer_substitution(st)
        K = sp.csr_matrix(st.K if S is None else S.T @ st.K @ S)
        M = sp.csr_matrix(st.M if S is None else S.T @ st.M @ S)
        t0 = time.perf_counter()
        cb = craig_bampton(K, M, m.fe.cb.retained, n_modes)        # (its basis T)
        t1 = time.perf_counter()
        with ThreadPoolExecutor(max_workers=2) as pool:
            Kw, Mw = pool.submit(whole, cb.T, K), pool.submit(whole, cb.T, M)
            Kw, Mw = Kw.result(), Mw.result()
        t2 = time.perf_counter()
        Kn = cb.project(K, threads=2)
        Mn = cb.project(M, threads=2)
        t3 = time.perf_counter()
        # the stuck structure's frequencies: the joint's stiffness added to each
        f_full, _ = eigenmodes(full_stuck_stiffness(m), st.M, 8)
        el = stuck_modes(m, 8, 20.0).elastic
        dK = sp.csr_matrix(m.linearisation.K) - sp.csr_matrix(m.K)
        errs, fs = [], []
        for Kr, Mr in ((Kw, Mw), (Kn, Mn)):
            f, _ = eigenmodes(sp.csr_matrix(Kr) + dK, sp.csr_matrix(Mr), 8)
            fs.append(f[el][:5])
            errs.append(np.abs(f[el][:5] / f_full[el][:5] - 1).max())
        print(f"{n:>9} {st.n_dof:>8} {cb.T.shape[1]:>5} {t1 - t0:>7.2f} {t2 - t1:>8.2f} "
              f"{t3 - t2:>6.2f} {(t2 - t1) / (t3 - t2):>8.2f} "
              f"{np.abs(Kn - Kw).max() / np.abs(Kw).max():>8.1e} "
              f"{np.abs(Mn - Mw).max() / np.abs(Mw).max():>8.1e} {errs[0]:>11.1e} "
              f"{errs[1]:>9.1e} {np.abs(fs[1] / fs[0] - 1).max():>11.1e}", flush=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--set", dest="overrides", action="append", default=[])
    p.add_argument("--orderings", action="store_true",
                   help="compare the sparse LU orderings of the reduction instead")
    p.add_argument("--projection", action="store_true",
                   help="compare the reduced matrices' products with the whole ones instead")
    p.add_argument("--gauss", type=int, nargs="+", default=[96, 192, 480],
                   help="Gauss points of --projection (multiples of 8)")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    if a.orderings:
        orderings()
        return 0
    if a.projection:
        projection(a.gauss)
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
