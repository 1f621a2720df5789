"""Import optional modules that register themselves (solvers, plotters)."""
from __future__ import annotations

import importlib


def import_available(modules) -> None:
    """Import each module that exists; a missing one is skipped, other errors raise."""
    for mod in modules:
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as exc:
            if exc.name != mod:
                raise
