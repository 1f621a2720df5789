"""A straight test branch for the continuation stepper's rules."""
import numpy as np

from jointsim.solvers.continuation import Continuation


def _line(y):
    """``R = z - lam``: a straight branch."""
    return np.array([y[0] - y[1]]), np.array([[1.0, -1.0]]), None


def line_continuation(**options) -> Continuation:
    """A :class:`Continuation` from ``(z, lam) = (0, 0)`` towards ``lam = 10`` along
    ``z = lam`` (step 0.1, step_max 0.5, at most 50 points; ``options`` go to it)."""
    return Continuation(_line, np.zeros(2), 10.0, scale=np.ones(2), rscale=1.0, step=0.1,
                        step_min=1e-6, step_max=0.5, max_points=50, tol=1e-12, **options)
