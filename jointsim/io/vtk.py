"""ParaView export (VTU/XDMF via meshio) of FE result files.

Reads the ``/mesh`` group written by the modes analysis (9-node quads over
every node of the biquadratic field) and writes:

* the mesh with point data ``mode_<k>`` (displacement vectors, padded to 3D
  for ParaView's *Warp By Vector*), ``preload_displacement`` and cell data
  ``body``, as ``.vtu`` (or ``.xdmf``);
* the interface as a polyline of its contact elements (their positions)
  with point data ``pressure``, ``N0``, ``area``, ``gap``.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


def _pad3(v: np.ndarray) -> np.ndarray:
    out = np.zeros((v.shape[0], 3))
    out[:, : v.shape[1]] = v
    return out


def mesh_fields(h5, n_modes: int | None = None) -> dict:
    """Point fields of the mesh: mode shapes and the preload displacement.

    Returns
    -------
    dict of str -> ndarray, shape (n_nodes, 3)
    """
    node_dofs = h5["mesh/node_dofs"][()]
    fields = {}
    if "modes/shapes_full" in h5:
        shapes = h5["modes/shapes_full"][()]
        f = h5["modes/frequency_hz"][()]
        k = shapes.shape[0] if n_modes is None else min(n_modes, shapes.shape[0])
        for i in range(k):
            fields[f"mode_{i + 1}_{f[i]:.1f}Hz"] = _pad3(shapes[i][node_dofs])
    if "static/x0_full" in h5:
        fields["preload_displacement"] = _pad3(h5["static/x0_full"][()][node_dofs])
    return fields


def write_mesh_file(h5, path, n_modes: int | None = None) -> Path:
    """Write the FE mesh with mode shapes as ``.vtu`` or ``.xdmf``.

    Parameters
    ----------
    h5 : h5py.File
        Result file with a ``/mesh`` group.
    path : str or Path
        Output file; the format follows the extension.
    n_modes : int, optional
        Modes exported (default all stored).
    """
    import meshio
    path = Path(path)
    pts = _pad3(h5["mesh/points"][()])
    cells = [("quad9", h5["mesh/quad9"][()])]
    mesh = meshio.Mesh(pts, cells, point_data=mesh_fields(h5, n_modes),
                       cell_data={"body": [h5["mesh/body"][()]]})
    mesh.write(path)
    return path


def write_interface_file(h5, path) -> Path:
    """Write the contact elements as a polyline with the preload pressure."""
    import meshio
    path = Path(path)
    pos = h5["contacts/position"][()]
    n = len(pos)
    cells = [("vertex", np.arange(n)[:, None])]
    if n > 1:  # a polyline needs two points (a one-element lumped joint has none)
        cells.insert(0, ("line", np.column_stack([np.arange(n - 1), np.arange(1, n)])))
    data = {"pressure": h5["static/pressure"][()], "N0": h5["static/N"][()],
            "area": h5["contacts/area"][()]}
    if "static/gap" in h5:
        data["gap"] = h5["static/gap"][()]
    mesh = meshio.Mesh(_pad3(pos), cells, point_data=data)
    mesh.write(path)
    return path


def export_paraview(h5, outdir, stem: str = "fe", fmt: str = "vtu") -> list[Path]:
    """Write every ParaView file a result file supports.

    Returns
    -------
    list of Path
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    out = []
    if "mesh" in h5:
        out.append(write_mesh_file(h5, outdir / f"{stem}_modes.{fmt}"))
    if "static/pressure" in h5 and "contacts/position" in h5:
        out.append(write_interface_file(h5, outdir / f"{stem}_interface.{fmt}"))
    return out
