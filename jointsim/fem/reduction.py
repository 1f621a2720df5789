"""Hurty/Craig-Bampton reduction of a sparse structure.

The DOFs are split into retained (boundary) DOFs ``B``
and interior DOFs ``I``.  The interior motion is the static response to the
boundary (constraint modes ``Psi = -K_II^-1 K_IB``) plus ``n`` fixed-interface
normal modes ``Phi`` (``K_II Phi = M_II Phi Omega^2``, mass-normalised)::

    x = T [x_B; q],   T = [[I, 0], [Psi, Phi]]   (in the original DOF order)

``K_II`` is factorised once (sparse LU) and reused by the shift-invert
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
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------
# Craig-Bampton
# --------------------------------------------------------------------------
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

    def project(self, A) -> np.ndarray:
        """``T^T A T`` of a full sparse matrix, dense (n_r, n_r), symmetrised."""
        AT = A @ self.T
        out = self.T.T @ AT
        return 0.5 * (out + out.T)


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
    K_IB = K[I][:, B]
    lu = spla.splu(K_II)
    # Fortran order: SuperLU solves column by column, and a C-ordered
    # right-hand side makes that an order of magnitude slower
    Psi = -lu.solve(np.asfortranarray(K_IB.toarray())) if B.size else np.zeros((I.size, 0))
    if n_modes == 0:
        w2, Phi = np.zeros(0), np.zeros((I.size, 0))
    elif I.size <= 400 or n_modes >= I.size - 1:
        w2, Phi = sla.eigh(K_II.toarray(), M[I][:, I].toarray(),
                           subset_by_index=(0, n_modes - 1))
    else:
        op = spla.LinearOperator(K_II.shape, matvec=lu.solve, dtype=float)
        w2, Phi = spla.eigsh(K_II, k=n_modes, M=sp.csc_matrix(M[I][:, I]), sigma=0.0,
                             which="LM", OPinv=op, v0=np.ones(I.size))
        order = np.argsort(w2)
        w2, Phi = w2[order], Phi[:, order]
        # normalise to unit modal mass (eigsh already does, to round-off)
        mm = np.einsum("ij,ij->j", Phi, M[I][:, I] @ Phi)
        Phi = Phi / np.sqrt(mm)
    Phi = with_fixed_signs(Phi)
    T = np.zeros((n, B.size + n_modes))
    T[B, np.arange(B.size)] = 1.0
    T[I, :B.size] = Psi
    T[I, B.size:] = Phi
    cb = CraigBampton(T=T, retained=B, frequency_hz=np.sqrt(np.maximum(w2, 0)) / (2 * np.pi),
                      K=np.zeros(0), M=np.zeros(0))
    return dataclasses.replace(cb, K=cb.project(K), M=cb.project(M))
