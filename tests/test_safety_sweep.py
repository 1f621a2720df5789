"""Nothing lost (issue 11) for sweeps: a killed sweep, rerun, gives the uninterrupted one.

``jointsim sweep models/hbm/chain2_jenkins.toml --vary joint.mu=0.1,0.2`` (two
variants of a three-branch scene on a local dask cluster of two workers) runs
as a subprocess in its own session and is killed with SIGKILL, SIGTERM or
SIGINT at seeded fractions of the measured uninterrupted sweep.  Checked: no
process of the sweep (scheduler, nannies, workers) outlives it by 2 s; the
index and every variant file open (``info`` reads them); a rerun into the
same folder keeps the variants that were complete (their files untouched),
completes the others, and every variant's points equal those of the
uninterrupted sweep to 1e-8.  All ``slow`` (a sweep takes tens of seconds).
"""
from __future__ import annotations

import os
import random
import signal
import time

import h5py
import pytest

from . import _safety as S

pytestmark = [pytest.mark.skipif(not hasattr(os, "fork") or not os.path.isdir("/proc"),
                                 reason="process tests need Linux"),
              pytest.mark.slow]

VARY = ("--vary", "joint.mu=0.1,0.2")


def _statuses(index) -> list[str]:
    with h5py.File(index, "r") as h5:
        return [s.decode() for s in h5["status"][()]]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The uninterrupted sweep's folder and its wall time [s]."""
    pytest.importorskip("distributed")
    out = tmp_path_factory.mktemp("ref") / "sw"
    t0 = time.perf_counter()
    r = S.run("sweep", S.CHAIN, *VARY, "-o", str(out), timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    assert _statuses(out / "sweep.h5") == ["complete"] * 2
    return out, time.perf_counter() - t0


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM, signal.SIGINT])
def test_a_killed_sweep_reruns_only_what_is_missing(tmp_path, reference, sig):
    ref, duration = reference
    rng = random.Random(9000 + int(sig))
    stopped = 0
    for k in range(4):   # 4 kills per signal: 12 kill points for the sweep
        out = tmp_path / f"sw{k}"
        p = S.start("sweep", S.CHAIN, *VARY, "-o", str(out))
        outlived = S.kill_after(p, rng.uniform(0.2, 0.9) * duration, sig)
        assert outlived < 2.0, f"processes of the sweep outlived it by {outlived:.2f} s"
        index = out / "sweep.h5"
        if not index.exists():  # killed before the cluster started: nothing to check
            continue
        before = _statuses(index)
        if p.returncode != 0:
            stopped += 1
            want = {"running"} if sig == signal.SIGKILL else {"interrupted"}
            assert set(before) <= want | {"complete"}, before
        kept = {}
        for f in sorted(out.glob("chain2_jenkins_*.h5")):
            info = S.run("info", str(f))
            assert info.returncode == 0, info.stderr
            if S.status(f) == "complete":
                kept[f.name] = f.stat().st_mtime_ns
        r = S.run("sweep", S.CHAIN, *VARY, "-o", str(out), timeout=900)
        assert r.returncode == 0, r.stderr[-2000:]
        assert _statuses(index) == ["complete"] * 2
        with h5py.File(index, "r") as h5:
            messages = [m.decode() for m in h5["message"][()]]
            outputs = [o.decode() for o in h5["output"][()]]
        for name, msg in zip(outputs, messages):
            if name in kept:  # finished before the kill: not run again
                assert msg.startswith("kept") and \
                    (out / name).stat().st_mtime_ns == kept[name], (name, msg)
            assert S.status(out / name) == "complete"
            S.assert_same_points(out / name, ref / name, atol=1e-8)
    assert stopped >= 3
