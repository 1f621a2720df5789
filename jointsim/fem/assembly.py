"""Plane-stress finite-element assembly with scikit-fem.

The element is the 9-node biquadratic Lagrange quadrilateral
(``ElementVector(ElementQuad2())``) on straight 4-node quads: quadratic
displacement fields do not shear-lock in bending, which linear quads do.

:func:`assemble_plane_stress` gives ``K`` and ``M`` of a mesh;
:func:`build_structure` adds what the lap joint needs on top (soft suspension
springs, bolts as springs plus clamping forces, the interface table and the
named points) from the tags of the mesh.

Bolts follow the usual two-step bolt-load procedure (as in Abaqus' bolt
load): in the preload step the bolt pulls its two ends together with exactly
its preload ``F`` (its spring is not active); afterwards its length is fixed
at the preloaded state and its axial spring ``k_b`` acts on changes of length,
so the bolt tension is ``F + k_b (elongation since preload)``.  The spring
``K_bolt`` is part of ``K``; :func:`jointsim.model.preload.structural_model` turns this into the
constant force ``f_static = f_clamp + K_bolt x0``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .interface import Interface, pair_interface
from .mesh import FEMesh

log = logging.getLogger(__name__)


def plane_stress_lame(E: float, nu: float):
    """Lame constants of plane stress: ``(lambda*, mu)`` [Pa].

    ``lambda* = E nu / (1 - nu^2)`` replaces the 3D ``lambda`` so that
    ``sigma = 2 mu eps + lambda* tr(eps) I`` is the plane-stress law.
    """
    return E * nu / (1.0 - nu ** 2), E / (2.0 * (1.0 + nu))


def vector_basis(mesh: FEMesh):
    """scikit-fem vector basis of biquadratic quads on the mesh."""
    from skfem import Basis, ElementQuad2, ElementVector
    return Basis(mesh.skfem(), ElementVector(ElementQuad2()))


def assemble_plane_stress(basis, E: float, nu: float, rho: float, thickness: float):
    """Stiffness and mass matrices of a plane-stress body.

    Parameters
    ----------
    basis : skfem.Basis
        Vector basis (x and y displacement).
    E : float
        Young's modulus [Pa].
    nu : float
        Poisson's ratio [-].
    rho : float
        Density [kg/m^3].
    thickness : float
        Out-of-plane depth [m].

    Returns
    -------
    K, M : scipy.sparse.csr_matrix, shape (n_dof, n_dof)
        [N/m] and [kg].
    """
    from skfem import BilinearForm
    from skfem.helpers import ddot, dot, eye, sym_grad, trace
    lam, mu = plane_stress_lame(E, nu)

    @BilinearForm
    def stiffness(u, v, w):
        eps = sym_grad(u)
        sig = 2.0 * mu * eps + lam * eye(trace(eps), 2)
        return thickness * ddot(sig, sym_grad(v))

    @BilinearForm
    def mass(u, v, w):
        return rho * thickness * dot(u, v)

    K = stiffness.assemble(basis).tocsr()
    M = mass.assemble(basis).tocsr()
    return K, M


def point_dofs(basis, node: int) -> np.ndarray:
    """The (x, y) DOFs of a mesh node."""
    return np.asarray(basis.nodal_dofs[:, node], dtype=np.int64)


@dataclass(frozen=True)
class BoltDofs:
    """A bolt between two mesh nodes.

    Attributes
    ----------
    name : str
    lower, upper : ndarray of int, shape (2,)
        (x, y) DOFs of the two ends.
    axis : ndarray, shape (2,)
        Unit vector from the lower to the upper end.
    stiffness : float
        Axial spring [N/m].
    preload : float
        Clamping force [N].
    """

    name: str
    lower: np.ndarray
    upper: np.ndarray
    axis: np.ndarray
    stiffness: float
    preload: float

    @property
    def active_dofs(self) -> np.ndarray:
        """DOFs the bolt acts on (those along its axis)."""
        keep = np.abs(self.axis) > 0
        return np.concatenate([self.lower[keep], self.upper[keep]])


@dataclass(frozen=True)
class FEStructure:
    """The full (unreduced) finite-element lap joint.

    Attributes
    ----------
    mesh : FEMesh
    basis : skfem.Basis
    K, M : scipy.sparse.csr_matrix, shape (n_dof, n_dof)
        Stiffness (continuum + suspension + bolt springs) [N/m] and mass [kg].
    K_bolt : scipy.sparse.csr_matrix, shape (n_dof, n_dof)
        The bolt springs alone [N/m].
    f_clamp : ndarray, shape (n_dof,)
        Bolt clamping forces [N].
    bolts : tuple of BoltDofs
    interface : Interface
        Contact pairs in full DOF numbering.
    points : dict of str -> ndarray of int, shape (2,)
        (x, y) DOFs of each named point.
    """

    mesh: FEMesh
    basis: object
    K: sp.csr_matrix
    M: sp.csr_matrix
    K_bolt: sp.csr_matrix
    f_clamp: np.ndarray
    bolts: tuple
    interface: Interface
    points: dict = field(default_factory=dict)

    @property
    def n_dof(self) -> int:
        return self.K.shape[0]


def _spring(n: int, a: np.ndarray, b: np.ndarray, axis: np.ndarray, k: float):
    """Axial spring ``k`` along ``axis`` between DOF pairs ``a`` and ``b`` (x, y)."""
    dofs = np.concatenate([a, b])
    vec = np.concatenate([-axis, axis])
    local = k * np.outer(vec, vec)
    r, c = np.meshgrid(dofs, dofs, indexing="ij")
    return sp.csr_matrix((local.ravel(), (r.ravel(), c.ravel())), shape=(n, n))


def build_structure(mesh: FEMesh, *, E: float, nu: float, rho: float, thickness: float,
                    bolts=(), suspension_stiffness: float = 0.0,
                    interface=("interface_lower", "interface_upper"),
                    contact_points: str = "nodes", contact_gauss: int = 3) -> FEStructure:
    """Assemble the lap joint from a tagged mesh.

    Parameters
    ----------
    mesh : FEMesh
    E, nu, rho, thickness : float
        Material and depth (see :func:`assemble_plane_stress`).
    bolts : sequence of jointsim.scene.Bolt
        Each names its mesh point sets ``<tag>_lower`` and ``<tag>_upper``.
    suspension_stiffness : float
        Spring to ground in x and in y at every point set whose name starts
        with ``suspension`` [N/m].
    interface : (str, str)
        Edge sets of the interface's lower and upper side.
    contact_points : {"nodes", "gauss"}
        Contact elements: node pairs or Gauss points per interface edge
        (:func:`jointsim.fem.interface.pair_interface`).
    contact_gauss : int
        Gauss points per edge with ``contact_points = "gauss"``.

    Returns
    -------
    FEStructure
    """
    basis = vector_basis(mesh)
    K, M = assemble_plane_stress(basis, E, nu, rho, thickness)
    n = K.shape[0]
    susp = [name for name in mesh.point_sets if name.startswith("suspension")]
    if suspension_stiffness > 0:
        if not susp:
            raise ValueError(f"{mesh.source}: no point set named 'suspension*' to hang the "
                             "structure from")
        diag = np.zeros(n)
        for name in susp:
            diag[point_dofs(basis, mesh.point(name))] += suspension_stiffness
        K = K + sp.diags(diag)
    K_bolt = sp.csr_matrix((n, n))
    f_clamp = np.zeros(n)
    bolt_list = []
    for b in bolts:
        lo_node, up_node = mesh.point(f"{b.tag}_lower"), mesh.point(f"{b.tag}_upper")
        axis = mesh.points[up_node] - mesh.points[lo_node]
        length = np.linalg.norm(axis)
        if length == 0:
            raise ValueError(f"bolt {b.tag!r}: its two ends coincide")
        axis = axis / length
        axis[np.abs(axis) < 1e-14] = 0.0
        lo, up = point_dofs(basis, lo_node), point_dofs(basis, up_node)
        K_bolt = K_bolt + _spring(n, lo, up, axis, b.stiffness)
        f_clamp[lo] += b.preload * axis       # pulls the lower end up
        f_clamp[up] -= b.preload * axis       # and the upper end down
        bolt_list.append(BoltDofs(b.tag, lo, up, axis, b.stiffness, b.preload))
    K = sp.csr_matrix(K + K_bolt)
    iface = pair_interface(basis, mesh, interface[0], interface[1], thickness,
                           points=contact_points, n_gauss=contact_gauss)
    points = {name: point_dofs(basis, mesh.point(name)) for name in mesh.point_sets}
    log.info("FE structure: %d nodes, %d quads, %d DOFs, %d contact pairs, %d bolts",
             len(mesh.points), len(mesh.quads), n, iface.n_elements, len(bolt_list))
    return FEStructure(mesh=mesh, basis=basis, K=K, M=M, K_bolt=sp.csr_matrix(K_bolt),
                       f_clamp=f_clamp, bolts=tuple(bolt_list), interface=iface,
                       points=points)


def merge_coincident(basis) -> sp.csr_matrix:
    """Selector that glues coincident DOFs of separate bodies.

    Returns
    -------
    P : scipy.sparse.csr_matrix, shape (n_dof, n_merged)
        ``x = P @ x_merged``; DOFs at the same position and of the same
        direction share one merged DOF.  ``P.T K P`` is the monolithic body.
    """
    loc = np.round(basis.doflocs.T / 1e-9).astype(np.int64)
    comp = np.arange(basis.N) % 2
    key = np.column_stack([loc, comp])
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    n_m = inverse.max() + 1
    return sp.csr_matrix((np.ones(basis.N), (np.arange(basis.N), inverse)),
                         shape=(basis.N, n_m))
