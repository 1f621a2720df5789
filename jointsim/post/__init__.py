"""Post-processing of result files: figures and tables.

Plot modules import matplotlib lazily (only when figures are made), with the
non-interactive Agg backend.  Each plotter looks at the groups present in a
result file and draws what applies; :func:`plotters` is the one ordered table
of group name -> plotter (``jointsim info``'s sections are
:func:`jointsim.post.tables.sections`).
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable


from ..io.hdf5 import open_result

log = logging.getLogger(__name__)

def figure_dir(result, outdir=None) -> Path:
    """Folder for a result file's figures (``<stem>_figures`` beside it by default)."""
    result = Path(result)
    d = Path(outdir) if outdir else result.with_name(result.stem + "_figures")
    d.mkdir(parents=True, exist_ok=True)
    return d


def plotters() -> dict[str, Callable]:
    """group name -> plotter(h5, outdir) -> list of written figure paths, in drawing order."""
    from . import fe_plots, hbm_plots, plots, study_plots, transient_plots
    return {
        "prescribed": plots.plot_prescribed,
        "static": fe_plots.pressure_plot,
        "modes": fe_plots.modes_figures,
        "hbm": hbm_plots.plot_frc,
        "epmc": hbm_plots.plot_epmc,
        "transient": transient_plots.plot_transient,
        "qsma": study_plots.plot_backbones,
        "contacts": study_plots.plot_masing_study,
    }


def make_figures(result, outdir=None, frequency: str = "Hz") -> list[Path]:
    """Write every figure that applies to a result file.

    Parameters
    ----------
    result : str or Path
        Result file.
    outdir : str or Path, optional
        Figure folder.
    frequency : {'Hz', 'rad/s'}
        Frequency axis of the FRC figures.

    Returns
    -------
    list of Path
        The figure files written.
    """
    d = figure_dir(result, outdir)
    written: list[Path] = []
    with open_result(result) as h5:
        for group, plotter in plotters().items():
            if group in h5:
                written.extend(plotter(h5, d, frequency=frequency) if group == "hbm"
                               else plotter(h5, d))
    if not written:
        log.warning("%s: nothing to plot", result)
    return written


def combined_figures(results, outdir=None) -> list[Path]:
    """Figures that compare several result files (e.g. the seed's Fig. 3 grid)."""
    from .plots import fig3_grid
    files = [Path(r) for r in results]
    with_prescribed = []
    for f in files:
        with open_result(f) as h5:
            if "prescribed" in h5:
                with_prescribed.append(f)
    out = []
    if len(with_prescribed) > 1:
        d = Path(outdir) if outdir else files[0].parent
        d.mkdir(parents=True, exist_ok=True)
        out.append(fig3_grid(with_prescribed, d / "fig3_grid.png"))
    return out
