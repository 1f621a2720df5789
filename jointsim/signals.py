"""Sampling of scene :class:`~jointsim.scene.Signal` inputs.

Their harmonic coefficients are in :mod:`jointsim.harmonics`
(:func:`~jointsim.harmonics.harmonic_coefficients`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np


def read_signal_file(path: Path):
    """Read a two-column text file (time [s], value) covering one period.

    Returns
    -------
    t, v : ndarray, shape (n,)
    """
    data = np.loadtxt(path, delimiter=None, ndmin=2, comments="#")
    if data.shape[1] != 2 or data.shape[0] < 2:
        raise ValueError(f"{path}: expected two columns (t, value) and at least two rows")
    t, v = data[:, 0], data[:, 1]
    if np.any(np.diff(t) <= 0):
        raise ValueError(f"{path}: the time column must increase strictly")
    if not np.all(np.isfinite(data)):
        raise ValueError(f"{path}: contains non-finite values")
    return t, v


def sample(signal, t, omega: float, base_dir: Path | None = None) -> np.ndarray:
    """Evaluate a signal at times ``t``.

    Parameters
    ----------
    signal : jointsim.scene.Signal
    t : ndarray
        Times [s].
    omega : float
        Base angular frequency [rad/s].
    base_dir : Path, optional
        Folder that ``signal.file`` is relative to.

    Returns
    -------
    ndarray, same shape as ``t``
    """
    t = np.asarray(t, dtype=float)
    if signal.file is not None:
        tf, vf = read_signal_file((base_dir or Path(".")) / signal.file)
        period = 2.0 * np.pi / omega
        out = np.interp(np.mod(t, period), tf, vf, period=period)
    else:
        out = np.full(t.shape, signal.constant)
        for h in signal.harmonics:
            out = out + h.cos * np.cos(h.h * omega * t) + h.sin * np.sin(h.h * omega * t)
    if signal.clip_at_zero:
        out = np.maximum(out, 0.0)
    return out
