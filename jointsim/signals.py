"""Sampling of scene :class:`~jointsim.scene.Signal` inputs."""
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


def harmonic_coefficients(signal, harmonics) -> np.ndarray:
    """Coefficients of a signal in the order ``[0, 1c, 1s, ...]`` of ``harmonics``.

    Only for signals given by harmonics (not files, not clipped).

    Parameters
    ----------
    signal : jointsim.scene.Signal
    harmonics : sequence of int
        Harmonics kept, e.g. ``(0, 1, 3)``.

    Returns
    -------
    ndarray, shape (n_coeff,)
        One entry for harmonic 0, two (cos, sin) for every other.
    """
    if signal.file is not None or signal.clip_at_zero:
        raise NotImplementedError("harmonic coefficients of a file or clipped signal: "
                                  "sample it and take its DFT instead")
    coeff = []
    for h in harmonics:
        if h == 0:
            coeff.append(signal.constant)
        else:
            c = sum(x.cos for x in signal.harmonics if x.h == h)
            s = sum(x.sin for x in signal.harmonics if x.h == h)
            coeff.extend([c, s])
    missing = {x.h for x in signal.harmonics} - set(harmonics)
    if missing:
        raise ValueError(f"signal has harmonics {sorted(missing)} outside the kept set")
    return np.asarray(coeff, dtype=float)


def coefficient_harmonics(harmonics) -> np.ndarray:
    """Harmonic number of each coefficient in the order ``[0, 1c, 1s, ...]``.

    Parameters
    ----------
    harmonics : sequence of int
        Harmonics kept, e.g. ``(0, 1, 3)``.

    Returns
    -------
    ndarray of int, shape (n_coeff,)
        ``(0, 1, 1, 3, 3)`` for the example.
    """
    return np.array([h for h in harmonics for _ in range(1 if h == 0 else 2)], dtype=np.int64)
