"""Issue 13 case 1: the first point of a branch is reached by a force homotopy.

``models/hbm/chain2_friction_fold.toml`` at force scales 0.3 to 0.7: one Newton
solve from the static state does not converge at the first frequency (the
contact slips and opens there), and the whole FRC used to be lost.  Oracles:
the homotopy reproduces the Newton solution where Newton converges (0.2), its
end satisfies the harmonic balance, and the branch then runs to its end.
"""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from jointsim.analyses.hbm import _system
from jointsim.model import build_model
from jointsim.run import run_scene
from jointsim.scene import load_scene
from jointsim.solvers.frc import first_point, force_homotopy, frc_scales
from jointsim.solvers.hbm import solve_point

from ._files import assert_all_finite
from .._scenes import MODELS

FOLD = MODELS / "hbm" / "chain2_friction_fold.toml"


def _fold_system(overrides=()):
    scene = load_scene(FOLD, list(overrides))
    model = build_model(scene)
    return scene.analysis.hbm, _system(model, scene.analysis.hbm, parallel=False)


def test_force_homotopy_reproduces_newton_where_newton_converges():
    a, system = _fold_system()
    F = system.force_coefficients(0.2)
    scale, rscale = frc_scales(system, F, a.omega_start, a.omega_end)
    direct = solve_point(system, a.omega_start, F, tol=1e-12, rscale=rscale)
    assert direct.convergence.success
    br = force_homotopy(system, a.omega_start, 0.2, scale=scale, rscale=rscale, tol=1e-12)
    assert br.convergence.success and br.y[-1, -1] == pytest.approx(0.2, rel=1e-12)
    np.testing.assert_allclose(br.y[-1, :-1], direct.z, atol=1e-9 * np.abs(direct.z).max())


@pytest.mark.parametrize("fs", [0.3, 0.4, 0.5, 0.7])
def test_first_point_of_the_fold_scene(fs):
    a, system = _fold_system()
    F = system.force_coefficients(fs)
    scale, rscale = frc_scales(system, F, a.omega_start, a.omega_end)
    fp = first_point(system, a.omega_start, fs, scale=scale, rscale=rscale, tol=a.tol,
                     max_iter=a.max_iter)
    # the case: the plain Newton solve from the static state fails here
    assert fp.convergence.success and fp.how == "force homotopy"
    R = system.evaluate(fp.z, a.omega_start, F, jacobian=False).R
    assert np.abs(R).max() <= 10 * a.tol * rscale
    # another method: Newton with a line search (30 iterations) converges here
    direct = solve_point(system, a.omega_start, F, tol=1e-12, rscale=rscale)
    assert direct.convergence.success
    np.testing.assert_allclose(fp.z, direct.z, atol=1e-7 * np.abs(direct.z).max())


def test_fold_frc_at_force_scale_0p3_completes(tmp_path):
    """The FRC runs from the homotopy's first point (a short range keeps it fast)."""
    scene = load_scene(FOLD, ["analysis.hbm.force_scale=[0.3]", "analysis.hbm.omega_end=0.9"])
    out = run_scene(scene, tmp_path / "f03.h5")
    with h5py.File(out) as h:
        assert h["hbm"].attrs["branch0_status"] == "complete"
        assert h["hbm/omega"][0] == pytest.approx(0.5) and h["hbm/omega"][-1] == 0.9
    assert_all_finite(out)


@pytest.mark.slow
@pytest.mark.parametrize("fs", [0.3, 0.4, 0.5, 0.7])
def test_fold_frc_completes_at_every_force_scale(tmp_path, fs):
    out = run_scene(load_scene(FOLD, [f"analysis.hbm.force_scale=[{fs}]"]), tmp_path / "f.h5")
    with h5py.File(out) as h:
        assert h["hbm"].attrs["branch0_status"] == "complete"
        assert h["hbm/omega"][-1] == 2.5
    assert_all_finite(out)


def test_resume_keeps_the_grown_z_scale(tmp_path, monkeypatch):
    """A stiff contact (kt = 1e4) whose solution outgrows its stuck scale many times: a
    run interrupted after 90 points and resumed takes the same points as the uninterrupted
    one (the grown scale is stored per point as /hbm/z_scale)."""
    from ..solvers.test_hbm import run_interrupted_after
    sc = load_scene(MODELS / "hbm" / "chain2_jenkins.toml", [
        "joint.kt=1e4", "analysis.hbm.force_scale=[0.2]", "analysis.hbm.harmonics=[0, 1, 3]",
        "analysis.hbm.n_samples=32", "analysis.hbm.omega_end=1.04"])
    full, part = tmp_path / "full.h5", tmp_path / "part.h5"
    run_scene(sc, full)
    with h5py.File(full) as g:
        zs = g["hbm/z_scale"][()]
        assert zs[-1] > 4 * zs[0]         # the scale grew
        assert zs[90] > zs[0]             # ... before the interruption
    run_interrupted_after(sc, part, 90, monkeypatch)
    run_scene(sc, part, resume=True)
    with h5py.File(part) as h, h5py.File(full) as g:
        assert h["hbm"].attrs["branch0_status"] == "complete"
        np.testing.assert_allclose(h["hbm/omega"][()], g["hbm/omega"][()], rtol=1e-12)
        np.testing.assert_allclose(h["hbm/q"][()], g["hbm/q"][()], rtol=0,
                                   atol=1e-9 * np.abs(g["hbm/q"][()]).max())
