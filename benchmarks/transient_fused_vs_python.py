"""Time marching: the fused numba march against the Python stepper, side by side.

Both march the same scene through the same steps with the same scheme (the
results agree to round-off, see tests/solvers/test_transient_paths.py); the ratio is
the cost of stepping in Python.  Run from the repository root:

    python benchmarks/transient_fused_vs_python.py [--periods 20]

Timings on a shared machine are noisy; the ratio, measured in one run, is the
number to read.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from jointsim.model import build_model
from jointsim.scene import parse_scene
from jointsim.loads import LoadFunction
from jointsim.solvers.generalized_alpha import GeneralizedAlpha
from jointsim.solvers.static import static_start
from jointsim.solvers._transient_kernels import single_threaded


def two_dof(omega=1.2):
    """The 2-DOF Jenkins scene of issue 4 (M = I, K = [[2,-1],[-1,2]], C = 0.01 I)."""
    return parse_scene({
        "model": {"kind": "lumped", "M": [[1.0, 0.0], [0.0, 1.0]],
                  "K": [[2.0, -1.0], [-1.0, 2.0]], "C": [[0.01, 0.0], [0.0, 0.01]],
                  "contacts": [{"t_dof": 1, "N0": 1.0}]},
        "joint": {"law": "jenkins", "kt": 0.25, "mu": 0.2},
        "excitation": {"loads": [{"dof": 0, "force": {"harmonics": [{"h": 1, "cos": 0.15}]}}]},
        "analysis": {"transient": {"omega": omega}}}, "two_dof")


def chain(n=60, n_contacts=20, omega=0.3):
    """A reduced-model-sized chain: n masses, Iwan elements (20 sliders) to ground with
    a coupled, unilateral normal contact each, preloaded by constant forces."""
    K = np.diag(np.full(n, 2.0)) - np.diag(np.ones(n - 1), 1) - np.diag(np.ones(n - 1), -1)
    nt = n - n_contacts
    contacts = [{"t_dof": i, "n_dof": nt + i, "gap0": 0.0} for i in range(n_contacts)]
    loads = [{"dof": nt + i, "force": -1.0} for i in range(n_contacts)]
    loads.append({"dof": 0, "force": {"harmonics": [{"h": 1, "cos": 0.5}]}})
    return parse_scene({
        "model": {"kind": "lumped", "M": np.eye(n).tolist(), "K": K.tolist(),
                  "C": (0.01 * np.eye(n)).tolist(), "contacts": contacts},
        "joint": {"law": "iwan4", "kt": 1.0, "mu": 0.3, "kn": 20.0, "n_sliders": 20},
        "effects": {"normal": "coupled"},
        "excitation": {"loads": loads},
        "analysis": {"transient": {"omega": omega}}}, "chain")


def timed(sc, fused, periods, steps_per_period=256):
    model = build_model(sc)
    w = sc.analysis.transient.omega
    force = LoadFunction(model, w)
    st = static_start(model)
    ga = GeneralizedAlpha(model, force, rho_inf=0.9, fused=fused)
    s = ga.start(0.0, st.x, np.zeros(model.n_dof), st.contact.state)
    h = 2 * np.pi / w / steps_per_period
    ga.march_block(s, np.arange(3) * h)  # compile / warm up
    t = np.arange(periods * steps_per_period + 1) * h
    with single_threaded():
        t0 = time.perf_counter()
        s1, x, *_ = ga.march_block(s, t)
        dt = time.perf_counter() - t0
    return dt, x, t.size - 1


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--periods", type=int, default=20)
    args = ap.parse_args()
    print(f"{'scene':<28}{'DOFs':>6}{'steps':>9}{'fused [us/step]':>17}"
          f"{'Python [us/step]':>18}{'ratio':>8}{'max |dx|':>11}")
    for name, sc in (("2-DOF Jenkins (issue 4)", two_dof()),
                     ("60-DOF chain, 20 Iwan, N(t)", chain())):
        tf, xf, n = timed(sc, True, args.periods)
        tp, xp, _ = timed(sc, False, args.periods)
        nd = xf.shape[1]
        print(f"{name:<28}{nd:>6}{n:>9}{1e6 * tf / n:>17.2f}{1e6 * tp / n:>18.1f}"
              f"{tp / tf:>8.1f}{np.abs(xf - xp).max():>11.1e}")


if __name__ == "__main__":
    from jointsim.blas import limit_blas_threads
    limit_blas_threads()
    main()
