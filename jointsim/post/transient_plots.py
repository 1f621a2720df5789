"""Figures and the ``jointsim info`` section of time-marching results (``/transient``).

* ``transient_history.png``: the stored time history of the output DOFs;
* steady runs: ``transient_convergence.png`` (period-to-period change, with the
  time-step error indicator in the title),
  ``transient_loops.png`` (element loops of the steady period with the
  manifold and Masing predictions), ``transient_crosscheck.png`` (per-harmonic
  differences against HBM, when present);
* free decays: ``transient_backbone.png`` (frequency and damping against the
  modal amplitude, and the ring-down of the modal coordinate).
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..harmonics import harmonic_amplitude
from .common import pyplot, quantity_label

log = logging.getLogger(__name__)

#: Most samples drawn per curve; longer histories are thinned for the figure.
MAX_POINTS = 20000


def _thin(n: int) -> slice:
    return slice(None, None, max(1, int(np.ceil(n / MAX_POINTS))))


def _labels(g) -> list[str]:
    raw = g.attrs.get("dof_labels", "")
    return raw.split(",") if raw else []


def plot_history(h5, outdir: Path) -> Path | None:
    """Time history of the output DOFs (thinned to at most ``MAX_POINTS`` samples)."""
    if "transient/t" not in h5:
        return None
    plt = pyplot()
    units = h5.attrs.get("units", "SI")
    g = h5["transient"]
    t = h5["transient/t"]
    sl = _thin(t.shape[0])
    t = t[sl]
    x = h5["transient/x"][sl]
    labels = _labels(g)
    fig, ax = plt.subplots(figsize=(9, 3.8))
    for j in range(x.shape[1]):
        ax.plot(t, x[:, j], lw=0.7, label=labels[j] if j < len(labels) else f"column {j}")
    ax.set_xlabel(quantity_label("t", "time", units))
    ax.set_ylabel(quantity_label("x", "displacement", units))
    kind = g.attrs.get("kind", "")
    title = (f"time marching, steady run at omega = {g.attrs['omega']:g}" if kind == "steady"
             else "time marching, free decay")
    ax.set_title(f"{title}: {g.attrs.get('message', '')}", fontsize=8)
    ax.grid(alpha=0.3)
    if x.shape[1] <= 8:
        ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    path = outdir / "transient_history.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_convergence(h5, outdir: Path) -> Path | None:
    """Period-to-period change of a steady run, with the tolerance."""
    if "transient/period_change" not in h5:
        return None
    plt = pyplot()
    c = h5["transient/period_change"][()]
    g = h5["transient"]
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    k = np.arange(1, c.size + 1)
    ok = np.isfinite(c) & (c > 0)
    ax.semilogy(k[ok], c[ok], "k.-", lw=0.8, ms=3)
    if "steady_tol" in g.attrs:
        ax.axhline(g.attrs["steady_tol"], color="tab:red", ls="--", lw=1, label="steady_tol")
        ax.legend(fontsize=8)
    ax.set_xlabel("period")
    ax.set_ylabel("change between periods / amplitude")
    ax.grid(alpha=0.3, which="both")
    title = str(g.attrs.get("message", ""))
    if "transient/error_step" in h5:
        ds = h5["transient/error_step"]
        val, tol = float(ds[()]), float(ds.attrs.get("tol", np.inf))
        title += (f"\ntime-step error indicator {val:.2e}"
                  + (f" > error_tol {tol:g}" if val > tol else f" (error_tol {tol:g})"))
    ax.set_title(title, fontsize=8)
    fig.tight_layout()
    path = outdir / "transient_convergence.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_loops(h5, outdir: Path, max_elements: int = 6) -> Path | None:
    """Steady element loops (u, f) with the manifold and classical Masing predictions."""
    g = h5["transient"]
    where = str(g.attrs.get("loops_group", "")).strip("/")
    if not where or where not in h5:
        return None
    base = where.rsplit("/", 1)[0] if "/" in where else ""
    masing = f"{base}/masing" if base else "masing"
    loops = h5[where]
    row = loops["u"].shape[0] - 1
    u, f = loops["u"][row], loops["f"][row]
    ne = u.shape[0]
    if ne == 0:
        return None
    pick = np.unique(np.linspace(0, ne - 1, min(ne, max_elements)).round().astype(int))
    plt = pyplot()
    units = h5.attrs.get("units", "SI")
    ncol = min(3, pick.size)
    nrow = int(np.ceil(pick.size / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.4 * nrow), squeeze=False)
    for ax, e in zip(axes.ravel(), pick):
        uu, ff = np.append(u[e], u[e][:1]), np.append(f[e], f[e][:1])
        ax.plot(uu, ff, "k-", lw=1.6, label="time marching")
        if masing in h5:
            m = h5[masing]
            ax.plot(u[e], m["f_manifold"][row, e], "--", color="tab:green", lw=1,
                    label="manifold")
            ax.plot(u[e], m["f_masing"][row, e], ":", color="tab:red", lw=1.2,
                    label="Masing (mean N)")
            ax.set_title(f"element {e}: dev_manifold {m['dev_manifold'][row, e]:.1e}",
                         fontsize=8)
        ax.set_xlabel(quantity_label("u_t", "displacement", units))
        ax.set_ylabel(quantity_label("f_t", "force", units))
        ax.grid(alpha=0.3)
    axes.ravel()[0].legend(fontsize=7)
    for ax in axes.ravel()[pick.size:]:
        ax.set_visible(False)
    fig.tight_layout()
    path = outdir / "transient_loops.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_crosscheck(h5, outdir: Path) -> Path | None:
    """Per-harmonic difference between time marching and HBM."""
    if "crosscheck/rel_diff" not in h5:
        return None
    plt = pyplot()
    g = h5["crosscheck"]
    hs = h5["crosscheck/harmonics"][()]
    rel = h5["crosscheck/rel_diff"][()]
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    colors = ["tab:orange" if (h == 0 and g.attrs.get("dc_history", False)) else
              ("tab:green" if r <= g.attrs["tol"] else "tab:red") for h, r in zip(hs, rel)]
    ax.bar([str(h) for h in hs], np.maximum(rel, 1e-17), color=colors)
    ax.set_yscale("log")
    ax.axhline(g.attrs["tol"], color="k", ls="--", lw=1, label="tolerance")
    if "tab:orange" in colors:
        from matplotlib.patches import Patch
        ax.legend(handles=ax.get_legend_handles_labels()[0]
                  + [Patch(color="tab:orange", label="DC: slider history (legitimate)")],
                  fontsize=8)
    else:
        ax.legend(fontsize=8)
    ax.set_xlabel("harmonic")
    ax.set_ylabel("||X_TM - X_HBM|| / ||X_HBM,1||")
    ax.set_title(f"time marching vs HBM at omega = {float(g.attrs.get('omega', np.nan)):.6g} "
                 f"(force scale {float(g.attrs.get('force_scale', np.nan)):g}): "
                 f"{'agree' if g.attrs.get('agree', False) else 'DISAGREE'}", fontsize=9)
    fig.tight_layout()
    path = outdir / "transient_crosscheck.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_backbone(h5, outdir: Path) -> Path | None:
    """Free decay: frequency and damping against the modal amplitude, and q(t)."""
    if "transient/amplitude" not in h5 or h5["transient/amplitude"].shape[0] == 0:
        return None
    plt = pyplot()
    units = h5.attrs.get("units", "SI")
    g = h5["transient"]
    a = h5["transient/amplitude"][()]
    fr = h5["transient/frequency_hz"][()]
    z = h5["transient/damping_ratio"][()]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    amp_label = f"modal amplitude [{h5['transient/amplitude'].attrs.get('unit', '')}]"
    axes[0].semilogx(a, fr, "k.-", lw=0.8, ms=3)
    if "frequency_linear_hz" in g.attrs:
        axes[0].axhline(g.attrs["frequency_linear_hz"], color="tab:blue", ls=":", lw=1,
                        label="linear, joint stuck")
        axes[0].legend(fontsize=8)
    axes[0].set_xlabel(amp_label)
    axes[0].set_ylabel(quantity_label("f", "frequency", units))
    axes[1].semilogx(a, 100.0 * z, "k.-", lw=0.8, ms=3)
    axes[1].set_xlabel(amp_label)
    axes[1].set_ylabel("damping ratio [%]")
    from matplotlib.ticker import NullFormatter, ScalarFormatter
    for ax in axes[:2]:
        ax.grid(alpha=0.3, which="both")
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
    if "transient/q" in h5:
        t = h5["transient/t"]
        sl = _thin(t.shape[0])
        axes[2].plot(t[sl], h5["transient/q"][sl], lw=0.6, color="k")
        axes[2].set_xlabel(quantity_label("t", "time", units))
        axes[2].set_ylabel("modal coordinate q")
        axes[2].grid(alpha=0.3)
    else:
        axes[2].set_visible(False)
    fig.suptitle(f"free decay of mode {g.attrs.get('mode', '?')} "
                 f"({g.attrs.get('method', '')})", fontsize=9)
    fig.tight_layout()
    path = outdir / "transient_backbone.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_transient(h5, outdir: Path) -> list[Path]:
    """Every time-marching figure that applies to the file."""
    outdir = Path(outdir)
    out = [plot_history(h5, outdir)]
    if h5["transient"].attrs.get("kind") == "steady":
        out += [plot_convergence(h5, outdir), plot_loops(h5, outdir),
                plot_crosscheck(h5, outdir)]
    else:
        out.append(plot_backbone(h5, outdir))
    return [p for p in out if p is not None]


def transient_table(h5) -> str:
    """The ``jointsim info`` section of a time-marching result."""
    g = h5["transient"]
    a = g.attrs
    kind = a.get("kind", "?")
    lines = [f"Time marching ({kind}), generalized-alpha rho_inf = {a.get('rho_inf', '?')}, "
             f"{a.get('steps_per_period', '?')} steps per period: "
             f"{a.get('status_name', '?')} - {a.get('message', '')}"]
    if "status_name" not in a and "transient/period_change" in h5:  # unfinished (issue 11)
        lines[0] = lines[0].replace("? - ", "unfinished - ") + \
            f"{h5['transient/period_change'].shape[0]} periods committed"
    if "steps" in a:
        lines.append(f"  {a['steps']} steps, {a.get('newton_iterations', 0)} Newton "
                     f"iterations, {a.get('step_cuts', 0)} step cuts (deepest "
                     f"{a.get('deepest_cut', 0)}), {float(a.get('wall_time_s', 0.0)):.2f} s")
    if kind == "steady":
        if "energy_input" in a:
            lines.append(f"  energy per period: input {a['energy_input']:.6g}, viscous "
                         f"{a['energy_viscous']:.6g}, friction {a['energy_friction']:.6g}, "
                         f"imbalance {a['energy_relative']:.2e} (relative)")
        if "error_estimate" in a:
            rigid = int(a.get("rigid_modes_left_out", 0))
            lines.append(f"  estimated distance to the steady state: "
                         f"{float(a['error_estimate']):.2e} of the amplitude"
                         + (f" ({rigid} rigid-body mode(s) left out of the period change)"
                            if rigid else ""))
        if "transient/error_step" in h5:
            ds = h5["transient/error_step"]
            val, tol = float(ds[()]), float(ds.attrs.get("tol", np.nan))
            lines.append(f"  time-step error indicator (error_step): {val:.2e} of the first "
                         f"harmonic" + (f", ABOVE the tolerance {tol:g}" if val > tol else
                                        f" (tolerance {tol:g})"))
        if int(a.get("undamped_modes", 0)):
            hz = np.atleast_1d(a.get("undamped_modes_hz", [np.nan]))
            lines.append(f"  {int(a['undamped_modes'])} modes of the stuck structure "
                         f"({np.min(hz):.4g} .. {np.max(hz):.4g} Hz) have no damping in the "
                         "scene: " + (f"damped at {float(a['undamped_mode_zeta']):g} for the "
                                      "march (undamped_mode_zeta)"
                                      if "undamped_mode_zeta" in a else
                                      "they settle only by numerical dissipation"))
        if "step_range_warning" in a:
            lines.append(f"  WARNING: {a['step_range_warning']}")
        if "transient/harmonics" in h5:
            X = h5["transient/harmonics"][()]
            dofs = h5["transient/dofs"][()]
            labels = _labels(g)
            hs = (tuple(int(h) for h in h5["transient/harmonic_numbers"][()])
                  if "transient/harmonic_numbers" in h5 else (0, 1))
            amp = harmonic_amplitude(hs, X, 1)
            for j, d in enumerate(dofs[:12]):
                name = labels[j] if j < len(labels) else f"x{d}"
                lines.append(f"  {name}: first-harmonic amplitude {amp[d]:.6g}, DC "
                             f"{X[0, d]:.6g}")
    elif "transient/amplitude" in h5 and h5["transient/amplitude"].shape[0]:
        amp = h5["transient/amplitude"][()]
        fr = h5["transient/frequency_hz"][()]
        z = h5["transient/damping_ratio"][()]
        lines.append(f"  mode {a.get('mode', '?')}: linear (stuck) "
                     f"{float(a.get('frequency_linear_hz', np.nan)):.6g} Hz; "
                     f"{amp.size} estimates, amplitude {amp.min():.3g} .. {amp.max():.3g}, "
                     f"frequency {fr.min():.6g} .. {fr.max():.6g} Hz, damping "
                     f"{np.nanmin(z):.3g} .. {np.nanmax(z):.3g}")
    return "\n".join(lines)


def crosscheck_table(h5) -> str:
    """The ``jointsim info`` section of the cross-check against harmonic balance."""
    a = h5["crosscheck"].attrs
    lines = [f"Cross-check, time marching vs HBM at omega = {float(a.get('omega', np.nan)):.8g}"
             f" (force scale {float(a.get('force_scale', np.nan)):g}): "
             f"{'agree' if a.get('agree', False) else 'DISAGREE'} within "
             f"{float(a.get('tol', np.nan)):g}",
             f"  HBM: {a.get('hbm_message', a.get('hbm_source', '?'))}"]
    if all(f"crosscheck/{k}" in h5 for k in ("harmonics", "rel_diff", "rel_own")):
        hs = h5["crosscheck/harmonics"][()]
        rel = h5["crosscheck/rel_diff"][()]
        own = h5["crosscheck/rel_own"][()]
        lines.append(f"  {'harmonic':>8} {'|dX_h|/|X_1|':>13} {'|dX_h|/|X_h|':>13}")
        for h, r, o in zip(hs, rel, own):
            note = ""
            if h == 0 and r > a.get("tol", np.inf):
                note = "  slider history (legitimate)" if a.get("dc_history", False) \
                    else "  not explained by the slider history"
            lines.append(f"  {int(h):>8} {r:>13.3e} {o:>13.3e}{note}")
    if "crosscheck/amplitude_transient" in h5 and "crosscheck/amplitude_hbm" in h5:
        # absent in a file interrupted while the cross-check was written
        at, ah = h5["crosscheck/amplitude_transient"][()], h5["crosscheck/amplitude_hbm"][()]
        with np.errstate(divide="ignore", invalid="ignore"):
            ra = np.where(ah > 0, np.abs(at / ah - 1.0), np.nan)
        j = int(np.nanargmax(ra)) if np.any(np.isfinite(ra)) else 0
        if ra.size:
            lines.append(f"  first-harmonic amplitude: largest relative difference "
                         f"{ra[j]:.3e} (DOF {j}: {at[j]:.6g} vs {ah[j]:.6g})")
    lines.append(f"  {a.get('verdict', '')}")
    return "\n".join(lines)
