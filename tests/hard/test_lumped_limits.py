"""Issue 13, the lumped hard-case suite: limits with exact answers, zero damping.

* mu -> 0 (1e-8): the frictionless response, the linear FRF of ``K`` (the
  tangential spring carries no force); mu -> large (1e6): the stuck response,
  the linear FRF of ``K + kt e e^T``.  Oracle: the analytic linear FRF.
* Zero damping: the linearised stuck and slipping systems' resonances and the
  Den Hartog balance of the force's work against the sliders' (analytic for
  the 2-DOF chain); a friction-only peak completes; an undamped resonance
  that nothing limits stops with a message naming the physics.
* Every file: no NaN or Inf in any dataset.
"""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from jointsim.analyses.hbm import _system
from jointsim.model import build_model
from jointsim.run import run_scene
from jointsim.scene import load_scene
from jointsim.solvers.frc_diagnosis import undamped_resonances

from .._scenes import CHAIN2, MODELS
from ._files import assert_all_finite

FOLD = MODELS / "hbm" / "chain2_friction_fold.toml"
QUICK = ["analysis.hbm.harmonics=[0,1,2,3]", "analysis.hbm.n_samples=64"]
C0 = "model.C=[[0,0],[0,0]]"


def _run(tmp_path, path, overrides, name="x.h5", expect_fail=False):
    out = tmp_path / name
    if expect_fail:
        with pytest.raises(RuntimeError) as err:
            run_scene(load_scene(path, overrides), out)
        return out, str(err.value)
    run_scene(load_scene(path, overrides), out)
    return out, ""


def _linear_frf(omega, K, kt_extra, F=0.2, C=0.01):
    """|x_0| of the 2-DOF chain, F cos(w t) on DOF 0, with ``kt_extra`` on DOF 1."""
    Kx = np.array(K, dtype=float)
    Kx[1, 1] += kt_extra
    out = []
    for w in omega:
        D = Kx - w * w * np.eye(2) + 1j * w * C * np.eye(2)
        out.append(abs(np.linalg.solve(D, [F, 0.0])[0]))
    return np.array(out)


@pytest.mark.parametrize("mu, kt_extra, rtol", [(1e-8, 0.0, 1e-6), (1e6, 0.25, 1e-6)])
def test_friction_limits_are_the_linear_responses(tmp_path, mu, kt_extra, rtol):
    """mu = 1e-8: frictionless (K alone); mu = 1e6: stuck (K + kt)."""
    out, _ = _run(tmp_path, CHAIN2, [*QUICK, f"joint.mu={mu}", "analysis.hbm.force_scale=[0.2]"])
    with h5py.File(out) as h:
        assert h["hbm"].attrs["branch0_status"] == "complete"
        w, a = h["hbm/omega"][()], h["hbm/amplitude"][()]
    np.testing.assert_allclose(a, _linear_frf(w, [[2, -1], [-1, 2]], kt_extra), rtol=rtol)
    assert_all_finite(out)


def test_undamped_resonances_of_the_chain_are_analytic():
    """C = 0: stuck resonance sqrt(eig(K + kt e2 e2^T)), slipping resonance 1 with mode
    (1, 1)/sqrt 2: force work pi F / sqrt 2, the most the slider dissipates 4 mu N / sqrt 2;
    unbounded exactly when F > 4 mu N / pi = 0.2546."""
    scene = load_scene(CHAIN2, [C0])
    model = build_model(scene)
    a = scene.analysis.hbm
    system = _system(model, a, parallel=False)
    w_stuck = np.sqrt(np.linalg.eigvalsh([[2.0, -1.0], [-1.0, 2.25]])[0])
    for F, unbounded in ((0.2, False), (0.26, True)):
        res = undamped_resonances(model, system.basis, system.force_coefficients(F),
                                  a.omega_start, a.omega_end)
        by = {r.joint: r for r in res}
        assert sorted(by) == ["slipping", "stuck"]
        assert by["stuck"].omega == pytest.approx(w_stuck, rel=1e-12)
        s = by["slipping"]
        assert s.omega == pytest.approx(1.0, rel=1e-12)
        assert s.force_work == pytest.approx(np.pi * F / np.sqrt(2), rel=1e-12)
        assert s.friction_work == pytest.approx(4 * 0.2 / np.sqrt(2), rel=1e-12)
        assert s.unbounded is unbounded and by["stuck"].unbounded is False
        assert ("unbounded" in s.describe()) is unbounded
    # with damping there is nothing to report
    assert undamped_resonances(model := build_model(load_scene(CHAIN2)), system.basis,
                               system.force_coefficients(0.3), 0.8, 1.3) == []


def test_a_failure_above_the_undamped_search_limit_says_so(monkeypatch, caplog):
    """``explain_branch_failure`` on a model above ``UNDAMPED_MAX_DOF`` (here the chain,
    the limit set to 1): the failure keeps its message, and the log says that no
    undamped resonance was looked for and why (round 43: it was silent); at the limit
    the explanation names the chain's unbounded slipping resonance."""
    import logging

    import jointsim.solvers.frc_diagnosis as fd
    from jointsim.results import Convergence
    model = build_model(load_scene(CHAIN2, [C0]))
    a = load_scene(CHAIN2, [C0]).analysis.hbm
    system = _system(model, a, parallel=False)
    F = system.force_coefficients(0.26)
    failed = Convergence(False, 3, "step shrunk below step_min", 10)
    found = fd.explain_branch_failure(failed, system, F, a.omega_start, a.omega_end, 1.0)
    assert "slipping joint" in found.message and found.message != failed.message
    monkeypatch.setattr(fd, "UNDAMPED_MAX_DOF", 1)
    with caplog.at_level(logging.INFO, logger="jointsim.solvers.frc_diagnosis"):
        kept = fd.explain_branch_failure(failed, system, F, a.omega_start, a.omega_end, 1.0)
    assert kept.message == failed.message
    assert "not checked against undamped resonances: the model has 2 DOFs" in caplog.text


def test_zero_damping_friction_only_peak_completes(tmp_path):
    """C = 0, F = 0.01: the response grows to the slip limit and friction bounds it (Den
    Hartog: 0.0222 < 0.566); the sharp corner at the slip onset is passed (it used to stop
    with "step shrunk below step_min" at omega = 1.054)."""
    out, _ = _run(tmp_path, CHAIN2, [C0, "analysis.hbm.force_scale=[0.01]"])
    with h5py.File(out) as h:
        assert h["hbm"].attrs["branch0_status"] == "complete"
        assert h["hbm/omega"][-1] == 1.3 and np.isfinite(h["hbm/peak_amplitude"][0])
    assert_all_finite(out)


@pytest.mark.slow
def test_zero_damping_fold_scene_names_the_unbounded_response(tmp_path):
    """The fold scene without damping: its clapping, sticking response at large amplitude
    has no dissipation, and grows without bound near omega = 1.33464."""
    out, msg = _run(tmp_path, FOLD, [C0], expect_fail=True)
    assert "grows without bound near lam = 1.3346" in msg and "model.C" in msg
    assert "physics" in msg
    with h5py.File(out) as h:
        assert h["hbm"].attrs["branch0_status"] == "gave up"
    assert_all_finite(out)


@pytest.mark.slow
def test_zero_damping_unbounded_by_den_hartog(tmp_path):
    """C = 0 and F = 0.3 > 4 mu N / pi: friction cannot bound the slipping joint's
    resonance at omega = 1; the branch stops there and says so, with the force limit."""
    out, msg = _run(tmp_path, CHAIN2, [C0, "analysis.hbm.force_scale=[0.3]"], expect_fail=True)
    assert "grows without bound near lam = 0.9999" in msg
    assert "slipping joint's resonance at omega = 1 " in msg and "unbounded" in msg
    assert "lower the force below 0.849 times" in msg      # 4 mu N / (pi F) = 0.8488
    assert_all_finite(out)
