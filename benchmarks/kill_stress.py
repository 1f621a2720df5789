"""Stress loop of crash consistency (issue 11, item 3): many SIGKILLs at random times.

Each trial starts ``jointsim run SCENE -o FILE`` (a fresh process in its own
session, as the kill tests do), sends SIGKILL after a random fraction of the
measured uninterrupted duration, and then checks that the file

* opens with plain ``h5py`` (``h5py.File(path, "r")`` and a walk over every
  object and attribute: a file torn inside the HDF5 library's flush fails here);
* is read by ``jointsim info`` (exit 0);
* when h5py cannot read it, ``--resume`` still completes the run (the damaged
  file is set aside and the run computed again; a copy is kept in the temp
  folder for study).

A trial whose process was killed before the file was created counts as
``no file``.  Prints one line per failure and the counts at the end.

Usage::

    PYTHONPATH=. python benchmarks/kill_stress.py [--trials 60] [--scene SCENE]
        [--set KEY=VALUE ...] [--seed 1] [--lo 0.05] [--hi 0.95]

Default: ``models/hbm/chain2_jenkins.toml`` with two HBM workers (the case that
tore a file once in about 60 trials).
"""
from __future__ import annotations

import argparse
import os
import random
import signal
import sys
import tempfile
import time
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests import _safety as S  # noqa: E402


def walk(path) -> int:
    """Open ``path`` with h5py and read every object's attributes; the object count."""
    n = 0
    with h5py.File(path, "r") as h5:
        dict(h5.attrs)

        def visit(name, obj):
            nonlocal n
            n += 1
            dict(obj.attrs)
            if isinstance(obj, h5py.Dataset) and obj.size:
                obj[(0,) * obj.ndim] if obj.ndim else obj[()]
        h5.visititems(visit)
    return n


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=60)
    ap.add_argument("--scene", default=str(ROOT / "models" / "hbm" / "chain2_jenkins.toml"))
    ap.add_argument("--set", action="append", default=None)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--lo", type=float, default=0.05)
    ap.add_argument("--hi", type=float, default=0.95)
    a = ap.parse_args(argv)
    sets = a.set if a.set is not None else ["analysis.hbm.workers=2"]
    extra = [x for s in sets for x in ("--set", s)]
    rng = random.Random(a.seed)
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        t0 = time.perf_counter()
        r = S.run("run", a.scene, "-o", str(d / "ref.h5"), *extra, timeout=600)
        duration = time.perf_counter() - t0
        assert r.returncode == 0, r.stderr
        print(f"uninterrupted: {duration:.2f} s; load {os.getloadavg()[0]:.2f}", flush=True)
        counts = {"ok": 0, "no file": 0, "h5py fails": 0, "recovered by --resume": 0,
                  "info fails": 0}
        for k in range(a.trials):
            out = d / f"k{k}.h5"
            p = S.start("run", a.scene, "-o", str(out), *extra)
            S.kill_after(p, rng.uniform(a.lo, a.hi) * duration, signal.SIGKILL)
            if not out.exists():
                counts["no file"] += 1
                continue
            try:
                walk(out)
            except Exception as exc:  # noqa: BLE001 - any failure to read is the finding
                counts["h5py fails"] += 1
                print(f"trial {k}: h5py: {type(exc).__name__}: {exc}", flush=True)
                keep = Path(tempfile.gettempdir()) / f"kill_stress_torn_{k}.h5"
                keep.write_bytes(out.read_bytes())
                r = S.run("run", a.scene, "-o", str(out), "--resume", *extra, timeout=600)
                ok = r.returncode == 0 and S.status(out) == "complete"
                counts["recovered by --resume"] += int(ok)
                print(f"trial {k}: --resume {'completes it' if ok else 'FAILS'} "
                      f"(copy in {keep})", flush=True)
                continue
            info = S.run("info", str(out))
            if info.returncode != 0:
                counts["info fails"] += 1
                print(f"trial {k}: info: {info.stderr.strip()[-300:]}", flush=True)
                continue
            counts["ok"] += 1
            out.unlink()
        print(f"{a.trials} trials: " + ", ".join(f"{k} {v}" for k, v in counts.items())
              + f"; load {os.getloadavg()[0]:.2f}", flush=True)
    lost = counts["h5py fails"] - counts["recovered by --resume"] + counts["info fails"]
    return 0 if lost == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
