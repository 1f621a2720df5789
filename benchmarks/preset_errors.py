"""Error and wall time of result files against a reference file, in the quantities
``jointsim converge`` compares (not collected by pytest).

    python benchmarks/preset_errors.py SCENE REFERENCE FILE [FILE ...]

For each FILE (e.g. the runs of ``jointsim run SCENE --preset fast|balanced``):
its wall time (result attribute ``wall_time_s``), its status, and its largest
error against REFERENCE over all quantities of SCENE
(:func:`jointsim.quantities.quantities`: FRC peaks, EPMC and QSMA frequency and
damping at the loop amplitudes, loop-set shares), and per kind (frequency,
damping, amplitude, share), with the quantity that is worst.  A quantity the
file did not reach counts as ``not reached``.
"""
from __future__ import annotations

import argparse
import sys

import h5py
import numpy as np

from jointsim.quantities import errors, kind_errors, quantities
from jointsim.scene import load_scene


def _e(v: float) -> str:
    return "-" if np.isnan(v) else ("not reached" if np.isinf(v) else f"{v:.1e}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scene")
    p.add_argument("reference")
    p.add_argument("files", nargs="+")
    p.add_argument("--set", action="append", default=[], dest="overrides",
                   help="overrides the files were run with (they fix the quantity list)")
    a = p.parse_args(argv)
    scene = load_scene(a.scene, a.overrides)
    ref = quantities(a.reference, scene)
    names = [q.name for q in ref]
    with h5py.File(a.reference, "r") as h5:
        print(f"reference {a.reference}: wall {h5.attrs.get('wall_time_s', np.nan):.0f} s, "
              f"status {h5.attrs.get('status')}")
    print("| file | status | wall [s] | max error | frequency | damping | amplitude | "
          "share | worst quantity |\n|---|---|---|---|---|---|---|---|---|")
    for f in a.files:
        e = errors(quantities(f, scene), ref)
        k = kind_errors(names, e)
        e0 = np.where(np.isnan(e), -1.0, e)
        j = int(np.argmax(e0))
        with h5py.File(f, "r") as h5:
            wall = float(h5.attrs.get("wall_time_s", np.nan))
            st = h5.attrs.get("status")
        print(f"| {f} | {st} | {wall:.0f} | {_e(e0.max())} | {_e(k['frequency'])} | "
              f"{_e(k['damping'])} | {_e(k['amplitude'])} | {_e(k['share'])} | {names[j]} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
