"""The linear part of the harmonic balance at one frequency, shared by every Jacobian
there: the per-harmonic blocks and ``S_h`` (formed on demand) and the operators that
apply ``S_h`` to every harmonic at once without forming it
(:class:`~jointsim.solvers.condensation.DynamicProducts`,
:class:`~jointsim.solvers.hierarchical.InterfaceProducts`)."""
from __future__ import annotations

import functools

import numpy as np

from .condensation import DynamicProducts, ReducedLinear
from .hierarchical import InterfaceHierarchy


class FrequencyBlocks:
    """The linear part at one frequency, shared by every Jacobian there.

    Parameters
    ----------
    lin : ReducedLinear
    harmonics : sequence of int
    omega : float
        Base angular frequency [rad/s].
    xi : float
        Self-excitation [1/s].

    Attributes
    ----------
    S : list
        ``S_h`` per harmonic once formed (by a preconditioner's build or after
        ``FORM_AFTER`` products, :class:`~jointsim.solvers.jacobian.HBMJacobian`),
        else None.
    """

    def __init__(self, lin: ReducedLinear, harmonics, omega: float, xi: float = 0.0):
        self.lin = lin
        self.harmonics = tuple(harmonics)
        self.omega, self.xi = float(omega), float(xi)
        self.S = [None] * len(self.harmonics)
        self._blocks = [None] * len(self.harmonics)
        self._welded = [None] * len(self.harmonics)
        self._dynamic = None
        self._stacked = None

    @property
    def formed(self) -> bool:
        """Whether every harmonic's blocks have been formed."""
        return all(b is not None for b in self._blocks)

    def block(self, i: int) -> tuple:
        """``(A, B, B', Ef)`` of the ``i``-th harmonic (read-only, ``Ef`` factorised),
        formed on first use (forming ``S_h`` needs them; products and residuals with a
        modal or low-rank condensation do not, :attr:`dynamic`)."""
        if self._blocks[i] is None:
            lin = self.lin
            A, B, Bp, E = lin.blocks(self.harmonics[i] * self.omega, self.xi)
            for a in (A, B, Bp):
                a.flags.writeable = False
            self._blocks[i] = (A, B, Bp, lin.factor_E(E) if lin.n_y else E)
        return self._blocks[i]

    def welded_factor(self, i: int):
        """``E`` of the ``i``-th harmonic, factorised (:meth:`ReducedLinear.factor_E`): the
        one of :meth:`block` when that is formed, else made alone (``A``, ``B``, ``B'``
        are not formed)."""
        if self._blocks[i] is not None:
            return self._blocks[i][3]
        if self._welded[i] is None:
            lin = self.lin
            E = lin.blocks(self.harmonics[i] * self.omega, self.xi, parts="")[3]
            self._welded[i] = lin.factor_E(E) if lin.n_y else E
        return self._welded[i]

    def schur(self, i: int) -> np.ndarray:
        """``S_h = A - B E^-1 B'`` of the ``i``-th harmonic (complex n_r x n_r, a new
        array): with a damping of low rank by :meth:`ReducedLinear.schur_low_rank_damping`
        (real products for a forced response), else from :meth:`block`."""
        lin = self.lin
        if lin.damping_factors is not None:
            return lin.schur_low_rank_damping(self.harmonics[i] * self.omega, self.xi)
        A, B, Bp, Ef = self.block(i)
        if not lin.n_y:
            return np.array(A, dtype=complex)
        return A - B @ lin.solve_E(Ef, Bp)

    @property
    def blocks(self) -> list:
        """Every harmonic's :meth:`block`."""
        return [self.block(i) for i in range(len(self.harmonics))]

    @property
    def stacked(self) -> np.ndarray:
        """``D_h = K - nu^2 M + i nu (C - xi M)`` of every harmonic in the coordinates
        ``(q, y)``, shape ``(n_h, n, n)`` complex (made once, read-only): ``A``, ``B``,
        ``B'``, ``E`` are its blocks.  For a small structure
        (:data:`~jointsim.solvers.condensation.STACKED_MAX_DOF`), whose per-harmonic
        blocks cost more in calls than in arithmetic."""
        if self._stacked is None:
            K, M, C = self.lin.transformed
            nu = np.asarray(self.harmonics, dtype=float)[:, None, None] * self.omega
            D = K + (-nu * nu) * M + 1j * nu * (C - self.xi * M)
            D.flags.writeable = False
            self._stacked = D
        return self._stacked

    @property
    def dynamic(self):
        """The :class:`DynamicProducts` at this frequency (made once), or None when the
        condensation is not modal or low-rank."""
        if self._dynamic is None and hasattr(self.lin, "KMC_q"):
            self._dynamic = DynamicProducts(self.lin, self._nus, self.xi)
        return self._dynamic

    @functools.cached_property
    def hierarchical(self):
        """The :class:`~jointsim.solvers.hierarchical.InterfaceProducts` at this frequency
        (made once), or None (:meth:`~jointsim.solvers.hierarchical.InterfaceHierarchy.of`)."""
        h = InterfaceHierarchy.of(self.lin)
        return None if h is None else h.products(self._nus, self.xi)

    @property
    def _nus(self):
        return np.asarray(self.harmonics, dtype=float) * self.omega
