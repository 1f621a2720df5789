"""Scene -> FE lap joint -> Craig-Bampton -> preloaded StructuralModel.

The retained (physical) DOFs of the reduced model are, in this order:

1. the interface pairs: for pair ``e``, lower x, lower y, upper x, upper y;
2. the bolt ends along the bolt axes (so that the clamping forces and the
   bolt springs act on retained DOFs, which makes the reduced preload exact);
3. x and y of every point of ``model.retain_points`` (default excitation and
   response), unless already retained;

followed by ``model.n_modes`` fixed-interface modal coordinates.  Named
points of the reduced model: ``"<point>.x"``, ``"<point>.y"`` and
``"<point>"`` (= its y DOF, the bending direction).
"""
from __future__ import annotations

import logging
import time

import numpy as np

from .._schema import SceneError
from ..reduction import BoltTable, ReducedModel, craig_bampton, structural_model
from .assembly import build_structure
from .mesh import read_mesh

log = logging.getLogger(__name__)


def retained_dofs(structure, retain_points=("excitation", "response")):
    """Full DOFs kept by the reduction, with a label each.

    Returns
    -------
    dofs : ndarray of int, shape (n_retained,)
    labels : list of str
    """
    dofs, labels = [], []
    seen = set()

    def add(d, label):
        d = int(d)
        if d not in seen:
            seen.add(d)
            dofs.append(d)
            labels.append(label)

    it = structure.interface
    for e in range(it.n_elements):
        for side, arr in (("lower", it.lower_dofs), ("upper", it.upper_dofs)):
            for c, axis in enumerate("xy"):
                add(arr[e, c], f"interface[{e}].{side}.{axis}")
    for b in structure.bolts:
        for side, arr in (("lower", b.lower), ("upper", b.upper)):
            for c, axis in enumerate("xy"):
                if b.axis[c] != 0:
                    add(arr[c], f"{b.name}_{side}.{axis}")
    for p in retain_points:
        if p not in structure.points:
            raise KeyError(p)
        for c, axis in enumerate("xy"):
            add(structure.points[p][c], f"{p}.{axis}")
    return np.array(dofs, dtype=np.int64), labels


def reduce_structure(structure, n_modes: int, retain_points=("excitation", "response")):
    """Craig-Bampton reduction of an :class:`~jointsim.fem.assembly.FEStructure`.

    Returns
    -------
    rom : jointsim.reduction.ReducedModel
    cb : jointsim.reduction.CraigBampton
    """
    B, labels = retained_dofs(structure, retain_points)
    cb = craig_bampton(structure.K, structure.M, B, n_modes)
    index = cb.reduced_index(structure.n_dof)
    bolts = None
    if structure.bolts:
        def red(d, axis):
            return np.where(axis != 0, index[d], -1)
        bl = structure.bolts
        bolts = BoltTable(lower_dofs=np.array([red(b.lower, b.axis) for b in bl]),
                          upper_dofs=np.array([red(b.upper, b.axis) for b in bl]),
                          axis=np.array([b.axis for b in bl]),
                          stiffness=np.array([b.stiffness for b in bl]),
                          preload=np.array([b.preload for b in bl]),
                          names=tuple(b.name for b in bl))
    points = {}
    for p in retain_points:
        dx, dy = structure.points[p]
        points[f"{p}.x"], points[f"{p}.y"] = int(index[dx]), int(index[dy])
        points[p] = int(index[dy])
    labels = labels + [f"mode{k + 1}" for k in range(cb.n_modes)]
    rom = ReducedModel(M=cb.M, K=cb.K, interface=structure.interface.renumbered(index),
                       bolts=bolts, points=points, dof_labels=tuple(labels))
    return rom, cb


def build_fe(scene):
    """Structural model of a ``kind = "fe"`` scene: the reduced, preloaded lap joint.

    ``extra`` holds ``structure`` (the full :class:`FEStructure`), ``cb``
    (the :class:`CraigBampton` basis), ``n_full_dof``, ``build_time_s``,
    ``reduce_time_s`` and everything :func:`jointsim.reduction.structural_model`
    adds (``x0``, ``preload``, ``rom``, ...).
    """
    m = scene.model
    file = str(scene.path)
    t0 = time.perf_counter()
    path = scene.resolve(m.mesh)
    try:
        mesh = read_mesh(path)
    except (OSError, ValueError) as exc:
        raise SceneError(file, "model.mesh", f"could not be read: {exc}") from None
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
                                    interface=(m.interface_lower, m.interface_upper))
    except ValueError as exc:
        raise SceneError(file, "model.mesh", str(exc)) from None
    t1 = time.perf_counter()
    rom, cb = reduce_structure(structure, m.n_modes, m.retain_points)
    t2 = time.perf_counter()
    log.info("FE: %d DOFs -> %d reduced (%d retained + %d modes); build %.2f s, reduce %.2f s",
             structure.n_dof, rom.n_dof, cb.n_retained, cb.n_modes, t1 - t0, t2 - t1)
    return structural_model(scene, rom, preload_tangential=m.preload_tangential,
                            preload_tol=m.preload_tol,
                            extra=dict(structure=structure, cb=cb, mesh_file=str(path),
                                       n_full_dof=structure.n_dof, build_time_s=t1 - t0,
                                       reduce_time_s=t2 - t1))
