"""Structural models: linear matrices plus a set of contact elements.

Every model kind that has a structure (lumped, FE, ROM) is turned into a
:class:`StructuralModel`: sparse ``M``, ``K``, ``C`` of the linear part and a
:class:`ContactSet` that maps the structure's DOFs to each element's
tangential slip and normal gap.  Solvers work on this object only.

Sign conventions
----------------
* Tangential slip ``u_t = Tt @ x`` [m]; normal gap ``g = gap0 + Tn @ x`` [m],
  negative in interpenetration; normal load ``N >= 0`` in compression.
* The contact force on the structure (added to the internal forces, on the
  left-hand side of ``M x'' + C x' + K x + f_c = f_ext``) is
  ``f_c = Tt.T @ f_t - Tn.T @ N``.
* With ``effects.normal = "fixed"`` the normal direction is a linear spring
  that is part of ``K`` (``K += Tn.T diag(kn A) Tn`` over the elements with
  ``N0 > 0``, see :func:`fixed_normal_stiffness`), and the slip limit uses the
  fixed load ``N0``; no gap is evaluated during the solve.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sp

from .contact import NormalLaw, TangentialLaw

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ContactSet:
    """``n_e`` contact elements attached to a structure with ``n_dof`` DOFs.

    Attributes
    ----------
    Tt : scipy.sparse.csr_matrix, shape (n_e, n_dof)
        Tangential slip operator, ``u_t = Tt @ x`` [m].
    Tn : scipy.sparse.csr_matrix, shape (n_e, n_dof)
        Normal gap operator, ``g = gap0 + Tn @ x`` [m] (rows of zeros where an
        element has no normal DOF).
    gap0 : ndarray, shape (n_e,)
        Gap at ``x = 0`` [m].
    N0 : ndarray, shape (n_e,)
        Normal load used when the normal load is fixed [N].
    area : ndarray, shape (n_e,)
        Element areas [m^2].
    law : TangentialLaw
        Tangential law of every element.
    normal : NormalLaw
        Normal law of every element (holds ``kn A`` [N/m]).
    position : ndarray, shape (n_e, 2)
        Element position for plots [m] (index along the interface for lumped models).
    """

    Tt: sp.csr_matrix
    Tn: sp.csr_matrix
    gap0: np.ndarray
    N0: np.ndarray
    area: np.ndarray
    law: TangentialLaw
    normal: NormalLaw
    position: np.ndarray

    @property
    def n_elements(self) -> int:
        return self.Tt.shape[0]

    @property
    def kn(self) -> np.ndarray:
        """Normal stiffness of each element, ``kn A`` [N/m], shape (n_e,)."""
        return self.normal.kn

    @property
    def coupled(self) -> bool:
        """True when the normal load is computed from the gap."""
        return self.normal.coupled


@dataclass(frozen=True)
class StructuralModel:
    """Linear structure plus contact elements.

    Attributes
    ----------
    M, K, C : scipy.sparse.csr_matrix, shape (n_dof, n_dof)
        Mass [kg], stiffness [N/m] and damping [N s/m] of the linear part.
    contacts : ContactSet
    load_dofs : ndarray of int, shape (n_loads,)
        DOF of each external load.
    load_signals : tuple of jointsim.scene.Signal
        Force signal of each load [N].
    f_static : ndarray, shape (n_dof,)
        Constant force on the structure (e.g. bolt preload) [N].
    dof_labels : tuple of str
        A name for every DOF.
    points : dict
        Named DOFs (e.g. ``{"response": 12}``).
    units : str
        ``"SI"`` or ``"nondimensional"``.
    extra : dict
        Kind-specific data (mesh, reduction basis, ...), not used by solvers.
    """

    M: sp.csr_matrix
    K: sp.csr_matrix
    C: sp.csr_matrix
    contacts: ContactSet
    load_dofs: np.ndarray
    load_signals: tuple
    f_static: np.ndarray
    dof_labels: tuple
    points: dict = field(default_factory=dict)
    units: str = "SI"
    extra: dict = field(default_factory=dict)

    @property
    def n_dof(self) -> int:
        return self.M.shape[0]

    def force_coefficients(self, harmonics, scale: float = 1.0) -> np.ndarray:
        """External force coefficients, shape (n_coeff, n_dof) [N]: see
        :func:`jointsim.loads.force_coefficients`."""
        from .loads import force_coefficients
        return force_coefficients(self, harmonics, scale)


def damping_matrix(M, K, damping, C0=None):
    """Linear damping matrix from a scene's ``[damping]`` table.

    Parameters
    ----------
    M, K : sparse matrix, shape (n, n)
    damping : jointsim.scene.Damping
    C0 : sparse matrix, optional
        Damping given directly (lumped ``model.C``); added to the result.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n, n) [N s/m]
    """
    n = M.shape[0]
    C = sp.csr_matrix((n, n)) if C0 is None else sp.csr_matrix(C0)
    if damping.kind == "rayleigh":
        C = C + damping.alpha * M + damping.beta * K
    elif damping.kind == "modal":
        zeta = np.asarray(damping.zeta, dtype=float)
        if zeta.size == 0:
            raise ValueError("damping.zeta must list at least one modal damping ratio")
        if n > 2000:
            raise NotImplementedError("modal damping of a model with more than 2000 DOFs: "
                                      "reduce it first (Craig-Bampton) or use Rayleigh damping")
        import scipy.linalg as sla
        w2, phi = sla.eigh(K.toarray(), M.toarray())
        m = min(zeta.size, n)
        w = np.sqrt(np.maximum(w2[:m], 0.0))
        Mphi = M @ phi[:, :m]
        C = C + sp.csr_matrix(Mphi @ np.diag(2.0 * zeta[:m] * w) @ Mphi.T)
    return sp.csr_matrix(C)


def _selector(n_rows: int, n_cols: int, plus, minus) -> sp.csr_matrix:
    """Rows of +1/-1 picking ``x[plus] - x[minus]``; index -1 means ground."""
    rows, cols, vals = [], [], []
    for r, (a, b) in enumerate(zip(plus, minus)):
        if a >= 0:
            rows.append(r), cols.append(a), vals.append(1.0)
        if b >= 0:
            rows.append(r), cols.append(b), vals.append(-1.0)
    return sp.csr_matrix((vals, (rows, cols)), shape=(n_rows, n_cols))


def make_contact_set(scene, Tt, Tn, gap0, N0, area, position) -> ContactSet:
    """Contact set with the scene's law and kernels (shared by all model kinds)."""
    kernels = scene.kernels()
    area = np.asarray(area, dtype=float)
    return ContactSet(Tt=sp.csr_matrix(Tt), Tn=sp.csr_matrix(Tn),
                      gap0=np.asarray(gap0, dtype=float), N0=np.asarray(N0, dtype=float),
                      area=area, law=kernels.tangential_law(scene.joint, area),
                      normal=kernels.normal_law(scene.joint, area),
                      position=np.asarray(position, dtype=float))


def fixed_normal_stiffness(contacts: ContactSet) -> np.ndarray:
    """Normal springs of a fixed-normal-load model [N/m], shape (n_e,).

    ``kn A`` for the elements that carry load at the preload (``N0 > 0``) and
    0 for the open ones: the linearisation of the unilateral contact at the
    preload state.  An element open at the preload stays open and carries no
    force, so the fixed-N model and the coupled one share their linear limit.
    """
    return np.where(contacts.N0 > 0.0, contacts.kn, 0.0)


def with_fixed_normal_springs(K, contacts: ContactSet):
    """``K`` plus the linear normal springs used when the normal load is fixed."""
    if contacts.coupled or contacts.Tn.nnz == 0:
        return sp.csr_matrix(K)
    Tn = contacts.Tn
    return sp.csr_matrix(K + Tn.T @ sp.diags(fixed_normal_stiffness(contacts)) @ Tn)


def build_lumped(scene) -> StructuralModel:
    """Structural model of a ``kind = "lumped"`` scene."""
    m = scene.model
    n = m.n_dof
    M = sp.csr_matrix(np.array(m.M, dtype=float))
    K = sp.csr_matrix(np.array(m.K, dtype=float))
    C0 = None if m.C is None else np.array(m.C, dtype=float)
    ne = len(m.contacts)
    Tt = _selector(ne, n, [c.t_dof for c in m.contacts], [c.t_ref for c in m.contacts])
    Tn = _selector(ne, n, [c.n_dof for c in m.contacts], [c.n_ref for c in m.contacts])
    N0 = np.array([c.N0 if c.N0 is not None else 0.0 for c in m.contacts])
    gap0 = np.array([c.gap0 for c in m.contacts])
    area = np.array([c.area for c in m.contacts])
    position = np.column_stack([np.arange(ne, dtype=float), np.zeros(ne)])
    contacts = make_contact_set(scene, Tt, Tn, gap0, N0, area, position)
    K = with_fixed_normal_springs(K, contacts)
    C = damping_matrix(M, K, scene.damping, C0)
    loads = scene.excitation.loads
    return StructuralModel(
        M=M, K=K, C=C, contacts=contacts,
        load_dofs=np.array([ld.dof for ld in loads], dtype=np.int64),
        load_signals=tuple(ld.force for ld in loads),
        f_static=np.zeros(n), dof_labels=tuple(f"x{i}" for i in range(n)),
        points={}, units=m.units)


#: model kind -> builder(scene) -> StructuralModel.  FE and ROM builders
#: register themselves here from their own modules.
BUILDERS: dict[str, Callable] = {"lumped": build_lumped}


def build_model(scene) -> StructuralModel:
    """Build the structural model of a scene (lumped, FE or ROM).

    Raises
    ------
    NotImplementedError
        For a model kind that has no builder yet.
    """
    kind = scene.model.kind
    if kind not in BUILDERS:
        _load_builders()
    if kind not in BUILDERS:
        raise NotImplementedError(f"no structural model builder for model.kind = {kind!r}")
    model = BUILDERS[kind](scene)
    log.info("model %s: %d DOFs, %d contact elements (%s / %s kernels)", kind, model.n_dof,
             model.contacts.n_elements, model.contacts.law.name,
             model.contacts.normal.name)
    return model


def _load_builders() -> None:
    """Import modules that register builders for the FE and ROM kinds."""
    from ._plugins import import_available
    import_available(("jointsim.fem", "jointsim.reduction"))
