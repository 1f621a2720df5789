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

import importlib
from typing import Callable


class _Runner:
    """A runner named by module and function, imported at its first call.

    A scene with one analysis then imports only that analysis' modules (and
    their solvers), not those of the others: part of the start-up cut
    (issue 15, item 11).  Called exactly like the function it names.
    """

    def __init__(self, module: str, name: str):
        self.module, self.name = module, name
        self._fn: Callable | None = None

    def resolve(self) -> Callable:
        """The runner function itself (imports its module on first use)."""
        if self._fn is None:
            self._fn = getattr(importlib.import_module(self.module, __name__), self.name)
        return self._fn

    def __call__(self, *args, **kwargs):
        return self.resolve()(*args, **kwargs)

    def __repr__(self) -> str:
        return f"<analysis runner {self.module}.{self.name}>"


#: analysis name -> runner(scene, model, writer, results), in the order they run
#: when the scene declares them.
ANALYSES: dict[str, Callable] = {
    "modes": _Runner(".modes", "run_modes"),
    "qsma": _Runner(".qsma", "run_qsma_analysis"),
    "epmc": _Runner(".epmc", "run_epmc_analysis"),
    "hbm": _Runner(".hbm", "run_hbm_analysis"),
    "transient": _Runner(".transient", "run_transient"),
}

#: the order in which analyses run when present
ORDER = tuple(ANALYSES)

_LAZY = {"run_prescribed_scene": (".prescribed", "run_prescribed_scene"),
         "write_model_tables": (".modes", "write_model_tables")}


def __getattr__(name: str):
    """``run_prescribed_scene`` and ``write_model_tables``, imported on first use."""
    if name in _LAZY:
        return _Runner(*_LAZY[name]).resolve()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["ANALYSES", "ORDER", "run_prescribed_scene", "write_model_tables"]
