"""Issue 13, case 15: EPMC far outside its light-damping range says so.

A SDOF Jenkins oscillator (m = k = 1) with a stiff element (kt = 1e4, slip
force 0.2) slips over most of the period at a modal amplitude of 0.1: the
EPMC solution there has a damping ratio of about 2.8 and a frequency of
0.665 rad/s, numbers that do not describe a free decay.  Each point above
``MAX_DAMPING_RATIO`` is flagged in ``/epmc/outside_range``, counted in the
attribute ``n_outside_range``, and a warning is logged.  Oracle for the flag:
the stored damping ratio itself; in the stuck range (no viscous damping) the
damping ratio is exactly 0 and nothing is flagged.
"""
import logging
from pathlib import Path

import h5py
import numpy as np

from jointsim.analyses.epmc import MAX_DAMPING_RATIO
from jointsim.run import run_scene
from jointsim.scene import load_scene

SCENE = Path(__file__).resolve().parents[2] / "models" / "hbm" / "sdof_jenkins_epmc.toml"


def _run(tmp_path, name, lam0, lam1):
    scene = load_scene(SCENE, ["joint.kt=1e4", f"analysis.epmc.log10_amplitude_start={lam0}",
                               f"analysis.epmc.log10_amplitude_end={lam1}",
                               "analysis.epmc.max_damping_change=0"])
    out = run_scene(scene, tmp_path / name)
    with h5py.File(out, "r") as h5:
        g = h5["epmc"]
        return (dict(g.attrs), g["damping_ratio"][()], g["omega"][()],
                g["outside_range"][()])


def test_heavily_damped_points_are_flagged_and_warned(tmp_path, caplog):
    with caplog.at_level(logging.WARNING, logger="jointsim.analyses.epmc"):
        attrs, zeta, omega, flag = _run(tmp_path, "heavy.h5", -1.0, -0.95)
    assert attrs["branch_status"] == "complete"
    assert np.all(np.isfinite(zeta)) and np.all(np.isfinite(omega))
    # the case of the issue: about 0.665 rad/s and damping ratio 2.8 at a = 0.1
    assert abs(omega[0] - 0.665) < 0.01 and abs(zeta[0] - 2.8) < 0.05
    np.testing.assert_array_equal(flag, np.abs(zeta) > MAX_DAMPING_RATIO)
    assert flag.all()
    assert attrs["n_outside_range"] == flag.size
    assert attrs["max_damping_ratio_valid"] == MAX_DAMPING_RATIO
    assert any("light-damping range" in r.getMessage() for r in caplog.records)


def test_stuck_range_is_within_range(tmp_path, caplog):
    with caplog.at_level(logging.WARNING, logger="jointsim.analyses.epmc"):
        attrs, zeta, _omega, flag = _run(tmp_path, "stuck.h5", -6.0, -5.8)
    assert attrs["branch_status"] == "complete"
    np.testing.assert_allclose(zeta, 0.0, atol=1e-12)
    assert not flag.any() and attrs["n_outside_range"] == 0
    assert not any("light-damping range" in r.getMessage() for r in caplog.records)
