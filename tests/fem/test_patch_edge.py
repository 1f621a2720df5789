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
SCENE = ROOT / "models" / "lap_joint.toml"
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
