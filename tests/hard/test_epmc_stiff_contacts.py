"""Issue 13, case 13: EPMC with stiff contacts.

With a contact stiffness far above the scene's (``--set joint.kt=3e16`` on the
coarse FE lap joint, 1e4 times the default), a slipping element sticks after
each reversal only for a slip of ``2 mu N / (kt A)``, shorter than one AFT
sample: its stick-slip switches fall inside a sample and Newton stalls on
them.  A branch that gives up then names that cause and what to change
(:func:`jointsim.analyses.epmc.stick_resolution`), and diverged iterates no
longer print raw numpy ``RuntimeWarning``s.  The fast cases use the SDOF
Jenkins oscillator (m = k = 1, slip force 0.2): at kt = 1e4 and a modal
amplitude of 0.1 the stick phase is about 0.8 of 128 samples (oracle:
``arccos(1 - 2 * 2 Fs / (kt a)) / (2 pi) * n_samples``).
"""
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

from jointsim.analyses.epmc import MIN_STICK_SAMPLES
from jointsim.run import run_scene
from jointsim.scene import load_scene

from .._scenes import FIXED, lap_scene

SDOF = Path(__file__).resolve().parents[2] / "models" / "hbm" / "sdof_jenkins_epmc.toml"
CAUSE = "raise analysis.epmc.n_samples or lower joint.kt"


def test_stick_phase_oracle_is_below_the_limit():
    fs, kt, a, nt = 0.2, 1e4, 0.1, 128
    n_stick = np.arccos(1.0 - 2.0 * 2.0 * fs / (kt * a)) / (2.0 * np.pi) * nt
    assert 2 * n_stick < MIN_STICK_SAMPLES


def test_stiff_contact_gives_up_naming_the_cause(tmp_path):
    scene = load_scene(SDOF, ["joint.kt=1e4", "analysis.epmc.max_points=3"])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(RuntimeError, match=CAUSE):
            run_scene(scene, tmp_path / "stiff.h5")
    with h5py.File(tmp_path / "stiff.h5", "r") as h5:
        assert CAUSE in h5["epmc"].attrs["message"]


def test_soft_contact_gives_up_without_that_cause(tmp_path):
    scene = load_scene(SDOF, ["analysis.epmc.max_points=3"])
    with pytest.raises(RuntimeError) as info:
        run_scene(scene, tmp_path / "soft.h5")
    assert CAUSE not in str(info.value)


@pytest.mark.slow
def test_stiff_fe_contacts_complete_or_name_the_cause(tmp_path):
    scene = lap_scene(FIXED, ("epmc",), ["joint.kt=3e16"])
    out = tmp_path / "stiff_fe.h5"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        try:
            run_scene(scene, out)
        except RuntimeError as exc:
            assert CAUSE in str(exc)
    with h5py.File(out, "r") as h5:
        for k in ("omega", "damping_ratio", "X"):
            assert np.all(np.isfinite(h5["epmc"][k][()]))
