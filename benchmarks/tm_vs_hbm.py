"""Time to the same steady state: time marching against harmonic balance, side by side.

For each case (a scene, a frequency and a force level) the script computes

1. a *reference* steady state: HBM with many harmonics and AFT samples;
2. **HBM**: the time of one Newton solve at the frequency, started cold from
   zero (its first step is the response of the structure with the joint stuck),
   best of ``--repeat``, with the cheapest harmonic set of a ladder
   (``HBM_LADDER``) whose first-harmonic amplitude is within 1% of the reference;
3. **time marching**: the march from rest at the static state (and, with
   ``start = "linear"``, from the steady response of the stuck structure), period
   by period, with the wall time and the first-harmonic amplitude of the response
   DOF recorded after every period.  The *time to 1%* is the wall time at the end
   of the first period after which every period's amplitude stays within 1% of the
   reference (the march runs on until it is steady, to be sure it stays).

It prints both times and their ratio.  Numba kernels are compiled before any
timing.  All timings are single runs on whatever machine runs the script (noisy
on a shared one); the ratio is what matters.

Cases: ``chain2`` and ``chain2_above`` (the 2-DOF Jenkins chain of
``models/hbm/chain2_jenkins.toml``, F = 0.2, at its resonance where the element
slips every period, and above it where it sticks once steady); ``lap_fixed`` (the
FE lap joint of ``models/lap_joint_nodes.toml`` with the normal load fixed at the
preload, 100 N at the peak of the softened first bending mode, coarse mesh by
default); ``lap_coupled`` (the same with the coupled, unilateral normal load, 10 N
at 990 rad/s, where the lap ends clap and HBM needs many harmonics);
``lap_fixed_10N`` (fixed N, 10 N at 990 rad/s: the joint stays stuck, the
response is linear and lightly damped).

Usage::

    python benchmarks/tm_vs_hbm.py                      # every case, coarse mesh
    python benchmarks/tm_vs_hbm.py --cases lap_coupled --mesh coarse
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import time
from pathlib import Path

import numpy as np

from jointsim.model import build_model
from jointsim.scene import load_scene
from jointsim.solvers.crosscheck import first_harmonic_amplitude
from jointsim.solvers.hbm import HBMSystem, solve_point
from jointsim.harmonics import dft_matrix
from jointsim.solvers.transient import march_steady

ROOT = Path(__file__).resolve().parents[1]


@dataclasses.dataclass
class Case:
    name: str
    scene: Path
    overrides: list
    omega: float            # rad/s
    force_scale: float
    dof: str | int          # response DOF (index or model point)
    ref_hmax: int           # reference HBM: harmonics 0..ref_hmax
    ref_samples: int
    steps_per_period: int   # time marching
    max_periods: int
    steady_tol: float


def cases(mesh: str) -> dict:
    lap = ROOT / "models" / "lap_joint_nodes.toml"
    mesh_set = f'model.mesh="../meshes/lap_joint_{mesh}.msh"'
    chain = ROOT / "models" / "hbm" / "chain2_jenkins.toml"
    return {
        "chain2": Case("2-DOF Jenkins chain, F = 0.2, at resonance", chain, [], 1.0202, 0.2,
                       0, 31, 4096, 256, 5000, 1e-8),
        "chain2_above": Case("2-DOF Jenkins chain, F = 0.2, above resonance", chain, [],
                             1.15, 0.2, 0, 31, 4096, 256, 5000, 1e-8),
        "lap_fixed": Case(f"FE lap joint ({mesh} mesh), fixed N, 100 N at the peak",
                          lap, [mesh_set, 'effects.normal="fixed"'], 982.0, 10.0,
                          "response", 31, 4096, 256, 3000, 1e-8),
        "lap_fixed_10N": Case(f"FE lap joint ({mesh} mesh), fixed N, 10 N (stuck)",
                              lap, [mesh_set, 'effects.normal="fixed"'], 990.0, 1.0,
                              "response", 15, 1024, 256, 3000, 1e-8),
        "lap_coupled": Case(f"FE lap joint ({mesh} mesh), coupled N, 10 N, clapping",
                            lap, [mesh_set, 'effects.normal="coupled"'], 990.0, 1.0,
                            "response", 31, 4096, 256, 3000, 1e-8),
    }


#: HBM settings tried in turn, cheapest first: (highest harmonic, AFT samples)
HBM_LADDER = ((1, 64), (3, 128), (7, 256), (15, 512), (31, 1024))


def first_harmonic(X, harmonics, dof: int) -> float:
    """First-harmonic amplitude of one DOF from coefficients ``[0, 1c, 1s, ...]``."""
    return float(first_harmonic_amplitude(X, harmonics)[dof])


def hbm_time(model, case: Case, harmonics, n_samples, repeat: int):
    """Best-of-``repeat`` time of a cold Newton solve (system set-up included), and
    the solution."""
    best, sol = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        system = HBMSystem(model, harmonics, n_samples)
        sol = solve_point(system, case.omega, system.force_coefficients(case.force_scale),
                          tol=1e-10, max_iter=50)
        best = min(best, time.perf_counter() - t0)
    return best, sol


def march_time(model, settings, dof: int, ref_amp: float, tol: float = 0.01):
    """March, recording the amplitude and wall time after each period."""
    n = settings.steps_per_period
    stamps, amps = [], []
    t0 = time.perf_counter()
    E = dft_matrix((0, 1), n, settings.omega)

    def on_period(p, change):
        X = E @ p.x[:n, dof]
        amps.append(float(np.hypot(X[1], X[2])))
        stamps.append(time.perf_counter() - t0)

    res = march_steady(model, settings, on_period=on_period, progress=False)
    amps = np.asarray(amps)
    off = np.abs(amps / ref_amp - 1.0) > tol
    if off[-1]:
        k, t = None, np.nan
    else:
        bad = np.flatnonzero(off)
        k = int(bad[-1]) + 1 if bad.size else 0
        t = stamps[k]
    return res, t, k, amps


def warm_up(model, case: Case):
    """Compile the numba kernels (HBM and march) outside the timings."""
    s = HBMSystem(model, (0, 1), 16)
    solve_point(s, case.omega, s.force_coefficients(case.force_scale), max_iter=2)
    tr = dataclasses.replace(model_settings(case), steps_per_period=16, max_periods=2,
                             min_periods=2)
    quiet = logging.getLogger("jointsim")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        march_steady(model, tr, progress=False)
    finally:
        quiet.setLevel(level)


def model_settings(case: Case, start: str = "rest"):
    sc = load_scene(case.scene, case.overrides + [
        f"analysis.transient.omega={case.omega}",
        f"analysis.transient.force_scale={case.force_scale}",
        f"analysis.transient.steps_per_period={case.steps_per_period}",
        f"analysis.transient.max_periods={case.max_periods}",
        f"analysis.transient.steady_tol={case.steady_tol}",
        f"analysis.transient.start='{start}'",
        "analysis.transient.harmonics=[0, 1, 2, 3]"])
    return sc.analysis.transient


def run_case(case: Case, repeat: int, starts, tol: float = 0.01) -> list:
    sc = load_scene(case.scene, case.overrides)
    t0 = time.perf_counter()
    model = build_model(sc)
    build = time.perf_counter() - t0
    dof = model.points[case.dof] if isinstance(case.dof, str) else int(case.dof)
    warm_up(model, case)
    ref_h = tuple(range(case.ref_hmax + 1))
    t_ref, ref = hbm_time(model, case, ref_h, case.ref_samples, 1)
    if not ref.convergence.success:
        raise RuntimeError(f"{case.name}: reference HBM failed: {ref.convergence.message}")
    ref_amp = first_harmonic(ref.X, ref_h, dof)
    print(f"\n{case.name}: omega = {case.omega:g} rad/s, {model.n_dof} DOFs, "
          f"{model.contacts.n_elements} contact elements (model built in {build:.2f} s)")
    print(f"  reference HBM (H = 0..{case.ref_hmax}, {case.ref_samples} samples): amplitude "
          f"{ref_amp:.6g} ({t_ref:.2f} s)")
    t_hbm, label = np.nan, "none within 1%"
    for hmax, nt in HBM_LADDER:
        hs = tuple(range(hmax + 1))
        t, sol = hbm_time(model, case, hs, nt, repeat)
        a = first_harmonic(sol.X, hs, dof)
        ok = sol.convergence.success and abs(a / ref_amp - 1.0) <= tol
        print(f"  HBM H = 0..{hmax}, {nt} samples, cold Newton: {t * 1e3:.1f} ms, "
              f"{sol.convergence.iterations} iterations, amplitude {a:.6g} "
              f"({a / ref_amp - 1:+.2e}){'' if sol.convergence.success else ' NOT CONVERGED'}")
        if ok:
            t_hbm, label = t, f"HBM H=0..{hmax}/{nt}"
            break
    rows = [(label, case.name, t_hbm, np.nan)]
    for start in starts:
        tr = model_settings(case, start)
        res, t, k, amps = march_time(model, tr, dof, ref_amp, tol)
        steps = res.stats["steps"]
        us = 1e6 * res.wall_time / max(steps, 1)
        final = amps[-1] / ref_amp - 1 if amps.size else np.nan
        within = f"{t:.3f} s (period {k + 1})" if np.isfinite(t) else "never"
        print(f"  time marching from {start}, {case.steps_per_period} steps/period: "
              f"{res.convergence.message}; {amps.size} periods, {res.wall_time:.2f} s "
              f"({us:.1f} us/step); final amplitude {final:+.2e}; within 1% after {within}")
        rows.append((f"TM from {start}", case.name, t, t / t_hbm))
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cases", default="chain2,chain2_above,lap_fixed,lap_fixed_10N,"
                   "lap_coupled", help="comma-separated: chain2, chain2_above, lap_fixed, "
                   "lap_fixed_10N, lap_coupled")
    p.add_argument("--mesh", default="coarse", choices=("coarse", "default"))
    p.add_argument("--repeat", type=int, default=3, help="HBM solves timed (best of)")
    p.add_argument("--starts", default="rest,linear")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    table = cases(args.mesh)
    rows = []
    for name in args.cases.split(","):
        rows += run_case(table[name], args.repeat, args.starts.split(","))
    print("\nsummary (time to within 1% of the reference first-harmonic amplitude)")
    for method, case, t, ratio in rows:
        r = "" if not np.isfinite(ratio) else f"  TM/HBM = {ratio:.3g}"
        print(f"  {case[:56]:56s} {method:20s} {t:9.4f} s{r}")


if __name__ == "__main__":
    from jointsim.blas import limit_blas_threads
    limit_blas_threads()
    main()
