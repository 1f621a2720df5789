"""Nothing lost (issue 11) for time marching: killed marches resume exactly.

A forced march commits, with each period's history rows and period change,
the march state at the start of that period (``/transient/checkpoint/state``);
``--resume`` continues from the last one.  The oracle is the uninterrupted
run of the same scene: the resumed file's history, period changes, harmonics,
loops and checkpoints equal it to 1e-8 (in practice bit for bit: the same
arithmetic from the same state).

The scene is ``models/transient/separation_steady.toml`` (2 DOFs, a Jenkins
slider and a unilateral normal contact that opens every period), marched for
at least 150 periods in the process tests (``min_periods``) so that the kill
times, fractions of the measured uninterrupted run, land inside the march.
The default suite interrupts in process; the ``slow`` cases kill real
processes with SIGKILL, SIGTERM and SIGINT at 10 seeded times each.
"""
from __future__ import annotations

import os
import random
import signal

import h5py
import pytest

from jointsim.scene import load_scene

from . import _safety as S

pytestmark = pytest.mark.skipif(not hasattr(os, "fork") or not os.path.isdir("/proc"),
                                reason="process tests need Linux")

TR = str(S.ROOT / "models" / "transient" / "separation_steady.toml")
LONG = ("--set", "analysis.transient.min_periods=150")
DECAY = str(S.ROOT / "models" / "transient" / "jenkins_free_decay.toml")
DECAY_LONG = ("--set", "analysis.transient.max_periods=300")

#: What a resumed steady march must reproduce.
STEADY = ("transient/t", "transient/x", "transient/period_change", "transient/harmonics",
          "transient/period_t", "transient/period_x", "transient/static_x",
          "transient/loops/u", "transient/loops/f", "transient/loops/N",
          "transient/masing/dev_manifold", "transient/masing/dev_masing",
          "transient/checkpoint/state")
#: What a resumed free decay must reproduce.
DECAY_SETS = ("transient/t", "transient/x", "transient/q", "transient/time",
              "transient/amplitude", "transient/frequency_hz", "transient/damping_ratio",
              "transient/phi", "transient/static_x")

_COUNTERS = ("steps", "substeps", "newton_iterations", "step_cuts", "factorizations",
             "iterations", "message")


def _same_counters(a, b):
    with h5py.File(a, "r") as x, h5py.File(b, "r") as y:
        for k in _COUNTERS:
            if k in y["transient"].attrs:
                assert x["transient"].attrs[k] == y["transient"].attrs[k], k


@pytest.mark.parametrize("keep,cut", [(0, 11), (4, 11), (0, 2)])
def test_an_interrupted_march_resumes_to_the_uninterrupted_file(tmp_path, monkeypatch, keep,
                                                                 cut):
    """In process: period ``cut``'s commit is cut by an interrupt; resume equals the
    uninterrupted run (rows, harmonics, loops, checkpoints and step counters).  With
    ``history_periods = 4`` only the last 4 periods' history is kept, written at the
    end: resume marches those 4 again to rebuild it."""
    from jointsim.analyses import transient as T
    from jointsim.run import run_scene
    scene = load_scene(TR, [f"analysis.transient.history_periods={keep}"])
    ref = run_scene(scene, tmp_path / "ref.h5")
    out = tmp_path / "cut.h5"
    calls = {"n": 0}
    append = T._Checkpoints.append

    def stop_at_cut(self, *args):
        calls["n"] += 1
        if calls["n"] == cut:
            raise KeyboardInterrupt("stopped by the test")
        return append(self, *args)

    monkeypatch.setattr(T._Checkpoints, "append", stop_at_cut)
    with pytest.raises(KeyboardInterrupt):
        run_scene(scene, out)
    monkeypatch.undo()
    assert S.status(out) == "interrupted"
    S.committed_exactly(out)
    with h5py.File(out, "r") as h5:
        assert h5["transient/period_change"].shape == (cut - 1,)
        assert h5["transient/checkpoint/state"].shape[0] == cut - 1
    # the resume is interrupted again, after the loops of the last period are written
    write_loops = T.write_loops

    def loops_then_stop(*args, **kw):
        write_loops(*args, **kw)
        raise KeyboardInterrupt("stopped by the test")

    monkeypatch.setattr(T, "write_loops", loops_then_stop)
    with pytest.raises(KeyboardInterrupt):
        run_scene(scene, out, resume=True)
    monkeypatch.undo()
    assert S.status(out) == "interrupted"
    run_scene(scene, out, resume=True)
    assert S.status(out) == "complete"
    S.committed_exactly(out)
    S.assert_same_datasets(out, ref, STEADY + ("loops/u", "masing/dev_manifold"), atol=1e-8)
    _same_counters(out, ref)
    # a complete march is not marched again by a second resume of the file
    before = h5py.File(out, "r")["transient/checkpoint/state"].shape
    run_scene(scene, out, resume=True)
    assert h5py.File(out, "r")["transient/checkpoint/state"].shape == before


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """``reference(scene, args)``: the uninterrupted run and its writing window
    (:class:`tests._safety.Window`)."""
    d = tmp_path_factory.mktemp("ref")
    refs = {}

    def get(scene, args):
        key = (scene, args)
        if key not in refs:
            out = d / f"ref{len(refs)}.h5"
            r, window = S.run_timed(out, "run", scene, *args)
            assert r.returncode == 0, r.stderr
            refs[key] = (out, window)
        return refs[key]
    return get


def _kill_and_resume(out, scene, args, names, ref, delay, sig):
    """Kill a run after ``delay`` s; check the file, ``info``, ``--resume`` and the result."""
    p = S.start("run", scene, "-o", str(out), *args)
    outlived = S.kill_after(p, delay, sig)
    assert outlived < 2.0, f"processes of the run outlived it by {outlived:.2f} s"
    if not out.exists():  # killed before the model was built: nothing written
        return None
    status = S.assert_killed_file(p, out, sig, "continue with --resume")
    S.committed_exactly(out)
    r = S.run("run", scene, "-o", str(out), "--resume", *args)
    assert r.returncode == 0, r.stderr
    assert S.status(out) == "complete"
    S.committed_exactly(out)
    S.assert_same_datasets(out, ref, names, atol=1e-8)
    _same_counters(out, ref)
    return status


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM, signal.SIGINT])
def test_a_killed_march_resumes_to_the_uninterrupted_one(tmp_path, reference, sig):
    ref, window = reference(TR, LONG)
    rng = random.Random(7000 + int(sig))
    seen = [_kill_and_resume(tmp_path / f"k{k}.h5", TR, LONG, STEADY, ref,
                             window.at(rng.uniform(0.0, 0.9)), sig) for k in range(10)]
    assert sum(s in ("running", "interrupted") for s in seen) >= 3, seen


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_a_killed_free_decay_is_marched_again_by_resume(tmp_path, reference, sig):
    ref, window = reference(DECAY, DECAY_LONG)
    rng = random.Random(8000 + int(sig))
    seen = [_kill_and_resume(tmp_path / f"d{k}.h5", DECAY, DECAY_LONG, DECAY_SETS, ref,
                             window.at(rng.uniform(0.0, 0.9)), sig) for k in range(5)]
    assert any(s in ("running", "interrupted") for s in seen), seen


def test_an_interrupt_inside_a_numba_call_is_still_an_interrupt():
    """A signal handled while a numba kernel is called surfaces as a chain of
    SystemError caused by the KeyboardInterrupt: it is found, other errors are not."""
    from jointsim.results import interrupt_cause
    from jointsim.solvers.transient import _interrupted

    try:
        try:
            raise KeyboardInterrupt("stopped by SIGTERM")
        except KeyboardInterrupt as e:
            raise SystemError("returned a result with an exception set") from e
    except SystemError as e2:
        inner = e2
    outer = SystemError("outer")
    outer.__cause__ = inner
    assert str(interrupt_cause(outer)) == "stopped by SIGTERM"
    assert _interrupted(outer, 7) == "interrupted in period 7 (stopped by SIGTERM)"
    try:
        try:
            raise KeyboardInterrupt("stopped by SIGINT")
        except KeyboardInterrupt:
            raise ImportError("initialization failed")
    except ImportError as e3:
        assert str(interrupt_cause(e3)) == "stopped by SIGINT"
    assert interrupt_cause(SystemError("a real bug")) is None
    assert interrupt_cause(ImportError("no module named x")) is None
    with pytest.raises(SystemError, match="a real bug"):
        _interrupted(SystemError("a real bug"), 7)
