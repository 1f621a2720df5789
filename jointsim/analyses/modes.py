"""Runner of ``[analysis.modes]`` and the model tables every run writes.

:func:`write_model_tables` writes the preload state (``/static``), the contact
elements (``/contacts``, with the tangential law's parameters so that
post-processing rebuilds the law without the scene), the model sizes
(``/model``) and, for FE models, the mesh (``/mesh``).  :func:`run_modes`
writes ``/modes`` (see :mod:`jointsim.solvers.modes` for the quantities).
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from ..io.hdf5 import unit
from ..solvers.modes import ModesResult, eigenmodes, full_stuck_stiffness, monolithic_modes, \
    stuck_modes

log = logging.getLogger(__name__)


def separation_warning(scene) -> str:
    """The warning ``effects.separation = false`` deserves for this scene ('' if none).

    With ``effects.normal = "fixed"`` the normal load is given, so a lumped or
    prescribed scene never separates and the key has no effect; an FE joint's
    preload solve still honours it and becomes bilateral (tension carried).
    """
    e = scene.effects
    if e.separation:
        return ""
    if scene.model.kind == "fe":
        msg = ("effects.separation = false makes the FE preload bilateral: the interface "
               "carries tension at the preload state instead of opening there")
    elif e.normal == "fixed":
        msg = ("effects.separation = false has no effect with effects.normal = 'fixed': the "
               "normal load is given, so no contact separates")
    else:
        return ""
    log.warning("%s: %s", scene.path, msg)
    return msg


def _all_open_warning(scene, model) -> bool:
    """Warn (and return True) when every contact element is open at the static state.

    The static state is the model's linearisation point (the preload solve of an
    FE joint, the static solve of a lumped one).  With every element open the
    joint transmits no force at rest, and a small-amplitude response is that of
    the structure without the joint: usually a reversed normal orientation
    (``model.contacts[].n_sign``), a positive ``gap0`` or a missing preload.
    """
    N = np.asarray(model.linearisation.N, dtype=float)
    if N.size == 0 or np.any(N > 0):
        return False
    log.warning("%s: all %d contact elements are open at the static state (normal load 0): "
                "the joint carries no load at rest and responds as the structure without "
                "it until a contact closes; check model.contacts[].n_sign and gap0 "
                "(lumped) or the preload (FE)", scene.path, N.size)
    return True


def write_model_tables(scene, model, writer) -> None:
    """Preload state, contact elements, model sizes and the mesh (for post-processing).

    Writes ``/static/*`` (``N`` [n_e] the preload N0, ``gap``, ``u_t``,
    ``f_t``, ``x0``, ``pressure``), ``/contacts/*`` (``area``, ``position``,
    ``kt``, ``kn``), ``/model`` attributes (DOF counts, times) and, for FE
    models, ``/mesh/*`` and ``/static/x0_full``.  ``/contacts`` also holds the
    tangential law (:func:`_write_law`).  Idempotent.
    """
    units = model.units
    c = model.contacts
    d, F = unit("displacement", units), unit("force", units)
    pre = None if model.preload is None else model.preload.result
    attrs = {}
    if pre is not None:
        attrs.update(pre.convergence.as_attrs())
        attrs["residual"] = pre.residual
    bolt_total = 0.0
    rom = model.rom
    if rom is not None and rom.bolts is not None:
        bolt_total = float(rom.bolts.preload.sum())
    all_open = _all_open_warning(scene, model)
    attrs["separation_warning"] = separation_warning(scene)
    writer.group("static", sum_N=float(c.N0.sum()), bolt_force_total=bolt_total,
                 n_in_contact=int(np.sum(c.N0 > 0)), all_open=all_open,
                 preload_tangential=getattr(scene.model, "preload_tangential", ""), **attrs)
    writer.write("static/N", c.N0, F, "normal load N0 of every contact element at the "
                                      "preload state")
    area = c.area
    writer.write("static/pressure", c.N0 / area, unit("pressure", units),
                 "interface pressure N0 / A")
    if pre is not None:
        writer.write("static/gap", pre.gap, d, "normal gap at the preload state")
        writer.write("static/u_t", pre.u_t, d, "tangential slip at the preload state")
        writer.write("static/f_t", pre.f_t, F, "tangential force at the preload state")
        writer.write("static/x0", pre.x, d, "preload displacement of the model DOFs")
    writer.write("contacts/area", area, "m^2" if units == "SI" else "length^2",
                 "tributary area of each contact element")
    writer.write("contacts/position", c.position, d, "position of each contact element")
    writer.write("contacts/kt", c.law.kt, unit("stiffness", units),
                 "tangential stiffness kt A of each element")
    writer.write("contacts/kn", c.kn, unit("stiffness", units),
                 "normal stiffness kn A of each element")
    _write_law(writer, scene, c.law, units)
    g = writer.group("model", kind=scene.model.kind, n_dof=model.n_dof,
                     n_contacts=c.n_elements,
                     normal_kernel=c.normal.name, tangential_kernel=c.law.name)
    if model.fe is not None:
        for key in ("n_full_dof", "build_time_s", "reduce_time_s"):
            g.attrs[key] = getattr(model.fe, key)
    if model.preload is not None:
        g.attrs["preload_time_s"] = model.preload.time_s
    cb = None if model.fe is None else model.fe.cb
    if cb is not None:
        g.attrs["n_retained"] = cb.n_retained
        g.attrs["n_cb_modes"] = cb.n_modes
        writer.write("model/fixed_interface_hz", cb.frequency_hz, unit("frequency", units),
                     "Craig-Bampton fixed-interface frequencies")
    writer.write("model/dof_labels", np.array(model.dof_labels, dtype=object), "1",
                 "name of every model DOF")
    st = None if model.fe is None else model.fe.structure
    if st is not None:
        _write_mesh(writer, st)
        if pre is not None:
            writer.write("static/x0_full", cb.T @ pre.x, d,
                         "preload displacement of every FE DOF")


def _write_law(writer, scene, law, units) -> None:
    """The tangential law's per-element parameters: ``/contacts/mu``, ``k``, ``g``.

    Attributes of ``/contacts``: ``law`` and ``reversal`` (the scene's joint)
    and ``kernel`` (the tangential kernel that marches it), so that
    :func:`jointsim.post.common.law_from_file` rebuilds the law.
    """
    writer.group("contacts", law=scene.joint.law, reversal=scene.joint.reversal,
                 kernel=law.name, friction=law.has_force)
    writer.write("contacts/mu", law.mu, "1", "friction coefficient of each element "
                 "(macroslip force mu N)")
    writer.write("contacts/k", law.k, unit("stiffness", units),
                 "slider stiffnesses of each element [n_e, n_s]")
    writer.write("contacts/g", law.g, "1", "slip force per unit normal load of each slider "
                 "[n_e, n_s]")


def _write_mesh(writer, st) -> None:
    """The FE mesh as 9-node quads over the DOF nodes, for plots and VTU export."""
    basis = st.basis
    xdofs = basis.element_dofs[0::2]             # (9, n_cells): x DOF of each local node
    nodes, inverse = np.unique(xdofs.ravel(), return_inverse=True)
    quad9 = inverse.reshape(xdofs.shape).T       # (n_cells, 9)
    node_dofs = np.column_stack([nodes, nodes + 1])
    if not np.all(basis.element_dofs[1::2].T == node_dofs[quad9, 1]):
        raise RuntimeError("unexpected DOF layout of the vector basis")
    body = np.zeros(len(st.mesh.quads), dtype=np.int64)
    names = sorted(st.mesh.cell_sets)
    for i, name in enumerate(names):
        body[st.mesh.cell_sets[name]] = i
    writer.write("mesh/points", basis.doflocs[:, nodes].T, "m", "position of every mesh node "
                 "(corners, midsides, centres)")
    writer.write("mesh/quad9", quad9, "1", "nodes of each 9-node quad (VTK biquadratic order)")
    writer.write("mesh/node_dofs", node_dofs, "1", "x and y DOF of every node")
    writer.write("mesh/body", body, "1", "body index of each quad",
                 names=np.array(names, dtype=object))


def run_modes(scene, model, writer, results=None) -> ModesResult:
    """Runner of ``[analysis.modes]``: the stuck modes, written to ``/modes``.

    The runner contract (arguments, ``results``) is in :mod:`jointsim.analyses`.

    Returns
    -------
    jointsim.solvers.modes.ModesResult
    """
    a = scene.analysis.modes
    t0 = time.perf_counter()
    write_model_tables(scene, model, writer)
    res = stuck_modes(model, a.n_modes, a.suspension_hz)
    hz = unit("frequency", model.units)
    g = writer.group("modes", n_modes=res.frequency_hz.size, rigid_method=res.rigid_method,
                     **res.convergence.as_attrs())
    if a.suspension_hz is not None:
        g.attrs["suspension_hz"] = a.suspension_hz
    writer.write("modes/frequency_hz", res.frequency_hz, hz,
                 "natural frequencies of the preloaded, stuck joint")
    writer.write("modes/elastic", res.elastic, "1", "elastic (not a rigid-body or "
                 "suspension mode); see the group attribute rigid_method")
    writer.write("modes/shapes", res.shapes, "1/sqrt(kg)",
                 "mass-normalised mode shapes over the model DOFs")
    cb = None if model.fe is None else model.fe.cb
    if cb is not None:
        writer.write("modes/shapes_full", res.shapes @ cb.T.T, "1/sqrt(kg)",
                     "mode shapes expanded to every FE DOF")
    fe = model.fe is not None
    if a.full_model:
        if not fe:
            log.warning("analysis.modes.full_model applies to FE models only; skipped")
        else:
            t1 = time.perf_counter()
            st = model.fe.structure
            f_full, _ = eigenmodes(full_stuck_stiffness(model), st.M, a.n_modes)
            writer.write("modes/frequency_hz_full", f_full, hz,
                         "natural frequencies of the unreduced FE model (same contact springs)")
            g.attrs["full_time_s"] = time.perf_counter() - t1
            m = min(f_full.size, res.frequency_hz.size)
            el = res.elastic[:m]
            err = np.abs(res.frequency_hz[:m] / f_full[:m] - 1)[el]
            g.attrs["max_rel_error_elastic"] = float(err.max()) if err.size else 0.0
    if a.monolithic:
        if not fe:
            log.warning("analysis.modes.monolithic applies to FE models only; skipped")
        else:
            writer.write("modes/monolithic_hz", monolithic_modes(model, a.n_modes), hz,
                         "natural frequencies of the monolithic body (coincident nodes glued)")
    if a.export_rom:
        from ..io.rom import save_rom
        path = Path(a.export_rom)
        if not path.is_absolute():
            path = writer.path.parent / path
        save_rom(path, model.rom)
        g.attrs["rom_file"] = str(path)
    g.attrs["time_s"] = time.perf_counter() - t0
    el = res.frequency_hz[res.elastic]
    log.info("modes: first elastic frequencies %s Hz", np.array2string(el[:5], precision=2))
    return res
