"""Nonlinear modes by the extended periodic motion concept (EPMC, Krack 2015).

The autonomous system with an artificial negative damping term,

    M x'' + (C - xi M) x' + K x + f_c(x) = f_static,

has periodic solutions along a nonlinear mode; ``xi`` [1/s] is the
self-excitation that exactly balances the dissipation, so that the mode's
damping ratio is ``zeta = xi / (2 omega)``.  It is solved by the same
condensed AFT harmonic balance as the FRC (:mod:`jointsim.solvers.hbm`), with
two extra unknowns (``omega``, ``xi``) and two extra equations that fix the
amplitude and the phase:

* **amplitude** -- the modal amplitude of the fundamental harmonic,
  ``a = phi^T M (X_1c - i X_1s)``, with ``phi`` the mass-normalised linear mode
  of the structure linearised at its static state ``x0`` with the joint stuck
  (:func:`jointsim.solvers.static.stuck_linearisation`; for the lap joint:
  the preloaded joint, the modes of ``[analysis.modes]``); the phase is fixed
  by making it real: ``Re = a``, ``Im = 0``.  For a single DOF with ``m = 1``
  this is the amplitude of the cosine of ``x``.  ``mode`` counts elastic
  modes only (:func:`jointsim.solvers.modes.elastic_mode`).
* **scaling** -- the unknowns are the contact coefficients measured from the
  static state and divided by ``a``, ``z = z0 + a zh`` with ``z0`` the
  contact coordinates of ``x0`` (harmonic 0), so that a branch over several
  decades of amplitude stays well scaled and starts at the static state; the
  residual is divided by ``a`` too.  The continuation parameter is
  ``log10(a)``.

At small amplitude the mode starts from the linear one (``omega`` = its
frequency, ``xi = phi^T C phi``, ``zh`` = the contact coordinates of
``phi`` in the cosine of harmonic 1).
"""
from __future__ import annotations

import logging

import numpy as np

from ..linalg import real_times
from .condensation import dense_array
from .hbm import HBMSystem
from .jacobian import BorderedJacobian

log = logging.getLogger(__name__)

LN10 = np.log(10.0)


class EPMCSystem:
    """EPMC equations in amplitude-normalised unknowns.

    Unknowns ``y = (zh, omega, xi, lam)`` with ``z = z0 + 10^lam zh`` the
    contact coefficients (``z0``: the static state, harmonic 0); equations
    ``R(z, omega, xi) / a`` and the amplitude and phase conditions.

    Parameters
    ----------
    system : HBMSystem
    phi : ndarray, shape (n_dof,)
        Mass-normalised reference mode.
    F : ndarray, shape (n_c, n_dof)
        Static force coefficients (no harmonic excitation).
    """

    def __init__(self, system: HBMSystem, phi, F):
        if 1 not in system.basis.harmonics:
            raise ValueError("EPMC needs harmonic 1")
        self.s = system
        self.z0 = system.static_coordinates()
        self.phi = np.asarray(phi, dtype=float)
        self.F = F
        lin = system.lin
        Mphi = dense_array(system.model.M) @ self.phi
        self.m_q = lin.Psi.T @ Mphi
        self.m_y = lin.Z.T @ Mphi
        # F's harmonic 1 on the welded coordinates (a real product: Z is not made complex)
        F1 = system._complex(np.asarray(F, dtype=float), 1)
        self.F_y1 = real_times(lin.Z.T, np.ascontiguousarray(F1, dtype=complex)[:, None])[:, 0]

    def coefficients(self, y):
        """Full harmonic coefficients ``X`` (n_c, n_dof) [m] of the point ``y``.

        Without contact unknowns (``n_z = 0``: fixed normal load and no
        friction) the structure is linear and the mode is the reference mode
        ``phi`` itself: ``X`` is the static state plus ``a phi`` in the cosine
        of harmonic 1 (see :meth:`linear_point`).
        """
        s = self.s
        nz = s.n_z
        omega, xi, lam = float(y[nz]), float(y[nz + 1]), float(y[nz + 2])
        amp = 10.0 ** lam
        X = s.reconstruct(self.z0 + amp * y[:nz], omega, self.F, xi=xi)
        if nz == 0:
            X[s.basis.index[1][0]] += amp * self.phi
        return X

    def linear_point(self, lam: float, omega: float, xi: float):
        """The point ``y`` of a joint without contact unknowns at ``log10 a = lam``.

        Such a joint is linear: its nonlinear mode is the linear mode at every
        amplitude, with frequency ``omega`` [rad/s] and self-excitation
        ``xi = phi^T C phi`` [1/s] (exact for damping that is diagonal in the
        modes, e.g. modal or Rayleigh damping).

        Returns
        -------
        ndarray, shape (3,)
            ``(omega, xi, lam)``.
        """
        if self.s.n_z:
            raise ValueError("the joint has contact unknowns: continue its branch instead")
        return np.array([omega, xi, lam], dtype=float)

    def _modal(self, Q, omega, xi, derivs: bool):
        """``q1 = phi^T M X_1`` (complex), its gradient in the harmonic-1 rows, and
        its derivatives by omega and xi."""
        s, lin = self.s, self.s.lin
        qh = s._complex(Q, 1)
        # harmonic 1's E, kept by the system at (omega, xi); B' by products (not formed)
        Ef = s.harmonic_blocks(omega, xi).welded_factor(list(s.basis.harmonics).index(1))
        y = lin.solve_E(Ef, self.F_y1 - lin.block_times("yq", omega, xi, qh)) if lin.n_y \
            else np.zeros(0, complex)
        q1 = self.m_q @ qh + self.m_y @ y
        if not derivs:
            return q1, None, None
        ell = self.m_q - (lin.block_times("yq", omega, xi, lin.solve_E(
            Ef, self.m_y.astype(complex), trans=True), transpose=True) if lin.n_y else 0.0)
        d = {}
        for p in ("omega", "xi"):
            if lin.n_y:
                _, dy = lin.dproducts(omega, xi, p, 1, qh, y, parts="y")
                d[p] = self.m_y @ (-lin.solve_E(Ef, dy))
            else:
                d[p] = 0.0 + 0.0j
        return q1, ell, d

    def fun(self, y):
        """Residual (n_z + 2,) and Jacobian (n_z + 2, n_z + 3) at ``y``, plus the evaluation.

        The Jacobian is dense on the direct path and a
        :class:`~jointsim.solvers.jacobian.BorderedJacobian` on the Krylov path.
        A diverged Newton iterate (huge coefficients, e.g. with very stiff
        contacts) gives non-finite values, which the solvers report as such,
        not floating-point warnings.
        """
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return self._fun(y)

    def residual(self, y) -> np.ndarray:
        """The structural rows of :meth:`fun`'s residual, ``R(z0 + a zh) / a`` (n_z,),
        without the Jacobian (the amplitude and phase rows depend on ``zh`` only)."""
        s = self.s
        nz = s.n_z
        a = 10.0 ** float(y[nz + 2])
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return s.evaluate(self.z0 + a * np.asarray(y[:nz]), float(y[nz]), self.F,
                              xi=float(y[nz + 1]), jacobian=False, wrt=()).R / a

    def _fun(self, y):
        """:meth:`fun` without the floating-point error state."""
        s = self.s
        nz = s.n_z
        zh, omega, xi, lam = y[:nz], y[nz], y[nz + 1], y[nz + 2]
        if not -300.0 < lam < 300.0 or not np.all(np.isfinite(y)):
            # a diverged Newton iterate: report it as non-finite, not as a warning
            return np.full(nz + 2, np.nan), np.full((nz + 2, nz + 3), np.nan), None
        a = 10.0 ** lam
        structured = s.krylov
        J = None if structured else np.zeros((nz + 2, nz + 3))
        ev = s.evaluate(self.z0 + a * zh, omega, self.F, xi=xi, wrt=("omega", "xi"),
                        J_out=None if structured else J[:nz, :nz])
        Rt = ev.R / a
        Q = zh.reshape(s.n_c, s.n_r)
        q1, ell, d = self._modal(Q, omega, xi, True)
        R = np.concatenate([Rt, [q1.real - 1.0, q1.imag]])
        C = np.column_stack([ev.dR["omega"] / a, ev.dR["xi"] / a, LN10 * (ev.J @ zh - Rt)])
        ic, is_ = s.basis.index[1]
        nr = s.n_r
        cols_c = ic * nr + np.arange(nr)
        cols_s = is_ * nr + np.arange(nr)
        # q1 = ell . (qc - i qs)
        rows = np.zeros((2, nz))
        rows[0, cols_c] = ell.real
        rows[0, cols_s] = ell.imag
        rows[1, cols_c] = ell.imag
        rows[1, cols_s] = -ell.real
        D = np.array([[d["omega"].real, d["xi"].real, 0.0],
                      [d["omega"].imag, d["xi"].imag, 0.0]])
        if structured:
            # the amplitude and phase rows deflate the mode from the preconditioner
            i1 = list(s.basis.harmonics).index(1)
            return R, BorderedJacobian(ev.J, C, rows, D, deflate=(i1, ell)), ev
        J[:nz, nz:] = C
        J[nz:, :nz] = rows
        J[nz:, nz:] = D
        return R, J, ev
