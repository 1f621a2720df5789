"""Figures and tables of harmonic-balance results: FRCs and EPMC backbones."""
from __future__ import annotations

import logging
from pathlib import Path

import h5py
import numpy as np

from .common import backbone_section, pyplot, quantity_label

log = logging.getLogger(__name__)


def plot_frc(h5: h5py.File, outdir: Path) -> list[Path]:
    """Amplitude at the response DOF against frequency, one curve per force level."""
    plt = pyplot()
    g = h5["hbm"]
    if "omega" not in g or g["omega"].shape[0] == 0:
        return []
    units = h5.attrs.get("units", "SI")
    om, amp, br = g["omega"][()], g["amplitude"][()], g["branch"][()]
    scales = g["force_scale"][()]
    fig, ax = plt.subplots(figsize=(7, 4.6))
    for b in np.unique(br):
        m = br == b
        line, = ax.plot(om[m], amp[m], ".-", ms=2.5, lw=1.2,
                        label=f"force x {scales[b]:g} ({int(m.sum())} points)")
        if "peak_amplitude" in g and np.isfinite(g["peak_amplitude"][b]):
            ax.plot(g["peak_omega"][b], g["peak_amplitude"][b], "o", mfc="none",
                    color=line.get_color())
    ax.set_xlabel(quantity_label("omega", "angular_frequency", units))
    where = str(g.attrs.get("response_label", "")) or f"DOF {int(g.attrs.get('response_dof', 0))}"
    ax.set_ylabel(quantity_label(f"|X_1| at {where}", "displacement", units))
    ax.set_title("frequency response (fundamental amplitude); circles: peaks", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = outdir / "frc.png"
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return [path]


def plot_epmc(h5: h5py.File, outdir: Path) -> list[Path]:
    """EPMC backbones: frequency and damping ratio against modal amplitude."""
    plt = pyplot()
    g = h5["epmc"]
    if "amplitude" not in g or g["amplitude"].shape[0] == 0:
        return []
    units = h5.attrs.get("units", "SI")
    a, f, z = g["amplitude"][()], g["frequency_hz"][()], g["damping_ratio"][()]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    ax1.semilogx(a, f, ".-", ms=3)
    ax1.set_ylabel(quantity_label("f", "frequency", units))
    ax1.set_title(f"EPMC backbone of mode {int(g.attrs.get('mode', 1))}", fontsize=9)
    ax2.semilogx(a, 100 * z, ".-", ms=3, color="tab:red")
    ax2.set_ylabel("damping ratio [%]")
    ax2.set_xlabel(f"modal amplitude [{g['amplitude'].attrs.get('unit', '')}]")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    path = outdir / "epmc_backbone.png"
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return [path]


def hbm_section(h5) -> str:
    g = h5["hbm"]
    lines = [f"  harmonic balance: harmonics {g['harmonics'][()].tolist()}, "
             f"{g.attrs.get('n_samples', '?')} samples, {g.attrs.get('condensation', '?')} "
             f"condensation onto {g.attrs.get('n_contact_coordinates', '?')} contact "
             f"coordinates"]
    if "omega" not in g:
        return "\n".join(lines + ["    (no points)"])
    br = g["branch"][()]
    for b, fs in enumerate(g["force_scale"][()]):
        m = br == b
        it = g["iterations"][()][m]
        pk = (f"peak {g['peak_amplitude'][b]:.6g} at omega = {g['peak_omega'][b]:.6g}"
              if "peak_amplitude" in g and b < g["peak_amplitude"].shape[0] else "")
        lines.append(f"    branch {b} (force x {fs:g}): {int(m.sum())} points, "
                     f"{int(it.sum()) if it.size else 0} Newton iterations; {pk}; "
                     f"{g.attrs.get(f'branch{b}_message', 'not run')}")
    return "\n".join(lines)


def epmc_section(h5) -> str:
    return backbone_section(h5, "epmc", "EPMC")
