"""Linear modes of the preloaded joint with a stuck interface.

The stiffness is the tangent at the preload state ``x0``
(:func:`jointsim.solvers.static.tangent_stiffness`): the structure, the
tangential springs ``kt A`` of the elements in contact, and the normal
tangent springs ``kn A`` where the interface is closed (the elements with N0 > 0 when the
normal load is fixed).  That is what every solver sees at vanishing
amplitude, so these modes are the low-amplitude limit of EPMC and of the
frequency responses.

Analysis ``[analysis.modes]`` (:func:`jointsim.analyses.modes.run_modes`) writes
(besides the preload, contact and model tables,
:func:`jointsim.analyses.modes.write_model_tables`):

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
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from ..fem.reduction import dense_spd_factor, shift_invert_modes, spd_lu, with_fixed_signs
from ..results import SUCCESS, Convergence

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
#: ... on a dense Cholesky factor when this share of the stiffness's entries is stored
#: (a reduced model, dense in its interface block: :func:`~jointsim.fem.reduction.
#: dense_spd_factor`), else on a sparse LU.
DENSE_FILL = 0.25


def eigenmodes(K, M, n_modes: int):
    """Lowest ``n_modes`` modes of ``K phi = w^2 M phi`` (dense for small models).

    Parameters
    ----------
    K, M : matrix or sparse matrix, shape (n, n)
        Symmetric, ``M`` positive definite.  Sparse ``K`` with more than
        ``DENSE_MAX`` rows: shift-invert Lanczos about 0 (on a dense factor from
        ``DENSE_FILL`` stored entries; a dense eigen-solver if ``K`` is singular).
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
            if K.nnz >= DENSE_FILL * n * n:
                Kd = K.toarray()
                Md = M.toarray() if sp.issparse(M) else np.asarray(M)
                w2, phi = shift_invert_modes(Kd, Md, m, dense_spd_factor(Kd))
            else:
                # on the stiffness's own ordering (half SuperLU's default fill)
                w2, phi = shift_invert_modes(K, M, m, spd_lu(K))
        except RuntimeError:  # singular K: the dense solver copes
            sparse_big = False
    if not sparse_big:
        Kd = K.toarray() if sp.issparse(K) else np.asarray(K)
        Md = M.toarray() if sp.issparse(M) else np.asarray(M)
        w2, phi = sla.eigh(0.5 * (Kd + Kd.T), 0.5 * (Md + Md.T), subset_by_index=(0, m - 1))
    return np.sqrt(np.maximum(w2, 0.0)) / (2 * np.pi), with_fixed_signs(phi).T


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
    preload state ``x0``), the same for every solver.  The model's own modes of it
    (``model.stuck_modes``, made for its modal damping) are taken where it has them.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    n_modes : int
    suspension_hz : float, optional
        Modes below this are rigid-body (suspension) modes; default: detected
        (:func:`rigid_body_modes`).
    """
    K = model.linearisation.K
    given = model.stuck_modes
    if given is not None:                   # the model's, made for its modal damping
        m = min(n_modes, K.shape[0])
        f = np.sqrt(np.maximum(given[0][:m], 0.0)) / (2 * np.pi)
        phi = with_fixed_signs(given[1][:, :m]).T
    else:
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
