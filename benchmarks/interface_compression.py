"""How compressible the interface operator is as a hierarchical (HODLR) matrix (issue 10).

A measurement, not a solver: for each interface resolution it condenses the lap
joint (``models/lap_joint.toml``, the lap refined to ``n`` Gauss points, the body
mesh fixed by ``--set``) onto its contact coordinates, forms ``S_h`` (the dynamic
stiffness of harmonic ``h``, :meth:`~jointsim.solvers.frequency_blocks.FrequencyBlocks.schur`)
and ``(S_h + diag(k))^-1`` (``k`` the stuck joint's stiffness on each coordinate, the
inverse the harmonic preconditioner applies), orders the coordinates by position
along the lap (slip and gap of one point together), bisects them down to leaves of
``--leaf`` coordinates and prints every level's largest off-diagonal numerical rank
at ``eps ||A||_2`` and the HODLR storage against the dense ``n_r^2`` (a product's
flops are in that ratio).  The growth of that storage with ``n`` is the growth a
hierarchical product would have (dense: ``n^2``).

    python benchmarks/interface_compression.py --elements 120 240 480 \\
        --set model.dx_full=0.004 --set model.ny_half=10

The 480-point model takes about 25 s to build and 3 GB.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np
import scipy.linalg as sla

sys.path.insert(0, str(Path(__file__).resolve().parent))
from resolution_study import only_analyses, resolution_sets  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
log = logging.getLogger("interface_compression")


def build_system(n: int, sets):
    """The HBM system (harmonics 0, 1, 7) of the lap joint with ``n`` Gauss points."""
    from jointsim import _toml
    from jointsim.model import build_model
    from jointsim.scene import apply_overrides, parse_scene
    from jointsim.solvers.hbm import HBMSystem
    path = ROOT / "models" / "lap_joint.toml"
    text = only_analyses(path.read_text(), ("modes",))      # the model and its modes only
    over = resolution_sets(0.24 / n, None) + list(sets)
    scene = parse_scene(apply_overrides(_toml.loads(text), over, str(path)),
                        str(path), path.parent)
    model = build_model(scene)
    return model, HBMSystem(model, [0, 1, 7], 32, linear_solver="krylov", parallel=False)


def ranks(A: np.ndarray, leaf: int, eps: float):
    """Largest off-diagonal rank per level (top first) and the HODLR storage / ``n^2``."""
    tol = eps * sla.norm(A, 2)
    per_level, store = {}, 0

    def split(lo, hi, level):
        nonlocal store
        if hi - lo <= leaf:
            store += (hi - lo) ** 2
            return
        mid = lo + (hi - lo) // 4 * 2               # keep a point's two coordinates
        for rows, cols in (((lo, mid), (mid, hi)), ((mid, hi), (lo, mid))):
            s = sla.svd(A[rows[0]:rows[1], cols[0]:cols[1]], compute_uv=False)
            k = int(np.count_nonzero(s > tol))
            per_level[level] = max(per_level.get(level, 0), k)
            store += k * (hi - lo)
        split(lo, mid, level + 1)
        split(mid, hi, level + 1)
    split(0, A.shape[0], 0)
    return [per_level[k] for k in sorted(per_level)], store / A.shape[0] ** 2


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, nargs="+", default=[120, 240, 480])
    ap.add_argument("--omega", type=float, default=1000.0, help="fundamental [rad/s]")
    ap.add_argument("--eps", type=float, nargs="+", default=[1e-8, 1e-12])
    ap.add_argument("--leaf", type=int, default=32, help="coordinates in a leaf")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    from jointsim.solvers.frequency_blocks import FrequencyBlocks
    harmonics = (7, 1, 0)          # the highest first: the quasi-static sums are made for it
    table = {}
    for n in args.elements:
        model, system = build_system(n, args.set)
        lin = system.lin
        ix = np.argsort(model.contacts.position[:, 0], kind="stable")   # along the lap
        order = np.ravel(np.column_stack([system.t_row[ix], system.n_row[ix]]))
        P = lin.Psi
        k = np.diag(P.T @ (lin._dK @ P))[order]          # stuck stiffness [N/m]
        blocks = FrequencyBlocks(lin, harmonics, args.omega)
        for i, h in enumerate(harmonics):
            S = blocks.schur(i)[np.ix_(order, order)]
            Ginv = np.linalg.inv(S + np.diag(k))
            for name, A in (("S_h", S), ("(S_h + diag k)^-1", Ginv)):
                for eps in args.eps:
                    table[n, h, name, eps] = ranks(A, args.leaf, eps)
        print(f"{n} Gauss points: n_r = {lin.n_r} contact coordinates, n_y = {lin.n_y}",
              flush=True)
    ns = args.elements
    print(f"\nomega = {args.omega:g} rad/s, leaves of {args.leaf} coordinates; per size: "
          "largest off-diagonal rank per level (top first) | HODLR storage / dense")
    for name in ("S_h", "(S_h + diag k)^-1"):
        for h in harmonics:
            for eps in args.eps:
                cells = [f"{table[n, h, name, eps][0]} | {table[n, h, name, eps][1]:.2f}"
                         for n in ns]
                stores = [table[n, h, name, eps][1] * (2 * n) ** 2 for n in ns]
                growth = "" if len(ns) < 2 else \
                    f"; storage ~ n^{np.log(stores[-1] / stores[0]) / np.log(ns[-1] / ns[0]):.2f}"
                print(f"{name:>18} h={h} eps={eps:.0e}: " + "; ".join(cells) + growth)


if __name__ == "__main__":
    main()
