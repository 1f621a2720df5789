"""Linear damping matrices from a scene's ``[damping]`` table (Rayleigh or modal)."""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

log = logging.getLogger(__name__)

#: Modal damping takes every mode of the (reduced) model by a dense generalised
#: eigen-decomposition; above this many DOFs it is refused.  Round 42: the limit was
#: 2,000, and the default scene refined to 504 Gauss points (2,060 reduced DOFs) failed
#: after its 30 s build.  A dense ``eigh`` of 1,964 DOFs takes 1.2 to 1.6 s; of 6,000, the
#: condensation's own dense limit (:data:`jointsim.solvers.condensation.MAX_DENSE_DOF`),
#: about 40 s by ``n^3`` (estimated, not measured).
MODAL_DAMPING_MAX_DOF = 6000


#: :meth:`ModalBasis.hold_for`: largest relative residual of the eigen-equations at a
#: random combination of the modes (a dense ``eigh`` leaves about ``1e-15``).
HOLD_RTOL = 1e-9


@dataclass(frozen=True)
class ModalBasis:
    """Every mode of the undamped structure ``(K, M)``: the basis of its modal damping.

    Made by :func:`damping_and_modes` (the one dense eigen-decomposition of the reduced
    model) and kept on the model (``StructuralModel.modal_basis``) for the solvers that
    need all of them (the stuck flexibility, :mod:`jointsim.solvers.flexibility`).

    Attributes
    ----------
    lam : ndarray, shape (n,)
        Eigenvalues ``omega^2``, ascending [rad^2/s^2].
    phi : ndarray, shape (n, n)
        The modes as columns, M-orthonormal (``phi^T M phi = I``) [1/sqrt(kg)].
    """

    lam: np.ndarray
    phi: np.ndarray

    def hold_for(self, K, M, seed: int = 0) -> bool:
        """Whether these are the modes of ``(K, M)`` (sparse or dense, shape (n, n)): the
        eigen-equations' residual at one random combination of them, ``|K v - M phi
        (lam a)| <= HOLD_RTOL (|K v| + |M phi (lam a)|)`` with ``v = phi a``, ``O(n^2)``.
        False for a stiffness or mass changed since (``dataclasses.replace``)."""
        n = self.lam.size
        if K.shape != (n, n) or M.shape != (n, n):
            return False
        a = np.random.default_rng(seed).standard_normal(n)
        kv = K @ (self.phi @ a)
        mv = M @ (self.phi @ (self.lam * a))
        ref = float(np.linalg.norm(kv) + np.linalg.norm(mv))
        return bool(np.isfinite(ref)) and float(np.linalg.norm(kv - mv)) <= HOLD_RTOL * ref


def held_modal_basis(model) -> ModalBasis | None:
    """``model.modal_basis`` when it holds for the model's stuck stiffness and mass
    (:meth:`ModalBasis.hold_for`), else None (logged when it no longer holds)."""
    basis = getattr(model, "modal_basis", None)
    lin = getattr(model, "linearisation", None)
    if basis is None or lin is None:
        return None
    if basis.hold_for(lin.K, model.M):
        return basis
    log.debug("the model's modal basis does not hold for its stuck stiffness and mass "
              "(changed since the build): not used")
    return None


def damping_matrix(M, K, damping, C0=None):
    """Linear damping matrix from a scene's ``[damping]`` table (:func:`damping_and_modes`
    without the modes)."""
    return damping_and_modes(M, K, damping, C0)[0]


def damping_and_modes(M, K, damping, C0=None):
    """Linear damping matrix from a scene's ``[damping]`` table, and the modes that
    modal damping is defined on.

    Parameters
    ----------
    M, K : sparse matrix, shape (n, n)
    damping : jointsim.scene.Damping
    C0 : sparse matrix, optional
        Damping given directly (lumped ``model.C``); added to the result.

    Returns
    -------
    C : scipy.sparse.csr_matrix, shape (n, n) [N s/m]
    modes : ModalBasis or None
        Every mode of ``(K, M)`` for modal damping, else None.

    Raises
    ------
    NotImplementedError
        Modal damping of a model above :data:`MODAL_DAMPING_MAX_DOF` DOFs.
    """
    n = M.shape[0]
    C = sp.csr_matrix((n, n)) if C0 is None else sp.csr_matrix(C0)
    modes = None
    if damping.kind == "rayleigh":
        C = C + damping.alpha * M + damping.beta * K
    elif damping.kind == "modal":
        zeta = np.asarray(damping.zeta, dtype=float)
        if zeta.size == 0:
            raise ValueError("damping.zeta must list at least one modal damping ratio")
        if n > MODAL_DAMPING_MAX_DOF:
            raise NotImplementedError(f"modal damping of a model with more than "
                                      f"{MODAL_DAMPING_MAX_DOF} DOFs ({n}): reduce it "
                                      f"further (Craig-Bampton) or use Rayleigh damping")
        import scipy.linalg as sla
        # on the mass's diagonal scaled to 1 (a Craig-Bampton mass spans 1e-6 to 1e2 kg;
        # the same pencil, better conditioned): the first elastic mode of the lap joint at
        # 480 Gauss points 8.5e-7 -> 8.9e-9 from the shift-invert one (round 43)
        s = 1.0 / np.sqrt(np.abs(M.diagonal()))
        s[~np.isfinite(s)] = 1.0
        Ms = M.toarray() * s[:, None] * s[None, :]
        w2, phi = sla.eigh(K.toarray() * s[:, None] * s[None, :], Ms)
        phi *= s[:, None]
        m = min(zeta.size, n)
        w = np.sqrt(np.maximum(w2[:m], 0.0))
        Mphi = M @ phi[:, :m]
        C = C + sp.csr_matrix(Mphi @ np.diag(2.0 * zeta[:m] * w) @ Mphi.T)
        modes = ModalBasis(lam=w2, phi=phi)
    return sp.csr_matrix(C), modes
