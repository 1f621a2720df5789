"""FE structure -> Craig-Bampton -> :class:`~jointsim.fem.reduced.ReducedModel`.

The retained (physical) DOFs of the reduced model are, in this order:

1. the interface: for node pairs, pair ``e``'s lower x, lower y, upper x,
   upper y (labels ``interface[e].lower.x`` ...); for Gauss-point elements,
   every node the points interpolate from, lower side then upper side in the
   order the points first use them (labels ``interface_node[k].lower.x`` ...);
2. the bolt ends along the bolt axes (so that the clamping forces and the
   bolt springs act on retained DOFs, which makes the reduced preload exact);
3. x and y of every point of ``model.retain_points`` (default excitation and
   response), unless already retained;

followed by ``model.n_modes`` fixed-interface modal coordinates.

With washer bolts (``model.bolt_washer_radius``) the retained coordinate of a
bolt end is not its centre node's displacement but the washer average
``sum_i w_i u_i`` (:func:`washer_substitution`): the centre node's axial DOF
is replaced by it before the reduction, so the bolt spring and the clamping
force act on one retained coordinate, as for a point bolt, and the reduced
preload stays exact.  ``cb.T`` maps back to the physical full DOFs.  Named
points of the reduced model: ``"<point>.x"``, ``"<point>.y"`` and
``"<point>"`` (= its y DOF, the bending direction).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from .reduced import BoltTable, ReducedModel
from .reduction import craig_bampton


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
    if it.node_pairs:
        for e in range(it.n_elements):
            for side, arr in (("lower", it.lower_dofs), ("upper", it.upper_dofs)):
                for c, axis in enumerate("xy"):
                    add(arr[e, c], f"interface[{e}].{side}.{axis}")
    else:
        for side, arr in (("lower", it.lower_dofs), ("upper", it.upper_dofs)):
            k = 0
            for node in arr.reshape(-1, arr.shape[-1]):
                if int(node[0]) in seen:
                    continue
                for c, axis in enumerate("xy"):
                    add(node[c], f"interface_node[{k}].{side}.{axis}")
                k += 1
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


def washer_substitution(structure):
    """Change of coordinates that makes each washer average a DOF.

    For every washer bolt end with centre DOF ``j`` (axial DOF of the tagged
    node) and weights ``w`` over DOFs ``d``, the new coordinate
    ``x'_j = sum_k w_k x[d_k]`` replaces ``x_j``; every other DOF is kept.

    Returns
    -------
    S : scipy.sparse.csr_matrix, shape (n_dof, n_dof), or None
        ``x = S @ x'`` (None without washers).  Each washer's ``w_j`` is > 0
        (the centre node is under its own washer); washers do not cover other
        centres (checked when the structure is built), so ``S`` is explicit:
        ``x_j = (x'_j - sum_{k != j} w_k x'_{d_k}) / w_j``.
    """
    n = structure.n_dof
    rows, cols, vals = [], [], []
    centres = set()
    for b in structure.bolts:
        for side in ("lower", "upper"):
            washer = getattr(b, f"washer_{side}")
            if washer is None:
                continue
            j = int(getattr(b, side)[b.axial_component])
            d, w = washer
            wj = float(w[d == j].sum())
            if wj <= 0:
                raise ValueError(f"{b.name}_{side}: the centre node has no weight under "
                                 "its washer")
            centres.add(j)
            rows += [j] * len(d)
            cols += d.tolist()
            vals += np.where(d == j, 1.0 / wj, -w / wj).tolist()
    if not centres:
        return None
    keep = np.setdiff1d(np.arange(n), np.fromiter(centres, dtype=np.int64))
    rows += keep.tolist()
    cols += keep.tolist()
    vals += [1.0] * keep.size
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, n))


def reduce_structure(structure, n_modes: int, retain_points=("excitation", "response")):
    """Craig-Bampton reduction of an :class:`~jointsim.fem.assembly.FEStructure`.

    Returns
    -------
    rom : jointsim.fem.reduced.ReducedModel
    cb : jointsim.fem.reduction.CraigBampton
        ``cb.T`` maps to the physical full DOFs; with washer bolts the
        retained coordinate of a bolt end is the washer average
        (:func:`washer_substitution`), so ``cb.T[retained, :n_retained]`` is
        the identity except on those rows.
    """
    B, labels = retained_dofs(structure, retain_points)
    S = washer_substitution(structure)
    if S is None:
        cb = craig_bampton(structure.K, structure.M, B, n_modes)
    else:
        cb = craig_bampton(S.T @ structure.K @ S, S.T @ structure.M @ S, B, n_modes)
        cb = dataclasses.replace(cb, T=np.asarray(S @ cb.T))
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
