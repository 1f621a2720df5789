"""Helpers of the hard-case suite (not collected)."""
from __future__ import annotations

import h5py
import numpy as np


def non_finite_datasets(path) -> list[str]:
    """Names of the numeric datasets and attributes of a result file holding NaN or Inf.

    Every numeric dataset of every group is read.  Exempt: ``+inf`` in the
    Masing margins (``*/masing/*_margin``), which :mod:`jointsim.masing`
    documents as "no interval checked".
    """
    bad = []

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset) and obj.dtype.kind in "fciu":
            v = obj[()]
            if "masing/" in name and name.endswith("_margin"):
                # documented: +inf where no interval of the loop was checked
                v = np.where(np.isposinf(v), 0.0, v)
            if not np.all(np.isfinite(v)):
                bad.append(name)

    with h5py.File(path, "r") as h:
        h.visititems(visit)
    return bad


def assert_all_finite(path, allow=()) -> None:
    """No NaN or Inf in any numeric dataset of the file (``allow``: names exempt)."""
    bad = [b for b in non_finite_datasets(path) if b not in allow]
    assert not bad, f"non-finite values in {path}: {bad}"
