"""Linear modes of the preloaded joint with a stuck interface.

The stiffness is the tangent at the preload state ``x0``
(:func:`jointsim.solvers.static.tangent_stiffness`): the structure, the
tangential springs ``kt A`` of the elements in contact, and the normal
tangent springs ``kn A`` where the interface is closed (the elements with N0 > 0 when the
normal load is fixed).  That is what every solver sees at vanishing
amplitude, so these modes are the low-amplitude limit of EPMC and of the
frequency responses.

Analysis ``[analysis.modes]`` writes (besides the preload, contact and model
tables, see :func:`write_model_tables`):

* ``/modes/frequency_hz`` [n_modes] Hz, ``/modes/elastic`` [n_modes] bool
  (frequency above ``suspension_hz``);
* ``/modes/shapes`` [n_modes, n_dof] mass-normalised shapes of the (reduced)
  model, ``/modes/shapes_full`` [n_modes, n_full_dof] expanded to the mesh
  (FE models);
* ``/modes/frequency_hz_full`` (``full_model = true``): the unreduced FE
  model with the same contact stiffness; ``/modes/monolithic_hz``
  (``monolithic = true``): the same mesh with coincident nodes glued.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..io.hdf5 import unit
from ..results import SUCCESS, Convergence
from ..run import ANALYSES

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ModesResult:
    """Linear modes.

    Attributes
    ----------
    frequency_hz : ndarray, shape (n_modes,)
    shapes : ndarray, shape (n_modes, n_dof)
        Mass-normalised mode shapes [1/sqrt(kg)].
    elastic : ndarray of bool, shape (n_modes,)
    convergence : Convergence
    """

    frequency_hz: np.ndarray
    shapes: np.ndarray
    elastic: np.ndarray
    convergence: Convergence = field(repr=False)


def eigenmodes(K, M, n_modes: int):
    """Lowest ``n_modes`` modes of ``K phi = w^2 M phi`` (dense for small models).

    Parameters
    ----------
    K, M : matrix or sparse matrix, shape (n, n)
        Symmetric; ``M`` positive definite, ``K`` nonsingular for large models
        (shift-invert about 0).
    n_modes : int

    Returns
    -------
    frequency_hz : ndarray, shape (m,)
    shapes : ndarray, shape (m, n)
        Mass-normalised.
    """
    n = K.shape[0]
    m = min(n_modes, n)
    if n <= 2000:
        Kd = K.toarray() if sp.issparse(K) else np.asarray(K)
        Md = M.toarray() if sp.issparse(M) else np.asarray(M)
        w2, phi = sla.eigh(0.5 * (Kd + Kd.T), 0.5 * (Md + Md.T), subset_by_index=(0, m - 1))
    else:
        m = min(m, n - 2)
        w2, phi = spla.eigsh(sp.csc_matrix(K), k=m, M=sp.csc_matrix(M), sigma=0.0, which="LM")
        order = np.argsort(w2)
        w2, phi = w2[order], phi[:, order]
        phi = phi / np.sqrt(np.einsum("ij,ij->j", phi, M @ phi))
    return np.sqrt(np.maximum(w2, 0.0)) / (2 * np.pi), phi.T


def stuck_modes(model, n_modes: int, suspension_hz: float = 0.0) -> ModesResult:
    """Modes of the preloaded, stuck joint of a structural model.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
        Uses ``extra["K_stuck"]`` when present (FE and ROM models), else the
        stuck tangent at ``x = 0``.
    n_modes : int
    suspension_hz : float
        Modes below this are flagged as rigid-body (suspension) modes.
    """
    from .static import tangent_stiffness
    K = model.extra.get("K_stuck")
    if K is None:
        K = tangent_stiffness(model.K, model.contacts, np.zeros(model.n_dof))
    f, phi = eigenmodes(K, model.M, n_modes)
    if not np.all(np.isfinite(f)):
        conv = Convergence(False, 3, "non-finite eigenvalues", 0)
    else:
        conv = Convergence(True, SUCCESS, f"{f.size} modes", 1)
    return ModesResult(frequency_hz=f, shapes=phi, elastic=f > suspension_hz, convergence=conv)


def full_stuck_stiffness(model):
    """The unreduced FE model's stiffness with the same stuck contact springs.

    The contact springs act on retained DOFs only, so their reduced matrix
    ``K_stuck - T^T K T`` is scattered back to the full DOFs.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n_full_dof, n_full_dof)
    """
    st, cb = model.extra["structure"], model.extra["cb"]
    Kc = model.extra["K_stuck"] - cb.K
    nb = cb.n_retained
    off = np.abs(Kc[nb:, :]).max() if Kc.shape[0] > nb else 0.0
    if off > 1e-8 * np.abs(Kc).max():
        raise RuntimeError("contact stiffness reaches modal DOFs; cannot expand it")
    r, c = np.meshgrid(cb.retained, cb.retained, indexing="ij")
    blk = Kc[:nb, :nb]
    keep = blk != 0
    Kc_full = sp.csr_matrix((blk[keep], (r[keep], c[keep])), shape=st.K.shape)
    return sp.csr_matrix(st.K + Kc_full)


def monolithic_modes(model, n_modes: int):
    """Modes of the monolithic body: the mesh with coincident nodes glued, no bolts.

    Returns
    -------
    frequency_hz : ndarray, shape (n_modes,)
    """
    from ..fem.assembly import merge_coincident
    st = model.extra["structure"]
    P = merge_coincident(st.basis)
    K = sp.csr_matrix(P.T @ (st.K - st.K_bolt) @ P)
    M = sp.csr_matrix(P.T @ st.M @ P)
    f, _ = eigenmodes(K, M, n_modes)
    return f


def write_model_tables(scene, model, writer) -> None:
    """Preload state, contact elements, model sizes and the mesh (for post-processing).

    Writes ``/static/*`` (``N`` [n_e] the preload N0, ``gap``, ``u_t``,
    ``f_t``, ``x0``, ``pressure``), ``/contacts/*`` (``area``, ``position``,
    ``kt``, ``kn``), ``/model`` attributes (DOF counts, times) and, for FE
    models, ``/mesh/*`` and ``/static/x0_full``.  Idempotent.
    """
    units = model.units
    ex = model.extra
    c = model.contacts
    d, F = unit("displacement", units), unit("force", units)
    pre = ex.get("preload")
    attrs = {}
    if pre is not None:
        attrs.update(pre.convergence.as_attrs())
        attrs["residual"] = pre.residual
    bolt_total = 0.0
    rom = ex.get("rom")
    if rom is not None and rom.bolts is not None:
        bolt_total = float(rom.bolts.preload.sum())
    writer.group("static", sum_N=float(c.N0.sum()), bolt_force_total=bolt_total,
                 n_in_contact=int(np.sum(c.N0 > 0)),
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
    g = writer.group("model", kind=scene.model.kind, n_dof=model.n_dof,
                     n_contacts=c.n_elements,
                     normal_kernel=c.kernels.normal, tangential_kernel=c.kernels.tangential)
    for key in ("n_full_dof", "build_time_s", "reduce_time_s", "preload_time_s"):
        if key in ex:
            g.attrs[key] = ex[key]
    cb = ex.get("cb")
    if cb is not None:
        g.attrs["n_retained"] = cb.n_retained
        g.attrs["n_cb_modes"] = cb.n_modes
        writer.write("model/fixed_interface_hz", cb.frequency_hz, unit("frequency", units),
                     "Craig-Bampton fixed-interface frequencies")
    writer.write("model/dof_labels", np.array(model.dof_labels, dtype=object), "1",
                 "name of every model DOF")
    st = ex.get("structure")
    if st is not None:
        _write_mesh(writer, st)
        if pre is not None:
            writer.write("static/x0_full", cb.T @ pre.x, d,
                         "preload displacement of every FE DOF")


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


def run_modes(scene, model, writer) -> ModesResult:
    """Runner of ``[analysis.modes]`` (registered in :data:`jointsim.run.ANALYSES`)."""
    a = scene.analysis.modes
    t0 = time.perf_counter()
    write_model_tables(scene, model, writer)
    res = stuck_modes(model, a.n_modes, a.suspension_hz)
    hz = unit("frequency", model.units)
    g = writer.group("modes", n_modes=res.frequency_hz.size, suspension_hz=a.suspension_hz,
                     **res.convergence.as_attrs())
    writer.write("modes/frequency_hz", res.frequency_hz, hz,
                 "natural frequencies of the preloaded, stuck joint")
    writer.write("modes/elastic", res.elastic, "1", "frequency above suspension_hz")
    writer.write("modes/shapes", res.shapes, "1/sqrt(kg)",
                 "mass-normalised mode shapes over the model DOFs")
    cb = model.extra.get("cb")
    if cb is not None:
        writer.write("modes/shapes_full", res.shapes @ cb.T.T, "1/sqrt(kg)",
                     "mode shapes expanded to every FE DOF")
    fe = "structure" in model.extra
    if a.full_model:
        if not fe:
            log.warning("analysis.modes.full_model applies to FE models only; skipped")
        else:
            t1 = time.perf_counter()
            st = model.extra["structure"]
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
        save_rom(path, model.extra["rom"])
        g.attrs["rom_file"] = str(path)
    g.attrs["time_s"] = time.perf_counter() - t0
    el = res.frequency_hz[res.elastic]
    log.info("modes: first elastic frequencies %s Hz", np.array2string(el[:5], precision=2))
    return res


ANALYSES["modes"] = run_modes
