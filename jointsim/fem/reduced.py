"""Reduced linear structures: matrices, contact interface, bolts and named DOFs.

A :class:`ReducedModel` is what both the FE reduction
(:func:`jointsim.fem.build.reduce_structure`) and a ROM file
(:func:`jointsim.io.rom.load_rom`) produce; it is plain data.
:func:`jointsim.model.preload.structural_model` turns it and a scene into a
preloaded :class:`~jointsim.model.StructuralModel`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .interface import Interface


@dataclass(frozen=True)
class BoltTable:
    """Bolts of a reduced model (their springs are already in ``K``).

    Attributes
    ----------
    lower_dofs, upper_dofs : ndarray of int, shape (n_b, d)
        DOFs of each bolt's two ends, one per direction (-1: none).
    axis : ndarray, shape (n_b, d)
        Unit vector from the lower to the upper end.
    stiffness : ndarray, shape (n_b,)
        Axial spring of each bolt [N/m].
    preload : ndarray, shape (n_b,)
        Clamping force [N].
    names : tuple of str
    """

    lower_dofs: np.ndarray
    upper_dofs: np.ndarray
    axis: np.ndarray
    stiffness: np.ndarray
    preload: np.ndarray
    names: tuple = ()

    @property
    def n_bolts(self) -> int:
        return len(self.stiffness)

    def operator(self, n_dof: int) -> sp.csr_matrix:
        """Elongation operator ``e = B @ x`` [m/m], shape (n_b, n_dof)."""
        rows, cols, vals = [], [], []
        for sign, dofs in ((1.0, self.upper_dofs), (-1.0, self.lower_dofs)):
            for c in range(dofs.shape[1]):
                v = sign * self.axis[:, c]
                keep = (dofs[:, c] >= 0) & (v != 0)
                rows += np.nonzero(keep)[0].tolist()
                cols += dofs[keep, c].tolist()
                vals += v[keep].tolist()
        return sp.csr_matrix((vals, (rows, cols)), shape=(self.n_bolts, n_dof))

    def stiffness_matrix(self, n_dof: int) -> sp.csr_matrix:
        """The bolt springs ``B^T diag(k_b) B`` [N/m]."""
        Bop = self.operator(n_dof)
        return sp.csr_matrix(Bop.T @ sp.diags(self.stiffness) @ Bop)

    def clamp_forces(self, n_dof: int) -> np.ndarray:
        """Clamping forces: each bolt pulls its ends together with its preload [N]."""
        return -(self.operator(n_dof).T @ self.preload)

    def dofs(self) -> np.ndarray:
        """DOFs the bolts act on."""
        Bop = self.operator(1 + max(self.lower_dofs.max(), self.upper_dofs.max()))
        return np.unique(Bop.indices)


@dataclass(frozen=True)
class ReducedModel:
    """A reduced linear structure with its interface (FE-built or imported).

    Attributes
    ----------
    M, K : ndarray, shape (n, n)
        Mass [kg] and stiffness [N/m], bolt springs included.
    interface : Interface
        Contact pairs in this model's DOF numbering.
    C : ndarray, shape (n, n), optional
        Damping [N s/m] (added to the scene's ``[damping]``).
    f_static : ndarray, shape (n,)
        Constant loads other than bolt clamping [N].
    bolts : BoltTable, optional
    points : dict of str -> int
        Named DOFs.
    dof_labels : tuple of str
    """

    M: np.ndarray
    K: np.ndarray
    interface: Interface
    C: np.ndarray | None = None
    f_static: np.ndarray | None = None
    bolts: BoltTable | None = None
    points: dict = field(default_factory=dict)
    dof_labels: tuple = ()

    def __post_init__(self):
        M = np.asarray(self.M.toarray() if sp.issparse(self.M) else self.M, dtype=float)
        K = np.asarray(self.K.toarray() if sp.issparse(self.K) else self.K, dtype=float)
        n = M.shape[0]
        if M.shape != (n, n) or K.shape != (n, n):
            raise ValueError(f"M and K must be square and of equal size, got {M.shape} "
                             f"and {K.shape}")
        object.__setattr__(self, "M", M)
        object.__setattr__(self, "K", K)
        if self.C is not None:
            C = np.asarray(self.C.toarray() if sp.issparse(self.C) else self.C, dtype=float)
            if C.shape != (n, n):
                raise ValueError(f"C must be {n} x {n}, got {C.shape}")
            object.__setattr__(self, "C", C)
        f = np.zeros(n) if self.f_static is None else np.asarray(self.f_static, float).ravel()
        if f.shape != (n,):
            raise ValueError(f"f_static must have {n} entries, got {f.size}")
        object.__setattr__(self, "f_static", f)
        for name in ("lower_dofs", "upper_dofs"):
            d = getattr(self.interface, name)
            if d.size and (d.max() >= n):
                raise ValueError(f"interface {name} has DOF {d.max()} >= n_dof = {n}")
        for name, dof in self.points.items():
            if not 0 <= int(dof) < n:
                raise ValueError(f"point {name!r} has DOF {dof} outside 0..{n - 1}")
        if not self.dof_labels:
            object.__setattr__(self, "dof_labels", tuple(f"x{i}" for i in range(n)))

    @property
    def n_dof(self) -> int:
        return self.M.shape[0]
