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


def coarse_study(tmp_path, name, overrides=(), out=None):
    """Run the committed scene ``name`` on the coarse mesh without its FRC (more
    ``overrides`` last); the result file's path."""
    path = ROOT / "models" / f"{name}.toml"
    data = _toml.loads(path.read_text())
    del data["analysis"]["hbm"]  # the FRC is tested elsewhere
    data = apply_overrides(data, ["model.mesh='../meshes/lap_joint_coarse.msh'",
                                  "analysis.modes.full_model=false",
                                  "analysis.modes.monolithic=false",
                                  f"analysis.epmc.loop_amplitudes={AMPLITUDES}",
                                  "analysis.epmc.log10_amplitude_start=-6.5",
                                  "analysis.qsma.log10_amplitude_start=-6.5",
                                  "analysis.qsma.n_steps=160", *overrides], str(path))
    scene = parse_scene(data, str(path), path.parent)
    return run_scene(scene, tmp_path / (out or f"{name}.h5"))


@pytest.fixture(scope="module")
def fixed(tmp_path_factory):
    return coarse_study(tmp_path_factory.mktemp("study"), "lap_joint_fixed_n_nodes")


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
    # the EPMC's error indicators are not read here (their extended solves were 15 of
    # the run's 21 s; tests/solvers/test_indicators.py checks them on this joint)
    out = coarse_study(tmp_path, "lap_joint_nodes", ["analysis.epmc.error_indicators=false"])
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
    # loops; the manifold-law control is on its (clipped) manifold up to its non-closure,
    # at round-off where its loop closes
    m = sets.loaded
    assert control.replay_error[m].max() < 1e-9
    assert np.all((control.dev_manifold <= control.periodicity + 1e-9)[m])
    closed = m & (control.periodicity < 1e-12)
    assert closed.any() and control.dev_manifold[closed].max() < 1e-12
    att = study.attribution(sets, control)
    assert att.total == conf.total
    on = list(att.columns).index("on manifold")
    assert att.count[:, on].sum() == int((sets.on_manifold & m).sum())
    assert att.count.sum() - att.count[:, on].sum() == conf.violated_off + conf.holds_off
    # rows are the conditions: condition 5 only where they hold, Eq. 4/6 only where violated
    assert att.count[0, list(att.columns).index("condition 5")] == 0
    assert att.count[1, list(att.columns).index("Eq. 4/Eq. 6")] == 0
    assert np.all(att.separating <= att.count) and np.all(att.clipped <= att.count)
    assert att.separating.sum() == int((sets.separating & m).sum())
    assert np.all(np.isfinite(sets.manifold_excess))
    # the README's tables come out of the same numbers, at the loop amplitudes
    # themselves: the EPMC's loop sets solved exactly there, with their own control
    from jointsim.post import study_tables
    with h5py.File(out, "r") as h5:
        assert study.study_group(h5) == study.EXACT_LOOPS
        sets = study.loop_points(h5, study.EXACT_LOOPS)
        control = study.control_sets(h5, study.EXACT_LOOPS)
        rows = study_tables.results_rows(h5)
        ctrl = study_tables.control_table(h5)
    np.testing.assert_array_equal(sets.parameter, AMPLITUDES)
    m = sets.loaded
    assert control.cause.shape == m.shape and control.replay_error[m].max() < 1e-9
    assert np.all((control.dev_manifold <= control.periodicity + 1e-9)[m])
    assert [r.split("|")[2].strip() for r in rows] == [f"{a:.2e}" for a in AMPLITUDES]
    assert len(rows) == sets.u.shape[0] and rows[0].startswith("| coupled N |")
    total = next(r for r in ctrl if r.startswith("| total |"))
    n_on = int((sets.on_manifold & m).sum())
    assert total.split("|")[2].strip().split()[0] == (str(n_on) if n_on else "-")
    assert "Third column" in text
    from jointsim.post.study_plots import plot_masing_study
    with h5py.File(out, "r") as h5:
        figs = plot_masing_study(h5, tmp_path)
    assert [p.name for p in figs] == ["deviation_map.png", "manifold_fraction.png",
                                      "element_loops.png"]
    assert all(p.stat().st_size > 10_000 for p in figs)


@pytest.mark.slow
def test_study_tables_do_not_depend_on_the_backbone_steps(tmp_path):
    """The tables are read at the loop amplitudes, solved exactly there: a backbone with
    half the step caps gives the same rows, while the branch's own loop sets move."""
    from jointsim.post import study_tables
    runs = {}
    for name, steps in (("coarse", ()), ("fine", ("analysis.epmc.step_max=0.1",
                                                  "analysis.epmc.max_damping_change=0.001"))):
        out = coarse_study(tmp_path, "lap_joint_nodes", steps, out=f"{name}.h5")
        with h5py.File(out, "r") as h5:
            runs[name] = (study_tables.results_rows(h5), study.loop_points(h5, "epmc").parameter,
                          h5["epmc/at_amplitudes/frequency_hz"][()])
    (rows_c, branch_c, f_c), (rows_f, branch_f, f_f) = runs["coarse"], runs["fine"]
    assert rows_c == rows_f
    assert not np.array_equal(branch_c, branch_f)
    np.testing.assert_allclose(f_c, f_f, rtol=1e-7)


@pytest.fixture(scope="module")
def serial_figures(fixed, tmp_path_factory):
    """The figures of :func:`fixed` drawn in this process (``parallel=False``)."""
    from jointsim.post import make_figures
    return make_figures(fixed, tmp_path_factory.mktemp("serial"), parallel=False)


def test_figures_drawn_in_a_forked_process_equal_the_serial_ones(fixed, serial_figures,
                                                                 tmp_path, caplog):
    """``make_figures`` draws the Masing-study figures in a forked process beside the
    others (on a machine with two cores or more, as CI's): the same files, in the same
    order, byte for byte, as drawn in one process."""
    import logging
    import os

    from jointsim.post import HEAVY_PLOTTERS, make_figures
    serial = serial_figures
    with caplog.at_level(logging.DEBUG, logger="jointsim.post"):
        forked = make_figures(fixed, tmp_path / "forked", parallel=True)
    if (os.cpu_count() or 1) > 1:
        assert "in a forked process" in caplog.text
    names = [p.name for p in serial]
    assert names == [p.name for p in forked] and "deviation_map.png" in names
    assert "contacts" in HEAVY_PLOTTERS and len(names) > 3
    for a, b in zip(serial, forked):
        assert a.read_bytes() == b.read_bytes(), a.name


def _figures_in_a_daemon(path, outdir):
    """In a daemonic pool worker: ``make_figures`` with its log lines."""
    import logging

    from jointsim.post import make_figures
    lines = []
    handler = logging.Handler()
    handler.emit = lambda record: lines.append(record.getMessage())
    logger = logging.getLogger("jointsim")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    return [p.name for p in make_figures(path, outdir, parallel=True)], lines


def test_figures_in_a_daemonic_worker_are_drawn_serially(fixed, serial_figures, tmp_path):
    """A daemonic process (a dask or pool worker) may not fork: the figures are drawn in
    it, the same files as in a plain process, and the log says so."""
    import multiprocessing as mp

    serial = serial_figures
    with mp.get_context("fork").Pool(1) as pool:
        names, lines = pool.apply(_figures_in_a_daemon, (fixed, tmp_path / "daemon"))
    assert names == [p.name for p in serial]
    assert "in a daemonic worker process: figures run serially" in lines
    for p in serial:
        assert (tmp_path / "daemon" / p.name).read_bytes() == p.read_bytes(), p.name


def test_a_plotter_that_fails_in_the_forked_process_raises_here(fixed, tmp_path, monkeypatch):
    """An error of a heavy plotter drawn in the forked process reaches the caller, as in
    one process (the child is forked after the patch, so it runs the failing plotter)."""
    import jointsim.post as post
    from jointsim.post import make_figures

    def broken(h5, d):
        raise ValueError("broken plotter")
    # one light plotter beside the broken heavy one: the fork needs both kinds
    table = post.plotters()
    monkeypatch.setattr(post, "plotters", lambda: {"qsma": table["qsma"], "contacts": broken})
    for parallel in (False, True):
        with pytest.raises(ValueError, match="broken plotter"):
            make_figures(fixed, tmp_path / str(parallel), parallel=parallel)


def test_table_signs_of_values_that_round_to_zero_are_not_round_off():
    """A relative difference that rounds to zero prints ``+0.00`` whatever the sign of
    its round-off (the fixed-N joint's EPMC and QSMA agree to 1e-12 at 1e-4)."""
    from jointsim.post.study_tables import _signed
    assert [_signed(x, 2) for x in (-1e-12, 1e-12, -0.004, -0.006, 0.0)] == \
        ["+0.00", "+0.00", "+0.00", "-0.01", "+0.00"]
    assert _signed(-211.64, 1) == "-211.6" and _signed(527.66, 1) == "+527.7"
