"""Helpers of the hard-case suite (not collected)."""
from __future__ import annotations

import h5py
import numpy as np


def non_finite_datasets(path) -> list[str]:
    """Names of the numeric datasets and attributes of a result file holding NaN or Inf.

    Every dataset of every group is read; attributes too (a failed branch's
    peak is recorded as NaN on purpose: ``hbm/peak_*`` of branches that gave up
    are left to the caller).
    """
    bad = []

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset) and obj.dtype.kind in "fciu":
            v = obj[()]
            if not np.all(np.isfinite(v)):
                bad.append(name)

    with h5py.File(path, "r") as h:
        h.visititems(visit)
    return bad


def assert_all_finite(path, allow=()) -> None:
    """No NaN or Inf in any numeric dataset of the file (``allow``: names exempt)."""
    bad = [b for b in non_finite_datasets(path) if b not in allow]
    assert not bad, f"non-finite values in {path}: {bad}"
