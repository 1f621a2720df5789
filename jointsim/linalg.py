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

import functools
import logging
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.linalg as sla

log = logging.getLogger(__name__)


def stacked_inverse(blocks, in_double: bool = False) -> np.ndarray:
    """The inverses of the stacked ``blocks`` (n, m, m) (or of one block, (m, m)), in
    their precision; a singular block's pseudo-inverse (a preconditioner's: GMRES then
    has to cope).

    Single precision (float32, complex64) is inverted by SciPy's LAPACK (``getrf`` and
    ``getri``) block by block, or with ``in_double`` in double and rounded.  NumPy 2.4's
    ``linalg.inv`` does the latter for every single-precision input (measured round 48:
    a complex64 block of 960 rows 0.134 s, as long as in complex128, with the error of
    a double inverse rounded, 1.4e-6; SciPy's 0.079 s, with a single-precision LU's
    error, 6e-4 on a random block), so the preconditioners' single inverses were double
    ones until round 48.  The 480-point FRC's harmonic stage keeps them so
    (``in_double``: in single precision its gross-slip branch needed 14 more builds);
    the capacitance blocks of a loose solve are inverted in single precision."""
    blocks = np.asarray(blocks)
    try:
        if in_double and blocks.dtype in (np.float32, np.complex64):
            return np.linalg.inv(blocks.astype(np.promote_types(blocks.dtype, np.float64))
                                 ).astype(blocks.dtype)
        if blocks.dtype not in (np.float32, np.complex64):
            return np.linalg.inv(blocks)
        if blocks.ndim == 2:
            return _lapack_inverse(blocks)
        out = np.empty_like(blocks)
        for k, block in enumerate(blocks):
            out[k] = _lapack_inverse(block)
        return out
    except np.linalg.LinAlgError:
        log.debug("a singular block: its pseudo-inverse is used")
        return np.linalg.pinv(blocks)


class PackedSymmetric:
    """Stacked blocks for products with one vector, the complex symmetric ones kept by
    their upper triangles (BLAS packed storage, ``cspmv`` and ``zspmv``): such a product
    reads half the memory of the full block, and it is memory-bound (the harmonic
    preconditioner's stage from the stuck flexibility, ``S_h + diag(k)`` complex
    symmetric: docs/hbm.md, "Round 58").

    Parameters
    ----------
    blocks : sequence of ndarray, shape (n, n), complex64 or complex128
        The blocks; a symmetric one's lower triangle is not read.
    symmetric : sequence of bool
        Which blocks are symmetric (the others are kept whole and multiplied as they are).
    """

    def __init__(self, blocks, symmetric):
        self.n = blocks[0].shape[0]
        self._given, self._parts = (list(blocks), list(symmetric)), None

    @property
    def parts(self) -> list:
        """``(spmv, packed upper triangle)`` of each symmetric block, ``(None, block)`` of
        the others: packed on the first product (a stage shared by several builds packs
        once, and one whose products all take several vectors never)."""
        if self._parts is None:
            upper = _upper_triangle(self.n)
            # (the upper triangle by rows is the lower one by columns: spmv's lower=1)
            blocks = [B.astype(np.promote_types(B.dtype, np.complex64), copy=False)
                      for B in self._given[0]]                 # (a real block as complex)
            self._parts = [(sla.get_blas_funcs("spmv", (B,)), np.take(B.reshape(-1), upper))
                           if sym else (None, B) for B, sym in zip(blocks, self._given[1])]
            self._given = None
        return self._parts

    def times(self, x) -> np.ndarray:
        """Each block times its vector: ``x`` (n_h, n) complex, returns (n_h, n) complex128."""
        out = np.empty(x.shape, dtype=complex)
        for i, (spmv, a) in enumerate(self.parts):
            xi = x[i].astype(a.dtype, copy=False)
            out[i] = a @ xi if spmv is None else spmv(self.n, 1.0, a, xi, lower=1)
        return out


def mixed_times(P, double: dict, X) -> np.ndarray:
    """``P[h] X[h]`` for every ``h``, in ``P``'s precision (often single) but for the blocks
    ``double`` holds in double instead (``{h: (n, m) complex128}``).

    Parameters
    ----------
    P : ndarray, shape (n_h, n, m)
    double : dict
    X : ndarray, shape (n_h, m, k), complex

    Returns
    -------
    ndarray, shape (n_h, n, k), complex128
    """
    Y = np.empty((P.shape[0], P.shape[1], X.shape[2]), dtype=complex)
    for h in range(P.shape[0]):
        B = double.get(h, P[h])
        Y[h] = B @ X[h].astype(np.promote_types(B.dtype, np.complex64), copy=False)
    return Y


@functools.lru_cache(maxsize=4)
def _upper_triangle(n: int) -> np.ndarray:
    """The flat indices of an (n, n) array's upper triangle, row by row."""
    return np.flatnonzero(np.triu(np.ones((n, n), dtype=bool)))


def _lapack_inverse(A) -> np.ndarray:
    """``A^-1`` by LAPACK's ``getrf`` and ``getri`` in ``A``'s precision (SciPy's ``inv``
    also estimates the condition number and warns above ``1 / eps``: a preconditioner's
    ill-conditioned block is no error); raises ``LinAlgError`` for a zero pivot."""
    getrf, getri, getri_lwork = sla.get_lapack_funcs(("getrf", "getri", "getri_lwork"), (A,))
    lu, piv, info = getrf(A)
    if info > 0:
        raise np.linalg.LinAlgError("singular block")
    work, _ = getri_lwork(A.shape[0])
    inv, info = getri(lu, piv, lwork=int(1.01 * np.real(work)) + 1, overwrite_lu=True)
    if info:
        raise np.linalg.LinAlgError(f"getri: info {info}")
    return inv


def real_times(A, Z) -> np.ndarray:
    """``A Z`` of a real ``A`` (m, n) and a C-contiguous complex ``Z`` (n, k), as one real
    product with the view of ``Z`` as (n, 2 k) reals: no complex copy of ``A`` (a real
    ``Z``: ``A Z``)."""
    if not np.iscomplexobj(Z):
        return A @ Z
    n, k = Z.shape
    return (A @ Z.view(np.float64).reshape(n, 2 * k)).view(np.complex128)


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
