"""Alternating frequency-time (AFT) evaluation of the contact elements.

The coefficients of ``q`` are turned into ``n_t`` samples per period
(``u = Gam U``), the element laws are marched over the samples from rest,
period after period, until their state repeats (at least two periods), and
the last period's forces are transformed back (``F = P f``).  The Jacobian is
analytic: the instantaneous tangents plus the history terms carried
forward through the march (see :mod:`jointsim.contact._aft_kernels`).  With
``effects.normal = "fixed"`` the normal load is ``N0`` and no gap is
evaluated; with ``"coupled"``, ``N = kn A max(0, -g)`` (or bilateral).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..harmonics import HarmonicBasis

log = logging.getLogger(__name__)


#: Values of ``AFT(closing=...)``.
CLOSINGS = ("interpolated", "sample")


@dataclass
class AFTResult:
    """Element forces and their derivatives for one set of coefficients.

    Attributes
    ----------
    Ft, Nc : ndarray, shape (n_e, n_c)
        Coefficients of the tangential force and the normal load [N].
    Juu, Jug, JNN : ndarray, shape (n_e, n_c, n_c) or None
        ``dFt/dU``, ``dFt/dG`` and ``dNc/dG`` (None when not computed or not
        applicable).
    u, f, N : ndarray, shape (n_e, n_t)
        Slip, tangential force and normal load over the last period.
    periods : ndarray of int, shape (n_e,)
        Periods marched until the state repeated.
    change : ndarray, shape (n_e,)
        Relative state change over the last period (0 when periodic).
    """

    Ft: np.ndarray
    Nc: np.ndarray
    Juu: np.ndarray | None
    Jug: np.ndarray | None
    JNN: np.ndarray | None
    u: np.ndarray
    f: np.ndarray
    N: np.ndarray
    periods: np.ndarray
    change: np.ndarray


class AFT:
    """Alternating frequency-time evaluation of a :class:`~jointsim.model.ContactSet`.

    Parameters
    ----------
    contacts : jointsim.model.ContactSet
    basis : HarmonicBasis
    min_periods, max_periods : int
        Periods marched at least / at most until the law's state repeats.
    periodic_tol : float
        Relative state change below which a period counts as periodic.
    parallel : bool
        Let the kernels run on numba threads (on enough elements); False keeps
        them on the calling thread (worker processes, which are the parallelism).
    closing : str
        Where the sliders of a contact that closes between two samples take
        their anchor (laws with ``uses_gap``, coupled normal load):
        ``"interpolated"`` at the closing instant, where the linear
        interpolation of the gap between the samples is zero, and the interval in
        which a contact opens is integrated up to the opening instant (sub-sample
        quadrature, :func:`jointsim.contact._aft_kernels.opening_weights`), so the
        forces are continuous in the coefficients when a closing or an opening
        instant crosses a sample; ``"sample"`` at the last open sample, plain
        samples (the force then steps by about ``kt |du/dt| dt`` when the first
        closed sample changes, and by the stuck force when the last closed one
        does).  None: the
        contact set's ``closing`` (scene key ``joint.closing``, default
        ``"sample"``; README "Hard cases").
    """

    def __init__(self, contacts, basis: HarmonicBasis, min_periods: int = 2,
                 max_periods: int = 50, periodic_tol: float = 1e-10, parallel: bool = True,
                 closing: str | None = None):
        self.contacts = contacts
        self.basis = basis
        self.law = contacts.law
        self.coupled = bool(contacts.coupled)
        self.min_periods = int(min_periods)
        self.max_periods = int(max(max_periods, min_periods))
        self.periodic_tol = float(periodic_tol)
        self.n_e = contacts.n_elements
        self.parallel = bool(parallel)
        closing = getattr(contacts, "closing", "sample") if closing is None else closing
        if closing not in CLOSINGS:
            raise ValueError(f"closing must be one of {CLOSINGS}, got {closing!r}")
        self.closing = closing

    def evaluate(self, U, G=None, jacobian: bool = True) -> AFTResult:
        """Forces of all elements from slip (and gap-change) coefficients.

        Parameters
        ----------
        U : ndarray, shape (n_c, n_e)
            Coefficients of the tangential slip [m].
        G : ndarray, shape (n_c, n_e), optional
            Coefficients of ``Tn x`` (the gap minus ``gap0``) [m]; required
            when the normal load is coupled.
        jacobian : bool
            Compute the derivative blocks.
        """
        b = self.basis
        c = self.contacts
        ne, nt = self.n_e, b.n_samples
        u = np.ascontiguousarray((b.Gam @ U).T)
        if self.coupled:
            g = c.gap0[:, None] + (b.Gam @ G).T
            N, dNdg = c.normal.load(g)
        else:
            N = np.ascontiguousarray(np.broadcast_to(c.N0[:, None], (ne, nt)), dtype=float)
            dNdg = np.zeros((ne, nt))
        extra = ({"gap": g, "dF": np.zeros((ne, b.n_coeff))}
                 if self.coupled and self.closing == "interpolated" and self.law.uses_gap
                 else {})
        f, au, ag, Juu, Jug, periods, change = self.law.aft(
            u, N, dNdg, b, self.min_periods, self.max_periods, self.periodic_tol, self.coupled,
            self.parallel, **extra)
        Ft = f @ b.P.T
        if extra:
            Ft += extra["dF"]       # the opening intervals' sub-sample quadrature
        Nc = N @ b.P.T
        JNN = None
        if jacobian:
            nc = b.n_coeff
            if Juu is None:
                Juu = np.zeros((ne, nc, nc))
            if au is not None:
                b.add_diag_product(Juu, au, self.parallel)
            if self.coupled:
                if Jug is None:
                    Jug = np.zeros((ne, nc, nc))
                if ag is not None:
                    b.add_diag_product(Jug, ag, self.parallel)
                JNN = b.diag_product(dNdg, self.parallel)
            else:
                Jug = None
        if np.any(periods >= self.max_periods) and np.any(change > self.periodic_tol):
            log.debug("AFT: %d elements not periodic after %d periods (largest change %.1e)",
                      int(np.sum(change > self.periodic_tol)), self.max_periods, change.max())
        return AFTResult(Ft=Ft, Nc=Nc, Juu=Juu, Jug=Jug, JNN=JNN, u=u, f=f, N=N,
                         periods=periods, change=change)
