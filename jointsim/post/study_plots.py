"""Figures of the lap-joint study: backbones, deviation maps, loops, manifold fractions."""
from __future__ import annotations

import logging
from pathlib import Path

import h5py
import numpy as np

from . import study
from .common import backbone_section, law_from_file, pyplot, quantity_label

log = logging.getLogger(__name__)


def plot_backbones(h5: h5py.File, outdir: Path) -> list[Path]:
    """Frequency and damping ratio against modal amplitude: EPMC, QSMA, free decay."""
    plt = pyplot()
    units = h5.attrs.get("units", "SI")
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7.5, 6.5), sharex=True)
    curves = [("epmc", "EPMC (first harmonic)", "-", "tab:blue"),
              ("qsma", "QSMA (secant, Masing)", "--", "tab:orange"),
              ("transient", "free decay (time marching)", ":", "tab:green")]
    amp_unit = ""
    for group, label, ls, color in curves:
        if group not in h5 or any(k not in h5[group] for k in (
                "amplitude", "frequency_hz", "damping_ratio")) \
                or h5[f"{group}/amplitude"].shape[0] == 0:
            continue
        g = h5[group]
        a = g["amplitude"][()]
        amp_unit = g["amplitude"].attrs.get("unit", amp_unit)
        ok = a > 0
        ax1.semilogx(a[ok], g["frequency_hz"][()][ok], ls, color=color, lw=1.6, label=label)
        ax2.loglog(a[ok], np.abs(g["damping_ratio"][()][ok]), ls, color=color, lw=1.6,
                   label=label)
        neg = ok & (g["damping_ratio"][()] < 0)
        if np.any(neg):
            ax2.loglog(a[neg], -g["damping_ratio"][()][neg], "x", color=color, ms=4,
                       label=f"{group}: |negative| values")
    exact = h5.get("epmc/at_amplitudes")
    if exact is not None and "converged" in exact and exact["converged"][()].any():
        # the EPMC solved at fixed amplitudes (the loop amplitudes: the study tables)
        ok = exact["converged"][()]
        a = exact["amplitude"][()][ok]
        for ax, v in ((ax1, exact["frequency_hz"][()][ok]),
                      (ax2, np.abs(exact["damping_ratio"][()][ok]))):
            ax.plot(a, v, "o", color="tab:blue", mfc="none", ms=6,
                    label="EPMC solved at fixed amplitudes")
    if "qsma" in h5 and "linear_frequency_hz" in h5["qsma"].attrs:
        ax1.axhline(float(h5["qsma"].attrs["linear_frequency_hz"]), color="0.5", lw=0.8,
                    label="linear, stuck joint")
    ax1.set_ylabel(quantity_label("f", "frequency", units))
    ax2.set_ylabel("damping ratio [1]")
    ax2.set_xlabel(f"modal amplitude [{amp_unit}]")
    ax1.set_title(f"{Path(h5.attrs.get('scene_path', '')).stem}: backbones of the first "
                  "bending mode", fontsize=9)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:  # an interrupted run may have no curve yet
            ax.legend(fontsize=8)
    fig.tight_layout()
    path = outdir / "backbones.png"
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return [path]


def plot_masing_study(h5: h5py.File, outdir: Path) -> list[Path]:
    """Deviation maps, manifold fractions and 3D loops of chosen elements."""
    prefix = study.study_group(h5)
    if prefix is None:
        return []
    sets = study.loop_points(h5, prefix)
    n_sets, ne = sets.dev_manifold.shape
    if ne < 2 or n_sets == 0:
        return []
    plt = pyplot()
    units = h5.attrs.get("units", "SI")
    x = (h5["contacts/position"][()][:, 0] if "contacts/position" in h5
         else np.arange(ne, dtype=float))
    x_label = "interface position x [mm]" if "contacts/position" in h5 else "element"
    xs = 1e3 * x if "contacts/position" in h5 else x
    order = np.argsort(xs)
    tol = float(h5[f"{prefix}/masing" if prefix else "masing"].attrs.get("tol", 0.01))
    out = [_deviation_map(plt, sets, xs, order, x_label, tol, outdir),
           _fraction_plot(plt, h5, prefix, sets, tol, outdir)]
    loops = _element_loops(plt, h5, prefix, sets, x, xs, units, outdir)
    return out + ([loops] if loops is not None else [])


def _deviation_map(plt, sets, xs, order, x_label, tol, outdir) -> Path:
    """Deviation of each loaded element from its manifold and from classical Masing
    against its position, one curve per loop set."""
    n_sets = sets.dev_manifold.shape[0]
    fig, axes = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    cmap = plt.get_cmap("viridis")
    for i in range(n_sets):
        c = cmap(i / max(n_sets - 1, 1))
        lab = f"{sets.parameter_name} {sets.parameter[i]:.3g}"
        for ax, dev in zip(axes, (sets.dev_manifold, sets.dev_masing)):
            d = np.where(sets.loaded[i], dev[i], np.nan)[order]
            ax.semilogy(xs[order], np.maximum(d, 1e-17), "o-", ms=3, lw=1, color=c, label=lab)
    for ax, name in zip(axes, ("dev_manifold", "dev_masing (classical, mean N)")):
        ax.axhline(tol, color="k", ls="--", lw=0.8, label=f"tol = {tol:g}")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7, ncol=2)
    axes[-1].set_xlabel(x_label)
    axes[0].set_title("deviation of each loaded element's loop from its manifold (top) and "
                      "from classical Masing (bottom)", fontsize=9)
    fig.tight_layout()
    p = outdir / "deviation_map.png"
    fig.savefig(p, dpi=130)
    plt.close(fig)
    return p



def _fraction_plot(plt, h5, prefix, sets, tol, outdir) -> Path:
    """Shares of loaded elements on their manifold and on classical Masing against
    amplitude (count and weighted), with the control and the clipped share."""
    ne = sets.dev_manifold.shape[1]
    man, mas, n = study.manifold_fractions(sets)
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.semilogx(sets.parameter, man, "o-", color="C0", label="on its Masing manifold (count)")
    ax.semilogx(sets.parameter, mas, "s--", color="C1",
                label="on the classical Masing curve (count)")
    for (name, w), ls in zip(study.fraction_weights(h5, ne).items(), (":", "-.")):
        wm, ws, _ = study.weighted_fractions(sets, w)
        ax.semilogx(sets.parameter, wm, ls, color="C0", label=f"manifold, by {name}")
        ax.semilogx(sets.parameter, ws, ls, color="C1", label=f"classical Masing, by {name}")
    control = study.control_sets(h5, prefix)
    if control is not None and control.cause.shape == sets.loaded.shape:
        # the third column: the same (u, N) through the manifold law (condition 5)
        con, _, _ = study.control_fractions(sets, control)
        ax.semilogx(sets.parameter, con, "^-", color="C2",
                    label="manifold law on its manifold (control, count)")
    if sets.manifold_excess is not None and np.isfinite(sets.manifold_excess).all():
        # where the unclipped construction leaves +-mu N the manifold follows the limit
        n_l = np.maximum(sets.loaded.sum(axis=1), 1)
        ax.semilogx(sets.parameter, (sets.clipped & sets.loaded).sum(axis=1) / n_l, "v:",
                    color="0.4", label="manifold held at +-mu N somewhere (count)")
    ax.set_ylim(-0.05, 1.05)
    ax.set_xlabel(sets.parameter_name)
    ax.set_ylabel(f"share of loaded elements (tol {tol:g})")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    p = outdir / "manifold_fraction.png"
    fig.savefig(p, dpi=130)
    plt.close(fig)
    return p



def _element_loops(plt, h5, prefix, sets, x, xs, units, outdir) -> Path | None:
    """Loops of three chosen elements at the largest amplitude, in 3D on their
    manifolds (the heaviest, the worst and the outermost); None without a loaded one."""
    n_sets, ne = sets.dev_manifold.shape
    from .plots import _loop_axes
    law = law_from_file(h5, n_elements=ne)
    i = n_sets - 1
    mg = h5[f"{prefix}/masing" if prefix else "masing"]
    loaded = np.nonzero(sets.loaded[i])[0]
    if loaded.size:
        worst = int(loaded[np.argmax(sets.dev_manifold[i, loaded])])
        heaviest = int(loaded[np.argmax(sets.N[i, loaded].mean(axis=1))])
        edge = int(loaded[np.argmax(np.abs(x[loaded]))])
        chosen = list(dict.fromkeys([heaviest, worst, edge]))
        fig = plt.figure(figsize=(11, 4.2 * len(chosen)))
        for r, e in enumerate(chosen):
            ax3 = fig.add_subplot(len(chosen), 2, 2 * r + 1, projection="3d")
            ax2 = fig.add_subplot(len(chosen), 2, 2 * r + 2)
            _loop_axes(ax3, ax2, sets.u[i, e], sets.f[i, e], sets.N[i, e],
                       mg["f_manifold"][i, e], mg["f_masing"][i, e], law, e, units,
                       title=f"element {e} (x = {xs[e]:.1f}), {sets.parameter_name} "
                             f"{sets.parameter[i]:.3g}")
            ax2.set_title(f"dev_manifold = {sets.dev_manifold[i, e]:.2e}, dev_masing = "
                          f"{sets.dev_masing[i, e]:.2e}", fontsize=9)
            if r == 0:
                ax2.legend(fontsize=7, loc="upper left")
        fig.tight_layout()
        p = outdir / "element_loops.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        return p
    return None


def study_section(h5) -> str:
    return study.study_text(h5)


def qsma_section(h5) -> str:
    return backbone_section(h5, "qsma", "QSMA")
