"""The stuck onset of an EPMC backbone (:func:`jointsim.analyses.epmc.stuck_onset`).

Oracle: a single DOF with a Jenkins element to ground (``models/hbm/
sdof_jenkins_epmc.toml``: k = 1, kt = 0.25, mu N0 = 0.2) sticks while
``kt |x| < mu N0``, so its modal amplitude at the onset of slip is
``mu N0 / kt = 0.8`` (m = 1: the modal amplitude is the amplitude of x).
"""
import h5py
import numpy as np
import pytest

from jointsim.analyses.epmc import _linear_start, _scales, stuck_onset
from jointsim.model import build_model
from jointsim.run import run_scene
from jointsim.scene import load_scene
from jointsim.solvers.condensation import dense_array
from jointsim.solvers.epmc import EPMCSystem
from jointsim.solvers.hbm import HBMSystem
from jointsim.solvers.modes import elastic_mode

from .._scenes import MODELS
from .test_hbm import run_interrupted_after

SDOF = MODELS / "hbm" / "sdof_jenkins_epmc.toml"
ONSET = np.log10(0.2 / 0.25)
#: quick SDOF settings (loops at one amplitude only: the file writes dominate)
QUICK = ["analysis.epmc.harmonics=[0, 1, 3]", "analysis.epmc.n_samples=32",
         "analysis.epmc.error_indicators=false", "analysis.epmc.loop_amplitudes=[3.0]"]


def _sdof(overrides=()):
    sc = load_scene(SDOF, list(overrides))
    m = build_model(sc)
    a = sc.analysis.epmc
    system = HBMSystem(m, a.harmonics, a.n_samples)
    em = elastic_mode(m, a.mode)
    ep = EPMCSystem(system, em.phi, system.force_coefficients(0.0))
    xi0 = float(em.phi @ dense_array(m.C) @ em.phi)
    y = _linear_start(a, system, em, xi0)
    _scale, rscale = _scales(ep, y, em.omega)
    return a, ep, y, rscale


def test_stuck_onset_of_a_jenkins_oscillator_is_the_slip_amplitude():
    a, ep, y, rscale = _sdof()
    onset = stuck_onset(ep, y, -1.0, 2.0, rscale, a.tol)
    # (the last amplitude at which the linear mode still solves the equations to the
    # tolerance: 7e-7 past the slip onset, where the slip is still tiny)
    assert onset == pytest.approx(ONSET, abs=2e-6)
    # downwards from the slipping range: the mode is not linear at the start
    assert stuck_onset(ep, y, 0.5, -1.0, rscale, a.tol) is None
    # a range that ends before the onset is linear throughout
    assert stuck_onset(ep, y, -1.0, -0.2, rscale, a.tol) is None


def test_backbone_has_a_point_at_the_onset_and_continues_from_it(tmp_path):
    sc = load_scene(SDOF, QUICK)
    with h5py.File(run_scene(sc, tmp_path / "sdof.h5"), "r") as h5:
        g = h5["epmc"]
        assert g.attrs["branch_status"] == "complete", g.attrs["message"]
        assert g.attrs["log10_stuck_onset"] == pytest.approx(ONSET, abs=2e-6)
        lam = np.log10(g["amplitude"][()])
        assert np.all(np.diff(lam) > 0)
        i = int(np.argmin(np.abs(lam - ONSET)))
        assert lam[i] == pytest.approx(ONSET, abs=2e-6)
        omega, zeta = g["omega"][()], g["damping_ratio"][()]
        # stuck up to the onset: the linear mode sqrt(k + kt) and no damping ...
        assert np.allclose(omega[:i + 1], np.sqrt(1.25), rtol=1e-9)
        assert np.abs(zeta[:i + 1]).max() < 1e-9
        # ... slipping beyond: softer and damped
        assert omega[i + 1] < np.sqrt(1.25) and zeta[i + 1] > 1e-4
        assert "stuck onset" in g.attrs["message"]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    sc = load_scene(SDOF, QUICK)
    full = tmp_path_factory.mktemp("full") / "full.h5"
    run_scene(sc, full)
    with h5py.File(full, "r") as h5:
        ref = h5["epmc/y"][()]
    k_onset = int(np.argmin(np.abs(ref[:, -1] - ONSET)))
    assert 2 < k_onset < len(ref) - 4
    return sc, ref, k_onset


@pytest.mark.parametrize("after", [pytest.param(-1, marks=pytest.mark.slow), 1,
                                   pytest.param(4, marks=pytest.mark.slow)],
                         ids=["stuck piece", "onset point", "second leg"])
def test_a_branch_interrupted_in_either_leg_resumes_to_the_same_points(
        uninterrupted, after, tmp_path, monkeypatch):
    """Interrupted on the stuck piece, right after the onset point (the second leg not
    begun) or in the second leg, ``--resume`` retraces the uninterrupted branch."""
    sc, ref, k_onset = uninterrupted
    n = k_onset + after
    part = tmp_path / "part.h5"
    run_interrupted_after(sc, part, n, monkeypatch, dataset="epmc/amplitude")
    with h5py.File(part, "r") as h5:
        assert h5.attrs["status"] == "interrupted" and h5["epmc/y"].shape[0] == n
    run_scene(sc, part, resume=True)
    with h5py.File(part, "r") as h5:
        assert h5.attrs["status"] == "complete"
        y = h5["epmc/y"][()]
    assert y.shape == ref.shape
    assert np.abs(y - ref).max() <= 1e-8 * np.abs(ref).max()
