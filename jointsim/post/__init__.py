"""Post-processing of result files: figures and tables.

Plot modules import matplotlib lazily (only when figures are made), with the
non-interactive Agg backend.  Each plotter looks at the groups present in a
result file and draws what applies; analyses add their plotters to
:data:`PLOTTERS`.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable

import h5py

log = logging.getLogger(__name__)

#: group name -> plotter(h5, outdir) -> list of written figure paths
PLOTTERS: dict[str, Callable] = {}


def figure_dir(result, outdir=None) -> Path:
    """Folder for a result file's figures (``<stem>_figures`` beside it by default)."""
    result = Path(result)
    d = Path(outdir) if outdir else result.with_name(result.stem + "_figures")
    d.mkdir(parents=True, exist_ok=True)
    return d


def _register() -> None:
    from .._plugins import import_available
    from . import plots  # noqa: F401  (registers the built-in plotters)
    import_available(("jointsim.post.fe_plots", "jointsim.post.hbm_plots",
                      "jointsim.post.transient_plots", "jointsim.post.study_plots"))


def make_figures(result, outdir=None) -> list[Path]:
    """Write every figure that applies to a result file.

    Parameters
    ----------
    result : str or Path
        Result file.
    outdir : str or Path, optional
        Figure folder.

    Returns
    -------
    list of Path
        The figure files written.
    """
    _register()
    d = figure_dir(result, outdir)
    written: list[Path] = []
    with h5py.File(result, "r") as h5:
        for group, plotter in PLOTTERS.items():
            if group in h5:
                written.extend(plotter(h5, d))
    if not written:
        log.warning("%s: nothing to plot", result)
    return written


def combined_figures(results, outdir=None) -> list[Path]:
    """Figures that compare several result files (e.g. the seed's Fig. 3 grid)."""
    _register()
    from .plots import fig3_grid
    files = [Path(r) for r in results]
    with_prescribed = []
    for f in files:
        with h5py.File(f, "r") as h5:
            if "prescribed" in h5:
                with_prescribed.append(f)
    out = []
    if len(with_prescribed) > 1:
        d = Path(outdir) if outdir else files[0].parent
        d.mkdir(parents=True, exist_ok=True)
        out.append(fig3_grid(with_prescribed, d / "fig3_grid.png"))
    return out
