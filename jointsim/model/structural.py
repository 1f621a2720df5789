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

import numpy as np
import scipy.sparse as sp

from ..contact import NormalLaw, TangentialLaw
from ..fem.assembly import FEStructure
from ..fem.reduced import ReducedModel
from ..fem.reduction import CraigBampton
from ..solvers.static import StaticResult, StuckLinearisation, stuck_linearisation
from ..solvers.flexibility import modes_of

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
    #: ``joint.closing``: where the AFT places a re-closing slider's anchor
    #: (:class:`jointsim.solvers.aft.AFT`).
    closing: str = "sample"

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
class Preload:
    """The preloaded static state solved by a model builder (bolt preload).

    Attributes
    ----------
    x0 : ndarray, shape (n_dof,)
        Preload displacement [m]: the equilibrium of the model's own ``K`` and
        ``f_static`` with the joint at rest.
    result : jointsim.solvers.static.StaticResult
        The preload solve (normal loads, gaps, slips, tangential forces at
        ``x0``, its convergence report).
    f_clamp : ndarray, shape (n_dof,)
        Bolt clamping forces [N] (zeros without bolts).
    K_bolt : scipy.sparse.csr_matrix, shape (n_dof, n_dof)
        Bolt springs [N/m] (part of the reduced model's ``K``; zero without bolts).
    time_s : float
        Wall time of the preload solve [s].
    """

    x0: np.ndarray
    result: StaticResult
    f_clamp: np.ndarray
    K_bolt: sp.csr_matrix
    time_s: float


@dataclass(frozen=True)
class FEParts:
    """The finite-element model behind a reduced (``kind = "fe"``) model.

    Attributes
    ----------
    structure : jointsim.fem.assembly.FEStructure
        The full assembled structure (``n_full_dof`` DOFs, mesh, basis, bolts).
    cb : jointsim.fem.reduction.CraigBampton
        The Craig-Bampton basis, ``x_full = cb.T @ x``, shape (n_full_dof, n_dof).
    mesh_file : str
        Path of the mesh file.
    build_time_s : float
        Wall time of the FE assembly [s].
    reduce_time_s : float
        Wall time of the reduction [s].
    """

    structure: FEStructure
    cb: CraigBampton
    mesh_file: str
    build_time_s: float = 0.0
    reduce_time_s: float = 0.0

    @property
    def n_full_dof(self) -> int:
        """DOFs of the unreduced FE model."""
        return self.structure.n_dof


@dataclass(frozen=True)
class StructuralModel:
    """Linear structure plus contact elements, with its static state.

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
    preload : Preload or None
        The preload state solved by the builder (FE and ROM models); None for
        lumped models.
    fe : FEParts or None
        The unreduced FE model (``kind = "fe"`` only).
    rom : jointsim.fem.reduced.ReducedModel or None
        The reduced model the structure was built from (FE and ROM models).
    source : str or None
        The file the model was read from (``kind = "rom"``).
    linearisation : jointsim.solvers.static.StuckLinearisation
        The static state ``x0`` (``preload.x0`` when it is an equilibrium,
        else solved under the static load with the joint stuck) and the stuck
        tangent stiffness there: the one linear joint of every solver.
        Computed once, when the model is constructed (leave it out, or pass
        None, to have it computed; pass None again to ``dataclasses.replace``
        when changing ``K``, the contacts or the loads).
    stuck_modes : tuple (lam, phi) or None
        Every mode of the stuck structure ``(K_stuck, M)`` at the preload when the
        builder made them (modal damping, :func:`~jointsim.model.damping.
        damping_and_modes`): ``lam`` (n_dof,) [rad^2/s^2], ascending, ``phi`` (n_dof,
        n_dof) mass-normalised.  Kept only where they are the modes of
        ``(linearisation.K, M)`` (checked when the model is made, :func:`~jointsim.solvers.
        flexibility.modes_of`); the stuck flexibility and the stuck modes reuse them.
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
    preload: Preload | None = None
    fe: FEParts | None = None
    rom: ReducedModel | None = None
    source: str | None = None
    linearisation: StuckLinearisation | None = None
    stuck_modes: tuple | None = None

    def __post_init__(self):
        if self.linearisation is None:
            object.__setattr__(self, "linearisation", stuck_linearisation(self))
        if self.stuck_modes is not None and not modes_of(self.stuck_modes,
                                                         self.linearisation.K, self.M):
            log.debug("the given stuck modes are not those of (linearisation.K, M): dropped")
            object.__setattr__(self, "stuck_modes", None)

    @property
    def n_dof(self) -> int:
        return self.M.shape[0]

    def force_coefficients(self, harmonics, scale: float = 1.0) -> np.ndarray:
        """External force coefficients, shape (n_coeff, n_dof) [N]: see
        :func:`jointsim.loads.force_coefficients`."""
        from ..loads import force_coefficients
        return force_coefficients(self, harmonics, scale)


def make_contact_set(scene, Tt, Tn, gap0, N0, area, position) -> ContactSet:
    """Contact set with the scene's law and kernels (shared by all model kinds)."""
    kernels = scene.kernels()
    area = np.asarray(area, dtype=float)
    return ContactSet(Tt=sp.csr_matrix(Tt), Tn=sp.csr_matrix(Tn),
                      gap0=np.asarray(gap0, dtype=float), N0=np.asarray(N0, dtype=float),
                      area=area, law=kernels.tangential_law(scene.joint, area),
                      normal=kernels.normal_law(scene.joint, area),
                      position=np.asarray(position, dtype=float),
                      closing=scene.joint.closing)


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


