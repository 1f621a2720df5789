"""Start-up of a run: wall time from process start to the first solve (issue 15).

Each sample is a fresh ``python`` process that runs ``jointsim run`` on a small
scene (default: the SDOF Jenkins EPMC, ``models/hbm/sdof_jenkins_epmc.toml``).
Two instants are reported: *ready*, when the continuation is about to start
(imports, scene check, model build, first AFT evaluation, which loads the numba
kernels from their cache), and *first solve*, when the first continuation point
has converged (so an import moved into the solve is still counted).  The numba
cache is warmed by one run first.

Two bytecode settings, both with a warm numba cache:

* ``pyc``: ``PYTHONDONTWRITEBYTECODE`` unset, ``__pycache__`` written by the
  warm-up run (the normal case);
* ``no-pyc``: ``PYTHONDONTWRITEBYTECODE=1`` and jointsim's ``__pycache__``
  removed, so jointsim's own sources are compiled in every run (installed
  packages keep their bytecode).

The *floor* is a process that only imports numpy, scipy.sparse, scipy.linalg,
numba, h5py and threadpoolctl and calls one cached ``@njit(cache=True)`` kernel
(numba's first cached load refreshes its typing registries: a fixed cost per
process): no program built on these libraries starts faster.  ``jointsim
share`` is first solve minus floor.  Each dependency's import alone is listed
too.  ``--against DIR`` measures another source tree (for example a ``git
worktree`` of an older commit) interleaved with this one, sample by sample, and
prints the ratios.  Medians of ``--repeat``.

Usage::

    PYTHONPATH=. python benchmarks/startup.py [--repeat 7] [--scene SCENE] [--against DIR]

``python -X importtime -c "import jointsim.cli"`` gives the per-module tree.
"""
from __future__ import annotations

import argparse
import os
import pathlib
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]

CHILD = r"""
import sys, time
t0 = float(sys.argv[1])
import jointsim.solvers.continuation as C
class _Stop(Exception):
    pass
_init = C.Continuation.__init__
ready = []
def _first(self, *a, **k):
    ready.append(time.time() - t0)
    _init(self, *a, **k)
    raise _Stop
C.Continuation.__init__ = _first
from jointsim.cli import main
try:
    main(["run", sys.argv[2], "-o", sys.argv[3], "-q", "--overwrite"])
except _Stop:
    print(f"{ready[0]:.4f} {time.time() - t0:.4f} {len(sys.modules)}")
"""

FLOOR_KERNEL = """
import numpy as np
from numba import njit

@njit(cache=True)
def kernel(x):
    s = 0.0
    for v in x:
        s += v * v
    return s
"""

FLOOR = r"""
import sys, time
t0 = float(sys.argv[1])
sys.path.insert(0, sys.argv[2])
import numpy as np, scipy.sparse, scipy.linalg, numba, h5py, threadpoolctl
import _startup_floor_kernel as k
k.kernel(np.ones(3))
print(f"{time.time() - t0:.4f}")
"""


def _env(tree: pathlib.Path, pyc: bool) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    if not pyc:
        env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def _drop_pycache(tree: pathlib.Path) -> None:
    for d in (tree / "jointsim").rglob("__pycache__"):
        shutil.rmtree(d, ignore_errors=True)


def first_solve(tree: pathlib.Path, scene: str, out: str, pyc: bool) -> tuple:
    """(ready, first solve, CPU time of the process) in seconds, modules loaded.

    One fresh process; wall times from its start.  CPU time (user + system,
    from ``getrusage``) is far less disturbed by other jobs on the machine.
    """
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.time()
    r = subprocess.run([sys.executable, "-c", CHILD, repr(t0), scene, out],
                       capture_output=True, text=True, env=_env(tree, pyc), cwd=tree)
    if r.returncode != 0 or not r.stdout.strip():
        raise RuntimeError(f"start-up child failed:\n{r.stderr[-2000:]}")
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    a, b, n = r.stdout.strip().splitlines()[-1].split()
    return float(a), float(b), cpu, int(n)


def floor(kdir: str) -> tuple[float, float]:
    """(wall, CPU) seconds of the floor process."""
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.time()
    r = subprocess.run([sys.executable, "-c", FLOOR, repr(t0), kdir],
                       capture_output=True, text=True, check=True)
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    return float(r.stdout.strip().splitlines()[-1]), cpu


def import_time(module: str, tree: pathlib.Path) -> float:
    code = f"import time; t = time.perf_counter(); import {module}; " \
           f"print(time.perf_counter() - t)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       check=True, env=_env(tree, True))
    return float(r.stdout.strip())


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repeat", type=int, default=7)
    p.add_argument("--scene", default="models/hbm/sdof_jenkins_epmc.toml")
    p.add_argument("--out", default=os.path.join(tempfile.gettempdir(), "jointsim_startup.h5"))
    p.add_argument("--against", type=pathlib.Path, default=None,
                   help="another source tree, measured interleaved with this one")
    a = p.parse_args()
    scene = str((ROOT / a.scene).resolve())
    trees = {"this": ROOT}
    if a.against is not None:
        trees["against"] = a.against.resolve()
    med = statistics.median

    with tempfile.TemporaryDirectory() as kdir:
        pathlib.Path(kdir, "_startup_floor_kernel.py").write_text(FLOOR_KERNEL)
        floor(kdir)  # compile and cache the floor kernel
        res = {}
        for pyc in (False, True):
            for tree in trees.values():
                if not pyc:
                    _drop_pycache(tree)
                first_solve(tree, scene, a.out, pyc)  # warm numba (and bytecode if pyc)
            samples = {k: [] for k in trees}
            fl = []
            for i in range(a.repeat):
                order = list(trees.items())
                for k, tree in (order if i % 2 == 0 else order[::-1]):  # no order bias
                    samples[k].append(first_solve(tree, scene, a.out, pyc))
                fl.append(floor(kdir))
            res[pyc] = (samples, med(x[0] for x in fl), med(x[1] for x in fl))

    print(f"start-up, {a.scene}, warm numba cache, median of {a.repeat} "
          f"(process start -> continuation ready / first point solved):")
    for pyc, (samples, fl, flc) in res.items():
        label = "pyc   " if pyc else "no-pyc"
        for k, s in samples.items():
            r, f = med(x[0] for x in s), med(x[1] for x in s)
            print(f"  {label} {k:8s} ready {r:.3f} s  first solve {f:.3f} s  "
                  f"(floor {fl:.3f} s, jointsim share {f - fl:.3f} s)  "
                  f"CPU {med(x[2] for x in s):.3f} s  modules {s[0][3]}")
        print(f"  {label} floor    {fl:.3f} s wall, CPU {flc:.3f} s")
        if "against" in samples:
            ratio = med(x[1] / y[1] for x, y in zip(samples["this"], samples["against"]))
            cpu = med(x[2] / y[2] for x, y in zip(samples["this"], samples["against"]))
            print(f"  {label} this/against first solve: wall {ratio:.2f}, CPU {cpu:.2f} "
                  f"(medians of per-sample ratios)")
    print("imports alone (pyc, median):")
    for m in ("numpy", "scipy.sparse", "scipy.linalg", "numba", "h5py", "jointsim.cli"):
        t = med(import_time(m, ROOT) for _ in range(a.repeat))
        print(f"  import {m:14s} {t:.3f} s")


if __name__ == "__main__":
    main()
