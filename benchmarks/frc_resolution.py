"""How well a coarser FRC resolves the curve of a finer one (the same scene, two step caps).

Usage (not collected by pytest)::

    python benchmarks/frc_resolution.py FINE.h5 COARSE.h5 [--zoom HZ]

Both files hold ``/hbm`` of the same scene and branches, e.g. from
``jointsim run models/lap_joint.toml --set analysis.hbm.step_max=0.17`` and ``=0.3``.
Per branch it prints the points of each, the largest (and 95th-percentile) distance of
the fine points from the coarse polyline in a plot of the peak region (x: frequency in
units of ``--zoom`` Hz, default 3 Hz; y: amplitude in units of the branch's peak), and
both refined peaks.  A distance of 0.01 is 1 % of the plot's height: what the eye can
tell apart.  Refined peaks of slipping branches differ at the 1e-4 level between any
two runs that sample the branch differently: near the peak the amplitude is jagged on
the scale of the AFT samples (docs/hbm.md, "Round 12"), and the search finds one of its
local maxima.
"""
from __future__ import annotations

import argparse

import h5py
import numpy as np


def polyline_distance(points, line) -> np.ndarray:
    """Distance of each of ``points`` (n, 2) from the polyline through ``line`` (m, 2)."""
    a, b = line[:-1], line[1:]
    ab = b - a
    den = np.maximum((ab * ab).sum(1), 1e-300)
    out = np.empty(len(points))
    for i, p in enumerate(points):
        t = np.clip(((p - a) * ab).sum(1) / den, 0.0, 1.0)
        out[i] = np.sqrt((((a + t[:, None] * ab) - p) ** 2).sum(1)).min()
    return out


def compare(fine: str, coarse: str, zoom_hz: float = 3.0) -> list[str]:
    """The report lines (module docstring)."""
    lines = []
    with h5py.File(fine, "r") as hf, h5py.File(coarse, "r") as hc:
        f, c = hf["hbm"], hc["hbm"]
        for b in np.unique(f["branch"][()]):
            mf, mc = f["branch"][()] == b, c["branch"][()] == b
            if mc.sum() < 2:
                lines.append(f"branch {b}: {mf.sum()} / {mc.sum()} points (nothing to compare)")
                continue
            peak = f["amplitude"][()][mf].max()

            def plot(g, m):
                return np.column_stack([g["omega"][()][m] / (2 * np.pi) / zoom_hz,
                                        g["amplitude"][()][m] / peak])
            d = polyline_distance(plot(f, mf), plot(c, mc))

            def pk(g):
                return (f"{g['peak_amplitude'][b]:.6e} m at "
                        f"{g['peak_omega'][b] / (2 * np.pi):.4f} Hz")
            lines.append(
                f"branch {b}: {mf.sum()} / {mc.sum()} points; distance from the coarse "
                f"curve max {d.max():.2e}, 95 % {np.quantile(d, 0.95):.2e} (plot units: "
                f"{zoom_hz:g} Hz and the peak); refined peaks {pk(f)} / {pk(c)}")
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("fine")
    ap.add_argument("coarse")
    ap.add_argument("--zoom", type=float, default=3.0, help="plot width unit [Hz]")
    args = ap.parse_args(argv)
    for line in compare(args.fine, args.coarse, args.zoom):
        print(line)


if __name__ == "__main__":
    main()
