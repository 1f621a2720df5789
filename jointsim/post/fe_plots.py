"""Figures and tables of the FE joint: preload pressure, mode shapes, ParaView files."""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .common import pyplot

log = logging.getLogger(__name__)


def pressure_plot(h5, outdir) -> list[Path]:
    """Interface pressure of the preload state along the interface (FE and ROM models)."""
    if "static/pressure" not in h5 or "contacts/position" not in h5 or \
            h5.attrs.get("model_kind") not in ("fe", "rom"):
        return []
    plt = pyplot()
    pos = h5["contacts/position"][()]
    p = h5["static/pressure"][()]
    N = h5["static/N"][()]
    x = pos[:, 0]
    si = h5.attrs.get("units", "SI") == "SI"
    scale, xl = (1e3, "x [mm]") if si else (1.0, "element position")
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.plot(x * scale, p / (1e6 if si else 1.0), "o-", ms=4)
    ax.set_xlabel(xl)
    ax.set_ylabel("pressure N0/A [MPa]" if si else "pressure N0/A")
    ax.set_title(f"preload: sum N0 = {N.sum():.6g} N, {int(np.sum(N > 0))}/{N.size} elements "
                 "in contact" if si else "preload pressure", fontsize=9)
    ax.axhline(0, color="0.6", lw=0.8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    out = Path(outdir) / "interface_pressure.png"
    fig.savefig(out, dpi=130)
    plt.close(fig)
    return [out]


def mode_shape_plot(h5, outdir, n_elastic: int = 4) -> list[Path]:
    """Deformed mesh of the first elastic modes (FE results with a mesh)."""
    if "mesh" not in h5 or any(k not in h5 for k in ("modes/shapes_full", "modes/frequency_hz",
                                                      "modes/elastic")):
        return []
    plt = pyplot()
    from matplotlib.collections import PolyCollection
    pts = h5["mesh/points"][()]
    quad9 = h5["mesh/quad9"][()]
    node_dofs = h5["mesh/node_dofs"][()]
    body = h5["mesh/body"][()]
    f = h5["modes/frequency_hz"][()]
    elastic = h5["modes/elastic"][()]
    shapes = h5["modes/shapes_full"][()]
    idx = np.nonzero(elastic)[0][:n_elastic]
    if idx.size == 0:
        return []
    # outline of each quad through its corner and midside nodes
    ring = quad9[:, [0, 4, 1, 5, 2, 6, 3, 7]]
    span = np.ptp(pts[:, 0])
    fig, axes = plt.subplots(idx.size, 1, figsize=(8, 1.6 * idx.size + 0.6), squeeze=False)
    colors = np.array(["tab:blue", "tab:orange", "tab:green", "tab:red"])
    for ax, k in zip(axes[:, 0], idx):
        u = shapes[k][node_dofs]
        amp = 0.08 * span / max(np.abs(u).max(), 1e-300)
        d = pts + amp * u
        ax.add_collection(PolyCollection(pts[ring], facecolors="none", edgecolors="0.85",
                                         linewidths=0.4))
        ax.add_collection(PolyCollection(d[ring], facecolors=colors[body % 4], alpha=0.55,
                                         edgecolors="k", linewidths=0.2))
        ax.set_xlim(pts[:, 0].min() - 0.02 * span, pts[:, 0].max() + 0.02 * span)
        lo = min(pts[:, 1].min(), d[:, 1].min())
        hi = max(pts[:, 1].max(), d[:, 1].max())
        ax.set_ylim(lo - 0.05 * span, hi + 0.05 * span)
        ax.set_aspect("equal")
        ax.set_title(f"mode {k + 1}: {f[k]:.2f} Hz", fontsize=9)
        ax.set_yticks([])
    axes[-1, 0].set_xlabel("x [m]")
    fig.tight_layout()
    out = Path(outdir) / "mode_shapes.png"
    fig.savefig(out, dpi=130)
    plt.close(fig)
    return [out]


def paraview_files(h5, outdir) -> list[Path]:
    """VTU files of the mode shapes and of the interface pressure."""
    from ..io.vtk import export_paraview
    try:
        return export_paraview(h5, outdir)
    except (KeyError, ValueError) as exc:
        log.warning("ParaView export skipped: %s", exc)
        return []


def modes_figures(h5, outdir) -> list[Path]:
    return mode_shape_plot(h5, outdir) + paraview_files(h5, outdir)


def modes_table(h5) -> str:
    """Frequencies of the stuck joint (and full/monolithic references)."""
    if "modes/frequency_hz" not in h5 or "modes/elastic" not in h5:
        return "Linear modes of the preloaded, stuck joint: (not stored)"
    f = h5["modes/frequency_hz"][()]
    el = h5["modes/elastic"][()]
    full = h5["modes/frequency_hz_full"][()] if "modes/frequency_hz_full" in h5 else None
    mono = h5["modes/monolithic_hz"][()] if "modes/monolithic_hz" in h5 else None
    head = f"{'mode':>5} {'kind':>10} {'f [Hz]':>11}"
    if full is not None:
        head += f" {'full [Hz]':>11} {'rel.err':>9}"
    if mono is not None:
        head += f" {'monolithic':>11}"
    lines = ["Linear modes of the preloaded, stuck joint:", head]
    for i in range(f.size):
        row = f"{i + 1:>5} {'elastic' if el[i] else 'suspension':>10} {f[i]:>11.3f}"
        if full is not None and i < full.size:
            row += f" {full[i]:>11.3f} {f[i] / full[i] - 1:>9.1e}"
        if mono is not None and i < mono.size:
            row += f" {mono[i]:>11.3f}"
        lines.append(row)
    if "model" in h5:
        a = h5["model"].attrs
        parts = [f"{a.get('n_dof', '?')} model DOFs"]
        if "n_full_dof" in a:
            parts.insert(0, f"{a['n_full_dof']} FE DOFs ->")
            parts.append(f"({a.get('n_retained', '?')} retained + {a.get('n_cb_modes', '?')} "
                         "fixed-interface modes)")
        parts.append(f"{a.get('n_contacts', '?')} contact elements")
        lines.append("  " + " ".join(parts))
        t = [f"{k[:-7]} {float(a[k]):.2f} s" for k in ("build_time_s", "reduce_time_s",
                                                         "preload_time_s") if k in a]
        if t:
            lines.append("  times: " + ", ".join(t))
    return "\n".join(lines)


def static_table(h5) -> str:
    if h5.attrs.get("model_kind") not in ("fe", "rom"):
        return ""
    a = h5["static"].attrs
    N = h5["static/N"][()]
    s = (f"Preload: sum N0 = {N.sum():.6g} N (bolts {float(a.get('bolt_force_total', 0)):.6g} N),"
         f" {int(np.sum(N > 0))}/{N.size} elements in contact; {a.get('message', '')}")
    if "static/pressure" in h5:
        s += f"; peak pressure {h5['static/pressure'][()].max() / 1e6:.3g} MPa"
    return s
