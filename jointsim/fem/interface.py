"""Contact interfaces: node pairs, tributary areas, local frames, operators.

An :class:`Interface` is the table every reduced model carries (FE-built or
imported): for each contact element (a node pair), the DOFs of its lower
(``a``) and upper (``b``) node, the local frame and the tributary area.  The
relative displacement ``b - a`` projected on the tangent is the slip
``u_t = Tt x``; projected on the normal (pointing from the lower body into
the upper one) it is the gap change, ``g = gap0 + Tn x``
(see :mod:`jointsim.model`).

:func:`pair_interface` builds it from a scikit-fem vector basis and two
tagged edge sets of a mesh.  Tributary areas are the consistent nodal
weights: the integral of each node's shape function over the interface edges
times the out-of-plane depth.  For the quadratic edges of the biquadratic
element that is ``L/6`` at corners and ``2L/3`` at midsides of an edge of
length ``L`` (corners add up over adjacent edges).
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
    lower_dofs, upper_dofs : ndarray of int, shape (n_e, d)
        DOF indices of the two nodes of each pair, one per space direction
        (``d`` = 2 in 2D: x and y; -1 for a missing direction).
    frame : ndarray, shape (n_e, 2, d)
        Row 0: unit tangent; row 1: unit normal (from lower into upper body).
    area : ndarray, shape (n_e,)
        Tributary area of each pair [m^2].
    position : ndarray, shape (n_e, 2)
        Position of each pair (of its lower node) [m].
    """

    lower_dofs: np.ndarray
    upper_dofs: np.ndarray
    frame: np.ndarray
    area: np.ndarray
    position: np.ndarray

    def __post_init__(self):
        lo = np.atleast_2d(np.asarray(self.lower_dofs, dtype=np.int64))
        up = np.atleast_2d(np.asarray(self.upper_dofs, dtype=np.int64))
        fr = np.asarray(self.frame, dtype=float)
        area = np.atleast_1d(np.asarray(self.area, dtype=float))
        pos = np.asarray(self.position, dtype=float).reshape(len(area), -1)
        ne, d = lo.shape
        if up.shape != (ne, d) or fr.shape != (ne, 2, d) or area.shape != (ne,):
            raise ValueError(f"interface table shapes disagree: lower_dofs {lo.shape}, "
                             f"upper_dofs {up.shape}, frame {fr.shape}, area {area.shape}")
        if np.any(area <= 0):
            raise ValueError("interface areas must be positive")
        for name, arr in (("lower_dofs", lo), ("upper_dofs", up), ("frame", fr),
                          ("area", area), ("position", pos)):
            object.__setattr__(self, name, arr)

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
            ``u_t = Tt @ x`` and ``g - gap0 = Tn @ x`` [m/m].
        """
        out = []
        for row in (0, 1):
            rows, cols, vals = [], [], []
            for sign, dofs in ((1.0, self.upper_dofs), (-1.0, self.lower_dofs)):
                for c in range(dofs.shape[1]):
                    v = sign * self.frame[:, row, c]
                    keep = (dofs[:, c] >= 0) & (v != 0.0)
                    rows.append(np.nonzero(keep)[0])
                    cols.append(dofs[keep, c])
                    vals.append(v[keep])
            out.append(sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                             np.concatenate(cols))),
                                     shape=(self.n_elements, n_dof)))
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
                         self.area, self.position)


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
                   tol: float = 1e-9) -> Interface:
    """Pair the nodes of two tagged interface sides by coordinates.

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

    Returns
    -------
    Interface
        One element per node pair, sorted along the interface.

    Raises
    ------
    ValueError
        If a node has no partner, or the two sides' tributary areas differ.
    """
    mesh = basis.mesh
    fl = _facet_index(mesh, mesh_sets.edges(lower), lower)
    fu = _facet_index(mesh, mesh_sets.edges(upper), upper)
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
