"""Issue 13, case 13 (last part): a failed analysis does not stop the next one.

No analysis needs another's result (the transient cross-check against
harmonic balance is skipped when the HBM analysis failed), so ``run_scene``
runs every declared analysis, then raises one ``RuntimeError`` naming the
failed ones and the file is marked failed.  Here the EPMC branch stops at
``max_points`` and the frequency sweep after it still runs to its end.
"""
import h5py
import pytest

from jointsim import _toml
from jointsim.run import run_scene
from jointsim.scene import apply_overrides, parse_scene

from .test_epmc_fold_scene import SCENE


def test_hbm_runs_after_a_failed_epmc(tmp_path):
    data = apply_overrides(_toml.loads(SCENE.read_text()), [
        "analysis.epmc.log10_amplitude_start=-2", "analysis.epmc.log10_amplitude_end=0",
        "analysis.epmc.max_points=3", "analysis.epmc.harmonics=[0,1,2,3]",
        "analysis.epmc.n_samples=64",
        "analysis.hbm.harmonics=[0,1,2,3]", "analysis.hbm.n_samples=64",
        "analysis.hbm.omega_start=0.5", "analysis.hbm.omega_end=0.8",
        "analysis.hbm.step_max=0.1"], str(SCENE))
    scene = parse_scene(data, str(SCENE), SCENE.parent)
    out = tmp_path / "r.h5"
    with pytest.raises(RuntimeError, match="epmc: stopped at max_points = 3"):
        run_scene(scene, out)
    with h5py.File(out, "r") as h5:
        assert h5.attrs["status"] == "failed"
        assert h5["epmc"].attrs["branch_status"] == "gave up"
        assert h5["epmc/omega"].shape[0] == 3
        g = h5["hbm"]
        assert g.attrs["branch0_status"] == "complete"
        assert g["omega"][-1] == pytest.approx(0.8)
