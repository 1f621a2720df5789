"""Post-processing of result files: figures and tables.

Plot modules import matplotlib lazily (only when figures are made), with the
non-interactive Agg backend.  Each plotter looks at the groups present in a
result file and draws what applies; :func:`plotters` is the one ordered table
of group name -> plotter (``jointsim info``'s sections are
:func:`jointsim.post.tables.sections`).
"""
from __future__ import annotations

import logging
import os
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


#: The plotters that take most of a lap joint's figures (the element loops, deviation
#: map and shares of every kept set: 3.2 of 7.2 s on the default scene), drawn by a
#: forked process while this one draws the others (:func:`make_figures`).
HEAVY_PLOTTERS = ("contacts",)


def _draw_open(h5, d: Path, frequency: str, groups) -> dict[str, list[Path]]:
    """Run the plotters of ``groups`` on the open result ``h5``: group -> its figures."""
    table = plotters()
    return {g: table[g](h5, d, frequency=frequency) if g == "hbm" else table[g](h5, d)
            for g in groups}


def _draw(result, d: Path, frequency: str, groups) -> dict[str, list[Path]]:
    """:func:`_draw_open` on ``result``, opened here (in a forked process: its own handle)."""
    with open_result(result) as h5:
        return _draw_open(h5, d, frequency, groups)


def make_figures(result, outdir=None, frequency: str = "Hz", parallel: bool = True
                 ) -> list[Path]:
    """Write every figure that applies to a result file.

    With ``parallel`` (and a second core, and a platform that forks), the
    :data:`HEAVY_PLOTTERS` draw in a forked process beside the others: the main job's
    figures 7.2 -> about 4 s on 2 cores (docs/hbm.md, "Round 20").  The figures are
    the same either way; a plotter's error is raised here either way.

    Parameters
    ----------
    result : str or Path
        Result file.
    outdir : str or Path, optional
        Figure folder.
    frequency : {'Hz', 'rad/s'}
        Frequency axis of the FRC figures.
    parallel : bool
        Draw the heavy plotters in a forked process.

    Returns
    -------
    list of Path
        The figure files written, in the order of :func:`plotters`.
    """
    from ..analyses.forking import _can_fork, _in_daemon

    d = figure_dir(result, outdir)
    with open_result(result) as h5:
        groups = [g for g in plotters() if g in h5]
        heavy = [g for g in groups if g in HEAVY_PLOTTERS]
        light = [g for g in groups if g not in HEAVY_PLOTTERS]
        fork = parallel and bool(heavy and light) and (os.cpu_count() or 1) > 1 \
            and _can_fork() and not _in_daemon("figures")
        if not fork:
            drawn = _draw_open(h5, d, frequency, groups)
    if fork:   # forked with no file open: each process opens its own handle
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor
        log.debug("figures: %s in a forked process, %s here", ", ".join(heavy),
                  ", ".join(light))
        # a worker that dies raises BrokenProcessPool here (a Pool would wait forever)
        with ProcessPoolExecutor(1, mp_context=mp.get_context("fork")) as pool:
            pending = pool.submit(_draw, result, d, frequency, heavy)
            drawn = _draw(result, d, frequency, light)
            drawn.update(pending.result())
    written = [f for g in groups for f in drawn[g]]
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
