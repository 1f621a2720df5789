"""The lap-joint study (issue 6): QSMA against EPMC, and the Masing manifold on the FE joint.

The committed scenes are run on the coarse mesh, without their FRC, so that the
whole chain (preload, modes, QSMA, EPMC with loops at chosen amplitudes) runs in
seconds.
"""

import h5py
import numpy as np
import pytest

from jointsim import _toml
from jointsim.post import study
from jointsim.run import run_scene
from jointsim.scene import apply_overrides, parse_scene

from .._scenes import ROOT

AMPLITUDES = [3e-4, 1e-3, 3e-3]


def coarse_study(tmp_path, name):
    path = ROOT / "models" / f"{name}.toml"
    data = _toml.loads(path.read_text())
    del data["analysis"]["hbm"]  # the FRC is tested elsewhere
    data = apply_overrides(data, ["model.mesh='../meshes/lap_joint_coarse.msh'",
                                  "analysis.modes.full_model=false",
                                  "analysis.modes.monolithic=false",
                                  f"analysis.epmc.loop_amplitudes={AMPLITUDES}",
                                  "analysis.epmc.log10_amplitude_start=-6.5",
                                  "analysis.qsma.log10_amplitude_start=-6.5",
                                  "analysis.qsma.n_steps=160"], str(path))
    scene = parse_scene(data, str(path), path.parent)
    return run_scene(scene, tmp_path / f"{name}.h5")


@pytest.fixture(scope="module")
def fixed(tmp_path_factory):
    return coarse_study(tmp_path_factory.mktemp("study"), "lap_joint_fixed_n")


def test_low_amplitude_qsma_epmc_and_the_linear_mode_agree(fixed):
    with h5py.File(fixed, "r") as h5:
        assert h5.attrs["status"] == "complete"
        f_lin = h5["modes/frequency_hz"][()][h5["modes/elastic"][()]][0]
        assert h5["qsma"].attrs["linear_frequency_hz"] == pytest.approx(f_lin, rel=1e-8)
        a_e, f_e = h5["epmc/amplitude"][()], h5["epmc/frequency_hz"][()]
        a_q, f_q = h5["qsma/amplitude"][()], h5["qsma/frequency_hz"][()]
        assert a_e[0] < 1e-6 and a_q[0] < 1e-6
        assert f_e[0] == pytest.approx(f_lin, rel=1e-3)
        assert f_q[0] == pytest.approx(f_lin, rel=1e-3)
        assert f_e[0] == pytest.approx(f_q[0], rel=1e-3)


def test_microslip_qsma_within_3_percent_frequency_10_percent_damping(fixed):
    """Secant (QSMA) against first-harmonic (EPMC) through microslip; the damping
    includes the mode's viscous 0.087 % in both."""
    with h5py.File(fixed, "r") as h5:
        rows = study.backbone_comparison(h5, AMPLITUDES)
        f_lin = float(h5["qsma"].attrs["linear_frequency_hz"])
        zeta0 = float(h5["qsma"].attrs["zeta_linear"])
    for r in rows:
        assert np.isfinite(r.f_epmc) and np.isfinite(r.f_qsma)
        assert abs(r.df_rel) < 0.03, r
        assert abs(r.dzeta_rel) < 0.10, r
    # and it is microslip: softened and damped well beyond the linear joint
    assert rows[-1].f_epmc < 0.99 * f_lin
    assert rows[-1].zeta_epmc > 5 * zeta0


def test_fixed_normal_load_every_element_on_manifold_and_masing(fixed):
    """The control case: with N frozen, every loaded element is on its manifold and
    on its classical Masing curve, at every stored amplitude."""
    with h5py.File(fixed, "r") as h5:
        sets = study.loop_points(h5, "epmc")
    assert sets.u.shape[0] == len(AMPLITUDES)
    np.testing.assert_array_less(AMPLITUDES, sets.parameter * (1 + 1e-12))
    assert sets.loaded.sum() > 0
    assert np.all(sets.on_manifold) and np.all(sets.on_masing)
    assert sets.dev_manifold.max() < 1e-9 and sets.dev_masing.max() < 1e-9
    # the loops do slip: the element forces reach mu N somewhere
    slipped = np.isclose(np.abs(sets.f), 0.6 * sets.N, rtol=1e-9) & (sets.N > 0)
    assert slipped.any()


def test_coupled_normal_load_departs_from_the_manifold(tmp_path):
    """With N from the structure (and clapping lap ends) elements leave their
    manifold, more of them as the amplitude grows; the figures and the table
    come out of the file."""
    out = coarse_study(tmp_path, "lap_joint")
    with h5py.File(out, "r") as h5:
        sets = study.loop_points(h5, "epmc")
        man, mas, n = study.manifold_fractions(sets)
        conf = study.condition_confusion(sets)
        text = study.study_text(h5)
        control = study.control_sets(h5, "epmc")
        assert h5["epmc/control/cause"].attrs["unit"] == "1"
    assert man[-1] < 0.5 and man[-1] <= man[0]
    assert conf.total == int(n.sum())
    assert "EPMC against QSMA" in text and "precision" in text
    # the third column (issue 14): the replayed physical law reproduces the stored (AFT)
    # loops (where the contact does not re-close in the period: with joint.closing =
    # 'interpolated' the AFT takes the anchor at the closing instant interpolated from
    # the gap, which (u, N) samples do not carry); the manifold-law control is on its manifold up to its manifold's excess over
    # mu N and its non-closure, at round-off where both vanish
    m = sets.loaded
    recloses = m & (sets.N <= 0.0).any(axis=2)
    assert (m & ~recloses).any()
    assert control.replay_error[m & ~recloses].max() < 1e-9
    assert np.all((control.dev_manifold <= control.excess + control.periodicity + 1e-9)[m])
    clean = m & (control.excess < 1e-12) & (control.periodicity < 1e-12)
    assert clean.any() and control.dev_manifold[clean].max() < 1e-12
    counts = study.attribution(sets, control)
    assert sum(counts.values()) == conf.total
    assert counts["on manifold"] == int((sets.on_manifold & m).sum())
    assert counts["condition 5"] + counts["Eq. 4/Eq. 6"] + counts["manifold outside mu N"] \
        == conf.violated_off + conf.holds_off
    assert "Third column" in text
