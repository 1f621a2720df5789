"""What accuracy costs in time: error against wall time (not collected by pytest).

First row, the FE lap joint itself (models/lap_joint_fixed_n.toml and
models/lap_joint.toml on their default 10 mm mesh), one harmonic-balance point
at 20 N (force scale 2) at the fixed-N scene's 20 N FRC peak, solved from the
static state, error of the first-harmonic vector of the contact and response
coordinates against a converged reference of the same point:

* harmonics H, fixed N (Nt = 1024; reference H = 31);
* AFT samples Nt, fixed N (H = 7; reference Nt = 4096);
* harmonics H, coupled N (Nt = 512; reference H = 15: the coupled FRC and
  EPMC fail at H = 11 and 15 today, a single point does not).

Second row, the 2-DOF Jenkins chain (models/hbm/chain2_jenkins.toml) near its
slipping peak: harmonics H (Nt = 2048, reference H = 63), the time step of
time marching to the steady state (reference: HBM with H = 63), and the
samples per period of a prescribed Jenkins loop against the analytic first
harmonic.  (The mesh is left to ``jointsim converge`` with ``model.dx_lap``:
with node-to-node contact the first bending frequency converges only to
about 1 %, not monotonically, so it has no converged reference here.)

    python benchmarks/accuracy_cost.py [--quick] [--figure docs/img/accuracy_cost.png]

Times are wall-clock medians of repeated warm calls (numba compilation is
excluded by a warm-up call; rows slower than 2 s are timed once) on whatever
the machine is doing: compare rows of one run, not runs on different days.
Each panel states whether its cost rises with its accuracy.
"""
from __future__ import annotations

import argparse
import logging
import statistics
import time
from pathlib import Path

import numpy as np

from jointsim.contact import tangential_law
from jointsim.model import build_model
from jointsim.scene import Joint, TransientAnalysis, load_scene
from jointsim.harmonics import HarmonicBasis, coefficient_index
from jointsim.solvers.hbm import HBMSystem, solve_point
from jointsim.solvers.prescribed import march_prescribed

ROOT = Path(__file__).resolve().parents[1]
CHAIN = ROOT / "models" / "hbm" / "chain2_jenkins.toml"
OMEGA, SCALE = 1.02, 0.2
FIXED = ROOT / "models" / "lap_joint_fixed_n.toml"
COUPLED = ROOT / "models" / "lap_joint.toml"
#: the fixed-N FRC peak at 20 N (force scale 2) with H = 0..7, Nt = 128 [rad/s]
FE_OMEGA, FE_SCALE = 988.15, 2.0


def timed(fn, repeat: int = 3):
    """Median wall time of ``fn()`` after one warm-up call, and its last result
    (a warm-up slower than 2 s is followed by one timed call)."""
    t0 = time.perf_counter()
    out = fn()
    if time.perf_counter() - t0 > 2.0:
        repeat = 1
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
    warm = TransientAnalysis(omega=OMEGA, force_scale=SCALE, steps_per_period=32,
                             max_periods=2, steady_tol=1e-8, harmonics=(0, 1), start="linear")
    march_steady(model, warm, progress=False)  # compile or load the kernels first
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


def fe_point(model, H: int, nt: int):
    """First-harmonic coefficients of every DOF at the FE point [m], and the solve time [s]."""
    sys_ = HBMSystem(model, tuple(range(H + 1)), nt)
    F = sys_.force_coefficients(FE_SCALE)

    def solve():
        p = solve_point(sys_, FE_OMEGA, F, tol=1e-10, max_iter=60)
        if not p.convergence.success:
            raise RuntimeError(f"H = {H}, Nt = {nt}: {p.convergence.message}")
        return p
    t, p = timed(solve)
    ic, is_ = coefficient_index(tuple(range(H + 1)), 1)
    return np.concatenate([p.X[ic], p.X[is_]]), t


def fe_harmonics_table(path, hs, h_ref, nt):
    model = build_model(load_scene(path))
    ref, _ = fe_point(model, h_ref, nt)
    rows = []
    for H in hs:
        try:
            v, t = fe_point(model, H, nt)
        except RuntimeError as exc:
            print(f"  {exc}")
            continue
        rows.append((H, np.abs(v - ref).max() / np.abs(ref).max(), t))
    return rows


def fe_samples_table(path, nts, nt_ref, H=7):
    model = build_model(load_scene(path))
    ref, _ = fe_point(model, H, nt_ref)
    rows = []
    for nt in nts:
        v, t = fe_point(model, H, nt)
        rows.append((nt, np.abs(v - ref).max() / np.abs(ref).max(), t))
    return rows


def cost_rises(rows) -> bool:
    """Time rises as the error falls: ordered by error (largest first), times increase
    (within 20 %, the noise of a shared machine)."""
    r = sorted([x for x in rows if x[1] > 0], key=lambda x: -x[1])
    return all(b[2] >= 0.8 * a[2] for a, b in zip(r, r[1:]))


def print_table(title, head, rows):
    print(f"\n{title}")
    print(f"{head:>34} {'rel. error':>11} {'wall time':>11}")
    for k, e, t in rows:
        print(f"{str(k):>34} {e:>11.2e} {1e3 * t:>9.2f} ms")
    print(f"{'cost rises with accuracy':>34} {'yes' if cost_rises(rows) else 'NO'}")


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
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("wall time [ms]")
        ax.set_ylabel("relative error")
        ax.set_title(title, fontsize=8)
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
    q = a.quick
    tables = [
        ("FE lap joint, fixed N, 20 N: harmonics H (Nt = 1024, ref. H = 31)", "H=",
         fe_harmonics_table(FIXED, [1, 3, 7] if q else [1, 3, 5, 7, 11, 15],
                            15 if q else 31, 1024)),
        ("FE lap joint, fixed N, 20 N: AFT samples Nt (H = 7, ref. 4096)", "Nt=",
         fe_samples_table(FIXED, [32, 128] if q else [16, 32, 64, 128, 256, 512], 4096)),
        ("FE lap joint, coupled N, 20 N: harmonics H (Nt = 512, ref. H = 15)", "H=",
         fe_harmonics_table(COUPLED, [1, 3, 7] if q else [1, 3, 5, 7, 9, 11], 15, 512)),
        ("2-DOF chain: harmonics H (HBM, Nt = 2048, ref. H = 63)", "H=",
         harmonics_table(model, q)),
        ("2-DOF chain: time steps per period (TM, ref. HBM H = 63)", "",
         timestep_table(model, q)),
        ("samples per period (Jenkins loop, analytic ref.)", "", prescribed_table(q)),
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
