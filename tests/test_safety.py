"""Nothing lost (issue 11): real processes, really killed.

Every case runs ``python -m jointsim.cli`` as a subprocess (helpers in
:mod:`tests._safety`) on ``models/hbm/chain2_jenkins.toml`` (3 branches,
about 4 s) and kills it with ``os.kill``; the oracle is the uninterrupted run
of the same scene.  The default suite holds one case of each kind; the
``slow`` cases kill at 10 seeded random times each.
"""
from __future__ import annotations

import os
import random
import signal
import time

import h5py
import numpy as np
import pytest

from jointsim.io import hdf5
from jointsim.io.hdf5 import (COMMITTED, DamagedFileError, FileLockedError, NotAResultError,
                              ResultWriter, lock_path, open_result)
from jointsim.scene import load_scene

from . import _safety as S

pytestmark = pytest.mark.skipif(not hasattr(os, "fork") or not os.path.isdir("/proc"),
                                reason="process tests need Linux")


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """``reference(workers)``: the uninterrupted run (computed once per worker count);
    ``reference.seconds[workers]``: its wall time, process start included."""
    d = tmp_path_factory.mktemp("ref")
    refs = {}

    def get(w):
        if w not in refs:
            out = d / f"ref{w}.h5"
            t0 = time.perf_counter()
            r = S.run("run", S.CHAIN, "-o", str(out), "--set", f"analysis.hbm.workers={w}")
            get.seconds[w] = time.perf_counter() - t0
            assert r.returncode == 0, r.stderr
            refs[w] = out
        return refs[w]
    get.seconds = {}
    return get


def _kill_and_resume(out, ref, delay, sig, workers):
    """Kill a run after ``delay`` s with ``sig``; check the file, ``info``, ``--resume``."""
    p = S.start("run", S.CHAIN, "-o", str(out), "--set", f"analysis.hbm.workers={workers}")
    outlived = S.kill_after(p, delay, sig)
    assert outlived < 2.0, f"processes of the run outlived it by {outlived:.2f} s"
    if not out.exists():  # killed before the model was built: nothing written
        return None
    assert not lock_path(out).exists() or sig == signal.SIGKILL
    status = S.assert_killed_file(p, out, sig, "committed points")
    S.consistent(out)
    r = S.run("run", S.CHAIN, "-o", str(out), "--resume", "--set",
              f"analysis.hbm.workers={workers}")
    assert r.returncode == 0, r.stderr
    assert S.status(out) == "complete"
    S.consistent(out)
    S.assert_same_points(out, ref, atol=1e-8)
    return status


def test_two_writers_the_second_is_refused_and_changes_nothing(tmp_path):
    out = tmp_path / "same.h5"
    # small steps: the first run (about 50 points) outlasts the moment it is stopped
    first = S.start("run", S.CHAIN, "-o", str(out), "--set", "analysis.hbm.workers=1",
                    "--set", "analysis.hbm.force_scale=[0.2]",
                    "--set", "analysis.hbm.step=0.01", "--set", "analysis.hbm.step_max=0.01")
    t0 = time.perf_counter()
    while not (out.exists() and lock_path(out).exists()):
        assert first.poll() is None, first.communicate()
        assert time.perf_counter() - t0 < 60
        time.sleep(0.02)
    # frozen mid-run with its lock held (not by a long run: the second one's start-up
    # under load would decide the outcome), then resumed once the second was refused
    os.killpg(first.pid, signal.SIGSTOP)
    try:
        second = S.run("run", S.CHAIN, "-o", str(out), "--overwrite")
        assert first.poll() is None, "the first run ended before it was stopped"
    finally:
        os.killpg(first.pid, signal.SIGCONT)
    assert second.returncode != 0
    lines = second.stderr.strip().splitlines()
    assert len(lines) == 1 and "another jointsim process is writing" in lines[0], lines
    assert first.wait(timeout=300) == 0, first.communicate()
    assert S.status(out) == "complete"
    S.consistent(out)
    with h5py.File(out, "r") as h5:
        g = h5["hbm"]
        assert g.attrs["branch0_status"] == "complete"
        assert g.attrs[COMMITTED] == g["omega"].shape[0] > 40


def test_sigkill_with_two_workers_leaves_no_process_and_resumes_exactly(tmp_path, reference):
    ref = reference(2)
    _kill_and_resume(tmp_path / "k.h5", ref, 0.5 * reference.seconds[2], signal.SIGKILL, 2)


@pytest.mark.slow
@pytest.mark.parametrize("sig,workers", [(signal.SIGKILL, 1), (signal.SIGKILL, 2),
                                         (signal.SIGTERM, 1), (signal.SIGTERM, 2),
                                         (signal.SIGINT, 1), (signal.SIGINT, 2)])
def test_killed_at_ten_random_times_resumes_to_the_uninterrupted_points(
        tmp_path, reference, sig, workers):
    rng = random.Random(1000 * int(sig) + workers)
    seen = []
    ref = reference(workers)
    duration = reference.seconds[workers]   # kill times within the run, whatever the load
    for k in range(10):
        seen.append(_kill_and_resume(tmp_path / f"k{k}.h5", ref,
                                     rng.uniform(0.2, 0.9) * duration, sig, workers))
    assert sum(s in ("running", "interrupted") for s in seen) >= 3, seen


# -- in-process: the torn point, deterministically --------------------------------------

def _scene():
    return load_scene(S.CHAIN)


def test_a_torn_point_is_ignored_by_readers_and_removed_by_resume(tmp_path, monkeypatch):
    monkeypatch.setattr(hdf5, "COMMIT_INTERVAL_S", 0.0)   # every point committed at once
    out = tmp_path / "t.h5"
    scene = _scene()
    w = ResultWriter(out, scene)
    for i in range(3):
        with w.commit():
            w.append("hbm/omega", float(i), "1")
            w.append("hbm/X", np.full((2, 2), float(i)), "1")
    # a point torn by a crash: some of its datasets appended, no commit
    w._txn = set()
    w.append("hbm/omega", 9.0, "1")
    w.h5.flush()
    S.writer_killed(w)  # killed here
    with h5py.File(out, "r") as h5:
        assert h5["hbm/omega"].shape == (4,) and h5["hbm/X"].shape == (3, 2, 2)
    with open_result(out) as h5:
        assert h5["hbm/omega"].shape == (3,) and h5["hbm"].attrs[COMMITTED] == 3
    with ResultWriter(out, scene, resume=True) as w2:
        assert w2.rows("hbm/omega") == 3
        with w2.commit():
            w2.append("hbm/omega", 3.0, "1")
            w2.append("hbm/X", np.full((2, 2), 3.0), "1")
    with h5py.File(out, "r") as h5:
        np.testing.assert_array_equal(h5["hbm/omega"][()], [0, 1, 2, 3])
        assert h5.attrs["status"] == "complete" and h5["hbm"].attrs[COMMITTED] == 4


def test_an_interrupted_writer_trims_and_says_how_far_it_got(tmp_path):
    out = tmp_path / "i.h5"
    with pytest.raises(KeyboardInterrupt):
        with ResultWriter(out, _scene()) as w:
            with w.commit():
                w.append("hbm/omega", 1.0, "1")
            with w.commit():
                w.append("hbm/omega", 2.0, "1")
                raise KeyboardInterrupt("stopped by SIGTERM")
    with h5py.File(out, "r") as h5:
        assert h5.attrs["status"] == "interrupted"
        assert "SIGTERM" in h5.attrs["message"] and "hbm 1" in h5.attrs["message"]
        assert h5["hbm/omega"].shape == (1,)
    assert not lock_path(out).exists()


def test_a_second_writer_is_refused_before_the_file_is_touched(tmp_path):
    out = tmp_path / "l.h5"
    scene = _scene()
    with ResultWriter(out, scene) as w:
        with w.commit():
            w.append("hbm/omega", 1.0, "1")
        before = out.read_bytes()
        for kw in ({}, {"overwrite": True}, {"resume": True}):
            with pytest.raises(FileLockedError):
                ResultWriter(out, scene, **kw)
        assert out.read_bytes() == before
    with pytest.raises(FileExistsError, match="--overwrite"):
        ResultWriter(out, scene)
    with ResultWriter(out, scene, overwrite=True):
        pass
    with h5py.File(out, "r") as h5:
        assert "hbm" not in h5


def test_a_damaged_file_is_named_by_info_and_computed_again_by_resume(tmp_path, capsys):
    """A file torn inside the HDF5 library (here: cut short) is not trusted: readers
    say so in one line, ``--resume`` keeps it aside and starts the run afresh."""
    out = tmp_path / "d.h5"
    scene = _scene()
    with ResultWriter(out, scene) as w:
        for i in range(3):
            with w.commit():
                w.append("hbm/omega", float(i), "1")
    data = out.read_bytes()
    out.write_bytes(data[:len(data) // 2])
    with pytest.raises(DamagedFileError, match="damaged"):
        open_result(out)
    from jointsim.cli import main
    assert main(["info", str(out)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(out) in err[0] and "--resume" in err[0]
    from jointsim.io.hdf5 import acquire_lock, release_lock
    fd = acquire_lock(out)   # a file being written is not called damaged
    with pytest.raises(DamagedFileError, match="while it is being written"):
        open_result(out)
    release_lock(out, fd)
    with ResultWriter(out, scene, resume=True) as w:
        assert w.rows("hbm/omega") == 0
    assert (tmp_path / "d.h5.damaged").read_bytes() == data[:len(data) // 2]
    assert S.status(out) == "complete"
    # a file that is not HDF5 at all is refused, not set aside
    junk = tmp_path / "junk.h5"
    junk.write_text("not hdf5")
    with pytest.raises(OSError, match="cannot resume"):
        ResultWriter(junk, scene, resume=True)
    assert junk.read_text() == "not hdf5"


def test_an_overwrite_stopped_before_its_header_is_written_leaves_the_old_file(
        tmp_path, monkeypatch):
    """A new file is created under a side name and renamed into place: a run stopped
    while creating it leaves the file it was to replace whole."""
    import jointsim.io.hdf5 as H
    out = tmp_path / "o.h5"
    scene = _scene()
    with ResultWriter(out, scene) as w:
        with w.commit():
            w.append("hbm/omega", 1.0, "1")
    before = out.read_bytes()

    def stop(*args):
        raise KeyboardInterrupt("stopped by SIGTERM")

    monkeypatch.setattr(H.os, "replace", stop)
    with pytest.raises(KeyboardInterrupt):
        ResultWriter(out, scene, overwrite=True)
    monkeypatch.undo()
    assert out.read_bytes() == before and not lock_path(out).exists()
    with ResultWriter(out, scene, overwrite=True):
        pass
    assert S.status(out) == "complete" and not (tmp_path / "o.h5.new").exists()


def test_info_on_an_hdf5_file_jointsim_did_not_write(tmp_path):
    out = tmp_path / "foreign.h5"
    with h5py.File(out, "w") as h5:
        h5["x"] = np.arange(3)
    with pytest.raises(NotAResultError):
        open_result(out)
    from jointsim.cli import main
    assert main(["info", str(out)]) != 0


# -- sweeps -------------------------------------------------------------------------------

def test_sweep_with_zero_workers_fails_at_once_and_writes_nothing(tmp_path, capsys):
    from jointsim.cli import main
    t0 = time.perf_counter()
    code = main(["sweep", S.CHAIN, "--vary", "joint.mu=0.1,0.2", "-o", str(tmp_path / "sw"),
                 "--workers", "0"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "--workers 0" in err[0]
    assert time.perf_counter() - t0 < 5 and not (tmp_path / "sw").exists()


@pytest.mark.slow
def test_a_bad_scheduler_fails_in_seconds_with_one_line(tmp_path):
    import socket
    srv = socket.socket()  # accepts connections, never speaks dask
    srv.bind(("127.0.0.1", 0))
    srv.listen()
    t0 = time.perf_counter()
    r = S.run("sweep", S.CHAIN, "--vary", "joint.mu=0.1,0.2", "-o", str(tmp_path / "sw"),
              "--scheduler", f"tcp://127.0.0.1:{srv.getsockname()[1]}", timeout=60)
    srv.close()
    assert r.returncode != 0 and time.perf_counter() - t0 < 30
    assert [ln for ln in r.stderr.splitlines() if ln.startswith("error")] \
        and "no dask scheduler answered" in r.stderr


@pytest.mark.slow
def test_multi_branch_sweep_completes_and_a_rerun_keeps_finished_variants(tmp_path):
    pytest.importorskip("distributed")
    out = tmp_path / "sw"
    args = ("sweep", S.CHAIN, "--vary", "joint.mu=0.1,0.2", "-o", str(out))
    r = S.run(*args, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    with h5py.File(out / "sweep.h5", "r") as idx:
        assert [s.decode() for s in idx["status"][()]] == ["complete"] * 2
    mtimes = [p.stat().st_mtime_ns for p in sorted(out.glob("chain2_jenkins_*.h5"))]
    r = S.run(*args, timeout=300)
    assert r.returncode == 0
    assert [p.stat().st_mtime_ns for p in sorted(out.glob("chain2_jenkins_*.h5"))] == mtimes
    with h5py.File(out / "sweep.h5", "r") as idx:
        assert all(m.decode().startswith("kept") for m in idx["message"][()])
