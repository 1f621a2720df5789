"""Start-up of a run: wall time from process start to the first solve (issue 15).

Each sample is a fresh ``python`` process that runs ``jointsim run`` on a small
scene (default: the SDOF Jenkins EPMC, ``models/hbm/sdof_jenkins_epmc.toml``)
and stops when the continuation is constructed, i.e. after the imports, the
scene check, the model build and the first AFT evaluation (which loads the
numba kernels from their cache).  The numba cache is warmed by one run first.
It also reports the import of ``jointsim.cli`` alone and of the heavy
dependencies (numpy, scipy.linalg, numba, h5py), each in its own process, so
that the share jointsim can influence is visible.  Median of ``--repeat``.

Usage::

    PYTHONPATH=. python benchmarks/startup.py [--repeat 5] [--scene SCENE]

``python -X importtime -c "import jointsim.cli"`` gives the per-module tree.
Set ``PYTHONDONTWRITEBYTECODE`` as in normal use (the numbers with it set
include compiling jointsim's sources every time).
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

CHILD = r"""
import sys, time
t0 = float(sys.argv[1])
import jointsim.solvers.continuation as C
class _Stop(Exception):
    pass
def _stop(self, *a, **k):
    raise _Stop
C.Continuation.__init__ = _stop
from jointsim.cli import main
try:
    main(["run", sys.argv[2], "-o", sys.argv[3], "-q"])
except _Stop:
    print(f"{time.time() - t0:.4f}")
"""


def first_solve(scene: str, out: str) -> float:
    t0 = time.time()
    r = subprocess.run([sys.executable, "-c", CHILD, repr(t0), scene, out],
                       capture_output=True, text=True, check=True)
    return float(r.stdout.strip().splitlines()[-1])


def import_time(module: str) -> float:
    code = f"import time; t = time.perf_counter(); import {module}; " \
           f"print(time.perf_counter() - t)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       check=True)
    return float(r.stdout.strip())


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--scene", default="models/hbm/sdof_jenkins_epmc.toml")
    p.add_argument("--out", default="/tmp/jointsim_startup.h5")
    a = p.parse_args()
    first_solve(a.scene, a.out)  # warm the numba cache
    fs = statistics.median(first_solve(a.scene, a.out) for _ in range(a.repeat))
    print(f"process start -> first solve ({a.scene}): {fs:.3f} s (median of {a.repeat})")
    for m in ("numpy", "scipy.linalg", "numba", "h5py", "jointsim.cli"):
        t = statistics.median(import_time(m) for _ in range(a.repeat))
        print(f"  import {m:14s} {t:.3f} s")


if __name__ == "__main__":
    main()
