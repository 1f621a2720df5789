"""How well a coarser EPMC backbone resolves the curves of a finer one (same scene).

Usage (not collected by pytest)::

    python benchmarks/epmc_resolution.py FINE.h5 COARSE.h5 [COARSE2.h5 ...]

The files hold ``/epmc`` of the same scene, e.g. from ``jointsim run
models/lap_joint.toml --set analysis.epmc.max_damping_change=0.001`` (fine) and the
scene as it is.  Per coarse file it prints its points, the analysis time, Newton and
GMRES iterations and preconditioner builds of the branch, then for the two backbone
plots (frequency [Hz] and damping ratio against ``log10`` of the modal amplitude) the
largest and 95th-percentile distance of the fine points from the coarse polyline, in
units of the fine curve's extent on each axis (0.01 is 1 % of the plot's height and
width: what the eye can tell apart), and the largest relative change of frequency and
damping at the exactly solved amplitudes (``/epmc/at_amplitudes``), which do not
depend on where the branch placed its points.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
from benchmarks.frc_resolution import polyline_distance  # noqa: E402


def _load(path: str) -> dict:
    with h5py.File(path, "r") as h5:
        g = h5["epmc"]
        out = dict(la=np.log10(g["amplitude"][()]), f=g["frequency_hz"][()],
                   zeta=g["damping_ratio"][()], time=float(g.attrs.get("time_s", np.nan)),
                   newton=int(g["iterations"][()].sum()),
                   gmres=int(g["krylov_iterations"][()].sum()),
                   builds=int(g["preconditioners"][()].sum()))
        if "at_amplitudes" in g:
            out["at_f"] = g["at_amplitudes/frequency_hz"][()]
            out["at_zeta"] = g["at_amplitudes/damping_ratio"][()]
    return out


def curve_distance(fine_x, fine_y, coarse_x, coarse_y) -> np.ndarray:
    """Distance of the fine points from the coarse polyline, both axes scaled by the
    fine curve's extent (plot units).

    Parameters
    ----------
    fine_x, fine_y : ndarray, shape (n,)
    coarse_x, coarse_y : ndarray, shape (m,)

    Returns
    -------
    ndarray, shape (n,)
    """
    sx = max(float(np.ptp(fine_x)), 1e-300)
    sy = max(float(np.ptp(fine_y)), 1e-300)
    return polyline_distance(np.column_stack([fine_x / sx, fine_y / sy]),
                             np.column_stack([coarse_x / sx, coarse_y / sy]))


def compare(fine: str, coarse: str) -> str:
    """The report line of ``coarse`` against ``fine`` (module docstring)."""
    F, C = _load(fine), _load(coarse)
    parts = [f"{coarse}: {C['la'].size} points (fine {F['la'].size}), {C['time']:.1f} s, "
             f"Newton {C['newton']}, GMRES {C['gmres']}, builds {C['builds']}"]
    for key, name in (("f", "frequency"), ("zeta", "damping")):
        d = curve_distance(F["la"], F[key], C["la"], C[key])
        parts.append(f"{name} curve max {d.max():.2e}, 95 % {np.quantile(d, 0.95):.2e}")
    if "at_f" in F and "at_f" in C and F["at_f"].shape == C["at_f"].shape:
        parts.append(f"exact amplitudes: frequency {np.abs(C['at_f'] / F['at_f'] - 1).max():.1e}, "
                     f"damping {np.abs(C['at_zeta'] / F['at_zeta'] - 1).max():.1e}")
    return "; ".join(parts)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("fine")
    ap.add_argument("coarse", nargs="+")
    args = ap.parse_args(argv)
    for c in args.coarse:
        print(compare(args.fine, c))


if __name__ == "__main__":
    main()
