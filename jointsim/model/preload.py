"""A reduced model under a scene's joint: contact set, bolt preload, damping.

Shared by the FE builder (:mod:`jointsim.model.fe`) and the ROM builder
(:mod:`jointsim.model.rom`): :func:`structural_model` turns a
:class:`~jointsim.fem.reduced.ReducedModel` and a scene into a preloaded
:class:`~jointsim.model.StructuralModel`; it solves the bolt preload, sets
``N0``, ``gap0`` and ``f_static`` consistently, and adds damping.
"""
from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np
import scipy.sparse as sp

from .._schema import SceneError
from ..fem.reduced import ReducedModel
from ..contact.select import NORMAL_TABLE
from ..solvers.static import solve_static, stuck_mode, tangent_stiffness
from .damping import damping_matrix
from .structural import (FEParts, Preload, StructuralModel, fixed_normal_stiffness,
                         make_contact_set, with_fixed_normal_springs)

log = logging.getLogger(__name__)


def structural_model(scene, rom: ReducedModel, *, preload_tangential: str = "stuck",
                     preload_tol: float = 1e-10, fe: FEParts | None = None,
                     source: str | None = None) -> StructuralModel:
    """The structural model of a reduced model under the scene's joint.

    Steps: build the contact set (areas from the interface table, stiffness
    per unit area from ``[joint]``); solve the bolt preload with unilateral
    normal contact (bolt-load procedure: bolt springs off, clamping forces
    on); set ``N0`` from it, ``gap0 = 0`` (the initial gap of coincident
    nodes, which reproduces ``N0`` at the preload state ``x0`` through
    ``N = kn A max(0, -(gap0 + Tn x0))``), and
    ``f_static = f_ext + f_clamp + K_bolt x0`` so that ``x0`` is the
    equilibrium of ``K x + f_c(x) = f_static``.  With a fixed normal load the
    linear normal springs of the elements closed at the preload (``N0 > 0``)
    go into ``K`` and ``f_static`` absorbs their force at ``x0``
    (``Tn^T (N0 + kn A (gap0 + Tn x0))``), so ``x0`` stays the equilibrium
    and the linearised joint is the same as with a coupled normal load.  Damping comes from ``[damping]`` on the preloaded, stuck
    tangent stiffness (plus ``rom.C``).

    Parameters
    ----------
    scene : jointsim.scene.Scene
    rom : ReducedModel
    preload_tangential : str
        ``stuck`` or ``frictionless``.
    preload_tol : float
        Relative residual tolerance of the preload solve.
    fe : FEParts, optional
        The unreduced FE model (FE builder), stored as ``model.fe``.
    source : str, optional
        The file the reduced model came from, stored as ``model.source``.

    Returns
    -------
    StructuralModel
        With ``preload`` (:class:`Preload`: ``x0`` [m], the preload
        :class:`~jointsim.solvers.static.StaticResult`, ``f_clamp``,
        ``K_bolt``, ``time_s``), ``rom``, and ``linearisation``: the stuck
        tangent at ``x0``.
    """
    t0 = time.perf_counter()
    n = rom.n_dof
    iface = rom.interface
    Tt, Tn = iface.operators(n)
    ne = iface.n_elements
    contacts = make_contact_set(scene, Tt, Tn, np.zeros(ne), np.zeros(ne), iface.area,
                                iface.position)
    K = sp.csr_matrix(rom.K)
    if rom.bolts is not None and rom.bolts.n_bolts:
        K_bolt = rom.bolts.stiffness_matrix(n)
        f_clamp = rom.bolts.clamp_forces(n)
    else:
        K_bolt, f_clamp = sp.csr_matrix((n, n)), np.zeros(n)
    f_pre = rom.f_static + f_clamp
    # the preload is solved with the gap law even when the scene fixes N afterwards
    normal = NORMAL_TABLE[("coupled", scene.effects.separation)](contacts.kn)
    if not np.any(f_pre):
        log.warning("no preload (no bolts, no static load): every N0 is 0")
    pre = solve_static(K - K_bolt, f_pre, contacts, tangential=preload_tangential,
                       normal=normal, tol=preload_tol)
    if not pre.convergence.success:
        raise RuntimeError(f"bolt preload solve failed: {pre.convergence.message}")
    x0 = pre.x
    N0 = pre.N
    contacts = dataclasses.replace(contacts, N0=N0)
    f_static = f_pre + K_bolt @ x0
    t_pre = time.perf_counter() - t0
    slip = np.abs(pre.f_t) > contacts.law.mu * N0 * (1 + 1e-9)
    if preload_tangential == "stuck" and np.any(slip & (N0 > 0)):
        log.warning("preload: %d of %d contact elements carry a tangential force above "
                    "mu N0 in the stuck preload state", int(np.sum(slip & (N0 > 0))), ne)
    K_model = with_fixed_normal_springs(K, contacts)  # springs where N0 > 0 (fixed N)
    if not contacts.coupled:
        k_fixed = fixed_normal_stiffness(contacts)
        f_static = f_static + Tn.T @ (N0 + k_fixed * (contacts.gap0 + Tn @ x0))
    K_stuck = tangent_stiffness(K_model, contacts, x0, tangential=stuck_mode(contacts))
    M = sp.csr_matrix(rom.M)
    C = damping_matrix(M, K_stuck, scene.damping,
                       None if rom.C is None else sp.csr_matrix(rom.C))
    loads = scene.excitation.loads
    load_dofs = reduced_load_dofs(scene, rom)
    preload = Preload(x0=x0, result=pre, f_clamp=f_clamp, K_bolt=K_bolt, time_s=t_pre)
    log.info("preload: sum N0 = %.6g N over %d/%d elements in contact (%s)",
             N0.sum(), int(np.sum(N0 > 0)), ne, pre.convergence.message)
    return StructuralModel(M=M, K=sp.csr_matrix(K_model), C=C, contacts=contacts,
                           load_dofs=np.array(load_dofs, dtype=np.int64),
                           load_signals=tuple(ld.force for ld in loads),
                           f_static=f_static, dof_labels=tuple(rom.dof_labels),
                           points=dict(rom.points), units=getattr(scene.model, "units", "SI"),
                           preload=preload, fe=fe, rom=rom, source=source)


def reduced_load_dofs(scene, rom: ReducedModel) -> list[int]:
    """DOF of each ``[[excitation.loads]]`` entry in the reduced model.

    Raises
    ------
    SceneError
        For a load on a point that is not retained or a DOF out of range.
    """
    n = rom.n_dof
    load_dofs = []
    for i, ld in enumerate(scene.excitation.loads):
        if ld.point:
            key = f"{ld.point}.{ld.direction}"
            if key not in rom.points:
                retained = sorted(set(p.split('.')[0] for p in rom.points))
                raise SceneError(str(scene.path), f"excitation.loads[{i}].point",
                                 f"names {ld.point!r}, which is not a retained point of the "
                                 f"model (retained: {retained})")
            load_dofs.append(rom.points[key])
        else:
            if ld.dof >= n:
                raise SceneError(str(scene.path), f"excitation.loads[{i}].dof",
                                 f"must be < {n} (the reduced model has {n} DOFs)")
            load_dofs.append(ld.dof)
    return load_dofs
