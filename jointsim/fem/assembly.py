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

A bolt end is either the tagged node (a point load, the default) or a
**washer patch** (``washer_radius``, :func:`washer_weights`): the end's axial
displacement is the weighted average ``sum_i w_i u_i`` of the surface nodes
under a washer of half-width ``r`` centred on the tagged node, with the
weights of a uniform pressure (``w_i = int_washer N_i ds / 2r``, summing to
1), and the clamping force and the spring act through the same weights (an
RBE3-like averaging: the force on node ``i`` is ``w_i F``).  A point load in
2D has a logarithmically singular local compliance, so a point bolt softens
without bound under refinement; a washer's does not (docs/fe.md).
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
    from skfem.helpers import dot
    lam, mu = plane_stress_lame(E, nu)

    @BilinearForm
    def mass(u, v, w):
        return rho * thickness * dot(u, v)

    K = plane_stress_stiffness(basis, lam, mu, thickness)
    M = mass.assemble(basis).tocsr()
    return K, M


#: Elements per block of :func:`plane_stress_stiffness` (bounds its work arrays: about
#: 15 MB for the 18 local functions of a biquadratic quad at 25 quadrature points).
STIFFNESS_BLOCK = 1024


def plane_stress_stiffness(basis, lam: float, mu: float, thickness: float):
    """``int t sigma(u) : eps(v)`` over the mesh, element matrices by batched products.

    ``sigma = 2 mu eps + lam tr(eps) I``.  The same form as scikit-fem's
    ``BilinearForm`` (the test's oracle, equal to 1e-13), but its element matrices come
    from one batched product per block of elements, ``W_e E_e^T`` with ``E_e`` the
    strains of the local basis functions at the quadrature points (stacked with the
    Lame weights), instead of one form evaluation per pair of local functions (324
    for a biquadratic vector element).  Measured (round 22, one run each): 3.49 ->
    0.35 s for the default scene's 22,500 DOFs, 1.81 -> 0.33 s for 34,844 DOFs (120
    Gauss points).

    Parameters
    ----------
    basis : skfem.Basis
        Vector basis (x and y displacement), :func:`vector_basis`.
    lam, mu : float
        Plane-stress Lame parameters [Pa] (:func:`plane_stress_lame`).
    thickness : float
        Out-of-plane depth [m].

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n_dof, n_dof)
        [N/m].
    """
    dofs = np.asarray(basis.element_dofs)                 # (n_loc, n_el)
    n_loc, n_el = dofs.shape
    data = np.empty((n_el, n_loc, n_loc))
    for e0 in range(0, n_el, STIFFNESS_BLOCK):
        e1 = min(e0 + STIFFNESS_BLOCK, n_el)
        G = np.stack([phi[0].grad[:, :, e0:e1] for phi in basis.basis])   # (a, i, j, e, q)
        eps = 0.5 * (G + G.transpose(0, 2, 1, 3, 4))
        tr = eps[:, 0, 0] + eps[:, 1, 1]                                  # (a, e, q)
        w = thickness * np.asarray(basis.dx[e0:e1])                       # (e, q)
        # per element: rows (a), columns (the strain entries i j and the trace, per q)
        A = np.concatenate([eps.reshape(n_loc, 4, e1 - e0, -1), tr[:, None]], axis=1)
        A = A.transpose(2, 0, 1, 3)                                       # (e, a, 5, q)
        scale = np.array([2 * mu] * 4 + [lam])[None, None, :, None] * w[:, None, None, :]
        data[e0:e1] = np.matmul((A * scale).reshape(e1 - e0, n_loc, -1),
                                A.reshape(e1 - e0, n_loc, -1).transpose(0, 2, 1))
    rows = np.broadcast_to(dofs.T[:, :, None], data.shape)
    cols = np.broadcast_to(dofs.T[:, None, :], data.shape)
    n = basis.N
    K = sp.coo_matrix((data.ravel(), (rows.ravel(), cols.ravel())), shape=(n, n)).tocsr()
    K.eliminate_zeros()
    return K


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
    washer_lower, washer_upper : (ndarray of int, ndarray), optional
        Washer patches (:func:`washer_weights`): the axial DOFs ``(m,)`` of the
        surface nodes under each end and their weights ``(m,)`` (sum 1); None
        for a point bolt (the end is the node ``lower`` / ``upper``).
    """

    name: str
    lower: np.ndarray
    upper: np.ndarray
    axis: np.ndarray
    stiffness: float
    preload: float
    washer_lower: tuple | None = None
    washer_upper: tuple | None = None

    @property
    def axial_component(self) -> int:
        """The component (0: x, 1: y) the bolt axis lies along (washer bolts only)."""
        return int(np.argmax(np.abs(self.axis)))

    def end_weights(self, side: str):
        """(DOFs, weights) of one end along the axis: the washer, or the node.

        Parameters
        ----------
        side : {"lower", "upper"}

        Returns
        -------
        dofs : ndarray of int, shape (m,)
        weights : ndarray, shape (m,)
            ``axis . u_end = sum_k weights[k] x[dofs[k]]``.
        """
        washer = getattr(self, f"washer_{side}")
        if washer is not None:
            c = self.axial_component
            return washer[0], washer[1] * self.axis[c]
        node = getattr(self, side)
        keep = np.abs(self.axis) > 0
        return node[keep], self.axis[keep]

    @property
    def active_dofs(self) -> np.ndarray:
        """DOFs the bolt acts on (those along its axis, every washer node's)."""
        return np.concatenate([self.end_weights("lower")[0], self.end_weights("upper")[0]])

    def elongation(self, n: int) -> sp.csr_matrix:
        """Elongation operator ``e = b @ x`` (upper minus lower end along the axis).

        Returns
        -------
        scipy.sparse.csr_matrix, shape (1, n) [m/m]
        """
        (dl, wl), (du, wu) = self.end_weights("lower"), self.end_weights("upper")
        cols = np.concatenate([du, dl])
        vals = np.concatenate([wu, -wl])
        return sp.csr_matrix((vals, (np.zeros_like(cols), cols)), shape=(1, n))


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


class WasherError(ValueError):
    """A washer patch that cannot be placed (bad radius for the mesh or the bolts)."""


def washer_weights(basis, mesh: FEMesh, node: int, axis: np.ndarray, radius: float):
    """Weights of the surface nodes under a washer centred on a bolt-end node.

    The washer is the segment of half-width ``radius`` [m] along the body's
    surface through ``node``, perpendicular to ``axis``.  The weight of each
    node is the integral of its edge shape function over the washer divided
    by the washer width (a uniform pressure: the weights sum to 1), computed
    with Gauss points on the part of each surface edge the washer covers
    (exact for the quadratic edges also when the washer ends inside an edge).

    Parameters
    ----------
    basis : skfem.Basis
        Vector basis of the mesh.
    mesh : FEMesh
    node : int
        The tagged bolt-end node (the washer centre), on the surface.
    axis : ndarray, shape (2,)
        Unit bolt axis; it must be along x or y.
    radius : float
        Washer half-width [m], > 0.

    Returns
    -------
    dofs : ndarray of int, shape (m,)
        The DOFs along the axis of the nodes under the washer.
    weights : ndarray, shape (m,)
        Their weights (sum 1).

    Raises
    ------
    WasherError
        If the axis is oblique, or the washer runs past the end of the
        surface (past a corner of the body).
    """
    from .interface import _edge_dofs, edge_shape
    axis = np.asarray(axis, dtype=float)
    c = int(np.argmax(np.abs(axis)))
    if abs(abs(axis[c]) - 1.0) > 1e-12:
        raise WasherError(f"a washer needs a bolt axis along x or y, got {axis}")
    if not radius > 0:
        raise WasherError(f"the washer radius must be > 0, got {radius}")
    m = basis.mesh
    p0 = mesh.points[node]
    tdir = 1 - c                          # the surface runs along the other axis
    tol = 1e-9
    # boundary facets on the line through the node, in the node's body
    bnd = m.boundary_facets()
    fn = m.facets[:, bnd]
    on_line = (np.abs(m.p[c, fn[0]] - p0[c]) < tol) & (np.abs(m.p[c, fn[1]] - p0[c]) < tol)
    body = _body_of(mesh)
    same = (body[fn[0]] == body[node]) & (body[fn[1]] == body[node])
    facets = bnd[on_line & same]
    lo, hi = p0[tdir] - radius, p0[tdir] + radius
    quadratic = basis.facet_dofs.size > 0
    xi, wg = np.polynomial.legendre.leggauss(4)
    acc: dict[int, float] = {}
    covered = 0.0
    for f in facets:
        a, b = m.facets[:, f]
        sa, sb = m.p[tdir, a], m.p[tdir, b]
        s0, s1 = max(min(sa, sb), lo), min(max(sa, sb), hi)
        if s1 - s0 <= tol:
            continue
        covered += s1 - s0
        s = (s0 + s1) / 2 + (s1 - s0) / 2 * xi               # points on the overlap
        xi_edge = 2 * (s - sa) / (sb - sa) - 1               # edge coordinate, a -> -1
        N = edge_shape(xi_edge, quadratic)                   # (4, m)
        w = (wg * (s1 - s0) / 2) @ N / (2 * radius)
        for d, wk in zip(_edge_dofs(basis, f, a, b, quadratic)[:, c], w):
            acc[int(d)] = acc.get(int(d), 0.0) + float(wk)
    if abs(covered - 2 * radius) > 1e-6 * radius:
        raise WasherError(f"a washer of radius {radius:g} m at ({p0[0]:g}, {p0[1]:g}) runs past "
                          f"the end of the surface (covers {covered:g} of {2 * radius:g} m)")
    dofs = np.array(sorted(acc), dtype=np.int64)
    return dofs, np.array([acc[d] for d in dofs])


def _body_of(mesh: FEMesh) -> np.ndarray:
    """Connected component (body) of each node of the mesh, shape (n_nodes,)."""
    from scipy.sparse.csgraph import connected_components
    q = mesh.quads
    n = len(mesh.points)
    r = np.repeat(q[:, 0], 3)
    cc = q[:, 1:].ravel()
    g = sp.csr_matrix((np.ones(r.size), (r, cc)), shape=(n, n))
    return connected_components(g, directed=False)[1]


def build_structure(mesh: FEMesh, *, E: float, nu: float, rho: float, thickness: float,
                    bolts=(), suspension_stiffness: float = 0.0,
                    interface=("interface_lower", "interface_upper"),
                    contact_points: str = "nodes", contact_gauss: int = 3,
                    washer_radius: float | None = None) -> FEStructure:
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
    washer_radius : float, optional
        Bolt ends as washer patches of this half-width [m]
        (:func:`washer_weights`); None: point bolts on the tagged nodes.

    Returns
    -------
    FEStructure

    Raises
    ------
    WasherError
        When a washer cannot be placed or two bolts' washers overlap.
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
        washers = (None, None)
        if washer_radius is not None:
            washers = tuple(washer_weights(basis, mesh, nd, axis, washer_radius)
                            for nd in (lo_node, up_node))
        bd = BoltDofs(b.tag, lo, up, axis, b.stiffness, b.preload, *washers)
        e = bd.elongation(n)
        K_bolt = K_bolt + b.stiffness * (e.T @ e)
        f_clamp -= b.preload * e.toarray().ravel()   # pulls the two ends together
        bolt_list.append(bd)
    if washer_radius is not None:
        _check_washers(bolt_list)
    K = sp.csr_matrix(K + K_bolt)
    iface = pair_interface(basis, mesh, interface[0], interface[1], thickness,
                           points=contact_points, n_gauss=contact_gauss)
    points = {name: point_dofs(basis, mesh.point(name)) for name in mesh.point_sets}
    log.info("FE structure: %d nodes, %d quads, %d DOFs, %d contact pairs, %d bolts",
             len(mesh.points), len(mesh.quads), n, iface.n_elements, len(bolt_list))
    return FEStructure(mesh=mesh, basis=basis, K=K, M=M, K_bolt=sp.csr_matrix(K_bolt),
                       f_clamp=f_clamp, bolts=tuple(bolt_list), interface=iface,
                       points=points)


def _check_washers(bolts) -> None:
    """Washers must not cover another bolt end's centre (the reduction substitutes it)."""
    centres = {}
    for b in bolts:
        for side in ("lower", "upper"):
            centres[int(getattr(b, side)[b.axial_component])] = f"{b.name}_{side}"
    for b in bolts:
        for side in ("lower", "upper"):
            own = int(getattr(b, side)[b.axial_component])
            for d in getattr(b, f"washer_{side}")[0]:
                if int(d) != own and int(d) in centres:
                    raise WasherError(f"the washer of {b.name}_{side} covers the end of "
                                      f"{centres[int(d)]}: washers must not overlap")


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
