"""Time-marching accuracy guards (issues 12 and 13): the step-size error indicator
against the true error, the scheme's frequency error, and range warnings from 8 to
100,000 steps per period."""
from __future__ import annotations

import logging

import numpy as np
import pytest

from jointsim.harmonics import coefficient_index
from jointsim.model import build_model
from jointsim.solvers.march_accuracy import (scheme_frequency_error, step_error,
                                             step_range_warnings)
from jointsim.solvers.transient import march_steady

from .._transient_scenes import lumped, two_dof_jenkins


def _first(X, hs=tuple(range(8))):
    return X[list(coefficient_index(hs, 1))]


def test_frequency_error_of_the_trapezoidal_rule_is_exact():
    # rho_inf = 1 is the trapezoidal rule: eigenvalues (1 + i wh/2) / (1 - i wh/2)
    for n in (8, 16, 64, 1000):
        wh = 2 * np.pi / n
        exact = wh / (2.0 * np.arctan(wh / 2.0)) - 1.0
        assert scheme_frequency_error(wh, 1.0) == pytest.approx(exact, rel=1e-9)
    # second order for any rho_inf, and more period error with more dissipation
    for rho in (0.9, 0.6, 0.0):
        e1, e2 = (scheme_frequency_error(2 * np.pi / n, rho) for n in (200, 400))
        assert e1 / e2 == pytest.approx(4.0, rel=2e-2)
        assert e1 >= scheme_frequency_error(2 * np.pi / 200, 1.0)


def test_range_warnings_name_the_key():
    assert step_range_warnings(2 * np.pi / 256, 0.9) == []
    w = step_range_warnings(2 * np.pi / 8, 0.9, 7)
    assert len(w) == 1 and "steps_per_period" in w[0] and "5%" in w[0]
    assert "round-off" in step_range_warnings(2 * np.pi / 1e7, 0.9)[0]


@pytest.mark.parametrize("n", [8, 16, 64, 1024, 100_000])
def test_linear_march_from_8_to_100000_steps(n, caplog):
    """A linear 2-DOF structure: finite at every step size; the march plus its
    step-error estimate is the exact (continuous) steady state; a warning where
    the step is outside the scheme's range."""
    w = 1.3
    sc = lumped([[1.0, 0.0], [0.0, 2.0]], [[3.0, -1.0], [-1.0, 2.0]],
                [[0.1, 0.0], [0.0, 0.05]],
                loads=[{"dof": 0, "force": {"harmonics": [{"h": 1, "cos": 1.0}]}}],
                transient={"omega": w, "steady_tol": 1e-9, "harmonics": [0, 1, 2, 3],
                           "steps_per_period": n, "start": "linear"})
    model = build_model(sc)
    with caplog.at_level(logging.WARNING):
        res = march_steady(model, sc.analysis.transient, progress=False)
    assert res.convergence.success and np.all(np.isfinite(res.last.x))
    M, K, C = (m.toarray() for m in (model.M, model.K, model.C))
    exact = np.linalg.solve(K - w * w * M + 1j * w * C, np.array([1.0, 0.0]))
    got = res.X[1] - 1j * res.X[2]
    e = res.step_error
    true = np.linalg.norm(got - exact) / np.linalg.norm(exact)
    corrected = res.X + e.dX
    assert np.linalg.norm(corrected[1] - 1j * corrected[2] - exact) \
        <= 1e-7 * np.linalg.norm(exact)
    assert e.value == pytest.approx(true, rel=1e-5, abs=1e-9)
    warned = any("outside the accurate range" in r.getMessage() for r in caplog.records)
    assert warned == (n < 64)
    assert bool(res.range_warnings) == (n < 64)


def test_step_error_ranks_and_matches_the_true_error_on_the_jenkins_chain():
    """2-DOF chain with a slipping Jenkins element near its resonance: the
    indicator is within a factor 3 of the error against a 1,024-step march
    and ranks the step sizes correctly."""
    w = 1.1
    tr = {"steady_tol": 1e-10, "max_periods": 5000, "start": "linear"}

    def run(n):
        sc = two_dof_jenkins(w, F=0.3, transient=dict(tr, steps_per_period=n))
        res = march_steady(build_model(sc), sc.analysis.transient, progress=False)
        assert res.convergence.success
        return res

    ref = _first(run(1024).X)
    ind, true = [], []
    for n in (32, 64, 128):
        res = run(n)
        f = res.last.f
        assert np.any(np.abs(f) >= 0.2 * (1 - 1e-9))   # the element slips
        true.append(np.linalg.norm(_first(res.X) - ref) / np.linalg.norm(ref))
        ind.append(res.step_error.value)
    ind, true = np.array(ind), np.array(true)
    assert np.all(np.diff(ind) < 0) and np.all(np.diff(true) < 0)
    assert np.all(ind / true < 3.0) and np.all(ind / true > 1 / 3.0)


def test_step_error_needs_a_period():
    sc = two_dof_jenkins(1.1, transient={"steps_per_period": 32, "start": "linear"})
    model = build_model(sc)
    res = march_steady(model, sc.analysis.transient, progress=False)
    e = step_error(model, res.last, 1.1, 1.0, sc.analysis.transient.harmonics, 32)
    assert e.value == pytest.approx(res.step_error.value, rel=1e-12)
    assert e.rel_harmonics.shape == (8,) and e.dX.shape == res.X.shape


# --------------------------------------------------------------------------
# periodicity: modes the scene leaves undamped (issue 13 item 8)
# --------------------------------------------------------------------------
def _half_damped(transient):
    """M = I, K = [[2, -1], [-1, 2]] (modes at 1 and sqrt 3 rad/s); C damps mode 1
    only (C = c phi_1 phi_1^T), so mode 2 has no damping at all."""
    c = 0.05
    return lumped([[1.0, 0.0], [0.0, 1.0]], [[2.0, -1.0], [-1.0, 2.0]],
                  [[c / 2, c / 2], [c / 2, c / 2]],
                  loads=[{"dof": 0, "force": {"harmonics": [{"h": 1, "cos": 1.0}]}}],
                  transient=transient)


def test_undamped_modes_are_found_and_damped_exactly():
    from jointsim.solvers.march_accuracy import undamped_modes, with_mode_damping
    model = build_model(_half_damped({"omega": 1.2}))
    modes = undamped_modes(model)
    assert modes.n == 1 and modes.omega[0] == pytest.approx(np.sqrt(3.0), rel=1e-12)
    damped = with_mode_damping(model, modes, 0.02)
    phi = modes.shapes[:, 0]
    assert phi @ damped.C.toarray() @ phi / (2 * np.sqrt(3.0)) == pytest.approx(0.02,
                                                                                 rel=1e-12)
    phi1 = np.array([1.0, 1.0]) / np.sqrt(2.0)   # mode 1 keeps its damping
    assert phi1 @ damped.C.toarray() @ phi1 == pytest.approx(0.05, rel=1e-12)
    assert undamped_modes(damped).n == 0


def test_undamped_mode_makes_the_march_aperiodic_and_the_option_fixes_it(tmp_path):
    """With rho_inf = 1 (no numerical dissipation) the free vibration of the
    undamped mode started at t = 0 never decays: the run fails and says why; with
    undamped_mode_zeta it becomes periodic, and matches the exact response of the
    damped structure."""
    import h5py

    from jointsim.run import run_scene
    tr = {"omega": 1.2, "rho_inf": 1.0, "steps_per_period": 128, "max_periods": 300,
          "steady_tol": 1e-8, "harmonics": [0, 1, 2, 3]}
    with pytest.raises(RuntimeError, match="undamped_mode_zeta"):
        run_scene(_half_damped(tr), tmp_path / "a.h5")
    with h5py.File(tmp_path / "a.h5") as h5:
        assert h5["transient"].attrs["undamped_modes"] == 1
        assert h5["transient"].attrs["undamped_modes_hz"][0] == pytest.approx(
            np.sqrt(3.0) / (2 * np.pi))
    out = run_scene(_half_damped(dict(tr, undamped_mode_zeta=0.05)), tmp_path / "b.h5")
    with h5py.File(out) as h5:
        g = h5["transient"]
        assert g.attrs["success"] and g.attrs["undamped_mode_zeta"] == 0.05
        X = h5["transient/harmonics"][()]
        e = h5["transient/error_step"]
        assert e.attrs["unit"] and "doc" in e.attrs
        dX = h5["transient/error_step_dX"][()]
    M, K = np.eye(2), np.array([[2.0, -1.0], [-1.0, 2.0]])
    p1, p2 = np.array([1.0, 1.0]) / np.sqrt(2), np.array([1.0, -1.0]) / np.sqrt(2)
    C = 0.05 * np.outer(p1, p1) + 2 * 0.05 * np.sqrt(3) * np.outer(p2, p2)
    exact = np.linalg.solve(K - 1.44 * M + 1.2j * C, [1.0, 0.0])
    got = X[1] - 1j * X[2]
    corrected = (X + dX)[1] - 1j * (X + dX)[2]
    assert np.abs(corrected - exact).max() < 1e-7 * np.abs(exact).max()
    assert np.abs(got - exact).max() < 2e-3 * np.abs(exact).max()   # 128 steps
    from jointsim.post.tables import info_text
    text = info_text(out)
    assert "time-step error indicator" in text and "damped at 0.05" in text


@pytest.mark.parametrize("n", [8, 100_000])
def test_slipping_chain_at_extreme_step_counts_stays_finite(n, caplog):
    """The 2-DOF Jenkins chain, slipping, from rest, at 8 and 100,000 steps per
    period (3 periods): finite everywhere, the range warning only at 8."""
    sc = two_dof_jenkins(1.1, F=0.3, transient={"steps_per_period": n, "max_periods": 3,
                                                 "min_periods": 2, "harmonics": [0, 1, 3]})
    with caplog.at_level(logging.WARNING):
        res = march_steady(build_model(sc), sc.analysis.transient, progress=False)
    assert res.last is not None
    for a in (res.last.x, res.last.v, res.last.f, res.X, res.step_error.dX):
        assert np.all(np.isfinite(a))
    assert np.abs(res.last.f).max() <= 0.2 * (1 + 1e-9)      # the slip limit holds
    assert (n == 8) == any("outside the accurate range" in r.getMessage()
                           for r in caplog.records)
