"""Figures of prescribed-motion runs and element loops (the seed's Fig. 3)."""
from __future__ import annotations

import logging
from pathlib import Path

import h5py

from ..io.hdf5 import open_result
import numpy as np

from .common import law_from_file, pyplot, quantity_label

log = logging.getLogger(__name__)


def manifold_surface(law, e: int, u_r: float, f_r: float, N_r: float, direction: float,
                     u_lim, N_lim, n: int = 40):
    """The Masing-manifold branch leaving reversal ``(u_r, f_r, N_r)``.

    ``f(u, N) = f_r N / N_r + 2 s f_bb(|u - u_r| / 2; N)`` with ``s`` the
    branch direction, clipped to ``+-mu N`` for laws that can slip (the
    manifold of :func:`jointsim.masing.check_loops`), on a grid of ``u`` and ``N``.

    Parameters
    ----------
    law : TangentialLaw
    e : int
        Element index.
    u_r, f_r, N_r : float
        Reversal point [m], [N], [N].
    direction : float
        +1 for the ascending branch, -1 for the descending one.
    u_lim, N_lim : (float, float)
        Grid ranges.

    Returns
    -------
    U, Nn, F : ndarray, shape (n, n)
    """
    U, Nn = np.meshgrid(np.linspace(*u_lim, n), np.linspace(*N_lim, n))
    one = law.subset([e])
    half = 0.5 * np.abs(U - u_r)
    bb = one.backbone(half.reshape(1, -1), Nn.reshape(1, -1)).reshape(U.shape)
    ref = f_r * Nn / N_r if N_r > 0 else 0.0 * Nn
    F = ref + 2.0 * direction * bb
    if law.can_slip:  # seed Eq. 7, second case: the branch follows +-mu N (issue 14)
        lim = one.slip_force(Nn.reshape(1, -1)).reshape(U.shape)
        F = np.clip(F, -lim, lim)
    return U, Nn, F


def _loop_axes(ax3, ax2, u, f, N, fman, fmas, law, e, units, title=""):
    """Draw one element loop: 3D with manifold surfaces, and the (u, f) projection."""
    imax, imin = int(np.argmax(u)), int(np.argmin(u))
    N_lo, N_hi = float(N.min()), float(N.max())
    if N_hi - N_lo < 1e-12 * max(abs(N_hi), 1.0):
        pad = 0.2 * max(abs(N_hi), 1.0)
        N_lo, N_hi = N_lo - pad, N_hi + pad
    u_lim = (float(u.min()), float(u.max()))
    for i_r, s, color in ((imax, -1.0, "tab:blue"), (imin, 1.0, "tab:orange")):
        U, Nn, F = manifold_surface(law, e, u[i_r], f[i_r], N[i_r], s, u_lim,
                                    (max(N_lo, 0.0), N_hi))
        ax3.plot_surface(U, Nn, F, color=color, alpha=0.25, linewidth=0, shade=False)
    ax3.plot(u, N, f, color="k", lw=1.8, label="loop")
    ax3.plot(u, np.full_like(N, max(N_lo, 0.0)), f, color="0.4", lw=0.8,
             label="projection")
    ax3.set_xlabel(quantity_label("u_t", "displacement", units))
    ax3.set_ylabel(quantity_label("N", "force", units))
    ax3.set_zlabel(quantity_label("f_t", "force", units))
    ax3.set_title(title, fontsize=9)
    ax2.plot(u, f, "k-", lw=1.8, label="loop")
    ax2.plot(u, fman, "--", color="tab:green", lw=1.2, label="manifold prediction")
    ax2.plot(u, fmas, ":", color="tab:red", lw=1.4, label="classical Masing (mean N)")
    ax2.set_xlabel(quantity_label("u_t", "displacement", units))
    ax2.set_ylabel(quantity_label("f_t", "force", units))
    ax2.ticklabel_format(axis="both", style="sci", scilimits=(-3, 4))
    ax2.grid(alpha=0.3)


def _read_loop(h5, point: int, e: int):
    g, m = h5["loops"], h5["masing"]
    return (g["u"][point, e], g["f"][point, e], g["N"][point, e],
            m["f_manifold"][point, e], m["f_masing"][point, e],
            float(m["dev_manifold"][point, e]), float(m["dev_masing"][point, e]))


def plot_prescribed(h5: h5py.File, outdir: Path) -> list[Path]:
    """Seed Fig. 3 for one prescribed-motion run: 3D loop on its manifold + projection."""
    if not all(k in h5 for k in ("loops/u", "masing/dev_manifold")) \
            or h5["loops/u"].shape[0] == 0:
        return []  # a run interrupted before its loop was stored
    plt = pyplot()
    law = law_from_file(h5, n_elements=1)
    units = h5.attrs.get("units", "SI")
    u, f, N, fman, fmas, dman, dmas = _read_loop(h5, 0, 0)
    fig = plt.figure(figsize=(11, 4.6))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)
    reversal = h5["prescribed"].attrs.get("reversal", "")
    _loop_axes(ax3, ax2, u, f, N, fman, fmas, law, 0, units,
               title=f"{Path(h5.attrs['scene_path']).stem} ({reversal})")
    ax2.set_title(f"dev_manifold = {dman:.2e}, dev_masing = {dmas:.2e}", fontsize=9)
    ax2.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    path = outdir / "loop_manifold.png"
    fig.savefig(path, dpi=130)
    plt.close(fig)

    # the time histories, to see what drives the loop
    g = h5["prescribed"]
    t = g["t"][()]
    fig, axes = plt.subplots(3, 1, figsize=(8, 6), sharex=True)
    for ax, name, lab, q in zip(axes, ("u_t", "N", "f"), ("u_t", "N", "f_t"),
                                ("displacement", "force", "force")):
        ax.plot(t, g[name][0], lw=1)
        ax.set_ylabel(quantity_label(lab, q, units))
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel(quantity_label("t", "time", units))
    fig.tight_layout()
    path2 = outdir / "time_history.png"
    fig.savefig(path2, dpi=110)
    plt.close(fig)
    return [path, path2]


def fig3_grid(results, path: Path) -> Path:
    """Several prescribed runs side by side (rows), as in the seed's Fig. 3."""
    plt = pyplot()
    n = len(results)
    fig = plt.figure(figsize=(10.5, 3.9 * n))
    for row, res in enumerate(results):
        with open_result(res) as h5:
            law = law_from_file(h5, n_elements=1)
            units = h5.attrs.get("units", "SI")
            u, f, N, fman, fmas, dman, dmas = _read_loop(h5, 0, 0)
            ax3 = fig.add_subplot(n, 2, 2 * row + 1, projection="3d")
            ax2 = fig.add_subplot(n, 2, 2 * row + 2)
            name = Path(h5.attrs["scene_path"]).stem
            reversal = h5["prescribed"].attrs.get("reversal", "")
            _loop_axes(ax3, ax2, u, f, N, fman, fmas, law, 0, units,
                       title=f"({chr(97 + 2 * row)}) {name}, {reversal} reversal")
            ax2.set_title(f"({chr(98 + 2 * row)}) dev_manifold = {dman:.1e}, "
                          f"dev_masing = {dmas:.1e}", fontsize=9)
            if row == 0:
                ax2.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
