"""Issue 13, the lumped hard-case suite: stiffness ratios, Iwan banks, many harmonics,
folds, separation.  Each case completes (or stops with a message naming its cause) and
writes no NaN or Inf; where a converged reference exists it is the oracle."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from jointsim.run import run_scene
from jointsim.scene import load_scene

from .._scenes import CHAIN2, MODELS
from ._files import assert_all_finite

F02 = "analysis.hbm.force_scale=[0.2]"
SDOF_FOLD = MODELS / "hbm" / "sdof_clearance_fold.toml"
FOLD = MODELS / "hbm" / "chain2_friction_fold.toml"


def _complete(tmp_path, path, overrides, name="x.h5"):
    out = run_scene(load_scene(path, overrides), tmp_path / name)
    with h5py.File(out) as h:
        g = h["hbm"]
        n = len(h["hbm/force_scale"])
        for ib in range(n):
            assert g.attrs[f"branch{ib}_status"] == "complete", g.attrs[f"branch{ib}_message"]
        b = h["hbm/branch"][()]
        counts = [int((b == ib).sum()) for ib in range(n)]
    assert_all_finite(out)
    return out, counts


# -- stiffness ratio kt / k from 1e-2 to 1e4 (k ~ 1 in the chain) ----------------------
@pytest.mark.parametrize("kt, max_points", [
    (1e-2, 200), (1.0, 200),
    pytest.param(1e2, 400, marks=pytest.mark.slow),     # 1,199 points before issue 13
    pytest.param(1e4, 1000, marks=pytest.mark.slow),    # 2,000 points, stopped at 1.02
])
def test_stiffness_ratio(tmp_path, kt, max_points):
    _, counts = _complete(tmp_path, CHAIN2, [f"joint.kt={kt}", F02])
    assert counts[0] <= max_points


# -- Iwan banks with 2 and 500 sliders --------------------------------------------------
@pytest.mark.parametrize("n", [2, pytest.param(500, marks=pytest.mark.slow)])
def test_iwan_sliders(tmp_path, n):
    _complete(tmp_path, CHAIN2, ["joint.law='iwan4'", f"joint.n_sliders={n}", F02])


# -- H = 31 with Nt = 2048: the peak converges to the H = 7 one -------------------------
@pytest.mark.slow
def test_many_harmonics(tmp_path):
    ref, _ = _complete(tmp_path, CHAIN2, [F02], "h7.h5")
    out, _ = _complete(tmp_path, CHAIN2, [F02, f"analysis.hbm.harmonics={list(range(32))}",
                                          "analysis.hbm.n_samples=2048"], "h31.h5")
    with h5py.File(ref) as a, h5py.File(out) as b:
        pa, pb = a["hbm/peak_amplitude"][0], b["hbm/peak_amplitude"][0]
    assert pb == pytest.approx(pa, rel=1e-2)


# -- two folds in one branch --------------------------------------------------------------
@pytest.mark.slow
def test_two_folds_in_one_branch(tmp_path):
    out, _ = _complete(tmp_path, SDOF_FOLD, [])
    with h5py.File(out) as h:
        b, w = h["hbm/branch"][()], h["hbm/omega"][()]
        for ib in np.unique(b):
            d = np.sign(np.diff(w[b == ib]))
            assert int((d[1:] != d[:-1]).sum()) >= 2   # the frequency turns back twice


# -- separation over most of the period -------------------------------------------------
@pytest.mark.slow
def test_separation_over_most_of_the_period(tmp_path):
    """The fold scene at force scale 0.7 (its first point needs the force homotopy): at the
    peak the contact is open over more than half of the period."""
    out, _ = _complete(tmp_path, FOLD, ["analysis.hbm.force_scale=[0.7]"])
    with h5py.File(out) as h:
        N = h["hbm/loops/N"][()]
    assert (N <= 0.0).mean() > 0.5


# -- item 5: mu = 1e6 on the fold scene (stuck contact with clapping) --------------------
@pytest.mark.slow
def test_fold_scene_with_huge_friction_names_the_near_discontinuity(tmp_path):
    """At mu = 1e6 the clapping element sticks within a sample of closing: the residual is
    nearly discontinuous one step past omega = 1.12 (its Jacobian agrees with finite
    differences at the point, 1.5e-11 at eps = 1e-7, but a step of 1e-5 changes R by
    7e-3).  The branch stops with a message naming that cause, and joint.closing, and
    keeps its points."""
    out = tmp_path / "x.h5"
    with pytest.raises(RuntimeError) as err:
        run_scene(load_scene(FOLD, ["joint.mu=1e6"]), out)
    msg = str(err.value)
    assert "corrector failed" in msg and "nearly discontinuous" in msg
    assert "joint.mu = 1e+06" in msg and "lower joint.mu" in msg and "clap" in msg
    assert "joint.closing = 'interpolated'" in msg
    with h5py.File(out) as h:
        assert h["hbm"].attrs["branch0_status"] == "gave up"
        assert len(h["hbm/omega"]) > 50 and h["hbm/omega"][-1] > 1.1
    assert_all_finite(out)


def _never_slipping(X, omega):
    """Largest difference, relative to ``max |X|``, between the points ``X`` at
    ``omega`` and the never-slipping contact (the same scene with ``mu = inf``: the
    element sticks whenever it is closed and its stuck force drops to 0 at the opening
    instant), solved by Newton from each point."""
    import dataclasses

    from jointsim.model import build_model
    from jointsim.solvers.hbm import HBMSystem, solve_point

    model = build_model(load_scene(FOLD, ["joint.mu=1", "joint.closing='interpolated'"]))
    law = model.contacts.law
    law = dataclasses.replace(law, g=np.full_like(law.g, np.inf),
                              mu=np.full_like(law.mu, np.inf))
    model = dataclasses.replace(model, contacts=dataclasses.replace(model.contacts, law=law))
    s = HBMSystem(model, tuple(range(8)), 512)
    err = []
    for x, w in zip(X, omega):
        sol = solve_point(s, float(w), s.force_coefficients(0.1), z0=s.contact_coordinates(x),
                          tol=1e-10, max_iter=40)
        assert sol.convergence.success, (w, sol.convergence.message)
        err.append(np.abs(sol.X - x).max() / np.abs(x).max())
    return np.array(err)


@pytest.mark.slow
def test_fold_scene_with_huge_friction_and_interpolated_closing(tmp_path):
    """joint.closing = 'interpolated' places the anchor at the closing instant and
    integrates the interval of each opening up to the opening instant, so the residual
    is continuous when a closing or an opening instant crosses a sample: the branch goes
    on from 74 points (omega = 1.12) through the whole clapping range (129 points) and
    equals the never-slipping contact (mu = inf) at every 8th point from the 4th
    (relative 5.5e-6 at most, measured; mu = 1e9 is within about 1e-9 of it: the 1/mu
    error of a finite mu; from the peak point itself, 48, Newton at mu = inf stalls at a
    residual of 1.3e-7: the Jacobian is nearly singular there).  It
    stops at omega = 1.47596, where the last clap vanishes (the contact grazes: open over
    1 of 512 samples) and the branch turns back on another clapping family, which the
    branch run from the other end of the range reaches at the same point; past it a
    contact that never opens takes the anchor of the rest state, so the residual jumps.
    The message names the grazing and what to change."""
    out = tmp_path / "x.h5"
    with pytest.raises(RuntimeError) as err:
        run_scene(load_scene(FOLD, ["joint.mu=1e6", "joint.closing='interpolated'"]), out)
    msg = str(err.value)
    assert "nearly discontinuous" in msg and "grazing" in msg and "lower joint.mu" in msg
    assert "opens over 1 of 512 samples" in msg and "omega_start" in msg
    with h5py.File(out) as h:
        assert h["hbm"].attrs["branch0_status"] == "gave up"
        om, X = h["hbm/omega"][()], h["hbm/X"][()]
    assert len(om) > 120 and om[-1] == pytest.approx(1.47596, abs=1e-4)
    assert om.min() < 1.054 and np.any(np.diff(om) < 0)            # the fold and its peak
    assert_all_finite(out)
    rows = np.arange(4, len(om), 8)
    assert _never_slipping(X[rows], om[rows]).max() < 2e-5
    # the same grazing point from the other end of the range
    back = tmp_path / "back.h5"
    with pytest.raises(RuntimeError) as err:
        run_scene(load_scene(FOLD, ["joint.mu=1e6", "joint.closing='interpolated'",
                                    "analysis.hbm.omega_start=2.5",
                                    "analysis.hbm.omega_end=0.5"]), back)
    assert "grazing" in str(err.value)
    with h5py.File(back) as h:
        ob, Xb = h["hbm/omega"][()], h["hbm/X"][()]
    assert ob[-1] == pytest.approx(om[-1], abs=1e-4)
    assert np.abs(Xb[-1] - X[-1]).max() < 2e-3 * np.abs(X[-1]).max() + 1e-3
    assert_all_finite(back)


@pytest.mark.slow
def test_fold_scene_with_huge_friction_time_marching_agrees_with_hbm(tmp_path):
    """Time marching (1,024 steps per period, from rest) at omega = 1.19, where the
    mu = 1e6 contact claps (open over 25 % of the period): HBM (H = 0..7, 512 samples,
    interpolated closing) solved by Newton from the march's harmonics agrees to 1.1e-3
    of the first harmonic (measured; against H = 0..31 at 2,048 samples 1.2e-3, and
    4.0e-4 for a march at 4,096 steps: the march's first order in the step)."""
    from jointsim.model import build_model
    from jointsim.solvers.hbm import HBMSystem, solve_point

    out = run_scene(load_scene(FOLD, [
        "joint.mu=1e6", "joint.closing='interpolated'", "analysis.hbm.omega_end=0.6",
        "analysis.transient.omega=1.19", "analysis.transient.force_scale=0.1",
        "analysis.transient.steps_per_period=1024", "analysis.transient.steady_tol=1e-9",
        "analysis.transient.max_periods=4000"]), tmp_path / "tm.h5")
    with h5py.File(out) as h:
        assert h["transient"].attrs["success"]
        Xt = h["crosscheck/X_transient"][()]
    # the first period's change is NaN by definition (solvers/transient.py, docs)
    assert_all_finite(out)
    s = HBMSystem(build_model(load_scene(FOLD, ["joint.mu=1e6",
                                                "joint.closing='interpolated'"])),
                  tuple(range(8)), 512)
    sol = solve_point(s, 1.19, s.force_coefficients(0.1), z0=s.contact_coordinates(Xt),
                      tol=1e-11, max_iter=40)
    assert sol.convergence.success
    ev = s.evaluate(s.contact_coordinates(sol.X), 1.19, s.force_coefficients(0.1), wrt=(),
                    jacobian=False)
    assert 0.1 < np.mean(ev.aft.N <= 0.0) < 0.9                    # it claps
    assert np.abs(sol.X - Xt).max() < 2e-3 * np.abs(sol.X[1:3]).max()


@pytest.mark.slow
def test_fold_scene_with_mu_1_completes_with_interpolated_closing(tmp_path):
    """mu = 1: the element sticks at its closing instants; with the anchor at the last
    open sample the branch stops at omega = 1.457 on a step of the residual, with
    joint.closing = 'interpolated' it completes (156 points) and folds."""
    out = tmp_path / "x.h5"
    run_scene(load_scene(FOLD, ["joint.mu=1", "joint.closing='interpolated'"]), out)
    with h5py.File(out) as h:
        assert h["hbm"].attrs["branch0_status"] == "complete"
        assert h["hbm/omega"][-1] == pytest.approx(2.5)
        assert np.any(np.diff(h["hbm/omega"][()]) < 0)       # the fold
    assert_all_finite(out)


def test_steepness_of_a_smooth_and_a_nearly_discontinuous_residual():
    """:func:`steepness`: 0 for a linear residual and before a tanh step of width 1e-9,
    >> 1 across it."""
    from jointsim.solvers.discontinuity import steepness

    A = np.array([[2.0, 1.0], [0.5, 3.0]])
    assert steepness(lambda y: A @ y, lambda y: A, np.zeros(2), np.ones(2)) < 1e-12

    def fun(y):
        return A @ y + np.array([np.tanh((y[0] - 0.5) / 1e-9), 0.0])

    def jac(y):
        J = A.copy()
        J[0, 0] += (1.0 - np.tanh((y[0] - 0.5) / 1e-9) ** 2) / 1e-9
        return J

    assert steepness(fun, jac, np.zeros(2), [0.4, 0.0]) < 1e-9    # before the step
    y0, y1 = np.array([0.5 - 1e-6, 0.0]), np.array([0.5 + 1e-6, 0.0])
    assert steepness(fun, jac, y0, y1) > 1e5            # jump 2 over |J d| = 4e-6
