"""Calibration of the default contact stiffness (not collected by pytest).

Prints the stuck joint's first elastic frequency of the default lap joint for
a grid of ``joint.kt`` and ``joint.kn`` (per unit area), the number of
contact elements the preload closes, and two references: the monolithic
body (same mesh, coincident nodes glued) and the fully bonded interface
(every pair bonded, stiff, bilateral).  docs/fe.md explains the choice.

    python benchmarks/fe_calibration.py
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from jointsim.model import build_model
from jointsim.scene import load_scene
from jointsim.solvers.modes import monolithic_modes, stuck_modes

SCENE = Path(__file__).resolve().parents[1] / "models" / "lap_joint_nodes.toml"


def f1(overrides):
    m = build_model(load_scene(SCENE, overrides))
    r = stuck_modes(m, 6, 20.0)
    return m, r.frequency_hz[r.elastic][0]


def main() -> int:
    logging.basicConfig(level=logging.WARNING)
    m, _ = f1([])
    mono = monolithic_modes(m, 6)[3]
    _, bonded = f1(["joint.kt=1e16", "joint.kn=1e16", "effects.normal=fixed",
                    "joint.law=stuck"])
    print(f"monolithic body f1 = {mono:.2f} Hz; fully bonded interface f1 = {bonded:.2f} Hz")
    kts = (3e11, 1e12, 3e12, 1e13, 1e16)
    print(f"{'kn|kt':>8} " + " ".join(f"{kt:>14.0e}" for kt in kts) + "   in contact")
    for kn in (1e13, 1e14, 1e16):
        row = []
        for kt in kts:
            m, f = f1([f"joint.kt={kt}", f"joint.kn={kn}"])
            row.append(f"{f:7.2f} ({(f / mono - 1) * 100:+5.1f}%)")
        n = int(np.sum(m.contacts.N0 > 0))
        print(f"{kn:>8.0e} " + " ".join(f"{s:>14}" for s in row) + f"   {n}/{m.contacts.n_elements}")
    return 0


if __name__ == "__main__":
    from jointsim.blas import limit_blas_threads
    limit_blas_threads()
    raise SystemExit(main())
