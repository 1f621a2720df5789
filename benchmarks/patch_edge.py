"""How much the contact-patch edge weighs in the stuck f1 of the lap joint (not collected by pytest).

Builds the lap joint at one resolution (uniform refinement: ``dx_full = 2
dx_lap``, ``ny_half = 0.02 / dx_lap``; washer bolts by default) and computes
the first elastic frequency of the stuck linearisation
``K + Tt^T diag(kt A) Tt + Tn^T diag(kn A) Tn`` over three contact sets: the
preload's closed set (this reproduces ``elastic_mode``), the same without its
two outermost nodes, and the same plus the two nearest open nodes; each
toggle also for the tangential stiffness alone and the normal one alone.
Then the closed set with the stiffnesses proportional to the preload
pressure, ``p0 / p_ref`` with the nominal ``p_ref = sum N0 / sum A``
(``joint.kt_pressure``, then with ``joint.kn_pressure`` too: the same
linearisation as the model built with those keys, whose preload ``x0`` and
``N0`` are those of this model).

    python benchmarks/patch_edge.py 0.005 [--washer 0.01] [--gauss 3] [--ramp 0.045 0.047]

docs/fe.md ("Washer bolts and the resolution study") quotes the output.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from jointsim.model import build_model
from jointsim.scene import load_scene
from jointsim.solvers.modes import elastic_mode

ROOT = Path(__file__).resolve().parents[1]


def _dense(a) -> np.ndarray:
    return a.toarray() if sp.issparse(a) else np.asarray(a)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("dx_lap", type=float)
    p.add_argument("--washer", type=float, default=0.01, help="0: point bolts")
    p.add_argument("--ramp", type=float, nargs="*", default=[],
                   help="also f1 with kt A and kn A times a fixed ramp, 1 inside and 0 "
                        "beyond |x| = RAMP [m], linear over the 6 mm before it (a "
                        "mesh-independent stiffness field: the quadrature's own error)")
    p.add_argument("--gauss", type=int, default=0,
                   help="contact at this many Gauss points per interface edge "
                        "(model.contact_points = 'gauss'); 0: node pairs")
    a = p.parse_args(argv)
    dx = a.dx_lap
    sets = ["model.mesh=''", f"model.dx_lap={dx:g}", f"model.dx_full={2 * dx:g}",
            f"model.ny_half={max(1, round(0.02 / dx))}"]
    if a.washer:
        sets.append(f"model.bolt_washer_radius={a.washer:g}")
    if a.gauss:
        sets += ["model.contact_points='gauss'", f"model.contact_gauss={a.gauss}"]
    m = build_model(load_scene(ROOT / "models" / "lap_joint_nodes.toml", sets))
    c = m.contacts
    x = c.position[:, 0]
    closed = c.N0 > 0
    kt = np.broadcast_to(np.asarray(c.law.kt, dtype=float).ravel(), x.shape)
    kn = np.asarray(c.kn, dtype=float)
    K0, M = _dense(m.K), _dense(m.M)
    Tt, Tn = _dense(c.Tt), _dense(c.Tn)

    def stiffness(sel_t, sel_n=None):
        st = np.asarray(sel_t, dtype=float)
        sn = st if sel_n is None else np.asarray(sel_n, dtype=float)
        return K0 + Tt.T @ (Tt * (kt * st)[:, None]) + Tn.T @ (Tn * (kn * sn)[:, None])

    err = np.abs(stiffness(closed) - _dense(m.linearisation.K)).max()
    f_ref = elastic_mode(m, 1).frequency_hz
    edge = np.isclose(np.abs(x), np.abs(x[closed]).max())
    nxt = np.isclose(np.abs(x), np.abs(x[~closed]).min())
    print(f"dx_lap = {dx * 1e3:g} mm, washer {a.washer:g} m: {closed.sum()} of {x.size} closed, "
          f"patch |x| <= {np.abs(x[closed]).max() * 1e3:.3f} mm, next node at "
          f"{np.abs(x[~closed]).min() * 1e3:.3f} mm; outermost N0 = "
          f"{c.N0[edge & closed].max():.4g} N (peak {c.N0.max():.4g} N); "
          f"|K_lin - rebuilt| = {err:.1e}")
    inner, outer = closed & ~edge, closed | nxt
    # pressure weights: p0 / p_ref with the nominal pressure p_ref = sum N0 / sum A
    p0 = c.N0 / c.area
    p_ref = c.N0.sum() / c.area.sum()
    w = p0 / p_ref
    print(f"  p_ref = {p_ref:.6g} Pa; outermost closed p0/p_ref = {w[edge & closed].max():.4f}")
    cases = (("closed set", closed, closed),
             ("outermost closed nodes opened", inner, inner),
             ("  only their tangential kt A", inner, closed),
             ("  only their normal kn A", closed, inner),
             ("next open nodes closed", outer, outer),
             ("  only their tangential kt A", outer, closed),
             ("  only their normal kn A", closed, outer),
             ("kt A p0/p_ref on the closed set (kt_pressure)", w, closed),
             ("kt A and kn A times p0/p_ref", w, w),
             *((f"kt A and kn A times a ramp ending at {1e3 * e:g} mm",
                np.clip((e - np.abs(x)) / 0.006, 0.0, 1.0),
                np.clip((e - np.abs(x)) / 0.006, 0.0, 1.0)) for e in a.ramp))
    for name, sel_t, sel_n in cases:
        w2 = sla.eigh(stiffness(sel_t, sel_n), M, eigvals_only=True)
        f = np.sqrt(np.abs(w2)) / (2 * np.pi)
        f1 = f[np.argmin(np.abs(f - f_ref))]
        print(f"  {name}: f1 = {f1:.3f} Hz ({100 * (f1 / f_ref - 1):+.2f} %)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
