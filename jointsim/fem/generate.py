"""Structured quadrilateral meshes of beams and of the BRB-like lap joint.

The meshes are made of straight-edged 4-node quadrilaterals; the finite
element on them is the 9-node biquadratic Lagrange quadrilateral
(``skfem.ElementQuad2``), whose midside and centre nodes scikit-fem adds.
Every entity the model needs is *tagged* here and written into the mesh file
as a gmsh physical group, so that the model code never looks for coordinates:

* surfaces (quads): one per body (``beam_left``, ``beam_right``; ``beam``);
* lines (mesh edges): ``interface_lower``, ``interface_upper`` (the two sides
  of the lap interface), ``clamp`` (cantilever root);
* vertices (mesh nodes): ``bolt<k>_lower`` / ``bolt<k>_upper`` (the two ends of
  bolt ``k``), ``suspension_left`` / ``suspension_right``, ``excitation``,
  ``response``, ``tip``.

The lap-joint geometry (DESIGN §2): two beams of 25.4 mm x 25.4 mm section,
each with 300 mm of full section and a 120 mm lap at half thickness; the laps
overlap on x in [-60, 60] mm and touch along y = 12.7 mm.  The right beam is
the left one rotated by 180 degrees about the lap centre (0, 12.7 mm), so the
mesh has that point symmetry exactly.  The two beams are separate bodies with
coincident, duplicated nodes along the interface.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

#: gmsh dimension of each tag kind
_DIM = {"vertex": 0, "line": 1, "quad": 2}


@dataclass(frozen=True)
class LapJointGeometry:
    """Dimensions of the lap joint [m] (defaults: DESIGN §2).

    Attributes
    ----------
    height : float
        Full section height (the lap is half of it).
    full_length : float
        Length of each beam's full section.
    lap_length : float
        Length of the overlap (each beam's lap).
    bolts : tuple of float
        Bolt axial positions, relative to the lap centre.
    suspension : float
        Distance of the suspension points from the lap centre (on the neutral
        axis y = height/2, one per beam).
    excitation, response : (float, float)
        Positions of the excitation and response nodes.
    """

    height: float = 0.0254
    full_length: float = 0.300
    lap_length: float = 0.120
    bolts: tuple = (-0.030, 0.0, 0.030)
    suspension: float = 0.240
    excitation: tuple = (0.300, 0.0)
    response: tuple = (0.360, 0.0)


class _Builder:
    """Collects nodes, quads, edges and vertex tags of structured blocks."""

    def __init__(self):
        self.points: list[tuple[float, float]] = []
        self.quads: list[tuple[int, int, int, int]] = []
        self.quad_tag: list[str] = []
        self.tags: dict[str, tuple[str, list]] = {}   # name -> (kind, entities)

    def body(self, blocks, name: str, tol: float):
        """Add one body made of rectangular blocks sharing their grid lines.

        ``blocks`` is a list of (x_nodes, y_nodes) arrays.  Nodes of the same
        body at the same position are merged; different bodies never share a
        node.  Returns a lookup ``(x, y) -> node index`` for this body.
        """
        lookup: dict[tuple[int, int], int] = {}

        def key(x, y):
            return (int(round(x / tol)), int(round(y / tol)))

        for xs, ys in blocks:
            idx = np.empty((len(xs), len(ys)), dtype=np.int64)
            for i, x in enumerate(xs):
                for j, y in enumerate(ys):
                    k = key(x, y)
                    if k not in lookup:
                        lookup[k] = len(self.points)
                        self.points.append((float(x), float(y)))
                    idx[i, j] = lookup[k]
            for i in range(len(xs) - 1):
                for j in range(len(ys) - 1):
                    self.quads.append((idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]))
                    self.quad_tag.append(name)

        def node(x, y):
            k = key(x, y)
            if k not in lookup:
                raise ValueError(f"no node of body {name!r} at ({x:g}, {y:g}): the mesh "
                                 "spacing must place a node there")
            return lookup[k]

        return node

    def tag(self, name: str, kind: str, entity) -> None:
        self.tags.setdefault(name, (kind, []))[1].append(entity)

    def mesh(self):
        import meshio
        pts = np.zeros((len(self.points), 3))
        pts[:, :2] = np.array(self.points)
        names = sorted(set(self.quad_tag)) + sorted(self.tags)
        number = {n: i + 1 for i, n in enumerate(names)}
        field_data = {n: np.array([number[n], 2]) for n in sorted(set(self.quad_tag))}
        cells = [("quad", np.array(self.quads, dtype=np.int64))]
        phys = [np.array([number[n] for n in self.quad_tag], dtype=np.int64)]
        for kind in ("line", "vertex"):
            conn, tags = [], []
            for n in sorted(self.tags):
                k, ents = self.tags[n]
                if k != kind:
                    continue
                field_data[n] = np.array([number[n], _DIM[kind]])
                for e in ents:
                    conn.append(e if kind == "line" else (e,))
                    tags.append(number[n])
            if conn:
                cells.append((kind, np.array(conn, dtype=np.int64)))
                phys.append(np.array(tags, dtype=np.int64))
        return meshio.Mesh(pts, cells, cell_data={"gmsh:physical": phys,
                                                  "gmsh:geometrical": phys},
                           field_data=field_data)


def _nodes(a: float, b: float, n: int) -> np.ndarray:
    return np.linspace(a, b, n + 1)


def _count(length: float, size: float) -> int:
    return max(1, int(round(length / size)))


def lap_joint_mesh(dx_lap: float, dx_full: float, ny_half: int,
                   geometry: LapJointGeometry = LapJointGeometry()):
    """The 2D lap-joint mesh with all its tags.

    Parameters
    ----------
    dx_lap : float
        Element length along the lap [m]; bolt positions must fall on nodes.
    dx_full : float
        Element length along the full sections [m].
    ny_half : int
        Elements through the half thickness (the lap).
    geometry : LapJointGeometry

    Returns
    -------
    meshio.Mesh
        Quads with gmsh physical tags (see the module docstring).
    """
    g = geometry
    h, hh = g.height, g.height / 2
    a = g.lap_length / 2
    tol = 1e-9
    nl, nf = _count(g.lap_length, dx_lap), _count(g.full_length, dx_full)
    b = _Builder()
    y_full, y_half = _nodes(0.0, h, 2 * ny_half), _nodes(0.0, hh, ny_half)
    left_blocks = [(_nodes(-a - g.full_length, -a, nf), y_full), (_nodes(-a, a, nl), y_half)]

    def rotate(blocks):  # 180 degrees about (0, h/2): (x, y) -> (-x, h - y)
        return [(-xs[::-1], h - ys[::-1]) for xs, ys in blocks]

    left = b.body(left_blocks, "beam_left", tol)
    right = b.body(rotate(left_blocks), "beam_right", tol)
    xs_lap = _nodes(-a, a, nl)
    for x0, x1 in zip(xs_lap[:-1], xs_lap[1:]):
        b.tag("interface_lower", "line", (left(x0, hh), left(x1, hh)))
        b.tag("interface_upper", "line", (right(x0, hh), right(x1, hh)))
    for k, xb in enumerate(g.bolts, start=1):
        b.tag(f"bolt{k}_lower", "vertex", left(xb, 0.0))
        b.tag(f"bolt{k}_upper", "vertex", right(xb, h))
    b.tag("suspension_left", "vertex", left(-g.suspension, hh))
    b.tag("suspension_right", "vertex", right(g.suspension, hh))
    for name, (x, y) in (("excitation", g.excitation), ("response", g.response)):
        node = right if x > 0 else left
        b.tag(name, "vertex", node(x, y))
    return b.mesh()


def beam_mesh(length: float, height: float, dx: float, ny: int):
    """A rectangular beam ``[0, length] x [0, height]`` tagged as a cantilever.

    Tags: ``beam`` (quads), ``clamp`` (the edges at x = 0), ``tip`` (the node
    at (length, 0)).

    Returns
    -------
    meshio.Mesh
    """
    b = _Builder()
    nx = _count(length, dx)
    ys = _nodes(0.0, height, ny)
    node = b.body([(_nodes(0.0, length, nx), ys)], "beam", 1e-9)
    for y0, y1 in zip(ys[:-1], ys[1:]):
        b.tag("clamp", "line", (node(0.0, y0), node(0.0, y1)))
    b.tag("tip", "vertex", node(length, 0.0))
    return b.mesh()


#: the committed meshes: name -> (dx_lap, dx_full, ny_half) [m, m, -]
RESOLUTIONS = {
    "coarse": (0.015, 0.030, 1),
    "default": (0.010, 0.020, 2),
}


@functools.lru_cache(maxsize=16)
def generated_lap_joint(dx_lap: float, dx_full: float, ny_half: int):
    """The lap-joint mesh of :func:`lap_joint_mesh` as a tagged FEMesh, cached in memory.

    This is what a scene with ``model.dx_lap`` (and ``dx_full``, ``ny_half``)
    builds instead of reading ``model.mesh``; the same parameters give the
    same mesh as ``meshes/make_meshes.py --dx-lap ... -o file.msh`` read back.
    Generating is cheap (milliseconds); the cache makes repeated builds in one
    process (tests, sweeps run in-process) reuse the object.

    Parameters
    ----------
    dx_lap, dx_full : float
        Element lengths along the lap and the full sections [m].
    ny_half : int
        Elements through the half thickness.

    Returns
    -------
    jointsim.fem.mesh.FEMesh
        ``source`` names the parameters.

    Raises
    ------
    ValueError
        When a bolt or a tagged point does not fall on a node.
    """
    from .mesh import from_meshio
    source = f"generated lap joint (dx_lap={dx_lap:g}, dx_full={dx_full:g}, ny_half={ny_half})"
    return from_meshio(lap_joint_mesh(dx_lap, dx_full, ny_half), source)


def layered_beam_mesh(length: float, height: float, dx: float, ny_half: int):
    """Two stacked beams ``[0, length] x [0, height]`` split at ``y = height/2``.

    A cantilever with an interface: the two layers are separate bodies with
    coincident, duplicated nodes along ``y = height/2``.  Tags: ``beam_lower``
    and ``beam_upper`` (quads), ``interface_lower`` and ``interface_upper``
    (the two sides of the interface), ``clamp`` (the edges at x = 0 of both
    layers), ``tip`` (the node at (length, 0)).

    Returns
    -------
    meshio.Mesh
    """
    b = _Builder()
    nx = _count(length, dx)
    xs = _nodes(0.0, length, nx)
    hh = height / 2
    lower = b.body([(xs, _nodes(0.0, hh, ny_half))], "beam_lower", 1e-9)
    upper = b.body([(xs, _nodes(hh, height, ny_half))], "beam_upper", 1e-9)
    for x0, x1 in zip(xs[:-1], xs[1:]):
        b.tag("interface_lower", "line", (lower(x0, hh), lower(x1, hh)))
        b.tag("interface_upper", "line", (upper(x0, hh), upper(x1, hh)))
    for node, ys in ((lower, _nodes(0.0, hh, ny_half)), (upper, _nodes(hh, height, ny_half))):
        for y0, y1 in zip(ys[:-1], ys[1:]):
            b.tag("clamp", "line", (node(0.0, y0), node(0.0, y1)))
    b.tag("tip", "vertex", lower(length, 0.0))
    return b.mesh()
