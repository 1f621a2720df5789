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


#: The per-point error indicators of /hbm and /epmc: dataset name -> (attribute of
#: :class:`~jointsim.solvers.indicators.ErrorIndicators`, doc, analyses).
ERROR_DATASETS = {
    "error_estimate": ("estimate", "estimated relative error of the retained harmonic "
                       "coefficients against a converged (larger H and n_samples) solution: "
                       "error_truncation + error_aliasing (jointsim.solvers.indicators)",
                       ("hbm", "epmc")),
    "error_truncation": ("truncation", "estimated relative error of the retained harmonics "
                         "from the contact-force harmonics above H (one linearised step of "
                         "the harmonic balance extended to about 2 max(H) + 1)", ("hbm", "epmc")),
    "error_aliasing": ("aliasing", "estimated relative error of the retained harmonics from "
                       "the AFT samples n_samples (change when the laws are sampled 4 times "
                       "finer, the force spectrum that folds back)", ("hbm", "epmc")),
    "error_force_tail": ("force_tail", "contact-force harmonics above H (up to the extended "
                         "set) against the retained ones h >= 1, ratio of norms", ("hbm", "epmc")),
    "error_curve": ("curve", "estimated relative error of the retained harmonic coefficients "
                    "across the branch: against the extended (converged) branch's nearest point, "
                    "not at the same frequency (the FRC's steep flanks and folds); solved where "
                    "error_estimate exceeds the scene's error_tol, else equal to it "
                    "(jointsim.solvers.indicators.ErrorEstimator._across)", ("hbm",)),
    "error_curve_frequency": ("curve_frequency", "|d omega| / omega from the point to that "
                              "nearest point of the extended branch (0 where error_curve is "
                              "error_estimate)", ("hbm",)),
    "error_frequency": ("frequency", "estimated relative error of the frequency (truncation "
                        "+ aliasing): its change in a Newton solve of the extended EPMC "
                        "system (jointsim.solvers.indicators)", ("epmc",)),
    "error_damping": ("damping", "estimated relative error of the damping ratio (truncation "
                      "+ aliasing): its change in a Newton solve of the extended EPMC "
                      "system (jointsim.solvers.indicators)", ("epmc",)),
}


def write_error_indicators(writer, prefix: str, point: int, ind) -> None:
    """Append the error indicators of point ``point`` to ``/<prefix>/error_*``.

    Call inside the point's ``writer.commit()`` so that they are committed with
    the point.  A dataset missing rows of earlier points (a file resumed from
    an older jointsim) is padded with NaN first, so rows stay aligned.

    Parameters
    ----------
    writer : jointsim.io.hdf5.ResultWriter
    prefix : {'hbm', 'epmc'}
    point : int
        Row of the point (``writer.rows(prefix + '/omega')`` before it was appended).
    ind : jointsim.solvers.indicators.ErrorIndicators or None
        None (not computed) writes NaN.
    """
    for name, (attr, doc, where) in ERROR_DATASETS.items():
        if prefix not in where:
            continue
        path = f"{prefix}/{name}"
        have = writer.rows(path)
        if have < point:
            writer.append_rows(path, np.full(point - have, np.nan), "1", doc)
        value = np.nan if ind is None else float(getattr(ind, attr))
        writer.append(path, value, "1", doc)


def read_error_indicators(h5, prefix: str) -> dict:
    """The ``error_*`` datasets of ``/<prefix>`` (``{name: ndarray}``, empty without them).

    Parameters
    ----------
    h5 : h5py.File or h5py.Group
    prefix : {'hbm', 'epmc'}
    """
    if prefix not in h5:
        return {}
    return {k: h5[prefix][k][()] for k in h5[prefix] if k.startswith("error_")
            and hasattr(h5[prefix][k], "shape") and len(h5[prefix][k].shape) == 1}


def pad_error_indicators(writer, prefix: str) -> None:
    """Pad ``/<prefix>/error_*`` with NaN up to the points stored (a file from before
    the indicators), so that every stored point has its rows.  Call inside a commit."""
    n = writer.rows(f"{prefix}/omega")
    for name, (_, doc, where) in ERROR_DATASETS.items():
        have = writer.rows(f"{prefix}/{name}")
        if prefix in where and have < n:
            writer.append_rows(f"{prefix}/{name}", np.full(n - have, np.nan), "1", doc)


def set_error_indicators(writer, prefix: str, point: int, ind) -> None:
    """Write the error indicators of stored point ``point`` into its rows of
    ``/<prefix>/error_*`` (computed after the point was written, e.g. on a worker:
    :mod:`jointsim.analyses.indicator_pool`).  Call inside a ``writer.commit()``.

    Parameters
    ----------
    writer : jointsim.io.hdf5.ResultWriter
    prefix : {'hbm', 'epmc'}
    point : int
        Row of the point; its ``error_*`` rows exist (written NaN with the point).
    ind : jointsim.solvers.indicators.ErrorIndicators or None
        None (not computed) writes NaN.
    """
    for name, (attr, doc, where) in ERROR_DATASETS.items():
        if prefix in where:
            value = np.nan if ind is None else float(getattr(ind, attr))
            writer.set_row(f"{prefix}/{name}", int(point), value)


def missing_error_indicators(h5, prefix: str) -> np.ndarray:
    """Rows of ``/<prefix>`` points whose error indicators are not computed (NaN
    ``error_estimate``, or rows it lacks), in row order.

    A point whose estimate failed (:func:`~jointsim.solvers.indicators.safe_indicators`)
    is NaN as well: it is counted here too.

    Parameters
    ----------
    h5 : h5py.File or h5py.Group
    prefix : {'hbm', 'epmc'}

    Returns
    -------
    ndarray of int64
    """
    n = h5[f"{prefix}/omega"].shape[0] if f"{prefix}/omega" in h5 else 0
    path = f"{prefix}/error_estimate"
    est = h5[path][()] if path in h5 else np.zeros(0)
    est = np.concatenate([est[:n], np.full(max(n - est.shape[0], 0), np.nan)])
    return np.flatnonzero(np.isnan(est)).astype(np.int64)
