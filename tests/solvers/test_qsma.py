"""Quasi-static modal analysis against analytic backbones and directly marched loops."""

import numpy as np
import pytest

from jointsim.model import build_model, build_lumped
from jointsim.scene import load_scene, parse_scene
from jointsim.solvers.modes import stuck_modes
from jointsim.solvers.qsma import masing_dissipation, qsma, qsma_cycle

from .._scenes import ROOT

COARSE = "model.mesh='../meshes/lap_joint_coarse.msh'"


def sdof_jenkins(mu=0.2, kt=0.25):
    data = {"model": {"kind": "lumped", "M": [[1.0]], "K": [[1.0]],
                      "contacts": [{"t_dof": 0, "N0": 1.0}]},
            "joint": {"law": "jenkins", "kt": kt, "mu": mu}}
    return build_lumped(parse_scene(data, "sdof.toml"))


def test_sdof_jenkins_backbone_and_damping():
    """m = k = 1, kt = 0.25, Fs = 0.2: alpha = 1.25 q while stuck, q + 0.2 beyond
    q = 0.8; the Masing dissipation is the Jenkins loop's 4 Fs (q - Fs/kt)."""
    model = sdof_jenkins()
    q_target = np.logspace(-2, 1, 301)
    res = qsma(model, np.array([1.0]), np.zeros(1), 1.25 * q_target)
    assert res.convergence.success
    q = res.amplitude
    alpha_exact = np.where(q <= 0.8, 1.25 * q, q + 0.2)
    np.testing.assert_allclose(res.alpha, alpha_exact, rtol=1e-12)
    w_exact = np.sqrt(alpha_exact / q) / (2 * np.pi)
    np.testing.assert_allclose(res.frequency_hz, w_exact, rtol=1e-12)
    D_exact = np.where(q <= 0.8, 0.0, 0.8 * (q - 0.8))
    # trapezoidal integral: exact on the straight pieces, one kink at q = 0.8
    h = np.max(np.diff(q)[q[1:] > 0.8][:1])
    assert np.max(np.abs(res.dissipation - D_exact)) < 8 * 0.25 * h ** 2
    big = q > 2.0
    zeta_exact = D_exact[big] / (2 * np.pi * q[big] * alpha_exact[big])
    np.testing.assert_allclose(res.damping_ratio_friction[big], zeta_exact, rtol=1e-3)
    assert res.zeta_linear == 0.0  # the model has no viscous damping
    np.testing.assert_array_equal(res.damping_ratio, res.damping_ratio_friction)
    assert res.linear_hz == pytest.approx(np.sqrt(1.25) / (2 * np.pi), rel=1e-14)


def test_masing_dissipation_of_a_line_is_zero():
    q = np.linspace(0.1, 1, 10)
    np.testing.assert_allclose(masing_dissipation(3.0 * q, q), 0.0, atol=1e-14)


def test_static_cycle_matches_jenkins_loop():
    model = sdof_jenkins()
    alpha, q, D = qsma_cycle(model, np.array([1.0]), np.zeros(1), alpha_max=5.0,
                             n_per_branch=400)
    q_max = q.max()
    assert q_max == pytest.approx(4.8, rel=1e-12)
    assert D == pytest.approx(0.8 * (q_max - 0.8), rel=1e-4)


@pytest.fixture(scope="module")
def fe_fixed():
    scene = load_scene(ROOT / "models" / "lap_joint_nodes.toml", [COARSE, "effects.normal=fixed"])
    model = build_model(scene)
    modes = stuck_modes(model, 8, suspension_hz=20.0)
    k = int(np.nonzero(modes.elastic)[0][0])
    return model, modes.shapes[k], 2 * np.pi * modes.frequency_hz[k]


def test_fe_low_amplitude_is_the_stuck_mode(fe_fixed):
    model, phi, w0 = fe_fixed
    res = qsma(model, phi, model.preload.x0, w0 ** 2 * np.array([1e-8, 1e-7]))
    np.testing.assert_allclose(2 * np.pi * res.frequency_hz, w0, rtol=1e-8)
    assert res.linear_hz == pytest.approx(w0 / (2 * np.pi), rel=1e-7)  # eigensolver accuracy
    assert np.all(np.abs(res.damping_ratio_friction) < 1e-8)
    # the total is the mode's viscous damping: 0.087 % in the scene
    np.testing.assert_allclose(res.damping_ratio, 0.00087, rtol=1e-6)


def test_fe_masing_dissipation_equals_marched_loop(fe_fixed):
    """Fixed N: the QSMA (Masing) dissipation at an amplitude equals the work over
    the static loop marched up, down and up again to the same load."""
    model, phi, w0 = fe_fixed
    x0 = model.preload.x0
    alpha_max = w0 ** 2 * 2e-3  # well into microslip (the curve has bent by ~5 %)
    alphas = np.linspace(alpha_max / 400, alpha_max, 400)
    res = qsma(model, phi, x0, alphas)
    assert res.convergence.success
    assert res.frequency_hz[-1] < 0.99 * res.linear_hz  # friction has softened it
    _, q_loop, D_loop = qsma_cycle(model, phi, x0, alpha_max, n_per_branch=200)
    assert q_loop.max() == pytest.approx(res.amplitude[-1], rel=1e-9)
    assert D_loop > 0
    assert res.dissipation[-1] == pytest.approx(D_loop, rel=2e-3)
