"""Contact stiffness proportional to the preload pressure (``joint.kt_pressure``,
``joint.kn_pressure``): the stuck stiffness vanishes continuously at the edge of
the contact patch.

Oracles: the per-element stiffnesses are the formula ``k A p0 / p_ref`` with
``p0 = N0 / A`` of the model's own preload; the normal law reproduces ``N0`` at
the preload state (so ``x0`` stays an equilibrium, to round-off); the stuck
linearisation equals an independent assembly ``K + Tt^T diag(kt_e) Tt +
Tn^T diag(kn_e) Tn`` over the closed set; with ``p_ref`` the nominal pressure
``sum N0 / sum A`` the summed stiffness equals ``k`` times the whole lap area;
coupled and fixed normal loads share their linearisation; bad values are
SceneErrors naming the key.  The slow test: with contact at Gauss points the
stuck f1 converges monotonically on 10, 5 and 2.5 mm (docs/fe.md has the
four-mesh table).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from jointsim._schema import SceneError
from jointsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "models" / "lap_joint_nodes.toml"
#: The nominal pressure of the lap joint: 36 kN on 120 mm x 25.4 mm.
P_NOM = 36e3 / (0.12 * 0.0254)


def _sets(dx, *extra):
    return ["model.mesh=''", f"model.dx_lap={dx:g}", f"model.dx_full={2 * dx:g}",
            f"model.ny_half={max(1, round(0.02 / dx))}", "model.bolt_washer_radius=0.01",
            *extra]


def _keys(p=P_NOM):
    return (f"joint.kt_pressure={p!r}", f"joint.kn_pressure={p!r}")


@pytest.fixture(scope="module")
def models():
    from jointsim.model import build_model
    scene = load_scene(SCENE, _sets(0.01, *_keys()))
    return (build_model(load_scene(SCENE, _sets(0.01))), build_model(scene), scene)


def test_stiffness_is_the_pressure_formula_and_x0_stays_an_equilibrium(models):
    default, m, scene = models
    c, c0 = m.contacts, default.contacts
    # kt per element [N/m]: kt A p0 / p_ref, zero where the preload left the element open
    p0 = c.N0 / c.area
    # (kt from the fixed point's previous N0: to its tolerance, KT_PRESSURE_RTOL = 1e-9)
    np.testing.assert_allclose(c.law.kt, scene.joint.kt * c.area * p0 / P_NOM, rtol=1e-9,
                               atol=1e-9 * c.law.kt.max())
    np.testing.assert_allclose(c.kn, scene.joint.kn * c.area * p0 / P_NOM, rtol=1e-13)
    assert np.all(c.law.kt[c.N0 == 0] == 0) and np.all(c.kn[c.N0 == 0] == 0)
    # the default model is untouched: uniform kt A, kn A, gap0 = 0
    np.testing.assert_allclose(c0.law.kt, scene.joint.kt * c0.area, rtol=1e-15)
    np.testing.assert_allclose(c0.kn, scene.joint.kn * c0.area, rtol=1e-15)
    assert np.all(c0.gap0 == 0)
    # the preload does not depend on kn (same x0, N0) and here not on kt either
    np.testing.assert_allclose(c.N0, c0.N0, rtol=1e-9, atol=1e-9 * c0.N0.max())
    # the normal law carries N0 at x0 (the shifted initial gap)
    x0 = m.preload.x0
    N, _ = c.normal.load(c.gap0 + c.Tn @ x0)
    np.testing.assert_allclose(N, c.N0, rtol=1e-12, atol=1e-12 * c.N0.max())
    assert m.linearisation.source == "model"       # residual at x0 below 1e-8
    # p_ref = sum N0 / sum A: the summed stiffness is k times the whole lap area
    np.testing.assert_allclose(c.law.kt.sum(), scene.joint.kt * c.area.sum(), rtol=1e-9)
    np.testing.assert_allclose(c.kn.sum(), scene.joint.kn * c.area.sum(), rtol=1e-12)


def test_stuck_linearisation_is_the_weighted_assembly(models):
    _default, m, _scene = models
    c = m.contacts
    closed = (c.N0 > 0).astype(float)
    Tt, Tn = c.Tt.toarray(), c.Tn.toarray()
    K = (m.K.toarray() + Tt.T @ (Tt * (c.law.kt * closed)[:, None])
         + Tn.T @ (Tn * (c.kn * closed)[:, None]))
    Kl = m.linearisation.K.toarray()
    assert np.abs(Kl - K).max() <= 1e-12 * np.abs(K).max()


def test_coupled_and_fixed_normal_share_the_linear_joint(models):
    from jointsim.model import build_model
    from jointsim.solvers.modes import elastic_mode
    _default, m, _scene = models
    fixed = build_model(load_scene(SCENE, _sets(0.01, *_keys(), "effects.normal='fixed'")))
    assert fixed.linearisation.source == "model"
    f_c, f_f = elastic_mode(m, 1).frequency_hz, elastic_mode(fixed, 1).frequency_hz
    assert f_f == pytest.approx(f_c, rel=1e-9)


def test_iwan_law_with_pressure_kt_has_finite_sliders():
    """Iwan sliders are discretised from KT (a division by it): open elements get
    zero stiffness, loaded ones the slider bank of KT = kt A p0 / p_ref."""
    from jointsim.model import build_model
    m = build_model(load_scene(SCENE, _sets(0.01, "joint.law='iwan4'",
                                            f"joint.kt_pressure={P_NOM!r}")))
    law, c = m.contacts.law, m.contacts
    assert np.all(np.isfinite(law.k)) and np.all(np.isfinite(law.g))
    np.testing.assert_allclose(law.k.sum(axis=1), law.kt, rtol=1e-12)
    np.testing.assert_allclose(law.kt, 3e12 * c.N0 / P_NOM, rtol=1e-9, atol=1e-9 * law.kt.max())


@pytest.mark.parametrize("key", ["joint.kt_pressure", "joint.kn_pressure"])
def test_bad_pressure_names_the_key(key):
    for bad in ("0", "-1e6", "inf", "'high'"):
        with pytest.raises(SceneError) as e:
            load_scene(SCENE, _sets(0.01, f"{key}={bad}"))
        assert e.value.key == key, bad
    with pytest.raises(SceneError) as e:        # a lumped model has no preload pressure
        load_scene(ROOT / "models" / "hbm" / "sdof_jenkins_epmc.toml", [f"{key}=1e7"])
    assert e.value.key == key and "preload" in e.value.message


@pytest.mark.slow
def test_stuck_f1_converges_monotonically_with_pressure_stiffness():
    """10, 5, 2.5 mm, 3 Gauss points per interface edge, kt and kn proportional to
    the preload pressure (3-5 min): f1 falls monotonically with shrinking
    increments at an order near 2, and 2.5 mm is within 0.15 % of the Richardson
    limit.  Measured (docs/fe.md): 165.956, 164.214, 163.721 and, at 1.25 mm,
    163.591 Hz (still monotone; limit 163.55 Hz).  With uniform kt, kn the same
    meshes give 168.893, 166.750, 165.206, 165.397 Hz (turns back)."""
    from jointsim.model import build_model
    from jointsim.solvers.modes import elastic_mode
    gauss = ("model.contact_points='gauss'", "model.contact_gauss=3")
    f = np.array([elastic_mode(build_model(load_scene(SCENE, _sets(dx, *_keys(), *gauss))), 1)
                  .frequency_hz for dx in (0.01, 0.005, 0.0025)])
    d = np.diff(f)
    assert np.all(d < 0) and abs(d[1]) < abs(d[0]), f
    order = np.log2(d[0] / d[1])
    limit = f[2] + d[1] / (2 ** order - 1)      # Richardson: f_h + (f_h - f_2h) / (2^p - 1)
    assert 1.5 < order < 3.0, (f, order)
    assert abs(f[2] / limit - 1) < 1.5e-3, (f, limit)


@pytest.mark.slow
def test_stuck_f1_converges_monotonically_on_two_gauss_points_per_edge():
    """2 Gauss points per quadratic edge measure fewer relative displacements than
    the edge's independent nodal motions, so (unlike 3) harmonic balance and EPMC
    run on them; with kt and kn proportional to the preload pressure the stuck f1
    falls monotonically on 10, 5, 2.5 mm, and 2.5 mm is within 0.2 % of the limit
    of the 3-point sequence (163.545 Hz, Richardson, docs/fe.md).  Measured:
    164.174, 163.945, 163.843 Hz, and 163.543 Hz at 1.25 mm
    (``python benchmarks/patch_edge.py 0.00125 --gauss 2``)."""
    from jointsim.model import build_model
    from jointsim.solvers.modes import elastic_mode
    gauss = ("model.contact_points='gauss'", "model.contact_gauss=2")
    f = np.array([elastic_mode(build_model(load_scene(SCENE, _sets(dx, *_keys(), *gauss))), 1)
                  .frequency_hz for dx in (0.01, 0.005, 0.0025)])
    d = np.diff(f)
    assert np.all(d < 0) and abs(d[1]) < abs(d[0]), f
    assert abs(f[2] / 163.545 - 1) < 2e-3, f


@pytest.mark.slow
def test_harmonic_balance_accepts_two_gauss_points_per_edge():
    """2 Gauss points per quadratic edge: the condensation accepts them (3 are
    refused as linearly dependent: docs/fe.md), and a forced point at a force too
    small to slip anything is the stuck joint's linear response (the oracle: the
    stuck linearisation solved directly, to the Newton tolerance)."""
    from jointsim.model import build_model
    from jointsim.solvers.hbm import HBMSystem, solve_point
    m = build_model(load_scene(SCENE, _sets(0.01, *_keys(), "model.contact_points='gauss'",
                                            "model.contact_gauss=2")))
    s = HBMSystem(m, (0, 1, 2, 3), 32)
    assert s.n_r == 2 * 24                      # slip and gap rows of 24 Gauss points
    w, scale = 2 * np.pi * 150.0, 1e-6          # below the stuck f1 (164 Hz), 10 uN
    F = s.force_coefficients(scale)
    p = solve_point(s, w, F)
    lin = m.linearisation
    K, M, C = lin.K.toarray(), m.M.toarray(), m.C.toarray()
    D = np.block([[K - w * w * M, w * C], [-w * C, K - w * w * M]])
    x = np.linalg.solve(D, np.concatenate([F[1], F[2]]))
    n = m.n_dof
    X1 = p.X[1:3]
    assert np.abs(X1 - np.stack([x[:n], x[n:]])).max() <= 1e-7 * np.abs(x).max()


@pytest.mark.slow
def test_epmc_runs_on_two_gauss_points_per_edge():
    """The condensation accepts 2 Gauss points per edge (3 are refused as linearly
    dependent): the EPMC of the fixed-N joint starts on the stuck mode, whose
    frequency and damping are the linear ones (the oracle: the linear modes)."""
    import dataclasses
    import tempfile

    import h5py

    from jointsim.model import build_model
    from jointsim.run import run_scene
    from jointsim.solvers.modes import elastic_mode
    fixed = ROOT / "models" / "lap_joint_fixed_n_nodes.toml"
    sets = _sets(0.01, *_keys(), "model.contact_points='gauss'", "model.contact_gauss=2",
                 "analysis.modes.full_model=false", "analysis.modes.monolithic=false",
                 "analysis.epmc.log10_amplitude_end=-4.0", "analysis.epmc.loop_amplitudes=[]",
                 "analysis.epmc.error_indicators=false")
    scene = load_scene(fixed, sets)
    scene = dataclasses.replace(scene, analysis=dataclasses.replace(scene.analysis, hbm=None,
                                                                    qsma=None))
    f1 = elastic_mode(build_model(scene), 1).frequency_hz
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "g2.h5"
        run_scene(scene, out)
        with h5py.File(out, "r") as h5:
            assert h5["epmc"].attrs["success"]
            assert h5["contacts/area"].shape[0] == 24
            np.testing.assert_allclose(h5["epmc/frequency_hz"][0], f1, rtol=1e-8)
            np.testing.assert_allclose(h5["epmc/damping_ratio"][0], 0.00087, rtol=1e-6)
