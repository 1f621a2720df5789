"""What accuracy costs in time: error against wall time (not collected by pytest).

Four dials, each measured side by side in one run against a converged
reference computed by the same code:

* harmonics H (harmonic balance, 2-DOF Jenkins chain near its slipping peak,
  Nt = 2048 so that aliasing plays no part; reference H = 63);
* AFT samples Nt (harmonic balance, H = 7; reference Nt = 8192), and the
  samples per period of a prescribed-motion Jenkins loop against the analytic
  first-harmonic coefficients;
* the time step (time marching of the same 2-DOF chain to its steady state;
  reference: the HBM solution with H = 63);
* the mesh (the FE lap joint's first bending frequency; reference: a mesh
  with 2.5 mm lap elements).

    python benchmarks/accuracy_cost.py [--quick] [--figure docs/img/accuracy_cost.png]

Times are wall-clock medians of repeated warm calls (numba compilation is
excluded by a warm-up call) on whatever the machine is doing: compare rows of
one run, not runs on different days.
"""
from __future__ import annotations

import argparse
import logging
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from jointsim.contact import tangential_law
from jointsim.model import build_model
from jointsim.scene import Joint, TransientAnalysis, load_scene
from jointsim.harmonics import HarmonicBasis
from jointsim.solvers.hbm import HBMSystem, solve_point
from jointsim.solvers.prescribed import march_prescribed

ROOT = Path(__file__).resolve().parents[1]
CHAIN = ROOT / "models" / "hbm" / "chain2_jenkins.toml"
OMEGA, SCALE = 1.02, 0.2


def timed(fn, repeat: int = 3):
    """Median wall time of ``fn()`` after one warm-up call, and its last result."""
    out = fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def hbm_response(model, H: int, nt: int, n_eval: int = 4096):
    """x_0(t) of the chain at OMEGA on a fine grid, and the solve time."""
    sys_ = HBMSystem(model, tuple(range(H + 1)), nt)
    F = sys_.force_coefficients(SCALE)

    def solve():
        p = solve_point(sys_, OMEGA, F, tol=1e-12)
        if not p.convergence.success:
            raise RuntimeError(p.convergence.message)
        return p
    t, p = timed(solve)
    return HarmonicBasis(tuple(range(H + 1)), n_eval).Gam @ p.X[:, 0], p.X, t


def harmonics_table(model, quick: bool):
    ref, _, _ = hbm_response(model, 63, 2048)
    rows = []
    for H in ([1, 3, 5, 7] if quick else [1, 2, 3, 5, 7, 9, 13, 17]):
        x, _, t = hbm_response(model, H, 2048)
        rows.append((H, np.abs(x - ref).max() / np.abs(ref).max(), t))
    return rows


def samples_table(model, quick: bool):
    _, Xref, _ = hbm_response(model, 7, 8192)
    rows = []
    for nt in ([16, 32, 64, 128] if quick else [16, 32, 64, 128, 256, 512, 1024, 2048]):
        _, X, t = hbm_response(model, 7, nt)
        rows.append((nt, np.abs(X - Xref).max() / np.abs(Xref).max(), t))
    return rows


def prescribed_table(quick: bool):
    """Jenkins under u = cos(theta): first-harmonic coefficients by DFT vs analytic."""
    kt, mu, N, A = 1.0, 0.1, 3.0, 1.0
    Fs = mu * N
    beta = np.arccos(1 - 2 * Fs / (kt * A))
    c1 = kt * A / np.pi * (beta - np.sin(2 * beta) / 2)
    s1 = -4 * Fs / np.pi * (1 - Fs / (kt * A))
    law = tangential_law("jenkins", "anchor", Joint(mu=mu, kt=kt), [1.0])
    rows = []
    for ns in ([64, 256, 1024] if quick else [64, 128, 256, 512, 1024, 2048, 4096, 8192]):
        th = 2 * np.pi * np.arange(3 * ns) / ns
        u = A * np.cos(th)[None, :]
        Nn = np.full(u.shape, N)

        def run():
            return march_prescribed(u, Nn, law, ns, 1.0)
        t, res = timed(run)
        f = res.f[0, -ns:]
        c, s = 2 / ns * f @ np.cos(th[:ns]), 2 / ns * f @ np.sin(th[:ns])
        rows.append((ns, max(abs(c / c1 - 1), abs(s / s1 - 1)), t))
    return rows


def timestep_table(model, quick: bool):
    from jointsim.solvers.transient import march_steady
    _, Xref, _ = hbm_response(model, 63, 2048)
    ref1 = np.hypot(Xref[1, 0], Xref[2, 0])
    rows = []
    for n in ([128, 256, 512] if quick else [64, 128, 256, 512, 1024, 2048]):
        st = TransientAnalysis(omega=OMEGA, force_scale=SCALE, steps_per_period=n,
                               max_periods=4000, steady_tol=1e-8, harmonics=(0, 1),
                               start="linear")
        t0 = time.perf_counter()
        res = march_steady(model, st, progress=False)
        t = time.perf_counter() - t0
        X = res.X
        a1 = np.hypot(X[1, 0], X[2, 0])
        rows.append((n, abs(a1 / ref1 - 1), t))
    return rows


def mesh_table(quick: bool):
    from jointsim.fem.generate import lap_joint_mesh
    from jointsim.fem.mesh import write_mesh
    from jointsim.solvers.modes import stuck_modes
    tmp = Path(tempfile.mkdtemp())
    meshes = {"coarse (15 mm)": ROOT / "meshes" / "lap_joint_coarse.msh",
              "default (10 mm)": ROOT / "meshes" / "lap_joint_default.msh",
              "fine (5 mm)": write_mesh(lap_joint_mesh(0.005, 0.02, 4), tmp / "fine.msh")}
    ref_path = write_mesh(lap_joint_mesh(0.0025, 0.01, 8), tmp / "finer.msh")

    def f1(path):
        scene = load_scene(ROOT / "models" / "lap_joint.toml", [f"model.mesh='{path}'"])
        t0 = time.perf_counter()
        m = build_model(scene)
        r = stuck_modes(m, 6, suspension_hz=20.0)
        return r.frequency_hz[r.elastic][0], time.perf_counter() - t0, m
    f_ref, t_ref, m_ref = f1(ref_path)
    rows = []
    for name, path in meshes.items():
        f, t, m = f1(path)
        rows.append((f"{name}, {m.fe.n_full_dof} DOFs", abs(f / f_ref - 1), t))
    rows.append((f"reference (2.5 mm), {m_ref.fe.n_full_dof} DOFs", 0.0, t_ref))
    return rows


def print_table(title, head, rows):
    print(f"\n{title}")
    print(f"{head:>34} {'rel. error':>11} {'wall time':>11}")
    for k, e, t in rows:
        print(f"{str(k):>34} {e:>11.2e} {1e3 * t:>9.2f} ms")


def figure(tables, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ncol = 3
    nrow = -(-len(tables) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.4 * ncol, 3.6 * nrow))
    axes = axes.ravel()
    for ax in axes[len(tables):]:
        ax.set_visible(False)
    for ax, (title, label, rows) in zip(axes, tables):
        t = np.array([r[2] for r in rows]) * 1e3
        e = np.array([max(r[1], 1e-17) for r in rows])
        keep = np.array([r[1] > 0 for r in rows])
        ax.loglog(t[keep], e[keep], "o-")
        for r, ti, ei, k in zip(rows, t, e, keep):
            if k:
                ax.annotate(f"{label}{str(r[0]).split(',')[0].split(' ')[0]}", (ti, ei),
                            fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.set_xlabel("wall time [ms]")
        ax.set_ylabel("relative error")
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"\nfigure: {path}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer rows")
    p.add_argument("--figure", default=None, help="write an error-vs-time figure")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    model = build_model(load_scene(CHAIN))
    tables = [
        ("harmonics H (HBM, Nt = 2048)", "H=", harmonics_table(model, a.quick)),
        ("AFT samples Nt (HBM, H = 7)", "Nt=", samples_table(model, a.quick)),
        ("samples per period (Jenkins loop)", "", prescribed_table(a.quick)),
        ("time steps per period (TM)", "", timestep_table(model, a.quick)),
        ("mesh (FE f1, build + reduce + modes)", "", mesh_table(a.quick)),
    ]
    for title, label, rows in tables:
        print_table(title, label or "setting", rows)
    if a.figure:
        figure(tables, a.figure)
    return 0


if __name__ == "__main__":
    from jointsim.blas import limit_blas_threads
    limit_blas_threads()
    raise SystemExit(main())
