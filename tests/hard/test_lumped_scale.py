"""Issue 13, the lumped hard-case suite: 500 lumped elements and a free decay from a huge
amplitude.

* 500 Jenkins elements in parallel on one coordinate are rejected before anything is
  computed, with a message naming the cause (linearly dependent contact coordinates)
  and the remedy (merge them: that is an Iwan bank, ``test_iwan_sliders`` runs 500).
* A brush of 500 elements (a mass with 500 bristles, each a spring to the mass and a
  Jenkins element to ground, slip limits spread over a decade): at a force small
  enough that no bristle slips, the FRC is the linear FRF of the summed stiffness
  (oracle: the complex linear solve of the 501-DOF system), and no dataset holds NaN
  or Inf.
* Free decay of ``models/transient/jenkins_free_decay.toml`` from 1e3 and 1e6 times
  its amplitude: no NaN or Inf, the amplitude (energy at the turning points) decreases
  at every half swing, and the exact macroslip limit of Coulomb friction holds: each
  half swing loses ``2 mu N / k`` (``4 mu N / k`` per cycle) and the frequency is the
  slipping one, ``sqrt(k / m) = 1``.
"""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from jointsim.run import run_scene
from jointsim.scene import load_scene, parse_scene

from .._scenes import MODELS
from ._files import assert_all_finite

DECAY = MODELS / "transient" / "jenkins_free_decay.toml"


def _brush(n, F, omega, parallel=False):
    """Mass 1 on a spring 1 to ground with ``n`` bristles (mass 0.05 / n, spring 2 / n to
    the mass, Jenkins kt = 100, mu = 0.2 to ground; bristle i slips at a mass amplitude
    of 0.2 ... 3).  ``parallel``: the ``n`` elements act on the mass itself instead."""
    nd = 1 if parallel else n + 1
    kc, mb = 2.0 / n, 0.05 / n
    M = np.diag([1.0] + [mb] * (nd - 1))
    K = np.zeros((nd, nd))
    K[0, 0] = 1.0
    for i in range(1, nd):
        K[0, 0] += kc
        K[i, i] += kc
        K[0, i] = K[i, 0] = -kc
    N0 = kc * np.linspace(0.2, 3.0, n) / 0.2
    d = {"model": {"kind": "lumped", "units": "nondimensional", "M": M.tolist(),
                   "K": K.tolist(), "C": (0.01 * M).tolist(),
                   "contacts": [{"t_dof": 0 if parallel else i + 1, "t_ref": -1,
                                 "N0": float(N0[i])} for i in range(n)]},
         "joint": {"law": "jenkins", "kt": 100.0, "mu": 0.2},
         "effects": {"normal": "fixed"},
         "excitation": {"loads": [{"dof": 0, "force": {"harmonics": [{"h": 1, "cos": 1.0}]}}]},
         "analysis": {"hbm": {"harmonics": [1], "n_samples": 32, "omega_start": omega[0],
                              "omega_end": omega[1], "force_scale": [F], "response_dof": 0,
                              "step": 0.02, "step_max": 0.05}}}
    return parse_scene(d, "brush.toml"), M, K, 0.01 * M


def test_parallel_elements_on_one_coordinate_are_named(tmp_path):
    scene, *_ = _brush(500, 0.002, (1.72, 1.74), parallel=True)
    with pytest.raises(ValueError, match="linearly dependent.*merge such elements"):
        run_scene(scene, tmp_path / "x.h5")


@pytest.mark.slow
def test_brush_of_500_elements_stuck_is_the_linear_frf(tmp_path):
    n, F = 500, 0.002              # peak amplitude 0.115 < 0.2: no bristle slips
    scene, M, K, C = _brush(n, F, (1.73, 1.734))
    out = run_scene(scene, tmp_path / "x.h5")
    with h5py.File(out) as h:
        assert h["hbm"].attrs["branch0_status"] == "complete", h["hbm"].attrs["branch0_message"]
        w, a = h["hbm/omega"][()], h["hbm/amplitude"][()]
    Ks = K + np.diag([0.0] + [100.0] * n)       # every Jenkins element a spring kt
    f = np.zeros(n + 1)
    f[0] = F
    lin = np.array([abs(np.linalg.solve(Ks - x * x * M + 1j * x * C, f)[0]) for x in w])
    np.testing.assert_allclose(a, lin, rtol=1e-6)
    assert w.min() < 1.7319 < w.max()           # the stuck peak is inside the range
    assert_all_finite(out)


@pytest.mark.parametrize("scale, rtol", [(1e3, 1e-3), (1e6, 0.1)])
def test_free_decay_from_a_huge_amplitude(tmp_path, scale, rtol):
    """The half-swing amplitude estimate interpolates extrema: at 8e6 its resolution is
    about 1e-8 of the amplitude (0.02 of the 0.4 loss), hence the looser tolerance."""
    out = run_scene(load_scene(DECAY, [f"analysis.transient.amplitude={8.0 * scale}",
                                       "analysis.transient.max_periods=5"]),
                    tmp_path / "x.h5")
    assert_all_finite(out)
    with h5py.File(out) as h:
        g = h["transient"]
        assert g.attrs["success"], g.attrs["message"]
        a, f = g["amplitude"][()], g["frequency_hz"][()]
    assert len(a) >= 3
    loss = -np.diff(a)
    assert np.all(loss > 0)                                   # energy decreases monotonically
    mu_n, k = 0.2 * 1.0, 1.0
    np.testing.assert_allclose(loss, 2 * mu_n / k, rtol=rtol)  # Coulomb: 4 mu N / k per cycle
    np.testing.assert_allclose(2 * np.pi * f, 1.0, rtol=1e-3)  # slipping: sqrt(k / m)
