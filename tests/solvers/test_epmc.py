"""Nonlinear modes by EPMC (:mod:`jointsim.solvers.epmc`): the equations and their start."""
import numpy as np
import pytest

from jointsim.model import build_model
from jointsim.scene import parse_scene
from jointsim.solvers.condensation import dense_array
from jointsim.solvers.continuation import Continuation
from jointsim.solvers.epmc import EPMCSystem
from jointsim.solvers.hbm import HBMSystem
from jointsim.solvers.modes import elastic_mode


def three_dof(normal="fixed", harmonics=(0, 1, 2, 3), n_samples=32,
              C=(0.02, 0.01, 0.02)):
    """A damped 3-DOF chain with one Jenkins element from DOF 1 to ground (its normal
    gap on DOF 2); damping ``diag(C)``."""
    d = {"model": {"kind": "lumped", "M": np.diag([1.0, 1.5, 1.0]).tolist(),
                   "K": [[2.0, -1.0, 0.0], [-1.0, 1.5, -0.3], [0.0, -0.3, 1.0]],
                   "C": np.diag(C).tolist(),
                   "contacts": [{"t_dof": 1, "n_dof": 2, "N0": 1.0, "gap0": -0.5}]},
         "joint": {"law": "jenkins", "mu": 0.3, "kt": 0.8, "kn": 1.0},
         "effects": {"normal": normal, "separation": True}}
    sc = parse_scene(d, "three_dof.toml")
    m = build_model(sc)
    system = HBMSystem(m, harmonics, n_samples)
    em = elastic_mode(m, 1)
    ep = EPMCSystem(system, em.phi, system.force_coefficients(0.0))
    return m, system, em, ep


def start(system, em, model, lam):
    """The linear mode as EPMC unknowns ``(zh, omega, xi, lam)``."""
    Q = np.zeros((system.n_c, system.n_r))
    Q[system.basis.index[1][0]] = system.T @ em.phi
    xi0 = float(em.phi @ dense_array(model.C) @ em.phi)
    return np.concatenate([Q.ravel(), [em.omega, xi0, lam]]), xi0


@pytest.mark.parametrize("normal", ["fixed", "coupled"])
def test_epmc_jacobian_matches_finite_differences(normal):
    """Every column of the EPMC Jacobian (shape, omega, xi, log10 a), at an amplitude
    where the element sticks and slips in each period."""
    m, system, em, ep = three_dof(normal)
    y, _ = start(system, em, m, 0.3)
    rng = np.random.default_rng(4)
    y[:system.n_z] *= 1.0 + 0.05 * rng.standard_normal(system.n_z)
    R, J, ev = ep.fun(y)
    assert R.shape == (system.n_z + 2,) and J.shape == (system.n_z + 2, system.n_z + 3)
    assert ev.aft is not None
    Jfd = np.empty_like(J)
    for k in range(y.size):
        e = 1e-7 * max(abs(y[k]), 1e-3)
        yp, ym = y.copy(), y.copy()
        yp[k] += e
        ym[k] -= e
        Jfd[:, k] = (ep.fun(yp)[0] - ep.fun(ym)[0]) / (2 * e)
    assert np.abs(J - Jfd).max() <= 1e-5 * np.abs(J).max()


def test_small_amplitude_mode_is_the_stuck_linear_mode():
    """At a tiny amplitude the element sticks: with mass-proportional damping the mode
    is the stuck linear one, omega its frequency and xi = phi^T C phi."""
    m, system, em, ep = three_dof(C=(0.01, 0.015, 0.01))
    y0, xi0 = start(system, em, m, -6.0)
    scale = np.concatenate([np.full(system.n_z, np.abs(y0[:system.n_z]).max()),
                            [em.omega, em.omega, 1.0]])
    cont = Continuation(ep.fun, y0, -5.0, scale=scale, rscale=1.0, step=0.01,
                        step_min=1e-8, step_max=0.1, max_points=1, tol=1e-12)
    assert cont.n_points == 1 and cont.infos[0].residual <= 1e-12
    y = cont.points[0]
    nz = system.n_z
    assert y[nz] == pytest.approx(em.omega, rel=1e-10)
    assert xi0 == pytest.approx(0.01, rel=1e-12)
    assert y[nz + 1] == pytest.approx(xi0, rel=1e-8)
    R, _, _ = ep.fun(y)
    assert abs(R[-2]) <= 1e-12 and abs(R[-1]) <= 1e-12


def test_epmc_needs_the_fundamental():
    m, system, em, _ = three_dof()
    sys0 = HBMSystem(m, (0, 2), 16)
    with pytest.raises(ValueError, match="harmonic 1"):
        EPMCSystem(sys0, em.phi, sys0.force_coefficients(0.0))
