"""Helpers of the process-killing tests (issue 11): run the CLI as a real process.

Every run is a ``python -m jointsim.cli`` subprocess in its own session (so
that all its processes can be found, and killed, by process group), bounded
in time.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CHAIN = str(ROOT / "models" / "hbm" / "chain2_jenkins.toml")


def env() -> dict:
    e = dict(os.environ)
    e["PYTHONPATH"] = str(ROOT) + os.pathsep + e.get("PYTHONPATH", "")
    return e


def _default_sigint() -> None:
    # a shell's background job inherits SIGINT ignored, and Python keeps it ignored:
    # give the run the SIGINT of a terminal, however the tests were started
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(*args) -> subprocess.Popen:
    """Start ``jointsim ARGS`` in a new session (its own process group), SIGINT not ignored."""
    return subprocess.Popen([sys.executable, "-m", "jointsim.cli", *args, "-q"],
                            cwd=ROOT, env=env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_default_sigint)


def run(*args, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run ``jointsim ARGS`` to its end (at most ``timeout`` s)."""
    p = start(*args)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        raise
    return subprocess.CompletedProcess(p.args, p.returncode, out, err)


class Window:
    """When an uninterrupted run wrote: from its output file's appearance to its end.

    Kill times drawn as fractions of this window land while the run works on its
    file, however long the interpreter's start and the imports take on the machine
    (round 30: after round 28 made the small runs faster, start-up was over half of
    a run, and fractions of the whole wall time missed the work).
    """

    def __init__(self, file_s: float, end_s: float):
        self.file_s, self.end_s = file_s, end_s

    def at(self, fraction: float) -> float:
        """Seconds after the start at ``fraction`` (0..1) of the writing window."""
        return self.file_s + fraction * (self.end_s - self.file_s)


def run_timed(out, *args, timeout: float = 120) -> tuple[subprocess.CompletedProcess, Window]:
    """Run ``jointsim ARGS -o OUT`` to its end; also time when ``out`` appeared."""
    t0 = time.perf_counter()
    p = start(*args, "-o", str(out))
    file_s = None
    while p.poll() is None:
        if file_s is None and os.path.exists(out):
            file_s = time.perf_counter() - t0
        if time.perf_counter() - t0 > timeout:
            os.killpg(p.pid, signal.SIGKILL)
            p.communicate()
            raise subprocess.TimeoutExpired(p.args, timeout)
        time.sleep(0.005)
    end_s = time.perf_counter() - t0
    stdout, stderr = p.communicate()
    window = Window(end_s if file_s is None else file_s, end_s)
    return subprocess.CompletedProcess(p.args, p.returncode, stdout, stderr), window


def group_alive(pgid: int) -> list[int]:
    """Pids of the live (not zombie) processes of a process group (Linux /proc)."""
    pids = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if fields[0] != "Z" and int(fields[2]) == pgid:
            pids.append(int(d.name))
    return pids


def kill_after(p: subprocess.Popen, delay: float, sig: int) -> float:
    """Send ``sig`` to the main process after ``delay`` s; wait for it (and its group).

    Returns
    -------
    float
        Seconds the last process of the run's group outlived the main process.
    """
    time.sleep(delay)
    if p.poll() is None:
        os.kill(p.pid, sig)
    try:
        p.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        raise AssertionError(f"{p.args}: still running 60 s after signal {sig}")
    t0 = time.perf_counter()
    while group_alive(p.pid):
        if time.perf_counter() - t0 > 10:
            survivors = group_alive(p.pid)
            for pid in survivors:
                os.kill(pid, signal.SIGKILL)
            raise AssertionError(f"processes {survivors} of the run outlived it by 10 s")
        time.sleep(0.05)
    return time.perf_counter() - t0


def branches(path) -> dict[int, dict[str, np.ndarray]]:
    """Committed HBM points of a file, per branch (file order within a branch)."""
    from jointsim.io.hdf5 import open_result
    with open_result(path) as h5:
        if "hbm/branch" not in h5:
            return {}
        b = h5["hbm/branch"][()]
        out = {}
        for ib in np.unique(b):
            rows = b == ib
            out[int(ib)] = {k: h5[f"hbm/{k}"][()][rows] for k in ("omega", "X", "q")}
            if "hbm/loops/point" in h5:
                pts = h5["hbm/loops/point"][()]
                out[int(ib)]["n_loops"] = int(np.isin(pts, np.flatnonzero(rows)).sum())
        return out


def assert_same_points(path, ref, atol: float = 1e-8) -> None:
    """Every branch of ``path`` has the points of ``ref`` (to ``atol``, relative to scale)."""
    a, b = branches(path), branches(ref)
    assert sorted(a) == sorted(b), (sorted(a), sorted(b))
    for ib in b:
        for k in ("omega", "X", "q"):
            x, y = a[ib][k], b[ib][k]
            assert x.shape == y.shape, f"branch {ib} {k}: {x.shape} against {y.shape}"
            scale = max(float(np.abs(y).max()), 1.0)
            err = float(np.abs(x - y).max(initial=0.0)) / scale
            assert err <= atol, f"branch {ib} {k}: differs by {err:.3g}"
        if "n_loops" in b[ib]:
            assert a[ib]["n_loops"] == b[ib]["n_loops"]


def status(path) -> str:
    with h5py.File(path, "r") as h5:
        return str(h5.attrs["status"])


def writer_killed(writer) -> None:
    """Leave ``writer`` as its process's death would: the lock dropped (the kernel does
    that), the file closed as it is, and the writer forgotten by this process, so that
    a worker forked later does not close its old descriptor numbers
    (:func:`jointsim.io.hdf5.release_inherited`), which other files reuse by then."""
    from jointsim.io import hdf5

    os.close(writer._lock_fd)
    writer.h5.close()
    hdf5._OPEN_WRITERS.pop(id(writer), None)


def consistent(path) -> None:
    """Every extendable dataset of every group has the group's committed rows."""
    from jointsim.io.hdf5 import COMMITTED, open_result
    with open_result(path) as h5:
        def visit(name, obj):
            if isinstance(obj, h5py.Dataset) and obj.maxshape and obj.maxshape[0] is None:
                n = obj.parent.attrs.get(COMMITTED)
                if n is None:   # a group created by a point that was never committed
                    n = 0
                assert obj.shape[0] == n, (name, obj.shape, n)
        h5.visititems(visit)
        if "hbm/loops/point" in h5:
            assert h5["hbm/loops/point"][()].max(initial=-1) < h5["hbm/omega"].shape[0]


def committed_exactly(path) -> None:
    """Every extendable dataset, as readers see it, holds exactly its committed rows
    (groups whose datasets take different rows per commit, such as ``/transient``)."""
    from jointsim.io.hdf5 import COMMITTED, open_result
    with open_result(path) as h5:
        def visit(name, obj):
            if isinstance(obj, h5py.Dataset) and obj.maxshape and obj.maxshape[0] is None:
                assert obj.shape[0] == int(obj.attrs.get(COMMITTED, 0)), (name, obj.shape)
        h5.visititems(visit)


def assert_same_datasets(path, ref, names, atol: float = 1e-8) -> None:
    """The datasets ``names`` of ``path`` equal those of ``ref`` (to ``atol`` relative
    to their scale; NaN where the reference has NaN)."""
    from jointsim.io.hdf5 import open_result
    with open_result(path) as a, open_result(ref) as b:
        for name in names:
            assert (name in a) == (name in b), name
            if name not in b:
                continue
            x, y = a[name][()], b[name][()]
            assert x.shape == y.shape, f"{name}: {x.shape} against {y.shape}"
            if x.dtype.kind not in "fc":
                np.testing.assert_array_equal(x, y, err_msg=name)
                continue
            np.testing.assert_array_equal(np.isnan(x), np.isnan(y), err_msg=name)
            scale = max(float(np.nanmax(np.abs(y), initial=0.0)), 1.0)
            err = float(np.nanmax(np.abs(x - y), initial=0.0)) / scale
            assert err <= atol, f"{name}: differs by {err:.3g}"


def assert_killed_file(p: subprocess.Popen, out, sig: int, interrupted_text: str) -> str:
    """The state a killed run left in ``out``: ``complete`` (the signal came after the
    file was done), ``running`` after SIGKILL, else ``interrupted`` with a message
    containing ``interrupted_text``; ``info`` reads it.  Returns the status."""
    st = status(out)
    if p.returncode == 0 or st == "complete":
        assert st == "complete"
    elif sig == signal.SIGKILL:
        assert st == "running"
    else:
        assert st == "interrupted", st
        with h5py.File(out, "r") as h5:
            assert interrupted_text in h5.attrs["message"]
    info = run("info", str(out))
    assert info.returncode == 0, info.stderr
    return st
