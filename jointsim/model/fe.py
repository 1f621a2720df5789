"""Builder of ``kind = "fe"`` scenes: mesh -> FE lap joint -> Craig-Bampton -> preload.

The mesh is either a file (``model.mesh``) or generated from
``model.dx_lap``/``dx_full``/``ny_half`` (:func:`fe_mesh`), so that the
interface resolution is a ``--set`` or a ``jointsim sweep --vary`` away.

The FE part (assembly and reduction) is :mod:`jointsim.fem`; the preload and
the contact set are :func:`jointsim.model.preload.structural_model`.
"""
from __future__ import annotations

import logging
import time

from .._schema import SceneError
from ..fem.assembly import WasherError, build_structure
from ..fem.build import reduce_structure
from ..fem.generate import generated_lap_joint
from ..fem.mesh import read_mesh
from .preload import structural_model
from .structural import FEParts, StructuralModel

log = logging.getLogger(__name__)


def build_fe(scene) -> StructuralModel:
    """Structural model of a ``kind = "fe"`` scene: the reduced, preloaded lap joint
    (a builder of :data:`jointsim.model.BUILDERS`).

    ``fe`` of the model holds the full :class:`~jointsim.fem.assembly.FEStructure`,
    the :class:`~jointsim.fem.reduction.CraigBampton` basis, the mesh file and the
    build and reduction times; ``preload``, ``rom`` and ``linearisation`` are set
    by :func:`jointsim.model.preload.structural_model`.

    Raises
    ------
    SceneError
        When the mesh cannot be read or lacks a set the scene names.
    """
    m = scene.model
    file = str(scene.path)
    t0 = time.perf_counter()
    mesh, mesh_file = fe_mesh(scene)
    for i, b in enumerate(m.bolts):
        for side in ("lower", "upper"):
            if f"{b.tag}_{side}" not in mesh.point_sets:
                raise SceneError(file, f"model.bolts[{i}].tag",
                                 f"{b.tag!r}: the mesh has no point set '{b.tag}_{side}'")
    for key in ("interface_lower", "interface_upper"):
        if getattr(m, key) not in mesh.edge_sets:
            raise SceneError(file, f"model.{key}", f"{getattr(m, key)!r} is not an edge set "
                                                   f"of the mesh ({sorted(mesh.edge_sets)})")
    for p in m.retain_points:
        if p not in mesh.point_sets:
            raise SceneError(file, "model.retain_points",
                             f"{p!r} is not a point set of the mesh ({sorted(mesh.point_sets)})")
    try:
        structure = build_structure(mesh, E=m.E, nu=m.nu, rho=m.rho, thickness=m.thickness,
                                    bolts=m.bolts, suspension_stiffness=m.suspension_stiffness,
                                    interface=(m.interface_lower, m.interface_upper),
                                    contact_points=m.contact_points,
                                    contact_gauss=m.contact_gauss,
                                    washer_radius=m.bolt_washer_radius)
    except WasherError as exc:
        raise SceneError(file, "model.bolt_washer_radius", str(exc)) from None
    except ValueError as exc:
        raise SceneError(file, "model.mesh" if m.mesh else "model.dx_lap", str(exc)) from None
    t1 = time.perf_counter()
    rom, cb = reduce_structure(structure, m.n_modes, m.retain_points)
    t2 = time.perf_counter()
    log.info("FE: %d DOFs -> %d reduced (%d retained + %d modes); build %.2f s, reduce %.2f s",
             structure.n_dof, rom.n_dof, cb.n_retained, cb.n_modes, t1 - t0, t2 - t1)
    return structural_model(scene, rom, preload_tangential=m.preload_tangential,
                            preload_tol=m.preload_tol,
                            fe=FEParts(structure=structure, cb=cb, mesh_file=mesh_file,
                                       build_time_s=t1 - t0, reduce_time_s=t2 - t1))


def fe_mesh(scene):
    """The tagged mesh of an FE scene: read from ``model.mesh`` or generated.

    Returns
    -------
    mesh : jointsim.fem.mesh.FEMesh
    source : str
        The mesh file (absolute path), or a description of the generation
        parameters (``generated lap joint (dx_lap=..., ...)``).

    Raises
    ------
    SceneError
        Naming ``model.mesh`` when the file cannot be read, or ``model.dx_lap``
        when the parameters cannot place a node at a bolt or tagged point.
    """
    m = scene.model
    file = str(scene.path)
    gen = m.generate
    if gen is None:
        path = scene.resolve(m.mesh)
        try:
            return read_mesh(path), str(path)
        except (OSError, ValueError) as exc:
            raise SceneError(file, "model.mesh", f"could not be read: {exc}") from None
        except SystemExit:  # meshio exits on a file it cannot parse
            raise SceneError(file, "model.mesh", f"could not be read as a mesh: {path}") from None
    try:
        mesh = generated_lap_joint(float(gen["dx_lap"]), float(gen["dx_full"]),
                                   int(gen["ny_half"]))
    except ValueError as exc:
        raise SceneError(file, "model.dx_lap", f"(with dx_full = {gen['dx_full']:g}, "
                                               f"ny_half = {gen['ny_half']}): {exc}") from None
    log.info("FE mesh: %s, %d nodes, %d quads", mesh.source, len(mesh.points), len(mesh.quads))
    return mesh, mesh.source
