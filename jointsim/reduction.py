"""Craig-Bampton reduction, reduced models, and the models built from them.

Hurty/Craig-Bampton: the DOFs are split into retained (boundary) DOFs ``B``
and interior DOFs ``I``.  The interior motion is the static response to the
boundary (constraint modes ``Psi = -K_II^-1 K_IB``) plus ``n`` fixed-interface
normal modes ``Phi`` (``K_II Phi = M_II Phi Omega^2``, mass-normalised)::

    x = T [x_B; q],   T = [[I, 0], [Psi, Phi]]   (in the original DOF order)

``K_II`` is factorised once (sparse LU) and reused by the shift-invert
Lanczos solver (``eigsh`` with ``sigma = 0``); no dense matrix of the full
model is formed (``T`` is dense but only ``n_dof x n_reduced``).  Because the
contact elements, bolts and loads act on retained DOFs only, the reduced
model is exact for them statically, and the nonlinear preload solve on the
reduced model gives the same state as on the full model.

A :class:`ReducedModel` (linear matrices, the interface table, bolts and
named points) is what both the FE builder and a ROM import produce;
:func:`structural_model` turns it and a scene into a
:class:`~jointsim.model.StructuralModel`: it solves the bolt preload, sets
``N0``, ``gap0`` and ``f_static`` consistently, and adds damping.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ._schema import SceneError
from .fem.interface import Interface
from .model import (BUILDERS, StructuralModel, damping_matrix, make_contact_set,
                    fixed_normal_stiffness, with_fixed_normal_springs)

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------
# Craig-Bampton
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class CraigBampton:
    """A Craig-Bampton reduction basis.

    Attributes
    ----------
    T : ndarray, shape (n_dof, n_retained + n_modes)
        Basis in the original DOF order, ``x = T @ x_r``.
    retained : ndarray of int, shape (n_retained,)
        Full DOF index of each retained DOF; reduced DOF ``i < n_retained`` is
        full DOF ``retained[i]`` (``T[retained, :n_retained]`` is the identity).
    frequency_hz : ndarray, shape (n_modes,)
        Fixed-interface natural frequencies [Hz].
    K, M : ndarray, shape (n_r, n_r)
        Reduced stiffness [N/m] and mass [kg].
    """

    T: np.ndarray
    retained: np.ndarray
    frequency_hz: np.ndarray
    K: np.ndarray
    M: np.ndarray

    @property
    def n_retained(self) -> int:
        return self.retained.size

    @property
    def n_modes(self) -> int:
        return self.frequency_hz.size

    def reduced_index(self, n_dof: int) -> np.ndarray:
        """Map full DOF -> reduced DOF (-1 for interior DOFs), shape (n_dof,)."""
        idx = np.full(n_dof, -1, dtype=np.int64)
        idx[self.retained] = np.arange(self.n_retained)
        return idx

    def project(self, A) -> np.ndarray:
        """``T^T A T`` of a full sparse matrix, dense (n_r, n_r), symmetrised."""
        AT = A @ self.T
        out = self.T.T @ AT
        return 0.5 * (out + out.T)


def craig_bampton(K, M, retained, n_modes: int) -> CraigBampton:
    """Hurty/Craig-Bampton reduction of a sparse model.

    Parameters
    ----------
    K, M : sparse matrix, shape (n_dof, n_dof)
        Stiffness [N/m] and mass [kg]; ``K_II`` must be nonsingular.
    retained : array_like of int
        Full DOFs kept physically (unique; kept in the given order).
    n_modes : int
        Fixed-interface modes kept (0: Guyan reduction).

    Returns
    -------
    CraigBampton
    """
    K = sp.csr_matrix(K)
    M = sp.csr_matrix(M)
    n = K.shape[0]
    B = np.asarray(retained, dtype=np.int64)
    if len(np.unique(B)) != len(B):
        raise ValueError("retained DOFs must be unique")
    if B.size and (B.min() < 0 or B.max() >= n):
        raise ValueError("retained DOF out of range")
    interior = np.ones(n, bool)
    interior[B] = False
    I = np.nonzero(interior)[0]
    n_modes = int(min(n_modes, I.size))
    K_II = sp.csc_matrix(K[I][:, I])
    K_IB = K[I][:, B]
    lu = spla.splu(K_II)
    # Fortran order: SuperLU solves column by column, and a C-ordered
    # right-hand side makes that an order of magnitude slower
    Psi = -lu.solve(np.asfortranarray(K_IB.toarray())) if B.size else np.zeros((I.size, 0))
    if n_modes == 0:
        w2, Phi = np.zeros(0), np.zeros((I.size, 0))
    elif I.size <= 400 or n_modes >= I.size - 1:
        w2, Phi = sla.eigh(K_II.toarray(), M[I][:, I].toarray(),
                           subset_by_index=(0, n_modes - 1))
    else:
        op = spla.LinearOperator(K_II.shape, matvec=lu.solve, dtype=float)
        w2, Phi = spla.eigsh(K_II, k=n_modes, M=sp.csc_matrix(M[I][:, I]), sigma=0.0,
                             which="LM", OPinv=op)
        order = np.argsort(w2)
        w2, Phi = w2[order], Phi[:, order]
        # normalise to unit modal mass (eigsh already does, to round-off)
        mm = np.einsum("ij,ij->j", Phi, M[I][:, I] @ Phi)
        Phi = Phi / np.sqrt(mm)
    T = np.zeros((n, B.size + n_modes))
    T[B, np.arange(B.size)] = 1.0
    T[I, :B.size] = Psi
    T[I, B.size:] = Phi
    cb = CraigBampton(T=T, retained=B, frequency_hz=np.sqrt(np.maximum(w2, 0)) / (2 * np.pi),
                      K=np.zeros(0), M=np.zeros(0))
    return dataclasses.replace(cb, K=cb.project(K), M=cb.project(M))


# --------------------------------------------------------------------------
# Reduced models
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class BoltTable:
    """Bolts of a reduced model (their springs are already in ``K``).

    Attributes
    ----------
    lower_dofs, upper_dofs : ndarray of int, shape (n_b, d)
        DOFs of each bolt's two ends, one per direction (-1: none).
    axis : ndarray, shape (n_b, d)
        Unit vector from the lower to the upper end.
    stiffness : ndarray, shape (n_b,)
        Axial spring of each bolt [N/m].
    preload : ndarray, shape (n_b,)
        Clamping force [N].
    names : tuple of str
    """

    lower_dofs: np.ndarray
    upper_dofs: np.ndarray
    axis: np.ndarray
    stiffness: np.ndarray
    preload: np.ndarray
    names: tuple = ()

    @property
    def n_bolts(self) -> int:
        return len(self.stiffness)

    def operator(self, n_dof: int) -> sp.csr_matrix:
        """Elongation operator ``e = B @ x`` [m/m], shape (n_b, n_dof)."""
        rows, cols, vals = [], [], []
        for sign, dofs in ((1.0, self.upper_dofs), (-1.0, self.lower_dofs)):
            for c in range(dofs.shape[1]):
                v = sign * self.axis[:, c]
                keep = (dofs[:, c] >= 0) & (v != 0)
                rows += np.nonzero(keep)[0].tolist()
                cols += dofs[keep, c].tolist()
                vals += v[keep].tolist()
        return sp.csr_matrix((vals, (rows, cols)), shape=(self.n_bolts, n_dof))

    def stiffness_matrix(self, n_dof: int) -> sp.csr_matrix:
        """The bolt springs ``B^T diag(k_b) B`` [N/m]."""
        Bop = self.operator(n_dof)
        return sp.csr_matrix(Bop.T @ sp.diags(self.stiffness) @ Bop)

    def clamp_forces(self, n_dof: int) -> np.ndarray:
        """Clamping forces: each bolt pulls its ends together with its preload [N]."""
        return -(self.operator(n_dof).T @ self.preload)

    def dofs(self) -> np.ndarray:
        """DOFs the bolts act on."""
        Bop = self.operator(1 + max(self.lower_dofs.max(), self.upper_dofs.max()))
        return np.unique(Bop.indices)


@dataclass(frozen=True)
class ReducedModel:
    """A reduced linear structure with its interface (FE-built or imported).

    Attributes
    ----------
    M, K : ndarray, shape (n, n)
        Mass [kg] and stiffness [N/m], bolt springs included.
    interface : Interface
        Contact pairs in this model's DOF numbering.
    C : ndarray, shape (n, n), optional
        Damping [N s/m] (added to the scene's ``[damping]``).
    f_static : ndarray, shape (n,)
        Constant loads other than bolt clamping [N].
    bolts : BoltTable, optional
    points : dict of str -> int
        Named DOFs.
    dof_labels : tuple of str
    """

    M: np.ndarray
    K: np.ndarray
    interface: Interface
    C: np.ndarray | None = None
    f_static: np.ndarray | None = None
    bolts: BoltTable | None = None
    points: dict = field(default_factory=dict)
    dof_labels: tuple = ()

    def __post_init__(self):
        M = np.asarray(self.M.toarray() if sp.issparse(self.M) else self.M, dtype=float)
        K = np.asarray(self.K.toarray() if sp.issparse(self.K) else self.K, dtype=float)
        n = M.shape[0]
        if M.shape != (n, n) or K.shape != (n, n):
            raise ValueError(f"M and K must be square and of equal size, got {M.shape} "
                             f"and {K.shape}")
        object.__setattr__(self, "M", M)
        object.__setattr__(self, "K", K)
        if self.C is not None:
            C = np.asarray(self.C.toarray() if sp.issparse(self.C) else self.C, dtype=float)
            if C.shape != (n, n):
                raise ValueError(f"C must be {n} x {n}, got {C.shape}")
            object.__setattr__(self, "C", C)
        f = np.zeros(n) if self.f_static is None else np.asarray(self.f_static, float).ravel()
        if f.shape != (n,):
            raise ValueError(f"f_static must have {n} entries, got {f.size}")
        object.__setattr__(self, "f_static", f)
        for name in ("lower_dofs", "upper_dofs"):
            d = getattr(self.interface, name)
            if d.size and (d.max() >= n):
                raise ValueError(f"interface {name} has DOF {d.max()} >= n_dof = {n}")
        for name, dof in self.points.items():
            if not 0 <= int(dof) < n:
                raise ValueError(f"point {name!r} has DOF {dof} outside 0..{n - 1}")
        if not self.dof_labels:
            object.__setattr__(self, "dof_labels", tuple(f"x{i}" for i in range(n)))

    @property
    def n_dof(self) -> int:
        return self.M.shape[0]


# --------------------------------------------------------------------------
# Reduced model + scene -> StructuralModel
# --------------------------------------------------------------------------
def structural_model(scene, rom: ReducedModel, *, preload_tangential: str = "stuck",
                     preload_tol: float = 1e-10, extra: dict | None = None) -> StructuralModel:
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
    extra : dict, optional
        Kind-specific data stored in ``StructuralModel.extra``.

    Returns
    -------
    StructuralModel
        ``extra`` gains ``x0`` (preload displacement, m), ``preload``
        (:class:`~jointsim.solvers.static.StaticResult`), ``rom`` and timings.
        The tangent of the preloaded stuck joint is
        :func:`jointsim.solvers.static.stuck_linearisation` of the model.
    """
    from .contact.select import NORMAL_TABLE
    from .solvers.static import solve_static, stuck_mode, tangent_stiffness
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
    load_dofs = []
    for i, ld in enumerate(loads):
        if ld.point:
            key = f"{ld.point}.{ld.direction}"
            if key not in rom.points:
                raise SceneError(str(scene.path), f"excitation.loads[{i}].point",
                                 f"names {ld.point!r}, which is not a retained point of the "
                                 f"model (retained: {sorted(set(p.split('.')[0] for p in rom.points))})")
            load_dofs.append(rom.points[key])
        else:
            if ld.dof >= n:
                raise SceneError(str(scene.path), f"excitation.loads[{i}].dof",
                                 f"must be < {n} (the reduced model has {n} DOFs)")
            load_dofs.append(ld.dof)
    info = dict(extra or {})
    info.update(x0=x0, preload=pre, rom=rom,
                f_clamp=f_clamp, K_bolt=K_bolt, preload_time_s=t_pre)
    log.info("preload: sum N0 = %.6g N over %d/%d elements in contact (%s)",
             N0.sum(), int(np.sum(N0 > 0)), ne, pre.convergence.message)
    return StructuralModel(M=M, K=sp.csr_matrix(K_model), C=C, contacts=contacts,
                           load_dofs=np.array(load_dofs, dtype=np.int64),
                           load_signals=tuple(ld.force for ld in loads),
                           f_static=f_static, dof_labels=tuple(rom.dof_labels),
                           points=dict(rom.points), units=getattr(scene.model, "units", "SI"),
                           extra=info)


def build_rom(scene) -> StructuralModel:
    """Structural model of a ``kind = "rom"`` scene (reduced model from a file)."""
    from .io.rom import load_rom
    m = scene.model
    path = scene.resolve(m.file)
    try:
        rom = load_rom(path)
    except (KeyError, ValueError) as exc:
        raise SceneError(str(scene.path), "model.file", f"{path}: {exc}") from None
    return structural_model(scene, rom, preload_tangential=m.preload_tangential,
                            preload_tol=m.preload_tol, extra={"source": str(path)})


def build_fe(scene) -> StructuralModel:
    """Structural model of a ``kind = "fe"`` scene (see :mod:`jointsim.fem.build`)."""
    from .fem.build import build_fe as _build
    return _build(scene)


BUILDERS["fe"] = build_fe
BUILDERS["rom"] = build_rom
