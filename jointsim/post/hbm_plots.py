"""Figures and tables of harmonic-balance results: FRCs and EPMC backbones."""
from __future__ import annotations

import logging
from pathlib import Path

import h5py
import numpy as np

from ..io.hdf5 import unit
from .common import backbone_section, pyplot, quantity_label

log = logging.getLogger(__name__)


def excitation_amplitude(h5) -> float:
    """First-harmonic force amplitude of the scene's excitation at force scale 1
    (the largest over the loads) [N], from the scene stored in the file; NaN
    when the loads have no harmonic 1 (then no receptance is drawn)."""
    from .. import _toml
    try:
        loads = _toml.loads(h5.attrs["scene"]).get("excitation", {}).get("loads", [])
    except Exception:  # an old or foreign file: no receptance
        return float("nan")
    amps = []
    for ld in loads:
        force = ld.get("force", {})
        if isinstance(force, dict):
            for hm in force.get("harmonics", []):
                if int(hm.get("h", 0)) == 1:
                    amps.append(float(np.hypot(hm.get("cos", 0.0), hm.get("sin", 0.0))))
    return max(amps) if amps and max(amps) > 0 else float("nan")


def marked_error(g) -> np.ndarray | None:
    """The estimated error per point that the tolerance applies to: ``error_curve`` (the
    FRC's, across the branch) where it is stored and finite, else ``error_estimate``
    (None without indicators)."""
    if "error_estimate" not in g:
        return None
    e = g["error_estimate"][()]
    if "error_curve" in g:
        c = _rows(g["error_curve"][()], e.shape[0])
        e = np.where(np.isfinite(c), c, e)
    return e


def _rows(v, n: int) -> np.ndarray:
    """``v`` (float, 1-D) cut or NaN-padded to ``n`` rows."""
    out = np.full(n, np.nan)
    out[:min(n, v.shape[0])] = v[:n]
    return out


def error_flags(g) -> np.ndarray | None:
    """Points of group ``g`` (``/hbm`` or ``/epmc``) whose estimated error
    (:func:`marked_error`) exceeds the group's ``error_tol`` attribute (bool per point;
    None without indicators or tolerance)."""
    tol = float(g.attrs.get("error_tol", 0.0))
    e = marked_error(g)
    if e is None or not tol > 0:
        return None
    return np.isfinite(e) & (e > tol)


def _mark_errors(ax, x, y, bad, labelled: bool) -> bool:
    """Red open squares on the points above the error tolerance; True once labelled."""
    if bad is None or not np.any(bad):
        return labelled
    ax.plot(x[bad], y[bad], "s", mfc="none", mec="tab:red", ms=6, mew=1.0,
            label=None if labelled else "error estimate > error_tol")
    return True


def error_lines(g, indent: str = "    ", groups=None) -> list[str]:
    """``jointsim info`` lines of the ``error_*`` indicators of ``/hbm`` or ``/epmc``.

    Parameters
    ----------
    g : h5py.Group
    indent : str
    groups : list of (str, ndarray of bool), optional
        (label, point mask) per branch; default: all points as one.
    """
    if "error_estimate" not in g:
        return []
    e = g["error_estimate"][()]
    tr = g["error_truncation"][()] if "error_truncation" in g else np.full_like(e, np.nan)
    al = g["error_aliasing"][()] if "error_aliasing" in g else np.full_like(e, np.nan)
    tol = float(g.attrs.get("error_tol", 0.0))
    marked = marked_error(g)
    across = [_rows(g[k][()], e.shape[0]) for k in ("error_curve", "error_curve_frequency")] \
        if "error_curve" in g else None
    out = []
    for label, m in groups or [("all points", np.ones(e.shape, dtype=bool))]:
        em = np.where(m & np.isfinite(e), e, -np.inf)
        if not np.any(np.isfinite(em)):
            out.append(f"{indent}{label}: error estimate not computed")
            continue
        i = int(np.argmax(em))
        n_bad = int(np.sum(m & np.isfinite(marked) & (marked > tol))) if tol > 0 else 0
        extra = ""
        if across is not None:
            c, cw = np.where(m, across[0], np.nan), across[1]
            if np.any(np.isfinite(c)):
                j = int(np.nanargmax(c))
                extra += (f", across the branch up to {c[j]:.1e} (frequency shift "
                          f"{cw[j]:.1e}) at point {j}")
        for name, what in (("error_frequency", "frequency"), ("error_damping", "damping")):
            if name in g:
                v = g[name][()][m]
                if np.any(np.isfinite(v)):
                    extra += f", {what} up to {np.nanmax(v):.1e}"
        out.append(f"{indent}{label}: error estimate up to {e[i]:.1e} (truncation "
                   f"{tr[i]:.1e}, aliasing {al[i]:.1e}) at point {i}{extra}; "
                   + (f"{n_bad}/{int(m.sum())} points above error_tol = {tol:g}" if tol > 0
                      else "no tolerance"))
    return out


def plot_frc(h5: h5py.File, outdir: Path, frequency: str = "Hz") -> list[Path]:
    """Amplitude at the response DOF against frequency, one curve per force level.

    Writes ``frc.png`` (amplitude on a linear axis) and, when the excitation
    has a first harmonic, ``frc_receptance.png``: the receptance ``|X| / F``
    on a log axis (``F`` the first-harmonic force amplitude of the branch),
    where small and large force levels can be compared.  The frequency axis
    is in Hz (``frequency="rad/s"`` on request: ``jointsim post --rad-s``).
    A branch that gave up is marked with an x at its last point; points whose
    estimated error (:func:`marked_error`: across the branch) exceeds
    ``analysis.hbm.error_tol`` with red open squares.

    Parameters
    ----------
    h5 : h5py.File
    outdir : Path
    frequency : {'Hz', 'rad/s'}
    """
    plt = pyplot()
    g = h5["hbm"]
    if "omega" not in g or g["omega"].shape[0] == 0:
        return []
    if frequency not in ("Hz", "rad/s"):
        raise ValueError(f"frequency must be 'Hz' or 'rad/s', got {frequency!r}")
    units = h5.attrs.get("units", "SI")
    om, amp, br = g["omega"][()], g["amplitude"][()], g["branch"][()]
    scales = g["force_scale"][()]
    to_x = (1.0 / (2 * np.pi)) if frequency == "Hz" else 1.0
    xlabel = quantity_label("f", "frequency", units) if frequency == "Hz" else \
        quantity_label("omega", "angular_frequency", units)
    measure = str(g.attrs.get("amplitude_measure", "fundamental"))
    sym = {"fundamental": "|X_1|", "rms": "x_rms", "peak_to_peak": "x_pp"}.get(measure, "|X|")
    where = str(g.attrs.get("response_label", "")) or f"DOF {int(g.attrs.get('response_dof', 0))}"
    F1 = excitation_amplitude(h5)
    kinds = [("frc.png", 1.0, False)]
    if np.isfinite(F1):
        kinds.append(("frc_receptance.png", F1, True))
    paths = []
    bad = error_flags(g)
    for name, F1k, receptance in kinds:
        fig, ax = plt.subplots(figsize=(7, 4.6))
        labelled = False
        for b in np.unique(br):
            m = br == b
            div = F1k * scales[b] if receptance else 1.0
            gave_up = str(g.attrs.get(f"branch{b}_status", "")) == "gave up"
            line, = ax.plot(om[m] * to_x, amp[m] / div, ".-", ms=2.5, lw=1.2,
                            label=f"force x {scales[b]:g} ({int(m.sum())} points"
                                  f"{', gave up' if gave_up else ''})")
            labelled = _mark_errors(ax, om[m] * to_x, amp[m] / div,
                                    None if bad is None else bad[m], labelled)
            if gave_up:
                ax.plot(om[m][-1] * to_x, amp[m][-1] / div, "x", ms=8, mew=2,
                        color=line.get_color())
            if "peak_amplitude" in g and np.isfinite(g["peak_amplitude"][b]):
                ax.plot(g["peak_omega"][b] * to_x, g["peak_amplitude"][b] / div, "o",
                        mfc="none", color=line.get_color())
        ax.set_xlabel(xlabel)
        if receptance:
            ax.set_yscale("log")
            d_u, f_u = unit("displacement", units), unit("force", units)
            ax.set_ylabel(f"{sym} / F at {where} [{d_u}/{f_u}]")
            ax.set_title(f"receptance ({measure} amplitude / force amplitude F = "
                         f"{F1:g} x scale); circles: peaks", fontsize=9)
        else:
            ax.set_ylabel(quantity_label(f"{sym} at {where}", "displacement", units))
            ax.set_title(f"frequency response ({measure} amplitude); circles: peaks",
                         fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = outdir / name
        fig.savefig(path, dpi=130)
        plt.close(fig)
        paths.append(path)
    return paths


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
    bad = error_flags(g)
    if bad is not None and bad.shape == a.shape and np.any(bad):
        _mark_errors(ax1, a, f, bad, False)
        _mark_errors(ax2, a, 100 * z, bad, False)
        ax1.legend(fontsize=8)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    path = outdir / "epmc_backbone.png"
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return [path]


def hbm_section(h5) -> str:
    g = h5["hbm"]
    hs = g["harmonics"][()].tolist() if "harmonics" in g else "(not stored)"
    lines = [f"  harmonic balance: harmonics {hs}, "
             f"{g.attrs.get('n_samples', '?')} samples, {g.attrs.get('condensation', '?')} "
             f"condensation onto {g.attrs.get('n_contact_coordinates', '?')} contact "
             f"coordinates"]
    if "omega" not in g or "branch" not in g or "force_scale" not in g:
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
    lines += error_lines(g, groups=[(f"branch {b}", br == b)
                                    for b in range(len(g["force_scale"][()]))])
    return "\n".join(lines)


def epmc_section(h5) -> str:
    text = backbone_section(h5, "epmc", "EPMC")
    lines = error_lines(h5["epmc"], groups=[("backbone", np.ones(
        h5["epmc/error_estimate"].shape, dtype=bool))]) if "error_estimate" in h5["epmc"] \
        else []
    return "\n".join(([text] if text else []) + lines)
