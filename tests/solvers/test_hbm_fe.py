"""Harmonic balance and EPMC on the FE lap joint (coarse mesh): checks against
oracles.  The static state and the stuck modes have their own files
(``test_static.py``, ``test_modes.py``)."""
import h5py
import numpy as np
import pytest

from jointsim.model import build_model
from jointsim.run import run_scene
from jointsim.scene import SceneError, load_scene, parse_scene
from jointsim.solvers.continuation import continue_branch
from jointsim.solvers.epmc import EPMCSystem
from jointsim.solvers.hbm import HBMSystem
from jointsim.solvers.modes import elastic_mode

from .._scenes import COUPLED, FIXED, NO_FULL, four_dof, lap_scene


@pytest.fixture
def fixed(coarse_lap_fixed):
    return coarse_lap_fixed


# --------------------------------------------------------------------------
# The static state as the start of the harmonic balance
# --------------------------------------------------------------------------
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


@pytest.mark.parametrize("xi", [0.0, 0.7])
def test_reconstruction_solves_the_condensed_coordinates(fixed, xi):
    """``reconstruct`` (every harmonic at once by ``DynamicProducts``, no block formed)
    against the formed blocks of each harmonic: ``x = Psi q + Z y`` with ``E_h y_h =
    F_y,h - B'_h q_h`` (``ReducedLinear.blocks``, ``solve_E``), forced and self-excited,
    to 1e-12 of the largest coefficient."""
    s = HBMSystem(fixed, (0, 1, 2, 3), 32, linear_solver="krylov")
    lin = s.lin
    assert lin.kind in ("modal", "lowrank") and lin.n_y
    F = s.force_coefficients(3.0)
    z = np.random.default_rng(8).normal(size=s.n_z) * 1e-6
    X = s.reconstruct(z, 900.0, F, xi)
    Q = z.reshape(s.n_c, s.n_r)
    Y = np.zeros((s.n_c, lin.n_y))
    FZ = F @ lin.Z
    for h in s.basis.harmonics:
        _, _, Bp, E = lin.blocks(h * 900.0, xi, parts="yq")
        s._store(Y, h, lin.solve_E(E, s._complex(FZ, h) - Bp @ s._complex(Q, h)))
    ref = Q @ lin.Psi.T + Y @ lin.Z.T
    assert np.abs(X - ref).max() <= 1e-12 * np.abs(ref).max()


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
