#!/usr/bin/env python
"""Make the committed lap-joint meshes (gmsh 2.2 .msh, read through meshio).

Usage::

    python meshes/make_meshes.py              # writes meshes/lap_joint_{coarse,default}.msh
    python meshes/make_meshes.py --dx-lap 0.005 --dx-full 0.01 --ny-half 3 -o my.msh

The geometry and the tags are described in :mod:`jointsim.fem.generate`.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from jointsim.fem.generate import RESOLUTIONS, lap_joint_mesh
from jointsim.fem.mesh import write_mesh

HERE = Path(__file__).resolve().parent


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--dx-lap", type=float, help="element length along the lap [m]")
    p.add_argument("--dx-full", type=float, help="element length along the full sections [m]")
    p.add_argument("--ny-half", type=int, help="elements through the half thickness")
    p.add_argument("-o", "--output", help="mesh file for a custom resolution")
    a = p.parse_args(argv)
    custom = (a.dx_lap, a.dx_full, a.ny_half)
    if any(v is not None for v in custom):
        if None in custom or not a.output:
            p.error("a custom mesh needs --dx-lap, --dx-full, --ny-half and -o")
        jobs = {a.output: custom}
    else:
        jobs = {HERE / f"lap_joint_{name}.msh": res for name, res in RESOLUTIONS.items()}
    for path, (dx_lap, dx_full, ny_half) in jobs.items():
        mesh = lap_joint_mesh(dx_lap, dx_full, ny_half)
        out = write_mesh(mesh, path)
        print(f"{out}: {len(mesh.points)} nodes, {len(mesh.cells[0].data)} quads "
              f"(dx_lap {dx_lap * 1e3:g} mm, dx_full {dx_full * 1e3:g} mm, "
              f"{ny_half} per half thickness)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
