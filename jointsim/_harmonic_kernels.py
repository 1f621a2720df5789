"""Numba kernels of the harmonic basis: products of a sampled tangent with the DFT.

:func:`add_diag_products` adds ``P diag(alpha) Gam`` to per-element blocks from
the Fourier sums of ``alpha``, so that no ``n_c x n_t x n_c`` product is formed
per element (used by :class:`jointsim.harmonics.HarmonicBasis`).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

#: Elements from which the products run in parallel threads ...
PARALLEL_MIN = 64
#: ... and work (elements x coefficients^2) from which they do: on a 2-core machine
#: shared with other jobs (load 13) 121 elements x 31^2 took 1.4 ms on one thread
#: against 23 ms threaded (the barrier waits for a descheduled thread).
PARALLEL_MIN_WORK = 4_000_000


@njit(cache=True)
def _diag_one(e, J, Ac, As, hk, sk, wk):
    nc = hk.shape[0]
    for kk in range(nc):
        hK = hk[kk]
        for j in range(nc):
            hJ = hk[j]
            dm = hK - hJ
            sgn = 1.0
            if dm < 0:
                dm = -dm
                sgn = -1.0
            sm = hK + hJ
            if sk[kk] == 0 and sk[j] == 0:
                v = 0.5 * (Ac[e, dm] + Ac[e, sm])
            elif sk[kk] == 1 and sk[j] == 1:
                v = 0.5 * (Ac[e, dm] - Ac[e, sm])
            elif sk[kk] == 0:
                # cos(hK) sin(hJ) = (sin(hK + hJ) - sin(hK - hJ)) / 2
                v = 0.5 * (As[e, sm] - sgn * As[e, dm])
            else:
                # sin(hK) cos(hJ) = (sin(hK + hJ) + sin(hK - hJ)) / 2
                v = 0.5 * (As[e, sm] + sgn * As[e, dm])
            J[e, kk, j] += wk[kk] * v


@njit(cache=True)
def _diag_serial(J, Ac, As, hk, sk, wk):
    for e in range(J.shape[0]):
        _diag_one(e, J, Ac, As, hk, sk, wk)


@njit(cache=True, parallel=True)
def _diag_parallel(J, Ac, As, hk, sk, wk):
    for e in prange(J.shape[0]):
        # prange's index is uint64: cast, so the element kernel keeps the one
        # compiled signature of the serial driver (a second costs 1 to 15 s cold)
        _diag_one(np.int64(e), J, Ac, As, hk, sk, wk)


def add_diag_products(J, Ac, As, hk, sk, wk, parallel=True):
    """Add ``P diag(alpha) Gam`` to per-element blocks from Fourier sums of alpha.

    With ``Ac[e, m] = sum_t alpha[e, t] cos(m theta_t)`` and ``As`` the sine
    sums (``m = 0 .. 2 max(h)``), product-to-sum identities give every entry
    exactly (aliasing included, since the sums are over the same samples).

    Parameters
    ----------
    J : ndarray, shape (n_e, n_c, n_c)
        Blocks, updated in place.
    Ac, As : ndarray, shape (n_e, 2 max(h) + 1)
    hk : ndarray of int, shape (n_c,)
        Harmonic of each coefficient.
    sk : ndarray of int, shape (n_c,)
        1 for a sine coefficient, 0 for cosine (and the constant).
    wk : ndarray, shape (n_c,)
        DFT weight of each coefficient (``1/n_t`` for h = 0, else ``2/n_t``).
    parallel : bool
        Allow numba threads (from ``PARALLEL_MIN`` elements and
        ``PARALLEL_MIN_WORK``); False keeps the
        products on the calling thread (e.g. in a worker process).
    """
    threaded = parallel and J.shape[0] >= PARALLEL_MIN \
        and J.shape[0] * J.shape[1] * J.shape[2] >= PARALLEL_MIN_WORK
    run = _diag_parallel if threaded else _diag_serial
    run(J, np.ascontiguousarray(Ac), np.ascontiguousarray(As), hk, sk, wk)
