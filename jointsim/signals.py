"""Sampling of scene :class:`~jointsim.scene.Signal` inputs.

Their harmonic coefficients are in :mod:`jointsim.harmonics`
(:func:`~jointsim.harmonics.harmonic_coefficients`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np


def read_signal_file(path: Path):
    """Read a two-column text file (time [s], value) covering one period.

    Columns are separated by commas or whitespace (``t, value`` or ``t value``);
    ``#`` starts a comment, and a first line that is not numbers (a header such
    as ``t,N``) is skipped.

    Returns
    -------
    t, v : ndarray, shape (n,)

    Raises
    ------
    ValueError
        Naming the file and the line, when it cannot be read as two columns of
        numbers, has fewer than two rows, a time column that does not increase
        or non-finite values.
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path}: is a directory, not a two-column text file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: is not a text file") from None
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = [p for p in line.replace(",", " ").replace(";", " ").split()]
        try:
            values = [float(p) for p in parts]
        except ValueError:
            if not rows and not any(_is_number(p) for p in parts):
                continue  # a header line such as "t,N"
            raise ValueError(f"{path}: line {lineno} is not two numbers: {line!r}") from None
        if len(values) != 2:
            raise ValueError(f"{path}: line {lineno} has {len(values)} columns, expected two "
                             f"(t, value)")
        rows.append(values)
    data = np.array(rows, dtype=float).reshape(-1, 2)
    if data.shape[0] < 2:
        raise ValueError(f"{path}: expected two columns (t, value) and at least two rows")
    if not np.all(np.isfinite(data)):
        raise ValueError(f"{path}: contains non-finite values")
    t, v = data[:, 0], data[:, 1]
    if np.any(np.diff(t) <= 0):
        raise ValueError(f"{path}: the time column must increase strictly")
    return t, v


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


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
