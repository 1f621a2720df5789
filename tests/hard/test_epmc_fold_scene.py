"""Issue 13, case 14: the EPMC of mode 1 of the friction-softening fold scene.

It used to give up at log10 a = -1.414.  Below that amplitude the contact is
stuck after shaking down (the AFT march lets the slider settle in its first
periods, so the mean tangential position grows with the amplitude while the
mode stays linear); there the shaken-down stuck range ends and the element
slips every period.  At that corner the new piece of the branch runs back
against the incoming tangent in the scaled unknowns (the mean position
shrinks again) while the amplitude still grows, so no pseudo-arclength
hyperplane cuts it near the corner; the stepper now passes such a corner by a
corrector at fixed amplitude.  Oracles: the stuck range is the linear mode
(frequency of the stuck 2-DOF system, damping ratio phi^T C phi / (2 omega));
past the corner the damping grows continuously from it.
"""
from pathlib import Path

import h5py
import numpy as np
import pytest

from jointsim import _toml
from jointsim.run import run_scene
from jointsim.scene import apply_overrides, parse_scene

SCENE = Path(__file__).resolve().parents[2] / "models" / "hbm" / "chain2_friction_fold.toml"


def _epmc_scene(lam0, lam1):
    text = SCENE.read_text().split("[analysis.hbm]")[0]
    data = _toml.loads(text)
    data = apply_overrides(data, ["analysis.epmc.mode=1",
                                  f"analysis.epmc.log10_amplitude_start={lam0}",
                                  f"analysis.epmc.log10_amplitude_end={lam1}",
                                  "analysis.epmc.harmonics=[0,1,2,3,4,5,6,7]",
                                  "analysis.epmc.n_samples=512"], str(SCENE))
    return parse_scene(data, str(SCENE), SCENE.parent)


def test_fold_scene_mode_1_passes_the_end_of_the_stuck_range(tmp_path):
    out = run_scene(_epmc_scene(-1.5, -1.3), tmp_path / "fold_epmc.h5")
    # the stuck 2-DOF system: K + diag(kt, kn), M = I, C = 0.01 I
    K = np.array([[1.0 + 1.0, -0.3], [-0.3, 1.0 + 2.0]])
    w2, _ = np.linalg.eigh(K)
    omega0 = np.sqrt(w2[0])
    zeta0 = 0.01 / (2 * omega0)
    with h5py.File(out, "r") as h5:
        g = h5["epmc"]
        assert g.attrs["branch_status"] == "complete", g.attrs["message"]
        lam = np.log10(g["amplitude"][()])
        w, z = g["omega"][()], g["damping_ratio"][()]
        assert np.all(np.isfinite(g["X"][()]))
    assert abs(lam[-1] + 1.3) < 1e-9
    assert np.all(np.diff(lam) > 0)
    stuck = lam < -1.42
    assert stuck.sum() >= 2
    np.testing.assert_allclose(w[stuck], omega0, rtol=1e-8)
    np.testing.assert_allclose(z[stuck], zeta0, rtol=1e-8)
    # past the corner: slip every period, more damping, lower frequency, no jump
    assert z[-1] > 10 * zeta0 and w[-1] < omega0
    assert np.max(np.abs(np.diff(z))) < 0.0025   # the monitor's 0.002 per step, no jump


def _sharp_corner(y):
    """``R = z - g(lam)``, ``g = lam`` below 0 and ``-3 lam`` above: a corner of
    117 degrees whose second piece runs back in ``z`` while ``lam`` advances."""
    z, lam = y
    slope = 1.0 if lam < 0.0 else -3.0
    return np.array([z - slope * lam]), np.array([[1.0, -slope]]), None


def test_fixed_lam_step_passes_a_corner_sharper_than_90_degrees():
    from jointsim.solvers.continuation import Continuation

    c = Continuation(_sharp_corner, np.array([-1e-3, -1e-3]), 1.0, scale=np.ones(2),
                     rscale=1.0, step=0.05, step_min=1e-6, step_max=0.2, max_points=200,
                     tol=1e-12)
    yk, t = c._yh, c._t
    np.testing.assert_allclose(t, [np.sqrt(0.5), np.sqrt(0.5)])   # the incoming piece
    h = 0.01
    # the hyperplane normal to the incoming tangent, h ahead, misses the new piece
    # anywhere: the pseudo-arclength corrector fails
    ok, *_ = c._correct(yk, t, h)
    assert not ok
    got = c._natural_step(yk, h)
    assert got is not None
    z, lam = got[0]
    assert lam == pytest.approx(yk[1] + h) and z == pytest.approx(-3.0 * lam, abs=1e-12)



def test_a_corner_remedy_repeats_no_stalled_corrector_and_drops_stalled_directions():
    """At a corner whose step just failed without a jump, the remedy does not repeat that
    corrector with a wider jump limit (it would fail alike) and passes the 117-degree
    corner; a tangent direction whose Newton stalls is given up after ``stall``
    iterations, not ``max_iter`` (the 240-point FRC's corner: 127 -> 49 linear solves)."""
    from jointsim.solvers.arclength import corner_step
    from jointsim.solvers.continuation import Continuation

    c = Continuation(_sharp_corner, np.array([-1e-3, -1e-3]), 1.0, scale=np.ones(2),
                     rscale=1.0, step=0.05, step_min=1e-6, step_max=0.2, max_points=200,
                     tol=1e-12)
    yk, t, h = c._yh, c._t, 0.01
    assert not c._correct(yk, t, h)[0] and not c._failed[1]      # failed, not by a jump
    correct, tried = c._correct, []
    c._correct = lambda *a, **k: tried.append(a) or correct(*a, **k)
    ok, _, (z, lam), *_ = c._try_corner(yk, t, h)
    assert ok and not tried and z == pytest.approx(-3.0 * lam, abs=1e-12) and lam > 0.0

    calls = []

    def nowhere(y):                     # z^2 + 1 = 0: Newton wanders, never converges
        calls.append(1)
        return np.array([y[0] ** 2 + 1.0]), np.array([[2.0 * y[0], 0.0]]), None
    y0, t0 = np.array([0.3, 0.0]), np.array([0.0, 1.0])
    counts = []
    for stall in (None, 5):
        calls.clear()
        assert corner_step(nowhere, y0, t0, 0.01, 1e-12, 20, stall=stall) is None
        counts.append(len(calls))
    assert counts[1] < counts[0] / 2
