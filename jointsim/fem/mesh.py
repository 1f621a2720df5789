"""Reading tagged meshes (meshio) into plain arrays and scikit-fem meshes.

A jointsim mesh is a 2D mesh of 4-node quadrilaterals (the element on it is
biquadratic, see :mod:`jointsim.fem.assembly`) plus named sets:

* ``cell_sets``: quads per body (gmsh physical surfaces);
* ``edge_sets``: mesh edges given as node pairs (gmsh physical lines), e.g.
  the two sides of the interface;
* ``point_sets``: mesh nodes (gmsh physical points), e.g. bolt ends, the
  suspension, excitation and response points.

Files written by :mod:`meshes/make_meshes.py` are gmsh 2.2 ``.msh``; any
format meshio reads works if it carries the names either as gmsh physical
groups (``gmsh:physical`` cell data plus ``field_data``) or as meshio
``cell_sets``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FEMesh:
    """A tagged quadrilateral mesh.

    Attributes
    ----------
    points : ndarray, shape (n_nodes, 2)
        Node coordinates [m].
    quads : ndarray of int, shape (n_cells, 4)
        Corner nodes of each quad, counter-clockwise.
    cell_sets : dict of str -> ndarray of int
        Quads of each named region.
    edge_sets : dict of str -> ndarray of int, shape (n_edges, 2)
        Node pairs of each named edge set.
    point_sets : dict of str -> ndarray of int
        Nodes of each named point set.
    source : str
        Where the mesh came from.
    """

    points: np.ndarray
    quads: np.ndarray
    cell_sets: dict = field(default_factory=dict)
    edge_sets: dict = field(default_factory=dict)
    point_sets: dict = field(default_factory=dict)
    source: str = ""

    def point(self, name: str) -> int:
        """The single node of a point set."""
        nodes = self.point_sets.get(name)
        if nodes is None:
            raise KeyError(f"{self.source}: the mesh has no point set {name!r}; it has "
                           f"{sorted(self.point_sets)}")
        if len(nodes) != 1:
            raise ValueError(f"{self.source}: point set {name!r} has {len(nodes)} nodes, "
                             "expected one")
        return int(nodes[0])

    def edges(self, name: str) -> np.ndarray:
        """Node pairs of an edge set, shape (n_edges, 2)."""
        if name not in self.edge_sets:
            raise KeyError(f"{self.source}: the mesh has no edge set {name!r}; it has "
                           f"{sorted(self.edge_sets)}")
        return self.edge_sets[name]

    def skfem(self):
        """The scikit-fem mesh (``MeshQuad1``) with the same node numbering."""
        from skfem import MeshQuad1
        return MeshQuad1(np.ascontiguousarray(self.points.T),
                         np.ascontiguousarray(self.quads.T))


def _orient(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Quads made counter-clockwise (positive signed area)."""
    p = points[quads]
    x, y = p[..., 0], p[..., 1]
    area2 = (x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y).sum(axis=1)
    if np.any(area2 == 0):
        raise ValueError("mesh has degenerate (zero-area) quads")
    out = quads.copy()
    flip = area2 < 0
    out[flip] = out[flip][:, ::-1]
    return out


def from_meshio(m, source: str = "<meshio>") -> FEMesh:
    """Convert a meshio mesh with named groups to :class:`FEMesh`.

    Raises
    ------
    ValueError
        If the mesh has no quads, has other 2D cells, or is not planar.
    """
    pts = np.asarray(m.points, dtype=float)
    if pts.shape[1] == 3:
        if np.any(np.abs(pts[:, 2]) > 1e-12 * max(1.0, np.abs(pts).max())):
            raise ValueError(f"{source}: the mesh is not planar (z != 0)")
        pts = pts[:, :2]
    names_by_tag: dict[tuple[int, int], str] = {}
    for name, (tag, dim) in (m.field_data or {}).items():
        names_by_tag[(int(dim), int(tag))] = name
    phys = (m.cell_data or {}).get("gmsh:physical")
    dims = {"vertex": 0, "line": 1, "line3": 1, "quad": 2, "quad9": 2, "quad8": 2}
    quads = []
    cell_sets: dict[str, list] = {}
    edge_sets: dict[str, list] = {}
    point_sets: dict[str, list] = {}
    n_quads = 0
    for b, block in enumerate(m.cells):
        kind, data = block.type, np.asarray(block.data, dtype=np.int64)
        if kind in ("triangle", "triangle6", "quad8", "quad9"):
            raise ValueError(f"{source}: cells of type {kind!r} are not supported; "
                             "give straight 4-node quads (the element is biquadratic)")
        tags = phys[b] if phys is not None else None
        for i, row in enumerate(data):
            name = None
            if tags is not None:
                name = names_by_tag.get((dims.get(kind, -1), int(tags[i])))
            if kind == "quad":
                quads.append(row)
                if name:
                    cell_sets.setdefault(name, []).append(n_quads)
                n_quads += 1
            elif kind in ("line", "line3") and name:
                edge_sets.setdefault(name, []).append(row[:2])
            elif kind == "vertex" and name:
                point_sets.setdefault(name, []).append(row[0])
    # meshio cell sets (XDMF, VTU written by meshio) as a second source of names
    for name, per_block in (getattr(m, "cell_sets", None) or {}).items():
        if name.startswith("gmsh:"):
            continue
        offset = 0
        for block, idx in zip(m.cells, per_block):
            idx = np.asarray(idx, dtype=np.int64)
            if block.type == "quad":
                cell_sets.setdefault(name, []).extend((offset + idx).tolist())
                offset += len(block.data)
            elif block.type == "line":
                edge_sets.setdefault(name, []).extend(block.data[idx, :2].tolist())
            elif block.type == "vertex":
                point_sets.setdefault(name, []).extend(block.data[idx, 0].tolist())
    if not quads:
        raise ValueError(f"{source}: the mesh has no quadrilaterals")
    quads_arr = _orient(pts, np.array(quads, dtype=np.int64))
    return FEMesh(points=pts, quads=quads_arr,
                  cell_sets={k: np.array(v, dtype=np.int64) for k, v in cell_sets.items()},
                  edge_sets={k: np.array(v, dtype=np.int64).reshape(-1, 2)
                             for k, v in edge_sets.items()},
                  point_sets={k: np.array(v, dtype=np.int64) for k, v in point_sets.items()},
                  source=source)


def read_mesh(path) -> FEMesh:
    """Read a tagged mesh file with meshio.

    Parameters
    ----------
    path : str or Path
        ``.msh`` (gmsh), ``.vtu``, ``.xdmf`` or any format meshio reads.
    """
    import meshio
    path = Path(path)
    # '.msh' is ambiguous to meshio (ANSYS or gmsh); it tries both and prints
    # the failure of the first, so name the format
    fmt = "gmsh" if path.suffix.lower() == ".msh" else None
    mesh = from_meshio(meshio.read(path, file_format=fmt), str(path))
    log.debug("%s: %d nodes, %d quads, sets %s", path, len(mesh.points), len(mesh.quads),
              sorted([*mesh.cell_sets, *mesh.edge_sets, *mesh.point_sets]))
    return mesh


def write_mesh(mesh, path) -> Path:
    """Write a meshio mesh made by :mod:`jointsim.fem.generate` (gmsh 2.2 ASCII)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.write(path, file_format="gmsh22", binary=False)
    return path
