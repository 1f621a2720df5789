"""Harmonic balance and EPMC on the FE lap joint (coarse mesh) and the shared static
state / stuck linearisation: checks against oracles."""
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from jointsim import _toml
from jointsim.model import build_model
from jointsim.run import run_scene
from jointsim.scene import SceneError, apply_overrides, load_scene, parse_scene
from jointsim.solvers.continuation import continue_branch
from jointsim.solvers.epmc import EPMCSystem
from jointsim.harmonics import harmonic_amplitude
from jointsim.solvers.hbm import HBMSystem, solve_point
from jointsim.solvers.modes import elastic_mode, eigenmodes, rigid_body_modes, stuck_modes
from jointsim.solvers.static import residual, stuck_linearisation, tangent_stiffness

sys.path.insert(0, str(Path(__file__).parent))
from test_hbm import four_dof  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
COUPLED = ROOT / "models" / "lap_joint.toml"
FIXED = ROOT / "models" / "lap_joint_fixed_n.toml"
COARSE = "model.mesh='../meshes/lap_joint_coarse.msh'"
NO_FULL = ["analysis.modes.full_model=false", "analysis.modes.monolithic=false"]


def lap_scene(path, analyses=("modes",), overrides=()):
    """A lap-joint scene on the coarse mesh keeping only the named analyses."""
    out, keep = [], True
    for line in path.read_text().splitlines():
        s = line.strip()
        if s.startswith("[") and not s.startswith("[["):
            keep = not s.startswith("[analysis.") or s[len("[analysis."):-1] in analyses
        if keep:
            out.append(line)
    data = apply_overrides(_toml.loads("\n".join(out)), [COARSE, *overrides], str(path))
    return parse_scene(data, str(path), path.parent)


@pytest.fixture(scope="module")
def coupled():
    return build_model(lap_scene(COUPLED))


@pytest.fixture(scope="module")
def fixed():
    return build_model(lap_scene(FIXED))


# --------------------------------------------------------------------------
# The static state and its stuck linearisation
# --------------------------------------------------------------------------
def test_stuck_linearisation_of_the_fe_model_is_the_preload(coupled):
    lin = coupled.linearisation                                      # built with the model
    assert lin.source == "model" and lin.convergence.success
    assert np.array_equal(lin.x0, coupled.preload.x0)
    assert abs(coupled.linearisation.K - lin.K).max() == 0.0  # the one definition
    # x0 is the equilibrium of the model's own K and f_static
    r = residual(coupled.K, lin.f0, coupled.contacts, lin.x0, tangential="stuck")
    assert np.linalg.norm(r) <= 1e-9 * np.linalg.norm(lin.f0)
    # N at x0 is N0, and the closed elements are those with N0 > 0
    assert np.allclose(lin.N, coupled.contacts.N0, rtol=1e-12, atol=1e-9)
    assert np.array_equal(lin.closed, coupled.contacts.N0 > 0)
    K = tangent_stiffness(coupled.K, coupled.contacts, lin.x0)
    assert abs(lin.K - K).max() == 0.0


def test_stuck_linearisation_of_a_lumped_model_solves_the_static_state():
    """A constant load on a lumped model with a stuck Jenkins element to ground:
    x0 = (K + kt e e^T)^-1 f0 (oracle), K0 = K + kt e e^T."""
    d = {"model": {"kind": "lumped", "M": [[1.0, 0.0], [0.0, 1.0]],
                   "K": [[2.0, -1.0], [-1.0, 2.0]],
                   "contacts": [{"t_dof": 1, "N0": 10.0}]},
         "joint": {"law": "jenkins", "kt": 0.25, "mu": 0.5},
         "excitation": {"loads": [{"dof": 0, "force": {"constant": 0.3,
                                                       "harmonics": [{"h": 1, "cos": 1.0}]}}]}}
    m = build_model(parse_scene(d, "static.toml"))
    lin = m.linearisation
    K0 = np.array([[2.0, -1.0], [-1.0, 2.25]])
    assert lin.source == "solved"
    assert np.allclose(lin.x0, np.linalg.solve(K0, [0.3, 0.0]), rtol=1e-12, atol=0)
    assert np.allclose(lin.K.toarray(), K0, rtol=0, atol=1e-15)
    # the harmonic balance starts there: harmonic 0 of the slip is Tt x0
    s = HBMSystem(m, (0, 1, 2), 16)
    z0 = s.static_coordinates().reshape(s.n_c, s.n_r)
    assert z0[0, 0] == pytest.approx(lin.x0[1], rel=1e-14)
    assert np.all(z0[1:] == 0.0)


def test_hbm_starts_at_the_static_state(fixed):
    """Without a harmonic load the static state solves the harmonic balance: the
    residual at z0 vanishes and X_0 = x0."""
    s = HBMSystem(fixed, (0, 1, 2, 3), 32)
    F = s.force_coefficients(0.0)
    z0 = s.static_coordinates()
    ev = s.evaluate(z0, 900.0, F, wrt=())
    # round-off of the condensation relative to the contact forces (N0 ~ kN)
    assert np.abs(ev.R).max() <= 1e-9 * fixed.contacts.N0.max()
    X = s.reconstruct(z0, 900.0, F)
    x0 = fixed.linearisation.x0
    # the welded-structure modes of the condensation resolve the near-rigid
    # (suspension) motions to ~eps |K| / w_susp^2 ~ 1e-7 relative
    assert np.abs(X[0] - x0).max() <= 1e-5 * np.abs(x0).max()
    assert np.abs(s.T @ (X[0] - x0)).max() <= 1e-12 * np.abs(x0).max()
    assert np.abs(X[1:]).max() <= 1e-12 * np.abs(x0).max()


def test_fixed_normal_load_linearises_like_the_coupled_joint(coupled, fixed):
    """Fixed N: normal springs only where the preload closed the interface, so the
    stuck linear modes are the coupled joint's."""
    fc = stuck_modes(coupled, 8).frequency_hz
    ff = stuck_modes(fixed, 8).frequency_hz
    assert np.allclose(fc[3:], ff[3:], rtol=1e-7, atol=0)
    # the suspension modes (w^2 ~ 1e-9 of the contact stiffness) to round-off
    assert np.allclose(fc[:3], ff[:3], rtol=1e-4, atol=0)
    Kc = coupled.linearisation.K.toarray()
    Kf = fixed.linearisation.K.toarray()
    assert np.abs(Kc - Kf).max() <= 1e-9 * np.abs(Kc).max()


# --------------------------------------------------------------------------
# Rigid-body (suspension) modes and the elastic mode numbering
# --------------------------------------------------------------------------
def test_suspension_modes_are_detected(coupled):
    res = stuck_modes(coupled, 8)
    assert list(res.elastic) == [False, False, False] + [True] * 5
    assert "rigid-body share" in res.rigid_method
    assert res.frequency_hz[2] < 6.0 < 100.0 < res.frequency_hz[3]
    em = elastic_mode(coupled, 1)
    assert em.index == 3 and em.n_rigid == 3
    assert em.frequency_hz == pytest.approx(res.frequency_hz[3], rel=1e-8)  # eigh round-off
    assert em.phi @ (coupled.M @ em.phi) == pytest.approx(1.0, rel=1e-10)
    # an explicit cutoff decides instead
    mask, how = rigid_body_modes(coupled, res.frequency_hz, res.shapes, cutoff_hz=4.0)
    assert list(mask[:4]) == [True, True, False, False] and "below 4" in how
    assert elastic_mode(coupled, 2, rigid_cutoff_hz=4.0).index == 3


def test_rom_uses_the_spectral_gap_and_lumped_models_have_no_rigid_modes(coupled):
    import dataclasses
    rom_like = dataclasses.replace(coupled, fe=None)
    f, phi = eigenmodes(coupled.linearisation.K, coupled.M, 8)
    mask, how = rigid_body_modes(rom_like, f, phi)
    assert list(mask) == [True, True, True] + [False] * 5 and "gap" in how
    lumped = build_model(four_dof())
    f, phi = eigenmodes(lumped.K, lumped.M, 4)
    mask, _ = rigid_body_modes(lumped, np.array([0.01, 1.0, 1.2, 1.5]), phi)
    assert not mask.any()
    assert elastic_mode(lumped, 1).index == 0
    with pytest.raises(ValueError, match="elastic modes"):
        elastic_mode(lumped, 5)


# --------------------------------------------------------------------------
# EPMC: linear limit, Jacobian, first point at small amplitude
# --------------------------------------------------------------------------
def test_epmc_jacobian_matches_finite_differences():
    """EPMC residual with the static offset z0 (closed gaps at rest, so z0 != 0),
    slip and separation inside the period: analytic J against central differences."""
    m = build_model(four_dof("jenkins", "anchor", "coupled"))
    s = HBMSystem(m, (0, 1, 2, 3), 64)
    em = elastic_mode(m, 1)
    ep = EPMCSystem(s, em.phi, s.force_coefficients(0.0))
    assert np.abs(ep.z0).max() > 0.1
    rng = np.random.default_rng(4)
    y = np.concatenate([rng.normal(size=s.n_z), [1.1, 0.03, np.log10(0.4)]])
    R, J, ev = ep.fun(y)
    assert ev.aft.N.min() == 0.0
    eps = 1e-7
    Jfd = np.column_stack([(ep.fun(y + eps * e)[0] - ep.fun(y - eps * e)[0]) / (2 * eps)
                           for e in np.eye(y.size)])
    assert np.abs(J - Jfd).max() <= 1e-6 * np.abs(Jfd).max()


@pytest.mark.parametrize("path", [COUPLED, FIXED], ids=["coupled", "fixed"])
def test_epmc_linear_limit_is_the_linear_mode(tmp_path, path):
    """The first EPMC point (a = 1e-7) converges at once, its frequency is the modes
    analysis' first elastic frequency (< 0.1 %, in fact ~1e-9) and its damping the
    modal damping."""
    sc = lap_scene(path, ("modes", "epmc"), NO_FULL + [
        "analysis.epmc.log10_amplitude_start=-7", "analysis.epmc.log10_amplitude_end=-6.8"])
    out = tmp_path / "epmc.h5"
    run_scene(sc, out)
    with h5py.File(out) as h:
        f_modes = h["modes/frequency_hz"][()][h["modes/elastic"][()]][0]
        f = h["epmc/frequency_hz"][()]
        g = h["epmc"]
        assert g.attrs["success"] and g.attrs["n_rigid_below"] == 3
        assert h["epmc/iterations"][0] <= 2
        assert g.attrs["linear_frequency_hz"] == pytest.approx(f_modes, rel=1e-8)
        assert np.abs(f / f_modes - 1).max() < 1e-3
        assert np.abs(f / f_modes - 1).max() < 1e-7
        assert np.allclose(h["epmc/damping_ratio"][()], 0.00087, rtol=1e-6)
        # harmonic 0 of every point is the preload state
        x0 = h["static/x0"][()]
        X0 = h["epmc/X"][:, 0, :]
        assert np.abs(X0 - x0).max() <= 1e-5 * np.abs(x0).max()   # see test_hbm_starts_at_the_static_state


def test_epmc_fixed_n_softens_and_damps_through_microslip(tmp_path):
    """Fixed N, EPMC into microslip: the frequency falls and the damping rises
    above the modal 0.087 % (Masing elements: every loop on its manifold)."""
    sc = lap_scene(FIXED, ("epmc",), [
        "analysis.epmc.log10_amplitude_start=-4.5", "analysis.epmc.log10_amplitude_end=-3.0"])
    out = tmp_path / "epmc.h5"
    run_scene(sc, out)
    with h5py.File(out) as h:
        f = h["epmc/frequency_hz"][()]
        z = h["epmc/damping_ratio"][()]
        assert h["epmc"].attrs["success"]
        assert f[-1] < f[0] * 0.995 and z[-1] > 2 * z[0]
        assert np.all(np.diff(f) <= 1e-9 * f[0])
        assert h["masing/dev_manifold"][()].max() <= 1e-9
        assert h["masing/dev_masing"][()].max() <= 1e-9


# --------------------------------------------------------------------------
# FRC on the FE model
# --------------------------------------------------------------------------
def test_fe_frc_small_force_equals_the_linear_frf(tmp_path):
    """Fixed N, 0.2 N: the joint stays stuck, so the branch is the linear FRF of the
    stuck linearisation (K0, M, C) and its refined peak is that FRF's peak; loops are
    kept at the peak only."""
    from scipy.optimize import minimize_scalar
    sc = lap_scene(FIXED, ("hbm",), ["analysis.hbm.force_scale=[0.02]",
                                     "analysis.hbm.omega_start=990.0",
                                     "analysis.hbm.omega_end=1020.0"])
    out = tmp_path / "frc.h5"
    run_scene(sc, out)
    m = build_model(sc)
    K0 = m.linearisation.K.toarray()
    M, C = m.M.toarray(), m.C.toarray()
    dof = m.points["response"]
    f = np.zeros(m.n_dof)
    f[m.points["excitation"]] = 0.2

    def amp(w):
        return abs(np.linalg.solve(K0 - w * w * M + 1j * w * C, f)[dof])

    with h5py.File(out) as h:
        om, a = h["hbm/omega"][()], h["hbm/amplitude"][()]
        assert h["hbm"].attrs["branch0_status"] == "complete"
        assert h["hbm"].attrs["response_dof"] == dof
        exact = np.array([amp(w) for w in om])
        assert np.abs(a / exact - 1).max() <= 1e-6
        i = int(np.argmax(a))
        r = minimize_scalar(lambda w: -amp(w), bounds=(om[i - 1], om[i + 1]),
                            method="bounded", options={"xatol": 1e-10})
        assert h["hbm/peak_amplitude"][0] == pytest.approx(-r.fun, rel=1e-7)
        assert list(h["loops/point"][()]) == [i]
        assert h["loops/u"].shape[0] == 1


def test_response_point_names_the_key():
    with pytest.raises(SceneError, match="analysis.hbm.response_point"):
        lap_scene(FIXED, ("hbm",), ["analysis.hbm.response_point=nowhere"])
    d = four_dof()
    raw = {"model": {"kind": "lumped", "M": [[1.0]], "K": [[1.0]]},
           "analysis": {"hbm": {"omega_start": 1.0, "omega_end": 2.0,
                                "response_point": "response"}}}
    with pytest.raises(SceneError, match="analysis.hbm.response_point"):
        parse_scene(raw, "lumped.toml")
    assert d is not None


def test_default_lap_joint_scenes_declare_the_study():
    """Both scenes parse, and run modes, EPMC of bending mode 1 and a three-level FRC
    (H = 0..7, Nt = 128) with the same amplitude definition."""
    for path, normal in ((COUPLED, "coupled"), (FIXED, "fixed")):
        sc = load_scene(path)
        a = sc.analysis
        assert sc.effects.normal == normal
        assert a.modes is not None and a.epmc.mode == 1 and a.epmc.rigid_cutoff_hz is None
        assert a.hbm.harmonics == tuple(range(8)) and a.hbm.n_samples == 128
        assert len(a.hbm.force_scale) == 3 and a.hbm.response_point == "response"
        assert a.epmc.log10_amplitude_start <= -4.5


# --------------------------------------------------------------------------
# Continuation on piecewise-smooth branches
# --------------------------------------------------------------------------
@pytest.mark.parametrize("angle", [30.0, 70.0])
def test_continuation_passes_a_sharp_corner_without_retracing(angle):
    """z = tan(angle) max(0, lam - 1) (scaled variables): a corner of the branch at
    lam = 1; the branch must pass it, stay on it and never come back."""
    k = np.tan(np.radians(angle))

    def fun(y):
        z, lam = y
        on = lam > 1.0
        return (np.array([z - k * max(0.0, lam - 1.0)]),
                np.array([[1.0, -k if on else 0.0]]), None)

    br = continue_branch(fun, np.array([0.0, 0.0]), 2.0, scale=np.ones(2), rscale=1.0,
                         step=0.1, step_min=1e-8, step_max=0.1, max_points=500, tol=1e-12,
                         progress=False)
    z, lam = br.y[:, 0], br.y[:, 1]
    assert br.convergence.success, br.convergence.message
    assert lam[-1] == 2.0
    assert np.all(np.diff(lam) > 0)
    assert np.abs(z - k * np.maximum(0.0, lam - 1.0)).max() <= 1e-10


@pytest.mark.slow
@pytest.mark.parametrize("path", [COUPLED, FIXED], ids=["coupled", "fixed"])
def test_default_scenes_run_through_on_the_coarse_mesh(tmp_path, path):
    """The whole default scene (modes, EPMC, three-level FRC) on the coarse mesh:
    every branch completes, nothing is NaN; with fixed N every element at every
    peak is on its manifold and on its classical Masing curve."""
    out = tmp_path / "run.h5"
    run_scene(lap_scene(path, ("modes", "epmc", "hbm"), NO_FULL), out)
    with h5py.File(out) as h:
        assert h.attrs["status"] == "complete"
        assert h["epmc"].attrs["branch_status"] == "complete"
        for b in range(3):
            assert h["hbm"].attrs[f"branch{b}_status"] == "complete"
        for name in ("hbm/X", "epmc/X", "hbm/loops/f", "hbm/masing/dev_manifold",
                     "epmc/loops/f"):
            assert np.all(np.isfinite(h[name][()]))
        assert h["hbm/loops/point"].shape == (3,)  # one loop set at each branch's peak
        peaks = h["hbm/peak_amplitude"][()]
        assert np.all(np.diff(peaks) > 0)
        if path == FIXED:
            hm = h["hbm/masing"]
            assert hm["on_manifold"][()].all() and hm["on_masing"][()].all()
