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
from .damping import damping_and_modes
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
    (``Tn^T (N0 + kn A Tn x0)``; the springs act on ``Tn x``, without
    ``gap0``), so ``x0`` stays the equilibrium
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
    if scene.joint.kt_pressure is not None:
        contacts, pre = pressure_kt_preload(scene, contacts, pre, K - K_bolt, f_pre, normal,
                                            preload_tangential, preload_tol)
    x0 = pre.x
    N0 = pre.N
    contacts = dataclasses.replace(contacts, N0=N0)
    if scene.joint.kn_pressure is not None:
        contacts = with_pressure_kn(contacts, scene.joint.kn, scene.joint.kn_pressure)
    f_static = f_pre + K_bolt @ x0
    t_pre = time.perf_counter() - t0
    slip = np.abs(pre.f_t) > contacts.law.mu * N0 * (1 + 1e-9)
    if preload_tangential == "stuck" and np.any(slip & (N0 > 0)):
        log.warning("preload: %d of %d contact elements carry a tangential force above "
                    "mu N0 in the stuck preload state", int(np.sum(slip & (N0 > 0))), ne)
    K_model = with_fixed_normal_springs(K, contacts)  # springs where N0 > 0 (fixed N)
    if not contacts.coupled:
        k_fixed = fixed_normal_stiffness(contacts)
        # the fixed springs act on Tn x (no gap0): their force at x0 is k Tn x0
        f_static = f_static + Tn.T @ (N0 + k_fixed * (Tn @ x0))
    K_stuck = tangent_stiffness(K_model, contacts, x0, tangential=stuck_mode(contacts))
    M = sp.csr_matrix(rom.M)
    C, modes = damping_and_modes(M, K_stuck, scene.damping,
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
                           preload=preload, fe=fe, rom=rom, source=source,
                           stuck_modes=modes)


#: Fixed-point iterations of :func:`pressure_kt_preload` and their tolerance on
#: ``max |N0_new - N0_old| / max N0`` [-].
KT_PRESSURE_MAX_ITER = 30
KT_PRESSURE_RTOL = 1e-9


def pressure_kt_weights(N0, area, p_ref) -> np.ndarray:
    """Per-element scale of ``kt`` under ``joint.kt_pressure``: ``p0 / p_ref``.

    Parameters
    ----------
    N0 : ndarray, shape (n_e,)
        Preload normal loads [N] (>= 0).
    area : ndarray, shape (n_e,)
        Element areas [m^2] (> 0).
    p_ref : float
        The pressure at which ``kt`` is the stiffness per unit area [Pa].

    Returns
    -------
    ndarray, shape (n_e,)
        ``N0 / (A p_ref)`` [-]: 0 on the elements open at the preload, and
        falling continuously to 0 towards the edge of the contact patch.
    """
    return np.maximum(np.asarray(N0, dtype=float), 0.0) / (np.asarray(area, dtype=float)
                                                           * float(p_ref))


def with_pressure_kt(scene, contacts, N0):
    """The contact set with ``kt A p0 / p_ref`` per element (``joint.kt_pressure``).

    Only the tangential law's per-element stiffness changes (the slider
    arrays of the scene's law at ``KT = kt A p0 / p_ref``); areas, the normal
    law and everything else stay.  Elements with ``N0 = 0`` get ``KT = 0``
    (no slider force: they carry no tangential load even if they close during
    the motion); their slider arrays are zero stiffnesses with the slip
    coefficients of a loaded element, so that every law (Iwan included, whose
    discretisation divides by ``KT``) sees only positive stiffnesses.

    Parameters
    ----------
    scene : jointsim.scene.Scene
    contacts : ContactSet
    N0 : ndarray, shape (n_e,)
        Preload normal loads [N].

    Returns
    -------
    ContactSet
    """
    joint = scene.joint
    kernels = scene.kernels()
    w = pressure_kt_weights(N0, contacts.area, joint.kt_pressure)
    KT = joint.kt * contacts.area * w
    mu = np.full(KT.size, joint.mu)
    on = KT > 0.0
    if not on.any():
        raise RuntimeError("joint.kt_pressure: no element carries a preload (every N0 is "
                           "0), so every tangential stiffness would vanish")
    k_on, g_on = kernels.parameters(joint, KT[on], mu[on])
    k = np.zeros((KT.size, k_on.shape[1]))
    g = np.empty_like(k)
    k[on], g[on] = k_on, g_on
    g[~on] = g_on[0]
    law = kernels.law_class(k=k, g=g, mu=mu)
    return dataclasses.replace(contacts, law=law)


def with_pressure_kn(contacts, kn: float, p_ref: float):
    """The contact set with ``kn A p0 / p_ref`` per element (``joint.kn_pressure``).

    The normal law of each element becomes the tangent, at the preload, of
    a rough-interface law whose stiffness is proportional to its pressure
    (``dp/dg = -p / sigma``, the exponential law of Greenwood-Williamson
    with exponential summit heights, ``sigma = p_ref / kn``), cut at zero
    force: ``N = kn A (p0 / p_ref) max(0, -g)`` with the initial gap
    ``gap0 = (p0 - p_ref) / kn`` on the elements closed at the preload, so
    that ``N = N0`` at ``x0`` (``x0`` stays the equilibrium; every closed
    element opens after the same gap change ``p_ref / kn``).  Elements open at
    the preload (``N0 = 0``) get ``kn A = 0`` and carry no normal load.
    Called with ``contacts.N0`` already the preload's, ``gap0 = 0`` and
    ``N0 = kn A max(0, -Tn x0)`` (:func:`structural_model`).

    Parameters
    ----------
    contacts : ContactSet
        With the preload's ``N0`` and the uniform ``kn A``.
    kn : float
        ``joint.kn``, the stiffness per unit area at ``p_ref`` [N/m^3].
    p_ref : float
        ``joint.kn_pressure`` [Pa].

    Returns
    -------
    ContactSet
    """
    w = pressure_kt_weights(contacts.N0, contacts.area, p_ref)
    closed = contacts.N0 > 0.0
    gap0 = np.where(closed, (contacts.N0 / contacts.area - p_ref) / kn, contacts.gap0)
    normal = type(contacts.normal)(kn=np.asarray(contacts.kn, dtype=float) * w)
    return dataclasses.replace(contacts, normal=normal, gap0=gap0)


def pressure_kt_preload(scene, contacts, pre, K, f_pre, normal, preload_tangential: str,
                        tol: float):
    """The preload with ``kt`` proportional to its own pressure (``joint.kt_pressure``).

    ``kt A p0 / p_ref`` depends on the preload's ``N0``, and with a stuck
    preload (``model.preload_tangential = "stuck"``) ``N0`` depends on ``kt``
    through the tangential springs.  Fixed point: ``kt`` from the last
    ``N0``, the preload solved again with it, until ``N0`` changes by at
    most :data:`KT_PRESSURE_RTOL` of its largest value, so that ``x0`` is an
    equilibrium of the model's own law and ``kt`` is that of its own
    ``N0`` to that tolerance.  A frictionless preload does not depend on
    ``kt``: one step.

    Parameters
    ----------
    scene : jointsim.scene.Scene
    contacts : ContactSet
        With the uniform ``kt A``.
    pre : jointsim.solvers.static.StaticResult
        The preload solved with ``contacts``.
    K : sparse matrix, shape (n_dof, n_dof)
        Stiffness of the preload solve (bolt springs off) [N/m].
    f_pre : ndarray, shape (n_dof,)
        Preload force [N].
    normal : jointsim.contact.normal.NormalLaw
        Normal law of the preload solve.
    preload_tangential : str
    tol : float
        Residual tolerance of each preload solve.

    Returns
    -------
    contacts : ContactSet
        With ``kt A p0 / p_ref`` from the returned preload's ``N0`` (to the
        fixed-point tolerance).
    pre : StaticResult
        The preload solved with that contact set.

    Raises
    ------
    RuntimeError
        When a preload solve fails or the fixed point does not settle.
    """
    if preload_tangential != "stuck":
        return with_pressure_kt(scene, contacts, pre.N), pre
    change = np.inf
    for it in range(1, KT_PRESSURE_MAX_ITER + 1):
        scaled = with_pressure_kt(scene, contacts, pre.N)
        new = solve_static(K, f_pre, scaled, tangential=preload_tangential, normal=normal,
                           tol=tol)
        if not new.convergence.success:
            raise RuntimeError(f"bolt preload solve (joint.kt_pressure, fixed-point iteration "
                               f"{it}) failed: {new.convergence.message}")
        change = np.abs(new.N - pre.N).max() / max(np.abs(pre.N).max(), 1e-300)
        pre = new
        log.debug("kt_pressure preload iteration %d: max |dN0| / max N0 = %.2e", it, change)
        if change <= KT_PRESSURE_RTOL:
            log.info("joint.kt_pressure: kt A p0 / %.6g Pa; the preload settled in %d "
                     "solves (max |dN0| / max N0 = %.1e)", scene.joint.kt_pressure, it, change)
            return scaled, pre
    raise RuntimeError(f"joint.kt_pressure: the preload did not settle in "
                       f"{KT_PRESSURE_MAX_ITER} solves (last max |dN0| / max N0 = {change:.1e})")


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
