"""The analyses of a scene: one runner per analysis, in one explicit ordered table.

The runners are the only code that writes result groups and runs the Masing
check.  Each is called as ``runner(scene, model, writer, results)`` where
``results`` maps the names of the analyses already run to their result
objects (later analyses take earlier results in memory: the transient
cross-check uses the HBM runner's
:class:`~jointsim.solvers.crosscheck.HBMSolutions`, never the file); the
runner returns its own result object.

Prescribed-motion scenes have no structural model; their one runner is
:func:`jointsim.analyses.prescribed.run_prescribed_scene`.
"""
from __future__ import annotations

from typing import Callable

from .epmc import run_epmc_analysis
from .hbm import run_hbm_analysis
from .modes import run_modes, write_model_tables
from .prescribed import run_prescribed_scene
from .qsma import run_qsma_analysis
from .transient import run_transient

#: analysis name -> runner(scene, model, writer, results), in the order they run
#: when the scene declares them.
ANALYSES: dict[str, Callable] = {
    "modes": run_modes,
    "qsma": run_qsma_analysis,
    "epmc": run_epmc_analysis,
    "hbm": run_hbm_analysis,
    "transient": run_transient,
}

#: the order in which analyses run when present
ORDER = tuple(ANALYSES)

__all__ = ["ANALYSES", "ORDER", "run_prescribed_scene", "write_model_tables"]
