"""Contact interfaces: contact points, areas, local frames, operators.

An :class:`Interface` is the table every reduced model carries (FE-built or
imported): for each contact element, the DOFs of its lower and upper side,
the local frame and the area it stands for.  The relative displacement
(upper minus lower) projected on the tangent is the slip ``u_t = Tt x``;
projected on the normal (pointing from the lower body into the upper one) it
is the gap change, ``g = gap0 + Tn x`` (see :mod:`jointsim.model`).

Two kinds of contact element (``model.contact_points``, see docs/fe.md):

``"nodes"`` (node-to-node pairs)
    One element per pair of coincident interface nodes; its area is the
    consistent nodal weight, the integral of the node's shape function over
    the interface edges times the out-of-plane depth.  For the quadratic
    edges of the biquadratic element that is ``L/6`` at corners and ``2L/3``
    at midsides of an edge of length ``L`` (corners add up over adjacent
    edges).  The interface energy is then integrated with the nodes as
    quadrature points (Simpson's rule on each edge).
``"gauss"`` (interface quadrature points)
    ``n_gauss`` Gauss-Legendre points on each lower edge (the meshes are
    conforming, so each lower edge has a coincident upper edge).  The relative
    displacement at a point is interpolated from the three nodes of each
    edge with the edge shape functions, and the point's area is
    ``w_g L / 2 x depth``.  With ``n_gauss >= 3`` the stuck interface
    stiffness ``int N^T k N dA`` is integrated exactly (the integrand is of
    degree 4 on an edge).

:func:`pair_interface` builds either from a scikit-fem vector basis and two
tagged edge sets of a mesh.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp


@dataclass(frozen=True)
class Interface:
    """Contact elements between two sides of a joint.

    Attributes
    ----------
    lower_dofs, upper_dofs : ndarray of int, shape (n_e, d) or (n_e, m, d)
        DOF indices, one per space direction (``d`` = 2 in 2D: x and y; -1
        for a missing direction).  Shape ``(n_e, d)``: one node per side (a
        node pair).  Shape ``(n_e, m, d)``: the ``m`` nodes of each side whose
        displacements are interpolated at the contact point with ``shape``.
    frame : ndarray, shape (n_e, 2, d)
        Row 0: unit tangent; row 1: unit normal (from lower into upper body).
    area : ndarray, shape (n_e,)
        Area each element stands for [m^2].
    position : ndarray, shape (n_e, 2)
        Position of each element (of its lower node or contact point) [m].
    shape : ndarray, shape (n_e, m), optional
        Interpolation weights of the ``m`` nodes at each contact point (the
        same for both sides); required with 3-D DOF tables, absent (None) for
        node pairs.
    """

    lower_dofs: np.ndarray
    upper_dofs: np.ndarray
    frame: np.ndarray
    area: np.ndarray
    position: np.ndarray
    shape: np.ndarray | None = None

    def __post_init__(self):
        lo = np.asarray(self.lower_dofs, dtype=np.int64)
        up = np.asarray(self.upper_dofs, dtype=np.int64)
        if lo.ndim < 2:
            lo, up = np.atleast_2d(lo), np.atleast_2d(up)
        fr = np.asarray(self.frame, dtype=float)
        area = np.atleast_1d(np.asarray(self.area, dtype=float))
        pos = np.asarray(self.position, dtype=float).reshape(len(area), -1)
        ne, d = lo.shape[0], lo.shape[-1]
        if up.shape != lo.shape or fr.shape != (ne, 2, d) or area.shape != (ne,):
            raise ValueError(f"interface table shapes disagree: lower_dofs {lo.shape}, "
                             f"upper_dofs {up.shape}, frame {fr.shape}, area {area.shape}")
        w = None
        if lo.ndim == 3:
            if self.shape is None:
                raise ValueError("an interface with (n_e, m, d) DOF tables needs 'shape'")
            w = np.asarray(self.shape, dtype=float)
            if w.shape != lo.shape[:2]:
                raise ValueError(f"interface 'shape' must be {lo.shape[:2]}, got {w.shape}")
        elif lo.ndim != 2 or self.shape is not None:
            raise ValueError(f"interface DOF tables must be (n_e, d) node pairs or "
                             f"(n_e, m, d) with 'shape', got {lo.shape}")
        if np.any(area <= 0):
            raise ValueError("interface areas must be positive")
        for name, arr in (("lower_dofs", lo), ("upper_dofs", up), ("frame", fr),
                          ("area", area), ("position", pos), ("shape", w)):
            object.__setattr__(self, name, arr)

    @property
    def node_pairs(self) -> bool:
        """True for node-to-node elements (one node per side)."""
        return self.shape is None

    def _tables(self):
        """DOF tables as (n_e, m, d) and weights as (n_e, m) for both kinds."""
        if self.shape is None:
            return (self.lower_dofs[:, None, :], self.upper_dofs[:, None, :],
                    np.ones((self.n_elements, 1)))
        return self.lower_dofs, self.upper_dofs, self.shape

    @property
    def n_elements(self) -> int:
        return self.area.size

    @property
    def dofs(self) -> np.ndarray:
        """All DOFs the interface touches, sorted and unique."""
        d = np.concatenate([self.lower_dofs.ravel(), self.upper_dofs.ravel()])
        return np.unique(d[d >= 0])

    def operators(self, n_dof: int):
        """Slip and gap operators.

        Returns
        -------
        Tt, Tn : scipy.sparse.csr_matrix, shape (n_e, n_dof)
            ``u_t = Tt @ x`` and ``g - gap0 = Tn @ x`` [m/m].  For
            interpolated points, row ``e`` is
            ``sum_k shape[e, k] frame[e, row] . (x[upper_k] - x[lower_k])``.
        """
        lo, up, w = self._tables()
        e_idx = np.broadcast_to(np.arange(self.n_elements)[:, None], w.shape)
        out = []
        for row in (0, 1):
            rows, cols, vals = [], [], []
            for sign, dofs in ((1.0, up), (-1.0, lo)):
                for c in range(dofs.shape[2]):
                    v = sign * w * self.frame[:, row, c][:, None]
                    keep = (dofs[:, :, c] >= 0) & (v != 0.0)
                    rows.append(e_idx[keep])
                    cols.append(dofs[:, :, c][keep])
                    vals.append(v[keep])
            T = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                      np.concatenate(cols))),
                              shape=(self.n_elements, n_dof)).tocsr()
            T.sum_duplicates()
            out.append(T)
        return out[0], out[1]

    def renumbered(self, new_index: np.ndarray) -> "Interface":
        """The same table with DOF ``i`` renamed ``new_index[i]`` (e.g. reduced DOFs)."""
        new_index = np.asarray(new_index)

        def remap(d):
            out = np.where(d >= 0, new_index[np.maximum(d, 0)], -1)
            if np.any((d >= 0) & (out < 0)):
                raise ValueError("an interface DOF is not kept by the renumbering")
            return out

        return Interface(remap(self.lower_dofs), remap(self.upper_dofs), self.frame,
                         self.area, self.position, self.shape)


def _facet_index(mesh, edges: np.ndarray, what: str) -> np.ndarray:
    """scikit-fem facet numbers of mesh edges given as node pairs."""
    lookup = {(int(a), int(b)): f for f, (a, b) in enumerate(np.sort(mesh.facets, axis=0).T)}
    out = []
    for a, b in np.sort(edges, axis=1):
        f = lookup.get((int(a), int(b)))
        if f is None:
            raise ValueError(f"edge ({a}, {b}) of {what!r} is not an edge of the mesh")
        out.append(f)
    return np.array(out, dtype=np.int64)


def _side(basis, facets: np.ndarray, thickness: float):
    """Nodes of one interface side: vector DOFs, positions, weights, frames."""
    from skfem import FacetBasis, LinearForm
    mesh = basis.mesh
    fb = FacetBasis(mesh, basis.elem, facets=facets)

    @LinearForm
    def weight(v, w):
        return thickness * v[0]

    wvec = weight.assemble(fb)
    nodes = np.unique(mesh.facets[:, facets])
    xdofs = np.concatenate([basis.nodal_dofs[0, nodes], basis.facet_dofs[0, facets]])
    ydofs = np.concatenate([basis.nodal_dofs[1, nodes], basis.facet_dofs[1, facets]])
    pos = basis.doflocs[:, xdofs].T
    # tangent per node: average of the adjacent edges' directions, oriented so
    # that the body lies on the negative side of the normal (outward normal).
    tang = np.zeros((len(xdofs), 2))
    p = mesh.p
    facet_nodes = mesh.facets[:, facets]
    elem = mesh.f2t[0, facets]
    centroid = p[:, mesh.t[:, elem]].mean(axis=1)
    mid = p[:, facet_nodes].mean(axis=1)
    for k, f in enumerate(facets):
        a, b = facet_nodes[:, k]
        t = p[:, b] - p[:, a]
        t /= np.linalg.norm(t)
        n = np.array([-t[1], t[0]])
        if n @ (centroid[:, k] - mid[:, k]) > 0:   # make n the outward normal
            t = -t
        for node_pos in (p[:, a], p[:, b], mid[:, k]):
            hit = np.nonzero(np.all(np.isclose(pos, node_pos, rtol=0, atol=1e-12), axis=1))[0]
            tang[hit] += t
    tang /= np.linalg.norm(tang, axis=1)[:, None]
    return np.column_stack([xdofs, ydofs]), pos, wvec[xdofs], tang


def pair_interface(basis, mesh_sets, lower: str, upper: str, thickness: float,
                   tol: float = 1e-9, points: str = "nodes", n_gauss: int = 3) -> Interface:
    """Contact elements between two tagged interface sides.

    Parameters
    ----------
    basis : skfem.Basis
        Vector basis of the 2D model (``ElementVector`` of a Lagrange element).
    mesh_sets : jointsim.fem.mesh.FEMesh
        The tagged mesh the basis was built on.
    lower, upper : str
        Names of the two edge sets.
    thickness : float
        Out-of-plane depth [m].
    tol : float
        Distance below which two nodes coincide [m].
    points : {"nodes", "gauss"}
        Node-to-node pairs with consistent nodal areas, or ``n_gauss``
        Gauss-Legendre points per edge (see the module docstring).
    n_gauss : int
        Points per edge for ``points = "gauss"``.

    Returns
    -------
    Interface
        Sorted along the interface.

    Raises
    ------
    ValueError
        If a node or edge has no partner, or the two sides' areas or normals
        disagree.
    """
    mesh = basis.mesh
    fl = _facet_index(mesh, mesh_sets.edges(lower), lower)
    fu = _facet_index(mesh, mesh_sets.edges(upper), upper)
    if points == "gauss":
        return _gauss_interface(basis, fl, fu, lower, upper, thickness, tol, n_gauss)
    if points != "nodes":
        raise ValueError(f"contact points must be 'nodes' or 'gauss', got {points!r}")
    dl, pl, wl, tl = _side(basis, fl, thickness)
    du, pu, wu, tu = _side(basis, fu, thickness)
    if len(pl) != len(pu):
        raise ValueError(f"interface sides {lower!r} and {upper!r} have {len(pl)} and "
                         f"{len(pu)} nodes; they must be paired one to one")
    from scipy.spatial import cKDTree
    dist, j = cKDTree(pu).query(pl)
    if np.any(dist > tol) or len(np.unique(j)) != len(j):
        bad = int(np.argmax(dist))
        raise ValueError(f"interface node at {pl[bad]} of {lower!r} has no partner in "
                         f"{upper!r} (nearest at {dist[bad]:.3g} m)")
    du, wu, tu = du[j], wu[j], tu[j]
    if not np.allclose(wl, wu, rtol=1e-10, atol=0):
        raise ValueError(f"tributary areas of {lower!r} and {upper!r} differ; the sides "
                         "must have matching edges")
    # the lower side's outward tangent/normal is the frame; the upper side's
    # outward normal must be opposite
    nl = np.column_stack([-tl[:, 1], tl[:, 0]])
    nu = np.column_stack([-tu[:, 1], tu[:, 0]])
    if not np.allclose(nl, -nu, atol=1e-9):
        raise ValueError(f"the normals of {lower!r} and {upper!r} are not opposite")
    # order along the tangent
    s = pl @ tl[0]
    order = np.argsort(s, kind="stable")
    frame = np.stack([tl, nl], axis=1)[order]
    return Interface(lower_dofs=dl[order], upper_dofs=du[order], frame=frame,
                     area=wl[order], position=pl[order])


def edge_shape(xi: np.ndarray, quadratic: bool) -> np.ndarray:
    """Lagrange shape functions of an edge at ``xi`` in [-1, 1].

    Returns
    -------
    ndarray, shape (len(xi), 3) or (len(xi), 2)
        Columns: start node (xi = -1), end node (xi = 1), and for quadratic
        edges the midside node (xi = 0).
    """
    xi = np.asarray(xi, dtype=float)
    if quadratic:
        return np.column_stack([xi * (xi - 1) / 2, xi * (xi + 1) / 2, 1 - xi ** 2])
    return np.column_stack([(1 - xi) / 2, (1 + xi) / 2])


def _edge_dofs(basis, facet: int, start: int, end: int, quadratic: bool) -> np.ndarray:
    """(m, 2) x/y DOFs of an edge's nodes in :func:`edge_shape` order."""
    rows = [basis.nodal_dofs[:, start], basis.nodal_dofs[:, end]]
    if quadratic:
        rows.append(basis.facet_dofs[:, facet])
    return np.array(rows, dtype=np.int64)


def _gauss_interface(basis, fl, fu, lower, upper, thickness, tol, n_gauss) -> Interface:
    """Interface of ``n_gauss`` Gauss points per lower edge (see :func:`pair_interface`)."""
    from scipy.spatial import cKDTree
    if n_gauss < 1:
        raise ValueError(f"n_gauss must be >= 1, got {n_gauss}")
    mesh = basis.mesh
    p = mesh.p
    quadratic = basis.facet_dofs.size > 0
    if quadratic and basis.facet_dofs.shape[0] != 2:
        raise ValueError("Gauss-point contact supports Lagrange elements with one facet "
                         "node per edge (linear or quadratic quads)")
    if len(fl) != len(fu):
        raise ValueError(f"interface sides {lower!r} and {upper!r} have {len(fl)} and "
                         f"{len(fu)} edges; they must match edge by edge")
    xi, wg = np.polynomial.legendre.leggauss(n_gauss)
    Nq = edge_shape(xi, quadratic)                       # (n_gauss, m)
    up_nodes = mesh.facets[:, fu]
    tree = cKDTree(p[:, up_nodes].mean(axis=1).T)
    lo_dofs, up_dofs, frames, areas, pos, shapes = [], [], [], [], [], []
    for f in fl:
        a, b = mesh.facets[:, f]
        t = p[:, b] - p[:, a]
        length = float(np.linalg.norm(t))
        t = t / length
        n = np.array([-t[1], t[0]])
        mid = (p[:, a] + p[:, b]) / 2
        centroid = p[:, mesh.t[:, mesh.f2t[0, f]]].mean(axis=1)
        if n @ (centroid - mid) > 0:      # n must point out of the lower body
            t, n, a, b = -t, -n, b, a
        dist, k = tree.query(mid)
        ua, ub = up_nodes[:, k]
        if dist > tol:
            raise ValueError(f"interface edge at {mid} of {lower!r} has no partner in "
                             f"{upper!r} (nearest at {dist:.3g} m)")
        if np.linalg.norm(p[:, ua] - p[:, a]) > tol:
            ua, ub = ub, ua
        if (np.linalg.norm(p[:, ua] - p[:, a]) > tol or
                np.linalg.norm(p[:, ub] - p[:, b]) > tol):
            raise ValueError(f"interface edge at {mid} of {lower!r} does not coincide with "
                             f"an edge of {upper!r}")
        cu = p[:, mesh.t[:, mesh.f2t[0, fu[k]]]].mean(axis=1)
        if n @ (cu - mid) <= 0:
            raise ValueError(f"the normals of {lower!r} and {upper!r} are not opposite at "
                             f"{mid}")
        dl = _edge_dofs(basis, f, a, b, quadratic)
        du = _edge_dofs(basis, fu[k], ua, ub, quadratic)
        for g in range(n_gauss):
            lo_dofs.append(dl)
            up_dofs.append(du)
            frames.append(np.stack([t, n]))
            areas.append(wg[g] * length / 2 * thickness)
            pos.append(p[:, a] + (xi[g] + 1) / 2 * (p[:, b] - p[:, a]))
            shapes.append(Nq[g])
    pos = np.array(pos)
    frames = np.array(frames)
    order = np.argsort(pos @ frames[0, 0], kind="stable")
    return Interface(lower_dofs=np.array(lo_dofs)[order], upper_dofs=np.array(up_dofs)[order],
                     frame=frames[order], area=np.array(areas)[order], position=pos[order],
                     shape=np.array(shapes)[order])
