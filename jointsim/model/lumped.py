"""Builder of ``kind = "lumped"`` scenes: matrices given in the scene, point contacts.

The linearisation of a lumped model (its static state under the constant
loads, stuck joint) is computed when the :class:`StructuralModel` is
constructed; lumped models carry no preload, FE parts or ROM.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .damping import damping_matrix
from .structural import StructuralModel, make_contact_set, with_fixed_normal_springs


def build_lumped(scene) -> StructuralModel:
    """Structural model of a ``kind = "lumped"`` scene (a builder of
    :data:`jointsim.model.BUILDERS`): ``preload``, ``fe``, ``rom`` and ``source``
    are None; ``linearisation`` is solved under the static load."""
    m = scene.model
    n = m.n_dof
    M = sp.csr_matrix(np.array(m.M, dtype=float))
    K = sp.csr_matrix(np.array(m.K, dtype=float))
    C0 = None if m.C is None else np.array(m.C, dtype=float)
    ne = len(m.contacts)
    Tt = _selector(ne, n, [c.t_dof for c in m.contacts], [c.t_ref for c in m.contacts])
    Tn = _selector(ne, n, [c.n_dof for c in m.contacts], [c.n_ref for c in m.contacts],
                   [c.n_sign for c in m.contacts])
    N0 = np.array([c.N0 if c.N0 is not None else 0.0 for c in m.contacts])
    gap0 = np.array([c.gap0 for c in m.contacts])
    area = np.array([c.area for c in m.contacts])
    position = np.column_stack([np.arange(ne, dtype=float), np.zeros(ne)])
    contacts = make_contact_set(scene, Tt, Tn, gap0, N0, area, position)
    K = with_fixed_normal_springs(K, contacts)
    C = damping_matrix(M, K, scene.damping, C0)
    loads = scene.excitation.loads
    return StructuralModel(
        M=M, K=K, C=C, contacts=contacts,
        load_dofs=np.array([ld.dof for ld in loads], dtype=np.int64),
        load_signals=tuple(ld.force for ld in loads),
        f_static=np.zeros(n), dof_labels=tuple(f"x{i}" for i in range(n)),
        points={}, units=m.units)


def _selector(n_rows: int, n_cols: int, plus, minus, sign=None) -> sp.csr_matrix:
    """Rows picking ``sign * (x[plus] - x[minus])``; index -1 means ground.

    ``sign`` (one +1 or -1 per row, default +1) orients the row: the normal
    gap of a contact whose coordinate is positive into contact has ``-1``
    (``model.contacts[].n_sign``).
    """
    sign = [1.0] * n_rows if sign is None else [float(v) for v in sign]
    rows, cols, vals = [], [], []
    for r, (a, b) in enumerate(zip(plus, minus)):
        if a >= 0:
            rows.append(r), cols.append(a), vals.append(sign[r])
        if b >= 0:
            rows.append(r), cols.append(b), vals.append(-sign[r])
    return sp.csr_matrix((vals, (rows, cols)), shape=(n_rows, n_cols))
