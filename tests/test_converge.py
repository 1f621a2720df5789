"""``jointsim converge`` and ``jointsim run --preset`` (issue 12 items 2 and 3).

The oracle of ``converge`` is a converged reference run by the same code at
the most refined settings; the recommendation for ``--rtol`` must reproduce
it within ``rtol`` in every quantity, which the test recomputes from the two
result files by its own arithmetic.
"""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from jointsim.cli import main
from jointsim.converge import (ConvergeResult, Dial, Ladder, _harmonics, _pick, kind_errors,
                               parse_ladders, quantities, table_text, write_h5)
from jointsim.presets import PRESETS, preset_overrides
from jointsim.run import run_scene
from jointsim.scene import SceneError, load_scene

# one DOF with a Jenkins element to ground (the scene of models/hbm/sdof_jenkins_epmc.toml,
# with light viscous damping), an FRC branch in microslip and its nonlinear mode; no
# harmonics or samples given, so that presets apply
SCENE = """
[scene]
name = "converge test"
[model]
kind = "lumped"
units = "nondimensional"
M = [[1.0]]
K = [[1.0]]
C = [[0.02]]
contacts = [{ t_dof = 0, N0 = 1.0 }]
[joint]
law = "jenkins"
kt = 0.25
mu = 0.2
[effects]
normal = "fixed"
[excitation]
loads = [{ dof = 0, force = { harmonics = [{ h = 1, cos = 0.1 }] } }]
[analysis.hbm]
omega_start = 0.9
omega_end = 1.25
force_scale = [1.0]
response_dof = 0
step = 0.04
step_max = 0.08
[analysis.epmc]
mode = 1
loop_amplitudes = [0.5, 2.0]
log10_amplitude_start = -1.0
log10_amplitude_end = 1.0
step = 0.1
step_max = 0.3
"""


@pytest.fixture
def scene_file(tmp_path) -> Path:
    p = tmp_path / "sdof.toml"
    p.write_text(SCENE)
    return p


def _rel(q, r):
    return abs(q - r) if r == 0 else abs(q - r) / abs(r)


def test_harmonic_pattern_and_pick():
    assert _harmonics((0, 1, 2, 3), 5) == (0, 1, 2, 3, 4, 5)
    assert _harmonics((1, 3), 7) == (1, 3, 5, 7)
    assert _harmonics((0, 1, 3), 5) == (0, 1, 3, 5)
    # the least refined setting from which on every setting is within rtol
    assert _pick(np.array([1e-3, 2e-2, 1e-3, 0.0]), 1e-2) == 2
    assert _pick(np.array([1e-3, 1e-3, 0.0]), 1e-2) == 0
    assert _pick(np.array([np.inf, 1e-3, 0.0]), 1e-2) == 1
    # a failed setting is never picked and does not block a coarser one
    usable = np.array([True, True, False, True])
    assert _pick(np.array([5e-2, 1e-3, np.inf, 0.0]), 1e-2, usable) == 1
    assert _pick(np.array([1e-3, 1e-3, 2e-3, 0.0]), 1e-2, [False, True, True, True]) == 1
    assert _pick(np.array([np.inf, np.inf]), 1e-2, [False, False]) == -1


def test_failed_setting_is_reported_with_what_it_reached(tmp_path):
    """A run that failed (here: its EPMC stopped before its end) keeps the errors of the
    quantities it reached, inf for the others, and its message, in the table and the
    file; the dial still recommends a complete setting."""
    names = ["EPMC frequency at a = 0.001", "EPMC damping at a = 0.001",
             "EPMC damping at a = 0.003", "FRC peak amplitude, force x 2"]
    err = np.array([[1e-3, 4e-2, np.inf, 2e-3],     # H = 1 failed: a = 3e-3 not reached
                    [2e-4, 6e-3, 8e-3, 1e-3],       # H = 3
                    [0.0, 0.0, 0.0, 0.0]])          # H = 5, the reference
    lad = Ladder(Dial("harmonics", (1, 3, 5), 7), [tmp_path / f"h{k}.h5" for k in (1, 3, 5)],
                 ["failed", "complete", "complete"],
                 ["epmc: stopped at max_points = 200 before lam = -2.45", "", ""],
                 wall_time_s=np.array([60.0, 80.0, 120.0]), quantity_names=names,
                 quantity_units=["Hz", "1", "1", "m"], reference_values=np.ones(4),
                 error=err, reference=2)
    lad.recommended = _pick(lad.worst, 1e-2, np.array([s == "complete" for s in lad.status]))
    assert lad.recommended == 1
    ke = kind_errors(names, err[0])
    assert (ke["frequency"], ke["damping"], ke["amplitude"]) == (1e-3, np.inf, 2e-3)
    assert np.isnan(ke["share"])  # no share quantity
    r = ConvergeResult("s.toml", 1e-2, [lad], {"harmonics": 3}, ("x=1",), err[1], names,
                       80.0, 120.0, True, tmp_path)
    text = table_text(r)
    row = next(line for line in text.splitlines() if line.strip().startswith("1 "))
    assert "FAILED (1 of 4 quantities not reached)" in row and "max_points = 200" in row
    assert "4.00e-02" in row  # the largest error of what it reached
    assert "<- recommended" in next(line for line in text.splitlines()
                                    if line.strip().startswith("3 "))
    write_h5(r, tmp_path / "c.h5")
    with h5py.File(tmp_path / "c.h5", "r") as h5:
        g = h5["converge/harmonics"]
        assert g["status"][0].decode() == "failed"
        assert "max_points" in g["message"][0].decode()
        assert np.isinf(g["error"][0, 2]) and g["error"][0, 1] == 4e-2
        assert g.attrs["reference"] == 2 and g.attrs["recommended"] == 1


def test_bad_ladders_and_dials_name_the_option(scene_file, tmp_path):
    assert parse_ladders(["harmonics=1,3,7", "tol=1e-4,1e-8"]) == {
        "harmonics": (1, 3, 7), "tol": (1e-4, 1e-8)}
    with pytest.raises(SceneError, match="unknown dial"):
        parse_ladders(["mesh=1,2"])
    with pytest.raises(SceneError, match="at least two"):
        parse_ladders(["samples=64"])
    out = tmp_path / "cv"
    code = main(["converge", str(scene_file), "--dials", "steps", "-o", str(out), "-q"])
    assert code == 2 and not out.exists()


def test_dial_overrides_are_valid_scene_values(scene_file):
    scene = load_scene(scene_file)
    d = Dial("harmonics", (1, 3), 7)
    ov = d.overrides(3, scene)
    s = load_scene(scene_file, list(ov))
    assert s.analysis.hbm.harmonics == (0, 1, 2, 3) == s.analysis.epmc.harmonics


def test_converge_recommendation_reproduces_the_reference(scene_file, tmp_path):
    pytest.importorskip("distributed")
    out = tmp_path / "cv"
    code = main(["converge", str(scene_file), "--rtol", "1e-2", "--dials", "harmonics",
                 "samples", "--ladder", "harmonics=1,3,11", "--ladder", "samples=32,64,256",
                 "-o", str(out), "--workers", "2", "-q"])
    assert code == 0
    scene = load_scene(scene_file)
    with h5py.File(out / "converge.h5", "r") as h5:
        g = h5["converge/harmonics"]
        assert g["setting"][()].tolist() == [1, 3, 11]
        assert g["error"].attrs["unit"] == "1" and g["wall_time_s"].attrs["unit"] == "s"
        assert "doc" in g["max_error"].attrs
        assert g["max_error"][-1] == 0.0
        names = [s.decode() for s in g["quantity"][()]]
        rec = h5["converge/recommendation"]
        assert rec.attrs["check_ok"]
        overrides = [s.decode() if isinstance(s, bytes) else s for s in rec.attrs["overrides"]]
    # the scene's quantities: the FRC peak, EPMC at the loop amplitudes, the loop shares
    assert "FRC peak amplitude, force x 1" in names
    assert "EPMC damping at a = 2" in names
    assert any("on-manifold share" in n for n in names)
    for dial in ("harmonics", "samples"):
        assert (out / f"converge_{dial}.png").stat().st_size > 0
    # the recommendation, rerun here, against the reference: every dial at its finest
    ref = out / "combined_reference.h5"
    recf = tmp_path / "rec.h5"
    run_scene(load_scene(scene_file, overrides), recf)
    qr = {q.name: q for q in quantities(ref, scene)}
    qs = {q.name: q.value for q in quantities(recf, scene)}
    assert len(qr) >= 8
    for name, r in qr.items():
        err = abs(qs[name] - r.value) if r.absolute else _rel(qs[name], r.value)
        assert err <= 1e-2, (name, qs[name], r.value)
    # and it is cheaper than the reference: fewer harmonics or samples
    s_rec = load_scene(scene_file, overrides)
    assert (len(s_rec.analysis.hbm.harmonics) * s_rec.analysis.hbm.n_samples
            < 12 * 256)


def test_preset_fills_only_keys_that_are_not_explicit(scene_file, tmp_path):
    ov = preset_overrides(scene_file, "fast")
    assert "analysis.hbm.n_samples=64" in ov
    assert not any(o.startswith("analysis.transient") for o in ov)  # no such analysis
    ov = preset_overrides(scene_file, "fast", ["analysis.hbm.n_samples=96"])
    assert not any(o.startswith("analysis.hbm.n_samples") for o in ov)
    explicit = tmp_path / "explicit.toml"
    explicit.write_text(SCENE.replace("[analysis.epmc]\n", "[analysis.epmc]\nn_samples = 96\n"))
    ov = preset_overrides(explicit, "reference")
    assert "analysis.hbm.n_samples=512" in ov
    assert not any(o.startswith("analysis.epmc.n_samples") for o in ov)
    with pytest.raises(SceneError, match="--preset"):
        preset_overrides(scene_file, "quick")
    # through the command line: the resolved scene in the file has the preset's value
    out = tmp_path / "r.h5"
    assert main(["run", str(explicit), "--preset", "fast", "-o", str(out), "-q",
                 "--set", "analysis.hbm.harmonics=[0,1,2,3,4,5]"]) == 0
    with h5py.File(out, "r") as h5:
        assert h5["hbm/harmonics"][()].tolist() == [0, 1, 2, 3, 4, 5]
        assert h5["hbm"].attrs["n_samples"] == 64
        assert h5["epmc/X"].shape[1] == 2 * 3 + 1  # fast: harmonics 0..3


def test_presets_order_work_and_error(scene_file, tmp_path):
    """fast < balanced < reference in work (AFT evaluations x samples x harmonics,
    from the Newton iterations the files store), errors the other way, against an
    oracle more refined than every preset."""
    scene = load_scene(scene_file)
    oracle = tmp_path / "oracle.h5"
    h = list(range(24))
    fine = [f"analysis.{g}.{k}" for g in ("hbm", "epmc")
            for k in (f"harmonics={h}", "n_samples=1024", "tol=1e-11")]
    run_scene(load_scene(scene_file, fine), oracle)
    qo = quantities(oracle, scene)
    work, err = [], []
    for name in ("fast", "balanced", "reference"):
        f = tmp_path / f"{name}.h5"
        s = load_scene(scene_file, preset_overrides(scene_file, name))
        run_scene(s, f)
        with h5py.File(f, "r") as h5:
            w = 0.0
            for g in ("hbm", "epmc"):
                n_h = len(getattr(s.analysis, g).harmonics)
                w += (h5[f"{g}/iterations"][()].sum() + h5[f"{g}/iterations"].shape[0]) \
                    * n_h * getattr(s.analysis, g).n_samples
        q = {x.name: x.value for x in quantities(f, scene)}
        e = [(abs(q[r.name] - r.value) if r.absolute else _rel(q[r.name], r.value))
             for r in qo if not r.absolute]
        work.append(w)
        err.append(max(e))
    assert work[0] < work[1] < work[2], work
    assert err[0] > err[1] > err[2], err
    assert err[1] < 1e-2 and err[2] < 1e-3, err
    assert set(PRESETS) == {"fast", "balanced", "reference"}


def test_a_failed_run_of_the_same_scene_is_kept_not_rerun(scene_file, tmp_path):
    """Runs are deterministic: converge reports a failed file of the same scene from
    its attributes (message kept) and reruns a file of another scene."""
    from jointsim.converge import _failed_before
    from jointsim.sweep import Variant
    ov = ("analysis.epmc.max_points=3",)   # the EPMC stops short: the run fails
    f = tmp_path / "failed.h5"
    with pytest.raises(RuntimeError, match="max_points"):
        run_scene(load_scene(scene_file, list(ov)), f)
    r = _failed_before(str(scene_file), Variant(4, ov, f))
    assert r["status"] == "failed" and r["index"] == 4 and "max_points = 3" in r["message"]
    assert _failed_before(str(scene_file), Variant(4, ("analysis.epmc.max_points=4",), f)) \
        is None
    assert _failed_before(str(scene_file), Variant(4, ov, tmp_path / "none.h5")) is None
    # and its quantities are read: what the EPMC reached is finite, the rest NaN
    q = {x.name: x.value for x in quantities(f, load_scene(scene_file))}
    assert np.isfinite(q["FRC peak amplitude, force x 1"])
    assert np.isnan(q["EPMC damping at a = 2"])


def test_epmc_quantities_are_solved_at_the_loop_amplitudes(scene_file, tmp_path):
    """The EPMC values converge compares at the loop amplitudes are the mode solved
    exactly there (/epmc/at_amplitudes), so they do not move with the branch's points:
    two runs that place their points differently agree to the Newton tolerance, where
    interpolating between their points differs by far more."""
    runs = []
    for k, step_max in enumerate((0.3, 0.07)):
        f = tmp_path / f"r{k}.h5"
        run_scene(load_scene(scene_file, [f"analysis.epmc.step_max={step_max}",
                                          "analysis.epmc.tol=1e-11"]), f)
        runs.append(f)
    scene = load_scene(scene_file)
    exact, interp, loops = [], [], []
    for f in runs:
        with h5py.File(f, "r") as h5:
            g = h5["epmc"]
            assert g["at_amplitudes/amplitude"][()].tolist() == [0.5, 2.0]
            assert g["at_amplitudes/converged"][()].all()
            interp.append(np.interp(np.log([0.5, 2.0]), np.log(g["amplitude"][()]),
                                    g["damping_ratio"][()]))
            q = {x.name: x.value for x in quantities(f, scene)}
            got = [q["EPMC damping at a = 0.5"], q["EPMC damping at a = 2"]]
            np.testing.assert_array_equal(got, g["at_amplitudes/damping_ratio"][()])
            exact.append(np.array(got))
            # the loop sets too are kept at the loop amplitudes themselves: the slip's
            # first harmonic (m = 1: the modal amplitude) is the amplitude asked for,
            # where the branch's own sets are at the first point past it
            u = g["at_amplitudes/loops/u"][()][:, 0, :]             # (set, sample)
            c1 = 2.0 * np.abs(np.fft.rfft(u, axis=1)[:, 1]) / u.shape[1]
            np.testing.assert_allclose(c1, [0.5, 2.0], rtol=1e-8)
            branch = g["amplitude"][()][g["loops/point"][()]]
            assert np.abs(branch / [0.5, 2.0] - 1).max() > 1e-4
            assert "epmc loops at a = 0.5: on-manifold share" in q
            loops.append(g["at_amplitudes/loops/f"][()])
    assert np.abs(exact[0] - exact[1]).max() < 1e-8 * np.abs(exact[0]).max()
    assert np.abs(interp[0] - interp[1]).max() > 1e3 * np.abs(exact[0] - exact[1]).max()
    assert np.abs(loops[0] - loops[1]).max() < 1e-6 * np.abs(loops[0]).max()


def test_frc_loop_sets_are_named_by_their_force_scale(tmp_path):
    """FRC branches on worker processes store their peak loops in the order they finish
    (largest force first since issue 10): converge names an FRC set by its branch's force
    scale, so two files with the sets in another order compare the same sets."""
    from jointsim.quantities import _set_labels
    f = tmp_path / "sets.h5"
    with h5py.File(f, "w") as h5:
        h5["hbm/force_scale"] = [0.02, 2.0, 20.0]
        h5["hbm/branch"] = [0, 0, 1, 1, 2, 2, 2]        # branch of each point
    with h5py.File(f, "r") as h5:
        a = dict((k, name) for k, name in _set_labels(h5, "hbm", np.array([5, 3, 0])))
        b = dict((k, name) for k, name in _set_labels(h5, "hbm", np.array([0, 3, 6, 4])))
        e = _set_labels(h5, "epmc", np.array([4, 9]))
    assert a == {0: "hbm loops 0 at force x 20", 1: "hbm loops 0 at force x 2",
                 2: "hbm loops 0 at force x 0.02"}
    assert b == {0: "hbm loops 0 at force x 0.02", 1: "hbm loops 0 at force x 2",
                 2: "hbm loops 1 at force x 20", 3: "hbm loops 0 at force x 20"}
    assert e == [(0, "epmc set 0"), (1, "epmc set 1")]
