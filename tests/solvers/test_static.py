"""Static contact solver: analytic oracles, the FE bolt preload, the stuck
linearisation, Jacobians vs FD."""
import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from jointsim.fem.build import reduce_structure
from jointsim.model import build_model, make_contact_set
from jointsim.results import SUCCESS
from jointsim.scene import load_scene, parse_scene
from jointsim.contact import BilateralPenalty, GivenNormal, UnilateralPenalty
from jointsim.solvers.hbm import HBMSystem
from jointsim.solvers.static import _Problem, residual, solve_static, tangent_stiffness

from .._scenes import ROOT

NORMALS = {"unilateral": UnilateralPenalty, "bilateral": BilateralPenalty, "fixed": GivenNormal}

SCENE = ROOT / "models" / "lap_joint_nodes.toml"
COARSE = ["model.mesh='../meshes/lap_joint_coarse.msh'"]


def lumped_scene(normal="coupled", mu=0.3, kt=50.0, kn=1e4, N0=None, law="jenkins"):
    c0 = {"t_dof": 1, "t_ref": 0, "n_dof": 1, "n_ref": 0}
    if N0 is not None:
        c0["N0"] = N0
    data = {"model": {"kind": "lumped", "M": [[1.0, 0], [0, 1.0]],
                      "K": [[100.0, 0], [0, 100.0]], "contacts": [c0]},
            "joint": {"law": law, "mu": mu, "kt": kt, "kn": kn},
            "effects": {"normal": normal}}
    return parse_scene(data, "lumped.toml")


def lumped_contacts(scene):
    m = build_model(scene)
    return m, m.contacts


@pytest.mark.parametrize("F", [30.0, -30.0])
def test_two_blocks_pressed_together_analytic(F):
    """Blocks on springs k pushed together by +-F: N = 2 kn F / (k + 2 kn), or 0 if pulled."""
    m, c = lumped_contacts(lumped_scene())
    k, kn = 100.0, 1e4
    f = np.array([F, -F])  # lower block (0) pushed up, upper (1) pushed down
    res = solve_static(sp.csr_matrix(np.diag([k, k])), f, c, tangential="frictionless")
    assert res.convergence.success and res.convergence.status == SUCCESS
    if F > 0:
        s = F / (k + 2 * kn)
        assert res.N[0] == pytest.approx(2 * kn * s, rel=1e-12)
        np.testing.assert_allclose(res.x, [s, -s], rtol=1e-12)
    else:
        assert res.N[0] == 0.0
        np.testing.assert_allclose(res.x, [F / k, -F / k], rtol=1e-12)


def test_jenkins_load_unload_history_analytic():
    """One DOF on a spring k with a Jenkins element to ground (fixed N0): load, then unload."""
    data = {"model": {"kind": "lumped", "M": [[1.0]], "K": [[100.0]],
                      "contacts": [{"t_dof": 0, "N0": 10.0}]},
            "joint": {"law": "jenkins", "mu": 0.5, "kt": 400.0}, "effects": {"normal": "fixed"}}
    m = build_model(parse_scene(data, "j.toml"))
    k, kt, fs = 100.0, 400.0, 5.0
    K = m.K
    # loading to F = 10 N: slips at x_s = fs/kt = 0.0125 (F_s = 6.25 N)
    up = solve_static(K, np.array([10.0]), m.contacts, n_increments=4)
    assert up.convergence.success
    x_max = (10.0 - fs) / k
    assert up.x[0] == pytest.approx(x_max, rel=1e-12)
    assert up.f_t[0] == pytest.approx(fs, rel=1e-12)
    # unloading to 0 from that state sticks with anchor w = x_max - fs/kt
    down = solve_static(K, np.array([0.0]), m.contacts, state=up.state, x_start=up.x,
                        f_start=np.array([10.0]))
    w = x_max - fs / kt
    assert down.convergence.success
    assert down.x[0] == pytest.approx(kt * w / (k + kt), rel=1e-12)
    assert abs(down.f_t[0]) < fs


@pytest.fixture(scope="module")
def coarse_parts(coarse_scene, coarse_structure):
    rom, cb = reduce_structure(coarse_structure, coarse_scene.model.n_modes)
    return coarse_scene, coarse_structure, rom, cb


def test_preload_equilibrium_and_symmetry(coarse_model):
    N0 = coarse_model.contacts.N0
    assert N0.sum() == pytest.approx(3 * 12e3, rel=1e-3)
    assert abs(N0.sum() - 36e3) < 1e-6 * 36e3  # in fact to round-off
    assert np.all(N0 >= 0) and 0 < np.sum(N0 > 0) < N0.size
    # the joint is point-symmetric about the lap centre: p(x) = p(-x)
    np.testing.assert_allclose(N0, N0[::-1], rtol=0, atol=1e-8 * N0.max())
    pre = coarse_model.preload.result
    assert pre.convergence.success and pre.residual < 1e-9


def test_reduced_preload_equals_full_model_preload(coarse_parts, coarse_model):
    """Contact, bolts and loads act on retained DOFs: the reduced solve is exact."""
    scene, st, rom, cb = coarse_parts
    Tt, Tn = st.interface.operators(st.n_dof)
    ne = st.interface.n_elements
    c = make_contact_set(scene, Tt, Tn, np.zeros(ne), np.zeros(ne), st.interface.area,
                         st.interface.position)
    full = solve_static(st.K - st.K_bolt, st.f_clamp, c, tangential="stuck",
                        normal=UnilateralPenalty(c.kn), tol=1e-11)
    assert full.convergence.success
    np.testing.assert_allclose(full.N, coarse_model.contacts.N0, rtol=0,
                               atol=1e-7 * full.N.max())
    # the rigid-body part of x is set by the soft suspension (1e3 N/m) under a
    # self-equilibrated load, so it is only defined to ~ tol ||f|| / k_susp
    x0_full = cb.T @ coarse_model.preload.x0
    np.testing.assert_allclose(x0_full, full.x, rtol=0, atol=1e-5 * np.abs(full.x).max())


@pytest.mark.parametrize("normal", ["coupled", "fixed"])
def test_preload_state_is_the_equilibrium_of_the_model(normal):
    """x0 solves K x + f_c(x) = f_static with the model's own K and f_static."""
    scene = load_scene(SCENE, COARSE + [f"effects.normal={normal}"])
    m = build_model(scene)
    x0 = m.preload.x0
    R = residual(m.K, m.f_static, m.contacts, x0, tangential="stuck")
    assert np.linalg.norm(R) < 1e-9 * np.linalg.norm(m.f_static)
    # and the scene's law, marched from rest, sees the same forces (no element slips)
    R = residual(m.K, m.f_static, m.contacts, x0)
    assert np.linalg.norm(R) < 1e-9 * np.linalg.norm(m.f_static)


def _fd_check(K, f, contacts, x, tangential, normal, state=None, seed=0):
    prob = _Problem(K, contacts, NORMALS[normal](contacts.kn), tangential,
                    state if state is not None else np.zeros(contacts.n_elements)
                    if tangential != "law" else contacts.law.rest_state(contacts.N0))
    J = prob.evaluate(x, f)["J"]
    rng = np.random.default_rng(seed)
    scale = np.abs(x).max()
    for _ in range(3):
        v = rng.standard_normal(x.size)
        h = 1e-7 * scale / np.abs(v).max()
        fd = (prob.evaluate(x + h * v, f, False)["R"] - prob.evaluate(x - h * v, f, False)["R"]) \
            / (2 * h)
        np.testing.assert_allclose(J @ v, fd, rtol=0, atol=1e-6 * np.abs(J @ v).max())


@pytest.mark.parametrize("tangential,normal", [("stuck", "unilateral"), ("law", "unilateral"),
                                               ("frictionless", "bilateral"),
                                               ("law", "fixed"), ("linear", "unilateral")])
def test_static_jacobian_matches_finite_differences(coarse_model, tangential, normal):
    m = coarse_model
    c = dataclasses.replace(m.contacts, law=dataclasses.replace(
        m.contacts.law, g=m.contacts.law.g * 0.05, mu=m.contacts.law.mu * 0.05))
    x0 = m.preload.x0
    rng = np.random.default_rng(1)
    x = x0 + 0.01 * np.abs(x0).max() * rng.standard_normal(x0.size)
    prob = _Problem(m.K, c, NORMALS[normal](c.kn), tangential, c.law.rest_state(c.N0)
                    if tangential == "law" else np.zeros(c.n_elements))
    ev = prob.evaluate(x, m.f_static)
    if tangential == "law":  # the point mixes sticking, slipping and open elements
        ft, N = ev["ft"], ev["N"]
        slipping = np.isclose(np.abs(ft), 0.6 * 0.05 * N, rtol=1e-12) & (N > 0)
        assert slipping.any() and (~slipping & (N > 0)).any() and (N == 0).any()
    _fd_check(m.K, m.f_static, c, x, tangential, normal)


def test_static_tangent_of_the_solution_matches_fd(coarse_model):
    """The tangent returned with the preload solution is dR/dx there."""
    m = coarse_model
    pre = m.preload.result
    rom = m.rom
    K = sp.csr_matrix(rom.K) - m.preload.K_bolt
    f = m.preload.f_clamp
    prob = _Problem(K, m.contacts, UnilateralPenalty(m.contacts.kn), "stuck",
                    np.zeros(m.contacts.n_elements))
    np.testing.assert_allclose(pre.K_t.toarray(), prob.evaluate(pre.x, f)["J"])
    _fd_check(K, f, m.contacts, pre.x, "stuck", "unilateral")


def test_failed_solve_reports_and_keeps_its_state(coarse_parts, coarse_model):
    scene, st, rom, cb = coarse_parts
    m = coarse_model
    K = sp.csr_matrix(rom.K) - m.preload.K_bolt
    res = solve_static(K, m.preload.f_clamp, m.contacts, tangential="stuck",
                       normal=UnilateralPenalty(m.contacts.kn), max_iter=1, min_increment=0.3)
    assert not res.convergence.success
    assert res.convergence.status != SUCCESS
    assert "load factor" in res.convergence.message
    assert np.all(np.isfinite(res.x)) and res.load_factor < 1.0


def test_sparse_and_dense_assembly_agree(monkeypatch):
    """Large sparse models assemble the Jacobian sparse, small ones and those whose
    stiffness is dense (a reduced model of any size) dense: same numbers."""
    import jointsim.solvers.static as static
    m = build_model(load_scene(SCENE, COARSE))
    x = m.preload.x0 * 1.3
    state = m.contacts.law.rest_state(m.contacts.N0)

    def problem():
        return static._Problem(m.K, m.contacts, UnilateralPenalty(m.contacts.kn), "law",
                               state)
    dense = problem().evaluate(x, m.f_static)
    monkeypatch.setattr(static, "DENSE_MAX_DOF", 0)
    assert problem().dense                    # the reduced stiffness is dense
    monkeypatch.setattr(static, "DENSE_MIN_FILL", 2.0)
    sparse = problem().evaluate(x, m.f_static)
    assert sp.issparse(sparse["J"]) and not sp.issparse(dense["J"])
    np.testing.assert_allclose(sparse["J"].toarray(), dense["J"], rtol=1e-12,
                               atol=1e-12 * np.abs(dense["J"]).max())
    np.testing.assert_allclose(sparse["R"], dense["R"], rtol=1e-12,
                               atol=1e-12 * np.abs(dense["R"]).max())


# --------------------------------------------------------------------------
# The static state and its stuck linearisation
# --------------------------------------------------------------------------
@pytest.fixture
def coupled(coarse_lap_coupled):
    return coarse_lap_coupled


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
