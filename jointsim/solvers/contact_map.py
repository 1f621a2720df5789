"""The contact elements seen from the structure, in condensed coordinates.

The contact coordinates are ``y = B x``: the tangential slips ``u_t = Tt x``
and, when the normal load is coupled, the gap changes ``Tn x`` (gap
``g = gap0 + Tn x``), so ``B = Tt`` or ``[Tt; Tn]``.  :class:`ContactMap`
evaluates the stacked forces ``phi`` conjugate to ``y`` (``[f_t]`` or
``[f_t, -N]``, so that the contact force on the structure is ``B^T phi``)
and the blocks of their tangent ``D = dphi/dy`` at fixed history, from the
same march kernels as harmonic balance.  The time integrator that uses it is
:mod:`jointsim.solvers.generalized_alpha`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ._transient_kernels import gap_correction


@dataclass(frozen=True)
class ContactEval:
    """The contact forces at given contact coordinates, with a fixed history.

    Attributes
    ----------
    phi : ndarray, shape (n_c,)
        Forces conjugate to the contact coordinates: ``[f_t]`` or
        ``[f_t, -N]`` [N].
    duu, dug, dgg : ndarray, shape (n_e,)
        Non-zero blocks of ``D = dphi/dy``: ``df_t/du_t`` [N/m],
        ``df_t/dg`` [N/m] and ``d(-N)/dg`` [N/m] (the last two are zero and
        unused with a fixed normal load).
    state : ndarray, shape (n_e, state_size)
        The law's state after this evaluation (committed only at the end of
        a converged step).
    u, f, N : ndarray, shape (n_e,)
        Tangential slip [m], tangential force [N] and normal load [N].
    """

    phi: np.ndarray
    duu: np.ndarray
    dug: np.ndarray
    dgg: np.ndarray
    state: np.ndarray
    u: np.ndarray
    f: np.ndarray
    N: np.ndarray


def empty_eval(state) -> ContactEval:
    """The contact evaluation of a structure without contact elements."""
    e = np.zeros(0)
    return ContactEval(e, e, e, e, state, e, e, e)


class ContactMap:
    """Contact elements seen from the structure, in condensed coordinates.

    Parameters
    ----------
    contacts : jointsim.model.ContactSet
    friction : bool
        Evaluate the tangential law (False: tangential forces are zero, as
        in a frictionless preload).

    Attributes
    ----------
    B : scipy.sparse.csr_matrix, shape (n_c, n_dof)
        ``Tt`` (fixed normal load) or ``[Tt; Tn]`` (coupled).
    n_e, n_c : int
        Elements and contact coordinates (``n_e`` or ``2 n_e``).
    coupled : bool
    """

    def __init__(self, contacts, friction: bool = True, dense: bool = False):
        self.contacts = contacts
        self.law = contacts.law
        self.coupled = bool(contacts.coupled)
        self.friction = bool(friction) and self.law.has_force
        self.n_e = contacts.n_elements
        if self.coupled:
            self.B = sp.csr_matrix(sp.vstack([contacts.Tt, contacts.Tn]))
        else:
            self.B = sp.csr_matrix(contacts.Tt)
        self.n_c = self.B.shape[0]
        #: the gap can open and close: the averaged normal force needs the
        #: energy-consistent correction (see ``_transient_kernels.gap_correction``)
        self.unilateral = self.coupled and contacts.normal.can_open
        if dense:  # small models: dense products are faster than sparse ones
            self.B = self.B.toarray()
            self.Bt = np.ascontiguousarray(self.B.T)
        else:
            self.Bt = sp.csr_matrix(self.B.T)
        self._zeros = np.zeros(self.n_e)
        self.N0 = np.asarray(contacts.N0, dtype=float)

    @property
    def active(self) -> bool:
        """False when there is nothing to evaluate (no elements)."""
        return self.n_c > 0

    def normal(self, y):
        """Normal load and ``dN/dg`` at contact coordinates ``y``, shape (n_e,) each."""
        if not self.coupled:
            return self.N0, self._zeros
        g = self.contacts.gap0 + y[self.n_e:]
        N, dNdg = self.contacts.normal.load(g[:, None])
        return N[:, 0], dNdg[:, 0]

    def evaluate(self, y, state) -> ContactEval:
        """Contact forces and tangent at ``y`` from the committed ``state``.

        Parameters
        ----------
        y : ndarray, shape (n_c,)
            Contact coordinates [m].
        state : ndarray, shape (n_e, state_size)
            Law state at the start of the step (not modified).
        """
        ne = self.n_e
        u = y[:ne]
        N, dNdg = self.normal(y)
        if self.friction:
            f, dfdu, dfdN, new = self.law.march(u[:, None], N[:, None], state)
            f, dfdu, dfdN = f[:, 0], dfdu[:, 0], dfdN[:, 0]
        else:
            f = dfdu = dfdN = self._zeros
            new = state
        if self.coupled:
            phi = np.concatenate([f, -N])
            return ContactEval(phi, dfdu, dfdN * dNdg, -dNdg, new, u, f, N)
        return ContactEval(f, dfdu, self._zeros, self._zeros, new, u, f, N)

    def correction(self, y0, ev0: ContactEval, y1, ev1: ContactEval):
        """Energy-consistent correction of the averaged normal force over a step.

        Parameters
        ----------
        y0, ev0 : ndarray, ContactEval
            Contact coordinates and forces at the start of the step.
        y1, ev1 : ndarray, ContactEval
            The same at the (trial) end of the step.

        Returns
        -------
        c, dc : ndarray, shape (n_c,)
            Force term added to the averaged contact forces [N] (non-zero only
            for the gap coordinates of elements that open or close within the
            step) and its derivative by ``y1`` (diagonal) [N/m].
        """
        c = np.zeros(self.n_c)
        dc = np.zeros(self.n_c)
        if self.unilateral:
            ne = self.n_e
            ce, dce = np.empty(ne), np.empty(ne)
            gap0 = self.contacts.gap0
            gap_correction(gap0 + y0[ne:], ev0.N, gap0 + y1[ne:], ev1.N, self.contacts.kn,
                           ce, dce)
            c[ne:], dc[ne:] = -ce, -dce
        return c, dc

    def times_D(self, G, ev: ContactEval):
        """``G @ D`` for a dense ``G`` of shape (m, n_c), using the block structure of D."""
        ne = self.n_e
        GD = np.empty_like(G)
        GD[:, :ne] = G[:, :ne] * ev.duu
        if self.coupled:
            GD[:, ne:] = G[:, :ne] * ev.dug + G[:, ne:] * ev.dgg
        return GD

    def D_matrix(self, ev: ContactEval) -> np.ndarray:
        """Dense ``D = dphi/dy``, shape (n_c, n_c) (for tests and modes)."""
        return self.times_D(np.eye(self.n_c), ev)

    def state_at(self, u0, N0) -> np.ndarray:
        """Law state of unloaded elements resting at slip ``u0`` under load ``N0``.

        Parameters
        ----------
        u0, N0 : ndarray, shape (n_e,)
        """
        return self.law.state_at(u0, N0)
