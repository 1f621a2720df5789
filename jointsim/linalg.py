"""Dense products shared by the FE reduction and the condensation; stacked inverses.

:func:`symmetric_congruence` forms ``V^T A V`` of a symmetric ``A`` by blocks of columns
(on one side of the diagonal, or on both and averaged), on threads of their own (each
product releases the GIL and runs on the one BLAS thread the entry points set,
:mod:`jointsim.blas`): the
Craig-Bampton projections (:meth:`jointsim.fem.reduction.CraigBampton.project`) and the
blocks of ``K`` and ``M`` in the condensation's coordinates
(:func:`jointsim.solvers.welded.welded_coordinates`).  :func:`stacked_inverse` inverts
the harmonic preconditioner's blocks (:mod:`jointsim.solvers.preconditioner`).
"""
from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor

import numpy as np

log = logging.getLogger(__name__)


def stacked_inverse(blocks) -> np.ndarray:
    """The inverses of the stacked ``blocks`` (n, m, m), in their precision; a singular
    block's pseudo-inverse (a preconditioner's: GMRES then has to cope)."""
    try:
        return np.linalg.inv(blocks)
    except np.linalg.LinAlgError:
        log.debug("a singular block: its pseudo-inverse is used")
        return np.linalg.pinv(blocks)


def symmetric_congruence(V, A, threads: int = 1, columns: int = 128,
                         both_sides: bool = False) -> np.ndarray:
    """``V^T A V`` of a symmetric ``A``, dense and symmetric.

    By blocks of ``columns`` columns, each formed only on and above the diagonal,
    ``out[:e, j:e] = V[:, :e]^T (A V[:, j:e])``, and mirrored: half the flops of the
    whole product, and no ``n x m`` temporary.  The diagonal blocks are symmetrised.
    With ``both_sides``, every block column is formed whole, ``out[:, j:e] = V^T (A
    V[:, j:e])``, and the result is ``(out + out^T) / 2``: the whole product's flops, and
    each pair of entries the mean of its two roundings.  An eigenvalue ``phi^T (V^T A V)
    phi`` sees the rounding errors of both triangles; the mirror counts the upper one
    twice, the mean each once: a standard deviation smaller by about ``sqrt(2)``
    (:mod:`jointsim.solvers.welded`, whose cancellations have a condition number of about
    1e11).  On ``threads`` threads the blocks are independent, and the result does not
    depend on how many there are.

    Parameters
    ----------
    V : ndarray, shape (n, m)
    A : ndarray or scipy.sparse matrix, shape (n, n)
        Symmetric (only ``A V`` is formed).
    threads : int
        Threads the blocks are shared among (largest first).
    columns : int
        Columns of each block.
    both_sides : bool
        Form the entries below the diagonal too, and average.

    Returns
    -------
    ndarray, shape (m, m)
    """
    m = V.shape[1]
    out = np.empty((m, m))

    def block(j):
        e = min(j + columns, m)
        if both_sides:
            out[:, j:e] = V.T @ (A @ V[:, j:e])
            return
        out[:e, j:e] = V[:, :e].T @ (A @ V[:, j:e])
        d = out[j:e, j:e]
        d[...] = 0.5 * (d + d.T)
        out[j:e, :j] = out[:j, j:e].T
    starts = range(0, m, columns)
    if threads > 1 and len(starts) > 1:
        with ThreadPoolExecutor(max_workers=threads) as pool:
            list(pool.map(block, starts[::-1]))       # the largest blocks first
    else:
        for j in starts:
            block(j)
    if both_sides:
        out += out.T
        out *= 0.5
    return out
