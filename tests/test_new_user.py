"""What a new user trips over (issue 15): normal orientation of lumped contacts,
EPMC at given amplitudes, amplitude measures, key texts, the cheap loop default,
``jointsim info`` and ``check``, the FRC figure and the EPMC step control."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from jointsim import _toml
from jointsim.analyses.hbm import response_amplitude
from jointsim.cli import main
from jointsim.harmonics import HarmonicBasis
from jointsim.run import run_scene
from jointsim.scene import SceneError, key_table, load_scene, parse_scene
from tests._scenes import CHAIN2, MODELS
from tests.solvers.test_hbm import _describing_function

FOLD = MODELS / "hbm" / "chain2_friction_fold.toml"
SDOF = MODELS / "hbm" / "sdof_jenkins_epmc.toml"
QUICK = ["analysis.hbm.harmonics=[0, 1, 2, 3]", "analysis.hbm.n_samples=64",
         "analysis.hbm.omega_start=0.9", "analysis.hbm.omega_end=1.3",
         "analysis.hbm.refine_peak=false", "analysis.hbm.workers=1"]


# -- item 1: normal orientation -------------------------------------------------
def test_flipped_normal_sign_gives_the_rewritten_model(tmp_path):
    """DOF 1 positive into contact, given by n_sign = -1, answers like the model
    rewritten with that DOF sign-flipped (K -> S K S, its loads negated)."""
    ref = load_scene(FOLD, QUICK)
    data = _toml.loads(FOLD.read_text())
    S = np.diag([1.0, -1.0])
    m = data["model"]
    m["K"] = (S @ np.array(m["K"]) @ S).tolist()
    m["contacts"][0]["n_sign"] = -1
    ld = data["excitation"]["loads"][0]
    ld["force"]["harmonics"][0]["cos"] = -ld["force"]["harmonics"][0]["cos"]
    data["analysis"]["hbm"].update(harmonics=[0, 1, 2, 3], n_samples=64, omega_start=0.9,
                                   omega_end=1.3, refine_peak=False, workers=1)
    flip = parse_scene(data, str(FOLD), FOLD.parent)
    a, b = run_scene(ref, tmp_path / "a.h5"), run_scene(flip, tmp_path / "b.h5")
    with h5py.File(a) as ha, h5py.File(b) as hb:
        Xa, Xb = ha["hbm/X"][()], hb["hbm/X"][()]
        assert Xa.shape == Xb.shape and Xa.shape[0] > 10
        np.testing.assert_allclose(ha["hbm/omega"][()], hb["hbm/omega"][()], rtol=1e-9)
        np.testing.assert_allclose(Xb[:, :, 0], Xa[:, :, 0], atol=1e-9)
        np.testing.assert_allclose(Xb[:, :, 1], -Xa[:, :, 1], atol=1e-9)
        # the normal load did vary (coupled) and the contact separates at large amplitude
        assert ha["loops/N"][()].min() == 0.0 and hb["loops/N"][()].min() == 0.0
        np.testing.assert_allclose(hb["loops/N"][()], ha["loops/N"][()], atol=1e-9)


def test_n_sign_key_is_validated():
    with pytest.raises(SceneError, match=r"model.contacts\[0\].n_sign"):
        load_scene(FOLD, ["model.contacts.0.n_sign=2"])


# -- item 2 and 9: EPMC at given amplitudes, step control -------------------------
def test_epmc_at_amplitudes_match_the_describing_function(tmp_path):
    amps = [0.3, 0.8, 1.2, 3.0, 40.0]
    sc = load_scene(SDOF, ["analysis.epmc.harmonics=[0, 1]", "analysis.epmc.n_samples=4096",
                           f"analysis.epmc.amplitudes={amps}"])
    out = run_scene(sc, tmp_path / "e.h5")
    W, Z = _describing_function(np.array(amps))
    with h5py.File(out) as h:
        g = h["epmc/at_amplitudes"]
        assert g["converged"][()].all()
        np.testing.assert_array_equal(g["amplitude"][()], amps)
        assert np.abs(g["omega"][()] / W - 1).max() <= 1e-6
        np.testing.assert_allclose(g["damping_ratio"][()], Z, rtol=1e-5, atol=1e-9)
        # exactly at the amplitude: X_1c of the SDOF (m = 1) is the modal amplitude
        np.testing.assert_allclose(g["X"][:, 1, 0], amps, rtol=1e-9)
        assert g["frequency_hz"].attrs["unit"]
        # the Newton residuals the solves reached, within the scene's tolerance
        res = g["residual"][()]
        assert np.all(np.isfinite(res)) and res.max() <= sc.analysis.epmc.tol


def test_epmc_amplitudes_outside_the_branch_are_refused():
    with pytest.raises(SceneError, match=r"analysis.epmc.amplitudes\[1\]"):
        load_scene(SDOF, ["analysis.epmc.amplitudes=[1.0, 500.0]"])


def test_default_backbone_resolves_the_slip_onset(tmp_path):
    """Slip starts at a_s = Fs / kt = 0.8.  The default step control places points
    within 3 % on both sides of it and keeps the damping change per step small;
    without it the first point past the onset is 12 % beyond it (before the runner
    placed a point at the onset, the onset lay between 0.56 and 0.89)."""
    a_s = 0.2 / 0.25
    res = {}
    for name, extra in (("default", []), ("off", ["analysis.epmc.max_damping_change=0",
                                                  "analysis.epmc.max_frequency_change=0"])):
        out = run_scene(load_scene(SDOF, extra), tmp_path / f"{name}.h5")
        with h5py.File(out) as h:
            assert h["epmc"].attrs["success"]
            res[name] = (h["epmc/amplitude"][()], h["epmc/damping_ratio"][()])
    a, z = res["default"]
    edge = a_s * (1 + 1e-5)   # the runner's onset point: within 2e-6 of a_s (log10)
    below, above = a[a <= edge].max(), a[a > edge].min()
    assert above / below <= 1.03
    assert np.abs(np.diff(z)).max() <= 0.002 * 1.05
    # the backbone around the onset agrees with the describing function (harmonics
    # 0..7 differ from it by a little; the coarse branch interpolates far worse)
    a_o, z_o = res["off"]
    probe = np.linspace(0.85, 1.3, 10)
    _W, Zp = _describing_function(probe)
    err = np.abs(np.interp(probe, a, z) - Zp).max()
    err_off = np.abs(np.interp(probe, a_o, z_o) - Zp).max()
    assert err < 0.5 * err_off
    # the onset itself is a branch point with or without the step control (the runner
    # ends the continuation's first leg there, analyses.epmc.stuck_onset); beyond it
    # the uncontrolled steps are longer
    ao_below, ao_above = a_o[a_o <= edge].max(), a_o[a_o > edge].min()
    assert ao_below == pytest.approx(a_s, rel=1e-5) and below == pytest.approx(a_s, rel=1e-5)
    assert ao_above / ao_below > 1.1


# -- items 3 and 6: amplitude measures, the cheap loop default -------------------
def test_amplitude_measures_and_loops_default(tmp_path):
    base = QUICK + ["analysis.hbm.force_scale=[0.2]"]
    runs = {}
    for measure, loops in (("fundamental", "auto"), ("rms", "all"), ("peak_to_peak", "auto")):
        sc = load_scene(CHAIN2, base + [f"analysis.hbm.amplitude={measure}",
                                        f"analysis.hbm.loops={loops}",
                                        "analysis.hbm.refine_peak=true"])
        runs[measure] = run_scene(sc, tmp_path / f"{measure}.h5")
    basis = HarmonicBasis([0, 1, 2, 3], 64)
    theta = np.linspace(0, 2 * np.pi, 4097)[:-1]
    for measure, path in runs.items():
        with h5py.File(path) as h:
            g = h["hbm"]
            assert g.attrs["amplitude_measure"] == measure
            assert measure.split("_")[0] in g.attrs["amplitude_definition"].lower() or \
                measure == "peak_to_peak" and "max x(t) - min x(t)" in \
                g.attrs["amplitude_definition"]
            X, amp = g["X"][:, :, 0], g["amplitude"][()]
            # oracle: the time signal on a fine grid
            cs = [np.ones_like(theta)] + [f(h * theta) for h in (1, 2, 3)
                                          for f in (np.cos, np.sin)]
            x = X @ np.array(cs)  # (n_points, n_theta)
            if measure == "fundamental":
                ref = np.hypot(X[:, 1], X[:, 2])
            elif measure == "rms":
                ref = np.sqrt((x * x).mean(axis=1))
            else:
                ref = x.max(axis=1) - x.min(axis=1)
            tol = 2e-2 if measure == "peak_to_peak" else 1e-10  # 64 AFT samples vs 4096
            np.testing.assert_allclose(amp, ref, rtol=tol)
            assert response_amplitude(basis, X[0], measure) == pytest.approx(amp[0])
            # the refined peak is in the same measure and not below the points
            assert g["peak_amplitude"][0] >= amp.max() * (1 - 1e-12)
            n_points = g["omega"].shape[0]
            expect = n_points if measure == "rms" else 1  # 'all' / default: the peak
            assert h["loops/u"].shape[0] == expect


# -- items 4-6: key texts ---------------------------------------------------------
def test_excess_damping_growth_lands_a_point_just_past_the_slip_onset(tmp_path):
    """``analysis.epmc.max_excess_damping_growth``: from point to point the damping
    ratio's excess over the linear mode's (here 0: no viscous damping, so counted from
    ``EXCESS_DAMPING_MIN``) grows at most by the factor, so the first point past the slip
    onset a_s = 0.8 lies where the excess is still tiny; without it that point's
    excess is the describing function's a full step past the onset."""
    from jointsim.analyses.epmc import EXCESS_DAMPING_MIN
    growth = 50.0
    res = {}
    for name, extra in (("on", [f"analysis.epmc.max_excess_damping_growth={growth}"]),
                        ("off", [])):
        out = run_scene(load_scene(SDOF, extra), tmp_path / f"{name}.h5")
        with h5py.File(out) as h:
            assert h["epmc"].attrs["success"]
            res[name] = (h["epmc/amplitude"][()], h["epmc/damping_ratio"][()])
    a, z = res["on"]
    excess = np.maximum(z, 0.0) + EXCESS_DAMPING_MIN
    assert np.all(np.abs(np.diff(np.log(excess))) <= np.log(growth) * (1 + 1e-9))
    a_s = 0.2 / 0.25
    past = a > a_s * (1 + 1e-5)
    z_onset = max(z[~past][-1], 0.0)     # the onset point: stuck, no dissipation yet
    assert z_onset < EXCESS_DAMPING_MIN
    assert z[past][0] <= growth * (z_onset + EXCESS_DAMPING_MIN) * (1 + 1e-9)
    # the describing function at that amplitude: the same tiny damping (an oracle)
    _W, Z = _describing_function(a[past][:1])
    assert z[past][0] == pytest.approx(Z[0], rel=0.05, abs=1e-7)
    a_o, z_o = res["off"]
    assert z_o[a_o > a_s * (1 + 1e-5)][0] > 10 * z[past][0]
    with pytest.raises(ValueError, match="max_excess_damping_growth"):
        load_scene(SDOF, ["analysis.epmc.max_excess_damping_growth=0.5"])


def test_key_texts_name_the_traps():
    text = key_table()
    row = {ln.split("|")[1].strip(" `"): ln for ln in text.splitlines() if ln.startswith("| `")}
    assert "NOT scaled" in row["analysis.hbm.force_scale"]
    assert "plain spring" in row["joint.kt"] and "plain spring" in row["joint.kn"]
    assert "plain springs" in row["model.contacts[].area"]
    assert "n_sign" in row["model.contacts[].n_sign"] and "into contact" in \
        row["model.contacts[].n_sign"]
    assert "'auto'" in row["analysis.hbm.loops"] and "40%" in row["analysis.hbm.loops"]
    assert "at_amplitudes" in row["analysis.epmc.amplitudes"]
    assert "slip onset" in row["analysis.epmc.max_damping_change"]


# -- items 7, 8, 10: info, the FRC figure, check --------------------------------
@pytest.fixture(scope="module")
def plain_frc(tmp_path_factory):
    out = tmp_path_factory.mktemp("frc") / "frc.h5"
    assert main(["run", str(CHAIN2), "-o", str(out), "-q",
                 *sum((["--set", s] for s in QUICK + ["analysis.hbm.force_scale=[0.01, 0.2]"]),
                      [])]) == 0
    return out


def test_info_prints_only_sections_with_data(plain_frc, capsys):
    capsys.readouterr()
    assert main(["info", str(plain_frc)]) == 0
    text = capsys.readouterr().out
    assert "harmonic balance" in text and "branch 1 (force x 0.2)" in text
    assert "nan" not in text.lower()
    assert "precision" not in text and "Eq. 4 / Eq. 6" not in text


def test_frc_figure_axes(plain_frc, tmp_path, monkeypatch):
    from jointsim.io.hdf5 import unit
    from jointsim.post import common, hbm_plots
    plt = common.pyplot()
    monkeypatch.setattr(plt, "close", lambda fig=None: None)  # keep the figures to read
    before = set(plt.get_fignums())
    with h5py.File(plain_frc) as h:
        paths = hbm_plots.plot_frc(h, tmp_path)
        om = h["hbm/omega"][()]
        units = h.attrs["units"]
        (tmp_path / "rad").mkdir()
        paths_rad = hbm_plots.plot_frc(h, tmp_path / "rad", frequency="rad/s")
    assert [p.name for p in paths] == ["frc.png", "frc_receptance.png"]
    figs = [plt.figure(n) for n in plt.get_fignums() if n not in before]
    assert len(figs) == 4 and len(paths_rad) == 2
    ax_amp, ax_rec, ax_rad = figs[0].axes[0], figs[1].axes[0], figs[2].axes[0]
    # Hz by default: label unit and data
    assert ax_amp.get_xlabel() == f"f [{unit('frequency', units)}]"
    x = np.concatenate([ln.get_xdata() for ln in ax_amp.get_lines()])
    assert x.max() == pytest.approx(om.max() / (2 * np.pi), rel=1e-12)
    assert ax_amp.get_yscale() == "linear"
    # receptance on a log axis, |X| / F with F = 1 x force scale
    assert ax_rec.get_yscale() == "log" and "/ F" in ax_rec.get_ylabel()
    y0 = ax_rec.get_lines()[0].get_ydata()
    ya = ax_amp.get_lines()[0].get_ydata()
    np.testing.assert_allclose(y0, ya / 0.01)
    # rad/s on request
    assert ax_rad.get_xlabel() == f"omega [{unit('angular_frequency', units)}]"
    for f in figs:
        plt.close(f)


def test_check_prints_analyses_effects_and_sizes(capsys):
    assert main(["check", str(CHAIN2)]) == 0
    text = capsys.readouterr().out
    assert "valid (lumped model, kernels" in text
    assert "lumped, 2 DOFs, 1 contact element(s), 1 load(s)" in text
    assert "analyses, in run order:" in text and "hbm: 3 branch(es)" in text
    assert "loops kept: peaks" in text
    assert "effects.normal = 'fixed'" in text and "no separation" in text
    assert main(["check", str(SDOF), "--set", "effects.friction=false"]) == 0
    text = capsys.readouterr().out
    assert "epmc: mode 1" in text and "frictionless" in text and "no Masing checks" in text
