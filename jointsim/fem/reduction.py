"""Hurty/Craig-Bampton reduction of a sparse structure.

The DOFs are split into retained (boundary) DOFs ``B``
and interior DOFs ``I``.  The interior motion is the static response to the
boundary (constraint modes ``Psi = -K_II^-1 K_IB``) plus ``n`` fixed-interface
normal modes ``Phi`` (``K_II Phi = M_II Phi Omega^2``, mass-normalised)::

    x = T [x_B; q],   T = [[I, 0], [Psi, Phi]]   (in the original DOF order)

``K_II`` is factorised once (sparse LU, :func:`spd_lu`) and reused by the shift-invert
Lanczos solver (``eigsh`` with ``sigma = 0``); no dense matrix of the full
model is formed (``T`` is dense but only ``n_dof x n_reduced``).  Because the
contact elements, bolts and loads act on retained DOFs only, the reduced
model is exact for them statically, and the nonlinear preload solve on the
reduced model gives the same state as on the full model.

The reduced model itself is a :class:`jointsim.fem.reduced.ReducedModel`
(built by :func:`jointsim.fem.build.reduce_structure`);
:func:`jointsim.model.preload.structural_model` turns it and a scene into a
:class:`~jointsim.model.StructuralModel`.
"""
from __future__ import annotations

import dataclasses
import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..linalg import symmetric_congruence

log = logging.getLogger(__name__)


def spd_lu(A):
    """Sparse LU of a symmetric positive definite ``A`` (an FE stiffness), ordered for it.

    SuperLU's default column ordering (COLAMD) ignores the symmetry; the minimum
    degree ordering of ``A^T + A`` with symmetric mode and no pivoting (stable for a
    symmetric positive definite matrix) halves the fill.  Measured on the lap joint
    (``python benchmarks/fe_build.py --orderings``, round 22, one run at load 1):

    ========================  =================  ==============  ===============
    ``K_II`` (interior DOFs)  fill L + U          factorisation   one solve
    ========================  =================  ==============  ===============
    22,102 (96 Gauss points)  4.20 M -> 2.07 M    0.31 -> 0.17 s  13.6 -> 8.3 ms
    34,350 (120)              7.79 M -> 3.65 M    0.40 -> 0.24 s  17.8 -> 11.7 ms
    ========================  =================  ==============  ===============

    The Lanczos iterations of the fixed-interface modes make 78 solves; the
    constraint modes' solve of all retained columns at once gains less (1.66 -> 1.33 s
    and 2.60 -> 2.37 s).  The two factors' constraint modes agree to 1.6e-9 of their
    largest entry (``K_II`` has a condition number of about 1e11: soft suspension).

    A matrix that is not (numerically) positive definite, where the unpivoted
    factorisation meets a zero pivot, gets SuperLU's default instead.

    Parameters
    ----------
    A : sparse matrix, shape (n, n)

    Returns
    -------
    scipy.sparse.linalg.SuperLU
    """
    A = sp.csc_matrix(A)
    try:
        return spla.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                         options=dict(SymmetricMode=True))
    except RuntimeError:     # a zero pivot: not positive definite
        log.debug("spd_lu: unpivoted factorisation failed; SuperLU's default used")
        return spla.splu(A)


class DenseFactor:
    """The Cholesky factor of a dense symmetric positive definite matrix, solved as
    :func:`spd_lu`'s (:func:`dense_spd_factor`)."""

    def __init__(self, A):
        self.factor = sla.cho_factor(A, check_finite=False)

    def solve(self, b) -> np.ndarray:
        return sla.cho_solve(self.factor, b, check_finite=False)


def dense_spd_factor(A) -> DenseFactor:
    """:func:`spd_lu` for a dense ``A`` (LAPACK's Cholesky).

    A reduced model stored as a sparse matrix is often dense (a Craig-Bampton
    reduction's interface block): SuperLU factored the 1,964 rows of the 480-Gauss-point
    lap joint's stuck stiffness in 0.55 s, LAPACK in 0.06 s (round 47).

    Raises
    ------
    RuntimeError
        Where ``A`` is not (numerically) positive definite, as SuperLU's for a singular
        matrix (the callers then take a dense eigen-solver).
    """
    try:
        return DenseFactor(np.asarray(A, dtype=float))
    except np.linalg.LinAlgError as exc:
        raise RuntimeError(f"dense_spd_factor: {exc}") from exc


# --------------------------------------------------------------------------
# Craig-Bampton
# --------------------------------------------------------------------------
#: Column blocks of the constraint modes' solve (``K_II^-1 K_IB``), each on a thread
#: beside the fixed-interface modes' Lanczos iterations in the calling thread: SuperLU
#: releases the GIL, and solves with one factor from several threads are safe (the
#: factor is made, and outlives, in the calling thread).  A fixed number, so that the
#: constraint modes (whose round-off depends on the blocking, 3e-17 relative) do not
#: depend on the machine's cores.  Measured (round 22, 96 Gauss points, 398 columns):
#: the solve 1.64 -> 0.93 s on two threads.
CONSTRAINT_BLOCKS = 2
#: Columns of ``T`` per product of :meth:`CraigBampton.project`, and right-hand sides
#: per sparse solve of the constraint modes (:func:`_constraint_modes`): only that many
#: columns of an ``n_dof``-row array are formed at once.  Measured (round 27) at 240
#: Gauss points (136,884 DOFs, 1,004 reduced): the model's peak memory 6,086 MB whole
#: -> 3,959 MB (256 right-hand sides) -> 2,955 MB (128), the reduction 68 -> 62 -> 58 s;
#: at 120 Gauss points 8.2 to 9.1 s either way, 725 MB.  Round 42 (480 Gauss points,
#: 65,084 DOFs, 1,964 reduced, one BLAS thread): the constraint modes' solve on two
#: threads 5.3 s with 128 right-hand sides, 5.0 s with 64 (5.8 and 4.9 s with 32); the
#: projections of :meth:`CraigBampton.project`, formed on one side of the diagonal,
#: save more with narrower blocks (192 Gauss points: 1.16 s with 256 columns, 0.86 s
#: with 128, against 1.22 s for the whole products).
PROJECT_COLUMNS = 128
SOLVE_COLUMNS = 64
#: Threads of each projection (:meth:`CraigBampton.project`) of the reduction.
PROJECT_THREADS = 2


@dataclass(frozen=True)
class CraigBampton:
    """A Craig-Bampton reduction basis.

    Attributes
    ----------
    T : ndarray, shape (n_dof, n_retained + n_modes)
        Basis in the original DOF order, ``x = T @ x_r``.
    retained : ndarray of int, shape (n_retained,)
        Full DOF index of each retained DOF; reduced DOF ``i < n_retained`` is
        full DOF ``retained[i]`` (``T[retained, :n_retained]`` is the identity).
    frequency_hz : ndarray, shape (n_modes,)
        Fixed-interface natural frequencies [Hz].
    K, M : ndarray, shape (n_r, n_r)
        Reduced stiffness [N/m] and mass [kg].
    """

    T: np.ndarray
    retained: np.ndarray
    frequency_hz: np.ndarray
    K: np.ndarray
    M: np.ndarray

    @property
    def n_retained(self) -> int:
        return self.retained.size

    @property
    def n_modes(self) -> int:
        return self.frequency_hz.size

    def reduced_index(self, n_dof: int) -> np.ndarray:
        """Map full DOF -> reduced DOF (-1 for interior DOFs), shape (n_dof,)."""
        idx = np.full(n_dof, -1, dtype=np.int64)
        idx[self.retained] = np.arange(self.n_retained)
        return idx

    def project(self, A, threads: int = 1) -> np.ndarray:
        """``T^T A T`` of a full sparse symmetric matrix, dense (n_r, n_r), symmetric
        (:func:`jointsim.linalg.symmetric_congruence`).

        By blocks of :data:`PROJECT_COLUMNS` columns (one ``n_dof x n_r`` array less,
        1.1 GB at 240 Gauss points), each formed only on and above the diagonal,
        ``out[:e, j:e] = T[:, :e]^T (A T[:, j:e])``, and mirrored: half the product's
        flops.  The diagonal blocks are symmetrised.  On ``threads`` threads the blocks
        are independent (products release the GIL), and the result does not depend on
        how many there are.  Measured (round 42, ``python benchmarks/fe_build.py
        --projection``, one BLAS thread): ``K`` and ``M`` 0.43 -> 0.19 s at 96 Gauss
        points, 1.45 -> 0.86 s at 192, 10.0 -> 6.3 s at 480 (65,084 DOFs, 1,964
        reduced), against the whole products side by side on two threads.
        """
        return symmetric_congruence(self.T, A, threads, PROJECT_COLUMNS)


def with_fixed_signs(Phi) -> np.ndarray:
    """Mode shapes with a deterministic sign: the entry of largest magnitude positive.

    Eigensolvers return each mode up to its sign, and the sign can change
    between builds of the same model; fixing it makes modal coordinates of
    files of the same scene comparable.

    Parameters
    ----------
    Phi : ndarray, shape (n, m)
        Mode shapes in columns.

    Returns
    -------
    ndarray, shape (n, m)
    """
    Phi = np.asarray(Phi)
    if Phi.size == 0:
        return Phi
    pick = Phi[np.argmax(np.abs(Phi), axis=0), np.arange(Phi.shape[1])]
    return Phi * np.where(pick < 0, -1.0, 1.0)


def craig_bampton(K, M, retained, n_modes: int) -> CraigBampton:
    """Hurty/Craig-Bampton reduction of a sparse model.

    Parameters
    ----------
    K, M : sparse matrix, shape (n_dof, n_dof)
        Stiffness [N/m] and mass [kg]; ``K_II`` must be nonsingular.
    retained : array_like of int
        Full DOFs kept physically (unique; kept in the given order).
    n_modes : int
        Fixed-interface modes kept (0: Guyan reduction).

    Returns
    -------
    CraigBampton
    """
    K = sp.csr_matrix(K)
    M = sp.csr_matrix(M)
    n = K.shape[0]
    B = np.asarray(retained, dtype=np.int64)
    if len(np.unique(B)) != len(B):
        raise ValueError("retained DOFs must be unique")
    if B.size and (B.min() < 0 or B.max() >= n):
        raise ValueError("retained DOF out of range")
    interior = np.ones(n, bool)
    interior[B] = False
    I = np.nonzero(interior)[0]
    n_modes = int(min(n_modes, I.size))
    K_II = sp.csc_matrix(K[I][:, I])
    K_IB = sp.csc_matrix(K[I][:, B])
    lu = spd_lu(K_II)
    T = np.zeros((n, B.size + n_modes))
    T[B, np.arange(B.size)] = 1.0
    with ThreadPoolExecutor(max_workers=CONSTRAINT_BLOCKS) as pool:
        # the constraint modes, column blocks on threads while this one runs the modes
        blocks = [pool.submit(_constraint_modes, lu, K_IB, c, T, I)
                  for c in np.array_split(np.arange(B.size), CONSTRAINT_BLOCKS) if c.size]
        w2, Phi = _fixed_interface_modes(K_II, M[I][:, I], lu, n_modes)
        for b in blocks:
            b.result()
    Phi = with_fixed_signs(Phi)
    T[I, B.size:] = Phi
    cb = CraigBampton(T=T, retained=B, frequency_hz=np.sqrt(np.maximum(w2, 0)) / (2 * np.pi),
                      K=np.zeros(0), M=np.zeros(0))
    # each product on two threads over its column blocks (about half the flops of the
    # whole product; the two whole products side by side on two threads before round 42)
    return dataclasses.replace(cb, K=cb.project(K, threads=PROJECT_THREADS),
                               M=cb.project(M, threads=PROJECT_THREADS))


def _constraint_modes(lu, K_IB, cols, T, I) -> None:
    """Write ``Psi[:, cols] = -K_II^-1 K_IB[:, cols]`` into the rows ``I`` of ``T``.

    Solved :data:`SOLVE_COLUMNS` columns at a time (``lu`` the factor of
    :func:`spd_lu`): only those columns' right-hand side and solution are dense at
    once, not the block's (at 240 Gauss points a whole ``Psi`` is 1.1 GB).  Fortran
    order: SuperLU solves column by column, and a C-ordered right-hand side makes that
    an order of magnitude slower.
    """
    for sub in np.array_split(cols, -(-cols.size // SOLVE_COLUMNS)):
        X = lu.solve(np.asfortranarray(K_IB[:, sub].toarray()))
        np.negative(X, out=X)
        T[I, sub[0]:sub[-1] + 1] = X


def _fixed_interface_modes(K_II, M_II, lu, n_modes: int):
    """The ``n_modes`` lowest modes of ``K_II Phi = M_II Phi Omega^2``, mass-normalised
    (``w2`` ascending; shift-invert Lanczos on the factor ``lu``, dense when small)."""
    n_i = K_II.shape[0]
    if n_modes == 0:
        return np.zeros(0), np.zeros((n_i, 0))
    if n_i <= 400 or n_modes >= n_i - 1:
        return sla.eigh(K_II.toarray(), M_II.toarray(), subset_by_index=(0, n_modes - 1))
    return shift_invert_modes(K_II, M_II, n_modes, lu)


def shift_invert_modes(K, M, n_modes: int, lu):
    """The ``n_modes`` lowest modes of ``K phi = w^2 M phi`` by shift-invert Lanczos
    about 0 on the factor ``lu`` of ``K`` (:func:`spd_lu`, or :func:`dense_spd_factor`
    for dense matrices).

    Parameters
    ----------
    K, M : sparse matrix or ndarray, shape (n, n)
        Symmetric, ``K`` nonsingular, ``M`` positive definite.
    n_modes : int
        Fewer than ``n - 1``.
    lu : scipy.sparse.linalg.SuperLU or DenseFactor
        Anything with ``solve(b)`` for ``K^-1 b``.

    Returns
    -------
    w2 : ndarray, shape (n_modes,)
        Eigenvalues ascending [rad^2/s^2].
    Phi : ndarray, shape (n, n_modes)
        Mass-normalised modes in columns (signs as the solver gives them).
    """
    n = K.shape[0]
    op = spla.LinearOperator(K.shape, matvec=lu.solve, dtype=float)
    Ka, Ma = (sp.csc_matrix(A) if sp.issparse(A) else np.asarray(A, dtype=float)
              for A in (K, M))
    w2, Phi = spla.eigsh(Ka, k=n_modes, M=Ma, sigma=0.0, which="LM", OPinv=op,
                         v0=np.ones(n))
    order = np.argsort(w2)
    w2, Phi = w2[order], Phi[:, order]
    # normalise to unit modal mass (eigsh already does, to round-off)
    return w2, Phi / np.sqrt(np.einsum("ij,ij->j", Phi, M @ Phi))
