"""Issue 13, case 6: a frictionless joint with fixed normal load is linear.

Its condensed harmonic-balance system has no contact unknowns; the EPMC branch
is then the linear mode at every amplitude (it used to fail at its first
point).  Oracle: the linear modal frequency and the mode's viscous damping
ratio phi^T C phi / (2 omega), and the FRC peak of the same linear system.
"""
import h5py
import numpy as np

from jointsim.model import build_model
from jointsim.run import run_scene
from jointsim.solvers.condensation import dense_array
from jointsim.solvers.modes import elastic_mode

from .._scenes import FIXED, lap_scene


def test_frictionless_fixed_normal_load_epmc_is_the_linear_mode(tmp_path):
    scene = lap_scene(FIXED, ("epmc",), ["effects.friction=false", "analysis.epmc.mode=4"])
    model = build_model(scene)
    em = elastic_mode(model, 4, scene.analysis.epmc.rigid_cutoff_hz)
    zeta = float(em.phi @ dense_array(model.C) @ em.phi) / (2 * em.omega)
    out = run_scene(scene, tmp_path / "nf.h5")
    with h5py.File(out, "r") as h5:
        g = h5["epmc"]
        assert g.attrs["branch_status"] == "complete"
        assert "linear" in g.attrs["message"]
        f, z, a = g["frequency_hz"][()], g["damping_ratio"][()], g["amplitude"][()]
        assert a.size >= 10 and np.all(np.diff(np.log10(a)) > 0)
        np.testing.assert_allclose(f, em.omega / (2 * np.pi), rtol=1e-9)   # two model builds
        np.testing.assert_allclose(z, zeta, rtol=1e-9)
        # the stored coefficients hold the mode itself at the modal amplitude
        X = g["X"][()]
        q1 = X[:, 1, :] @ (dense_array(model.M) @ em.phi)
        np.testing.assert_allclose(q1, a, rtol=1e-10)
