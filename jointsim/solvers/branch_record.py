"""The records of a continued branch: one accepted point (:class:`PointInfo`) and the
whole branch (:class:`Branch`), as :class:`jointsim.solvers.continuation.Continuation`
returns them."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..results import Convergence


@dataclass
class PointInfo:
    """Bookkeeping of one accepted point.

    Attributes
    ----------
    iterations : int
        Newton iterations of its corrector.
    residual : float
        ``max|R| / rscale`` at the point.
    step : float
        Scaled arclength step that led to it (0 for the first point).
    tangent : ndarray, shape (n + 1,)
        Unit tangent at the point (scaled variables).
    extra : object
        What the residual function returned besides ``R`` and ``J``.
    z_scale : float
        Largest ``z`` scale to continue from the point with (``adapt_scale``;
        ``tangent`` is scaled by it).  A resumed branch starts with it.
    """

    iterations: int
    residual: float
    step: float
    tangent: np.ndarray
    extra: object = None
    z_scale: float = 0.0


@dataclass
class Branch:
    """A continued branch.

    Attributes
    ----------
    y : ndarray, shape (n_points, n + 1)
        Accepted points (unscaled), ``lam`` last.
    iterations, residual, step : ndarray, shape (n_points,)
    convergence : jointsim.results.Convergence
        ``iterations`` counts accepted points.
    """

    y: np.ndarray
    iterations: np.ndarray
    residual: np.ndarray
    step: np.ndarray
    convergence: Convergence
    tangents: list = field(default_factory=list, repr=False)
