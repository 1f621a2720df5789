"""The harmonic projection of the element tangents: the part of each element's contact
tangent that couples a harmonic with itself, in complex form (the harmonic stage of
:class:`~jointsim.solvers.preconditioner.HarmonicPreconditioner`, the uncoupled solve of
:class:`~jointsim.solvers.jacobian.HBMJacobian`)."""
from __future__ import annotations


def project_tangent(Jb, ic, is_, h):
    """Complex-form projection of the ``(h, h)`` coefficient blocks of ``Jb``.

    Parameters
    ----------
    Jb : ndarray, shape (n_e, n_c, n_c)
        A tangent block of every element over the coefficients [N/m].
    ic, is_ : int
        The cosine and sine coefficients of harmonic ``h``.
    h : int

    Returns
    -------
    ndarray, shape (n_e,), complex
        ``(T_cc + T_ss) / 2 + i (T_cs - T_sc) / 2`` (``T_cc`` for ``h = 0``) [N/m].
    """
    if h == 0:
        return Jb[:, ic, ic].astype(complex)
    return 0.5 * (Jb[:, ic, ic] + Jb[:, is_, is_]) + 0.5j * (Jb[:, ic, is_] - Jb[:, is_, ic])


def add_projected_tangent(P, jac, i: int, proj=None) -> None:
    """Add the harmonic-``i`` projection of every element's tangent to ``P`` in place.

    Parameters
    ----------
    P : ndarray, complex, shape (n_r, n_r)
        A harmonic block (``S_h`` of the ``i``-th harmonic, or a copy of it) [N/m].
    jac : jointsim.solvers.jacobian.HBMJacobian
    i : int
        Index of the harmonic in ``jac.basis.harmonics``.
    proj : dict, optional
        The projections already computed (``"uu"``, ``"ug"``, ``"NN"``: (n_h, n_e)
        complex or None, :attr:`~jointsim.solvers.preconditioner.HarmonicPreconditioner.proj`); else computed here for
        this harmonic.
    """
    t, n = jac.t_row, jac.n_row
    h = jac.basis.harmonics[i]
    for key, Jb, rows, sign in (("uu", jac.Juu, (t, t), 1.0), ("ug", jac.Jug, (t, n), 1.0),
                                ("NN", jac.JNN, (n, n), -1.0)):
        if Jb is not None:
            p = proj[key][i] if proj is not None else project_tangent(Jb, jac._ic[i], jac._is[i], h)
            P[rows] += sign * p
