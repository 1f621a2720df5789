"""The curve comparisons behind the scenes' step caps (``benchmarks/frc_resolution.py``,
``benchmarks/epmc_resolution.py``): distances against analytic chords."""
import re

import h5py
import numpy as np
import pytest

from benchmarks.epmc_resolution import compare, curve_distance


def test_curve_distance_is_the_chord_sagitta_in_plot_units():
    """y = x^2 on [0, 1] (201 points) against the polyline through x = 0, 1/2, 1: the
    largest distance is at x = 1/4, the vertical gap 1/16 to the chord of slope 1/2,
    i.e. (1/16) / sqrt(1 + 1/4) in units of the curve's extent on both axes; points on
    the polyline are at distance 0.  Scaling an axis scales its plot unit with it."""
    x = np.linspace(0.0, 1.0, 201)
    xc = np.array([0.0, 0.5, 1.0])
    d = curve_distance(x, x ** 2, xc, xc ** 2)
    assert d.max() == pytest.approx(0.0625 / np.sqrt(1.25), rel=1e-12)
    assert np.argmax(d) == 50 and d[[0, 100, 200]].max() < 1e-15
    d2 = curve_distance(3.0 - 4.0 * x, 1e-3 * x ** 2, 3.0 - 4.0 * xc, 1e-3 * xc ** 2)
    assert d2.max() == pytest.approx(d.max(), rel=1e-12)


def _epmc_file(path, la, at_f, at_zeta):
    with h5py.File(path, "w") as h5:
        g = h5.create_group("epmc")
        g["amplitude"] = 10.0 ** la
        g["frequency_hz"] = 160.0 - la
        g["damping_ratio"] = 1e-3 * la ** 2
        for k in ("iterations", "krylov_iterations", "preconditioners"):
            g[k] = np.ones(la.size, dtype=int)
        g.attrs["time_s"] = 1.0
        g["at_amplitudes/frequency_hz"] = np.asarray(at_f)
        g["at_amplitudes/damping_ratio"] = np.asarray(at_zeta)


def test_epmc_resolution_report(tmp_path):
    """A backbone against itself is at distance 0 with equal exact values; a coarse
    one (3 of 201 points) reports the sagitta of its damping chords and the relative
    change of the exactly solved values."""
    la = np.linspace(-5.0, -3.0, 201)
    _epmc_file(tmp_path / "fine.h5", la, [160.0, 150.0], [1e-3, 2e-2])
    _epmc_file(tmp_path / "coarse.h5", la[::100], [160.0, 150.0 * (1 + 2e-6)],
               [1e-3 * (1 - 3e-5), 2e-2])
    same = compare(str(tmp_path / "fine.h5"), str(tmp_path / "fine.h5"))
    assert "frequency curve max 0.00e+00" in same and "damping curve max 0.00e+00" in same
    assert "exact amplitudes: frequency 0.0e+00, damping 0.0e+00" in same
    rep = compare(str(tmp_path / "fine.h5"), str(tmp_path / "coarse.h5"))
    # damping 1e-3 la^2 on la in [-5, -3]: plot units 2 (x) and 0.016 (y); a parabola
    # c la^2 lies c w^2 / 4 = 2.5e-4 below each chord of width w = 1 at its middle, i.e.
    # 0.015625 plot units, and the distance is that over sqrt(1 + s^2), s the chord's
    # slope in plot units (-1.125 on [-5, -4], -0.875 on [-4, -3]): the larger is
    # 0.015625 / sqrt(1 + 0.875^2)
    expect = 0.015625 / np.sqrt(1.0 + 0.875 ** 2)
    assert "3 points (fine 201)" in rep
    got = float(re.search(r"damping curve max (\S+),", rep).group(1))
    assert got == pytest.approx(expect, rel=5e-3)       # the report's 3 digits
    straight = float(re.search(r"frequency curve max (\S+),", rep).group(1))
    assert straight < 1e-12                            # a straight line: no sagitta
    assert "exact amplitudes: frequency 2.0e-06, damping 3.0e-05" in rep


def test_scale_keeps_the_fastest_of_repeated_runs(monkeypatch, capsys):
    """``benchmarks/scale.py --repeat 3``: each case's fastest run (analysis time) is the
    one printed and fitted (time per point 0.3 / 2 and 1.2 / 2 s: n^2 from 48 to 96)."""
    import benchmarks.scale as scale
    times = iter([0.9, 0.3, 0.6, 2.0, 1.2, 1.6])          # two sizes, three runs each

    def child(mesh, analysis, solver, points, tmp, numba_cache=None, sets=()):
        t = next(times)
        return dict(n_z=100, solver=solver, time=t, wall=t, setup=0.1, points=points,
                    newton=1, solves=2, krylov=1, builds=1, X=[[1.0]], lam=[1.0], rss_mb=1.0,
                    process=t)
    monkeypatch.setattr(scale, "_run_child", child)
    scale.main(["--interface", "gauss", "--elements", "48", "96", "--points", "2",
                "--repeat", "3", "--dense-limit", "0", "--analyses", "hbm"])
    out = capsys.readouterr().out
    rows = {int(r.split()[0]): r.split() for r in out.splitlines()
            if re.match(r"\s+(48|96)\s", r)}
    assert rows[48][3:5] == ["1", "2"]                  # Newton iterations, linear solves
    assert float(rows[48][7]) == 0.15 and float(rows[96][7]) == 0.6
    assert "from 48 to 96 elements: n^2.00" in out and "run 3 times" in out


def test_scale_case_leaves_out_the_other_analysis_overrides():
    """One ``--set`` list serves both analyses of ``benchmarks/scale.py``: an override of
    the analysis a case does not run (its section is removed from the case's scene) is
    left out, the others kept in their order before the case's own."""
    import benchmarks.scale as scale
    sets = ["model.ny_half=10", "analysis.epmc.error_indicators=false",
            "analysis.hbm.error_indicators=false"]
    hbm = scale._overrides("lap.msh", "hbm", "krylov", 25, sets)
    epmc = scale._overrides("lap.msh", "epmc", "direct", 4, sets)
    assert hbm[:3] == ["model.mesh='lap.msh'", "model.ny_half=10",
                       "analysis.hbm.error_indicators=false"]
    assert "analysis.hbm.max_points=25" in hbm and "analysis.hbm.force_scale=[2.0]" in hbm
    assert not any(s.startswith("analysis.epmc.") for s in hbm)
    assert epmc[:3] == ["model.mesh='lap.msh'", "model.ny_half=10",
                        "analysis.epmc.error_indicators=false"]
    assert "analysis.epmc.linear_solver='direct'" in epmc
    assert not any(s.startswith("analysis.hbm.") for s in epmc)


def test_scale_setup_timer_counts_a_nested_piece_once_for_the_inner_one():
    """``benchmarks/scale.py``'s set-up timer on a fake clock: an outer piece of 5 s that
    calls an inner one of 2 s, the inner one again alone (3 s) and a class's method (1 s).
    The parts are the pieces' own times (outer 3, inner 5, the method 1) and add up to the
    total (9); an attribute that does not exist is left alone."""
    import types

    import benchmarks.scale as scale
    now = [0.0]
    mod = types.ModuleType("pieces")

    def inner(dt):
        now[0] += dt
        return "inner"

    def outer():
        now[0] += 3.0
        return mod.inner(2.0)
    mod.inner, mod.outer = inner, outer

    class Owner:
        @staticmethod
        def method():
            now[0] += 1.0
    timer = scale.SetupTimer(clock=lambda: now[0])
    for owner, name in ((mod, "inner"), (mod, "outer"), (Owner, "method"),
                        (mod, "absent")):
        timer.wrap(owner, name)
    assert mod.outer() == "inner" and mod.inner(3.0) == "inner"
    Owner.method()
    assert timer.parts == {"inner": 5.0, "outer": 3.0, "Owner.method": 1.0}
    assert timer.total == 9.0 and not hasattr(mod, "absent")
