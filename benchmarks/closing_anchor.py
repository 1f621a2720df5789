"""Sample-count convergence (aliasing) of clapping HBM points with
``AFT(closing="interpolated")`` (scene key ``joint.closing``: the anchor of a re-closing
contact at the interpolated closing instant, and the interval of each opening
integrated up to the interpolated opening instant) or ``AFT(closing="sample")`` (the
default: the anchor at the last open sample, plain samples), issue 13 case 5.

Two points, each solved by Newton at fixed frequency for every sample count from the
same start, first harmonic compared with the finest interpolated solution:

* ``fold``: the fold scene (mu = 0.3, force scale 0.1) on its lower branch near
  omega = 1.95, contact open over about 30 % of the period (from the scene's FRC);
* ``lap``: the coupled lap joint, coarse mesh, 20 N at 1053 rad/s, H = 0..7, undamped
  Craig-Bampton modes damped at 5 % (as in the coupled cross-check).

Usage: ``PYTHONPATH=. python benchmarks/closing_anchor.py [fold|lap]`` (both by
default; lap: minutes on 2 shared cores).
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np

from jointsim.harmonics import coefficient_index
from jointsim.model import build_model
from jointsim.run import run_scene
from jointsim.scene import load_scene
from jointsim.solvers.frc import first_point, frc_scales
from jointsim.solvers.hbm import HBMSystem, solve_point

ROOT = Path(__file__).resolve().parents[1]


def _fold():
    sc = load_scene(ROOT / "models/hbm/chain2_friction_fold.toml", [])
    with tempfile.TemporaryDirectory() as d:
        out = run_scene(sc, Path(d) / "fold.h5")
        with h5py.File(out) as h:
            om, X = h["hbm/omega"][()], h["hbm/X"][()]
    i = int(np.flatnonzero((om > 1.9) & (om < 2.0))[0])
    return build_model(sc), 7, 0.1, float(om[i]), X[i], [32, 64, 128, 256, 512, 1024, 2048,
                                                          4096, 16384]


def _lap():
    from jointsim.solvers.march_accuracy import undamped_modes, with_mode_damping
    sc = load_scene(ROOT / "models/lap_joint_nodes.toml",
                    ["model.mesh='../meshes/lap_joint_coarse.msh'"])
    model = build_model(sc)
    model = with_mode_damping(model, undamped_modes(model), 0.05)
    hs = tuple(range(8))
    # the branch start's robust path (Newton from the static state, else a force
    # homotopy) at 128 samples, then Newton at 1,024
    s = HBMSystem(model, hs, 128)
    s.aft.closing = "interpolated"
    scale, rscale = frc_scales(s, s.force_coefficients(2.0), 1000.0, 1100.0)
    first = first_point(s, 1053.0, 2.0, scale=scale, rscale=rscale, tol=1e-9)
    assert first.convergence.success, first.convergence.message
    s = HBMSystem(model, hs, 1024)
    s.aft.closing = "interpolated"
    sol = solve_point(s, 1053.0, s.force_coefficients(2.0), z0=first.z, tol=1e-11,
                      max_iter=60)
    assert sol.convergence.success, sol.convergence.message
    return model, 7, 2.0, 1053.0, sol.X, [128, 256, 512, 1024, 2048, 4096, 8192]


def convergence(model, H, fs, omega, X0, nts):
    hs = tuple(range(H + 1))
    rows = list(coefficient_index(hs, 1))
    res = {}
    for closing in ("sample", "interpolated"):
        X, out = X0.copy(), []
        for nt in nts:
            s = HBMSystem(model, hs, nt)
            s.aft.closing = closing
            sol = solve_point(s, omega, s.force_coefficients(fs),
                              z0=s.contact_coordinates(X), tol=1e-11, max_iter=60)
            if not sol.convergence.success:
                out.append(np.full(len(rows) * model.n_dof, np.nan))
                continue
            X = sol.X
            out.append(X[rows].ravel())
        res[closing] = out
    ref = res["interpolated"][-1]
    nr = np.linalg.norm(ref)
    print(f"omega = {omega:.6g}, H = 0..{H}: first harmonic against {nts[-1]} samples "
          "(interpolated)")
    print("   n_samples   last open sample   closing instant")
    for j, nt in enumerate(nts):
        print(f"   {nt:9d}   {np.linalg.norm(res['sample'][j] - ref) / nr:16.3e}"
              f"   {np.linalg.norm(res['interpolated'][j] - ref) / nr:15.3e}")


if __name__ == "__main__":
    which = sys.argv[1:] or ["fold", "lap"]
    for w in which:
        print(w)
        convergence(*(_fold() if w == "fold" else _lap()))
