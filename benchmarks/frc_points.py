"""FRC points per branch of the default scenes (HBM only), for comparing two trees.

Usage (not collected by pytest)::

    python benchmarks/frc_points.py ROOT TAG [name-filter ...]

runs the ``[analysis.hbm]`` of ``models/hbm/*.toml`` and of the two lap-joint
scenes (coarse mesh) with the jointsim found in ``ROOT`` and prints, per scene,
the points of each branch, their status, the peaks and the CPU time.  Run it
on two trees (e.g. a ``git archive`` of the base commit and the work tree) to
see what a continuation change does to the default branches.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path


def main(argv):
    root, tag, sel = Path(argv[1]).resolve(), argv[2], argv[3:]
    sys.path.insert(0, str(root))
    import h5py
    import numpy as np

    from jointsim import _toml
    from jointsim.run import run_scene
    from jointsim.scene import apply_overrides, parse_scene
    from resolution_study import only_analyses
    coarse = "model.mesh='../meshes/lap_joint_coarse.msh'"

    def only_hbm(path, ovs):
        text = only_analyses(path.read_text(), ("hbm",))
        return parse_scene(apply_overrides(_toml.loads(text), ovs, str(path)),
                           str(path), path.parent)

    m = root / "models"
    cases = [(m / "hbm/chain2_jenkins.toml", []), (m / "hbm/chain2_friction_fold.toml", []),
             (m / "hbm/sdof_clearance_fold.toml", []), (m / "lap_joint_nodes.toml", [coarse]),
             (m / "lap_joint_fixed_n_nodes.toml", [coarse])]
    for p, ovs in cases:
        if sel and not any(s in p.name for s in sel):
            continue
        out = Path(f"/tmp/frc_points_{tag}_{p.stem}.h5")
        out.unlink(missing_ok=True)
        c0 = time.process_time()
        try:
            run_scene(only_hbm(p, ovs), out)
        except RuntimeError as e:
            print("failed:", e)
        with h5py.File(out) as h:
            b = h["hbm/branch"][()]
            n = [int((b == i).sum()) for i in range(len(h["hbm/force_scale"]))]
            st = [h["hbm"].attrs.get(f"branch{i}_status") for i in range(len(n))]
            pk = h["hbm/peak_amplitude"][()]
        print(f"{tag} {p.name}: points {n} status {st} peaks "
              f"{np.array2string(pk, precision=6)} cpu {time.process_time() - c0:.1f} s",
              flush=True)


if __name__ == "__main__":
    if len(sys.argv) < 3 or sys.argv[1] in ("-h", "--help"):
        print(__doc__)
        sys.exit(0 if sys.argv[1:2] in (["-h"], ["--help"]) else 2)
    main(sys.argv)
