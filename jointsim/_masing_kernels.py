"""Numba kernel of the Masing memory rule (reversal stack) over loop samples.

Only the governing reversal of every sample is found here; the predictions
built on it (the manifold construction clipped to ``+-mu N``, seed Eq. 7, and
the unclipped classical Masing curve) are vectorised over the samples in
:func:`jointsim.masing.check_loops`.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _references_one(u, ref, branch):
    """Reference reversal of every sample of one period (see :func:`references`)."""
    n = u.shape[0]
    stack = np.empty(n + 2, dtype=np.int64)
    imin = 0
    for k in range(n):
        if u[k] < u[imin]:
            imin = k
    # the period starts at the global maximum (index 0 after rolling); the
    # reversal before it is the global minimum, taken periodically
    stack[0] = imin
    stack[1] = 0
    top = 2
    d = -1.0
    ref[0] = 0
    branch[0] = 0.0
    for k in range(1, n):
        du = u[k] - u[k - 1]
        if du != 0.0:
            s = 1.0 if du > 0.0 else -1.0
            if s != d:
                stack[top] = k - 1
                top += 1
                d = s
            # Masing's third rule: an inner loop closes when u passes the
            # reversal before the current one; pop both and carry on along
            # the older branch.  The two outer reversals stay.
            while top > 3:
                prev = stack[top - 2]
                if (d > 0.0 and u[k] > u[prev]) or (d < 0.0 and u[k] < u[prev]):
                    top -= 2
                else:
                    break
        ref[k] = stack[top - 1]
        branch[k] = d


@njit(cache=True)
def references(u):
    """Masing reference reversal of each sample, with the memory rule.

    Parameters
    ----------
    u : ndarray, shape (n_e, n)
        Tangential displacement over one period, each row rolled so that
        sample 0 is the row's global maximum.

    Returns
    -------
    ref : ndarray of int64, shape (n_e, n)
        Index of the reversal whose branch governs each sample.
    branch : ndarray, shape (n_e, n)
        Direction of motion at each sample (+1 up, -1 down).
    """
    ne, n = u.shape
    ref = np.empty((ne, n), dtype=np.int64)
    branch = np.empty((ne, n))
    for e in range(ne):
        _references_one(u[e], ref[e], branch[e])
    return ref, branch
