"""Time the harmonic balance and EPMC of the FE lap joint (issue 4's 30 s target).

Runs the two default scenes, ``models/lap_joint_fixed_n_nodes.toml`` (normal load
frozen at the preload) and ``models/lap_joint_nodes.toml`` (coupled normal load with
separation), one after the other in this process, and prints per analysis the
wall time, the points and the Newton iterations, read back from the result
files.  Numba kernels are compiled (or loaded from the cache) by a warm-up run
of a tiny scene first, so the times exclude compilation.

    python benchmarks/fe_frc.py [--coarse] [--outdir DIR]

Timings on a shared machine are noisy: compare the two scenes within one run.
"""
from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from jointsim.run import run_scene
from jointsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENES = {"fixed N": ROOT / "models" / "lap_joint_fixed_n_nodes.toml",
          "coupled N": ROOT / "models" / "lap_joint_nodes.toml"}


def warm_up(outdir: Path) -> float:
    """Compile (or load) the numba kernels on the coarse mesh, 2 FRC points."""
    t0 = time.perf_counter()
    sc = load_scene(SCENES["coupled N"], [
        "model.mesh='../meshes/lap_joint_coarse.msh'", "analysis.hbm.force_scale=[0.02]",
        "analysis.hbm.max_points=3", "analysis.epmc.log10_amplitude_start=-6",
        "analysis.epmc.log10_amplitude_end=-5.9",
        "analysis.modes.full_model=false", "analysis.modes.monolithic=false"])
    try:
        run_scene(sc, outdir / "warmup.h5")
    except RuntimeError:
        pass  # stopping at max_points is a "failure"; the kernels are compiled
    return time.perf_counter() - t0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--coarse", action="store_true", help="use meshes/lap_joint_coarse.msh")
    p.add_argument("--outdir", default=None, help="keep the result files here")
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING)
    outdir = Path(args.outdir or tempfile.mkdtemp(prefix="fe_frc_"))
    outdir.mkdir(parents=True, exist_ok=True)
    print(f"warm-up (numba compile or cache load): {warm_up(outdir):.1f} s")
    over = ["model.mesh='../meshes/lap_joint_coarse.msh'"] if args.coarse else []
    rows = []
    for name, path in SCENES.items():
        out = outdir / f"{path.stem}.h5"
        t0 = time.perf_counter()
        try:
            run_scene(load_scene(path, over), out)
        except RuntimeError as exc:
            print(f"{name}: {exc}")
        wall = time.perf_counter() - t0
        with h5py.File(out, "r") as h:
            hb, ep = h["hbm"], h["epmc"]
            n_h = int(hb.attrs["n_points"])
            it_h = int(np.sum(hb["iterations"][()]))
            status = [str(hb.attrs[f"branch{b}_status"]) for b in range(hb["force_scale"].size)]
            rows.append((name, wall, float(h["modes"].attrs["time_s"]),
                         float(ep.attrs["time_s"]), int(ep.attrs["n_points"]),
                         float(hb.attrs["time_s"]), n_h, it_h, "/".join(status),
                         int(hb.attrs["n_contact_coordinates"]) * hb["coefficient_harmonic"].size))
    print(f"\n{'scene':10s} {'run [s]':>8s} {'modes':>6s} {'EPMC [s]':>9s} {'pts':>4s} "
          f"{'FRC [s]':>8s} {'pts':>4s} {'Newton':>7s} {'ms/pt':>6s} {'unknowns':>9s}  branches")
    for r in rows:
        print(f"{r[0]:10s} {r[1]:8.1f} {r[2]:6.2f} {r[3]:9.1f} {r[4]:4d} {r[5]:8.1f} {r[6]:4d} "
              f"{r[7]:7d} {1e3 * r[5] / max(r[6], 1):6.0f} {r[9]:9d}  {r[8]}")
    print(f"\nresult files in {outdir}")


if __name__ == "__main__":
    from jointsim.blas import limit_blas_threads
    limit_blas_threads()
    main()
