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
  (false for rigid-body/suspension modes: below ``suspension_hz`` when the
  scene gives it, else detected by :func:`rigid_body_modes`);
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
        False for rigid-body (suspension) modes, see :func:`rigid_body_modes`.
    rigid_method : str
        How the rigid-body modes were told apart.
    convergence : Convergence
    """

    frequency_hz: np.ndarray
    shapes: np.ndarray
    elastic: np.ndarray
    rigid_method: str = ""
    convergence: Convergence = field(default=None, repr=False)


#: Sparse models above this many DOFs are solved by shift-invert Lanczos.
DENSE_MAX = 600


def eigenmodes(K, M, n_modes: int):
    """Lowest ``n_modes`` modes of ``K phi = w^2 M phi`` (dense for small models).

    Parameters
    ----------
    K, M : matrix or sparse matrix, shape (n, n)
        Symmetric, ``M`` positive definite.  Sparse ``K`` with more than
        ``DENSE_MAX`` rows: shift-invert Lanczos about 0 (dense if ``K`` is
        singular).
    n_modes : int

    Returns
    -------
    frequency_hz : ndarray, shape (m,)
    shapes : ndarray, shape (m, n)
        Mass-normalised.
    """
    n = K.shape[0]
    m = min(n_modes, n)
    sparse_big = sp.issparse(K) and n > DENSE_MAX and m < n - 2
    if sparse_big:
        try:
            w2, phi = spla.eigsh(sp.csc_matrix(K), k=m, M=sp.csc_matrix(M), sigma=0.0,
                                 which="LM")
        except RuntimeError:  # singular K: the dense solver copes
            sparse_big = False
        else:
            order = np.argsort(w2)
            w2, phi = w2[order], phi[:, order]
            phi = phi / np.sqrt(np.einsum("ij,ij->j", phi, M @ phi))
    if not sparse_big:
        Kd = K.toarray() if sp.issparse(K) else np.asarray(K)
        Md = M.toarray() if sp.issparse(M) else np.asarray(M)
        w2, phi = sla.eigh(0.5 * (Kd + Kd.T), 0.5 * (Md + Md.T), subset_by_index=(0, m - 1))
    return np.sqrt(np.maximum(w2, 0.0)) / (2 * np.pi), phi.T


#: Rigid-body modes by the spectral gap: at most this many ...
MAX_RIGID = 6
#: ... below a jump of at least this frequency ratio to the next mode.
GAP_RATIO = 10.0
#: Rigid-body modes by geometry: share of the modal mass in the rigid-body subspace.
RIGID_SHARE = 0.5


def _fe_rigid_fields(structure) -> np.ndarray:
    """The three rigid-body displacement fields of a 2D FE structure, (n_full_dof, 3)."""
    b = structure.basis
    xd = np.unique(b.element_dofs[0::2])
    yd = np.unique(b.element_dofs[1::2])
    R = np.zeros((structure.n_dof, 3))
    R[xd, 0] = 1.0
    R[yd, 1] = 1.0
    R[xd, 2] = -b.doflocs[1, xd]
    R[yd, 2] = b.doflocs[0, yd]
    return R


def rigid_body_modes(model, frequency_hz, shapes, cutoff_hz=None):
    """Which modes are rigid-body (suspension) modes rather than elastic ones.

    The rule, in order:

    1. ``cutoff_hz`` given: the modes below it;
    2. FE models: the modes whose modal mass lies mostly (> 50 %) in the
       rigid-body motions of the mesh (x and y translation and in-plane
       rotation).  This is exact whatever the suspension stiffness;
    3. otherwise the modes at (numerically) zero frequency, and the modes
       below a spectral gap: at most 6 lowest modes followed by a jump of at
       least 10x in frequency (a soft suspension of a free structure).
       Lumped models use zero frequency only (no gap rule): their modes are
       all taken as elastic unless ``cutoff_hz`` is given.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    frequency_hz : ndarray, shape (m,)
        Lowest modes, ascending.
    shapes : ndarray, shape (m, n_dof)
        Their mass-normalised shapes.
    cutoff_hz : float, optional

    Returns
    -------
    rigid : ndarray of bool, shape (m,)
    method : str
    """
    f = np.asarray(frequency_hz, dtype=float)
    if cutoff_hz is not None:
        return f < cutoff_hz, f"below {cutoff_hz:g} Hz"
    fe = model.fe
    st, cb = (fe.structure, fe.cb) if fe is not None else (None, None)
    if st is not None and cb is not None and hasattr(st, "basis"):
        R = _fe_rigid_fields(st)
        MR = st.M @ R
        G = R.T @ MR
        full = np.asarray(shapes) @ cb.T.T            # (m, n_full)
        c = full @ MR                                  # (m, 3)
        share = np.einsum("mi,ij,mj->m", c, np.linalg.inv(G), c)
        share /= np.maximum(np.einsum("mi,mi->m", full, (st.M @ full.T).T), 1e-300)
        return share > RIGID_SHARE, "rigid-body share of the modal mass > 0.5"
    rigid = f <= 1e-6 * max(float(f.max(initial=0.0)), 1e-300)
    if model.rom is not None and f.size > 1:
        n = min(MAX_RIGID, f.size - 1)
        ratio = f[1:n + 1] / np.maximum(f[:n], 1e-300)
        big = np.flatnonzero(ratio >= GAP_RATIO)
        if big.size:
            rigid[:big[-1] + 1] = True
        return rigid, f"zero frequency or below a {GAP_RATIO:g}x spectral gap"
    return rigid, "zero frequency"


def stuck_modes(model, n_modes: int, suspension_hz=None) -> ModesResult:
    """Modes of the structure linearised at its static state with the joint stuck.

    The stiffness is ``model.linearisation.K``
    (:func:`jointsim.solvers.static.stuck_linearisation`: the tangent at the
    preload state ``x0``), the same for every solver.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    n_modes : int
    suspension_hz : float, optional
        Modes below this are rigid-body (suspension) modes; default: detected
        (:func:`rigid_body_modes`).
    """
    K = model.linearisation.K
    f, phi = eigenmodes(K, model.M, n_modes)
    rigid, method = rigid_body_modes(model, f, phi, suspension_hz)
    if not np.all(np.isfinite(f)):
        conv = Convergence(False, 3, "non-finite eigenvalues", 0)
    else:
        conv = Convergence(True, SUCCESS, f"{f.size} modes ({int(rigid.sum())} rigid-body: "
                                          f"{method})", 1)
    return ModesResult(frequency_hz=f, shapes=phi, elastic=~rigid, rigid_method=method,
                       convergence=conv)


@dataclass(frozen=True)
class ElasticMode:
    """One elastic mode of the stuck, statically loaded structure.

    Attributes
    ----------
    phi : ndarray, shape (n_dof,)
        Mass-normalised shape (``phi^T M phi = 1``), its largest entry positive.
    omega : float
        Angular frequency [rad/s].
    frequency_hz : float
    index : int
        0-based index among all modes (rigid-body ones included).
    n_rigid : int
        Rigid-body modes below it.
    """

    phi: np.ndarray
    omega: float
    frequency_hz: float
    index: int
    n_rigid: int


def elastic_mode(model, mode: int, rigid_cutoff_hz=None) -> ElasticMode:
    """The ``mode``-th elastic mode (1-based) of the stuck linearisation.

    This is the reference mode of EPMC (and of QSMA): rigid-body
    (suspension) modes are skipped as decided by :func:`rigid_body_modes`.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    mode : int
        1-based index among the elastic modes.
    rigid_cutoff_hz : float, optional
        Modes below this are rigid-body modes (default: detected).

    Raises
    ------
    ValueError
        When the model has fewer elastic modes.
    """
    n = model.n_dof
    res = stuck_modes(model, min(n, mode + MAX_RIGID), rigid_cutoff_hz)
    keep = np.flatnonzero(res.elastic)
    if mode > keep.size:
        raise ValueError(f"mode {mode} was asked for, but only {keep.size} elastic modes were "
                         f"found among the lowest {res.frequency_hz.size} "
                         f"(rigid-body modes: {res.rigid_method})")
    i = int(keep[mode - 1])
    phi = res.shapes[i].copy()
    j = int(np.argmax(np.abs(phi)))
    if phi[j] < 0:
        phi = -phi
    f = float(res.frequency_hz[i])
    return ElasticMode(phi=phi, omega=2 * np.pi * f, frequency_hz=f, index=i,
                       n_rigid=int(np.sum(~res.elastic[:i])))


def full_stuck_stiffness(model):
    """The unreduced FE model's stiffness with the same stuck contact springs.

    The contact springs act on retained DOFs only, so their reduced matrix
    (the stuck linearisation minus ``T^T K T``) is scattered back to the full DOFs.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n_full_dof, n_full_dof)
    """
    st, cb = model.fe.structure, model.fe.cb
    Kc = model.linearisation.K.toarray() - cb.K
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
    st = model.fe.structure
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


ANALYSES["modes"] = run_modes
