"""Read the harmonic-balance solution points back from a result file.

The solvers never read files: the HBM runner hands its points to later
analyses in memory (:class:`~jointsim.solvers.crosscheck.HBMSolutions`).
:func:`read_hbm_solutions` gives the same object from the ``/hbm`` group of a
finished file, for a cross-check run after the fact and for tests.
"""
from __future__ import annotations

import numpy as np

from ..solvers.crosscheck import HBMSolutions


def read_hbm_solutions(h5) -> HBMSolutions | None:
    """The points stored in the ``/hbm`` group of a result file (None without them).

    Uses ``/hbm/omega``, ``/hbm/X``, ``/hbm/harmonics`` and, when present,
    ``/hbm/q``, ``/hbm/branch``, ``/hbm/force_scale`` and the ``n_samples``
    attribute of ``/hbm`` (DESIGN §4 paths).

    Parameters
    ----------
    h5 : h5py.File or h5py.Group
        An open result file (or the root group of one).

    Returns
    -------
    HBMSolutions or None
    """
    if "hbm/omega" not in h5 or "hbm/X" not in h5:
        return None

    def opt(name):
        return h5[name][()] if name in h5 else None

    n_samples = h5["hbm"].attrs.get("n_samples")
    return HBMSolutions(omega=h5["hbm/omega"][()], X=h5["hbm/X"][()],
                        harmonics=tuple(int(h) for h in h5["hbm/harmonics"][()]),
                        n_samples=None if n_samples is None else int(n_samples),
                        q=opt("hbm/q"), branch=opt("hbm/branch"),
                        force_scale=None if "hbm/force_scale" not in h5
                        else np.atleast_1d(h5["hbm/force_scale"][()]))
