"""Linear damping matrices from a scene's ``[damping]`` table (Rayleigh or modal)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

#: Modal damping takes every mode of the (reduced) model by a dense generalised
#: eigen-decomposition; above this many DOFs it is refused.  Round 42: the limit was
#: 2,000, and the default scene refined to 504 Gauss points (2,060 reduced DOFs) failed
#: after its 30 s build.  A dense ``eigh`` of 1,964 DOFs takes 1.2 to 1.6 s; of 6,000, the
#: condensation's own dense limit (:data:`jointsim.solvers.condensation.MAX_DENSE_DOF`),
#: about 40 s by ``n^3`` (estimated, not measured).
MODAL_DAMPING_MAX_DOF = 6000


def damping_matrix(M, K, damping, C0=None):
    """Linear damping matrix from a scene's ``[damping]`` table.

    Parameters
    ----------
    M, K : sparse matrix, shape (n, n)
    damping : jointsim.scene.Damping
    C0 : sparse matrix, optional
        Damping given directly (lumped ``model.C``); added to the result.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n, n) [N s/m]

    Raises
    ------
    NotImplementedError
        Modal damping of a model above :data:`MODAL_DAMPING_MAX_DOF` DOFs.
    """
    return damping_and_modes(M, K, damping, C0)[0]


def damping_and_modes(M, K, damping, C0=None) -> tuple:
    """:func:`damping_matrix`, and the modes of ``(K, M)`` when modal damping made them.

    Returns
    -------
    C : scipy.sparse.csr_matrix, shape (n, n) [N s/m]
    modes : tuple (lam, phi) or None
        Every eigenvalue ``lam`` (n,) [rad^2/s^2], ascending, and the mass-normalised
        modes ``phi`` (n, n) of ``K phi = M phi diag(lam)`` (modal damping; None for
        Rayleigh damping).  The stuck flexibility reuses them (:class:`~jointsim.solvers.
        condensation.ReducedLinear`): the same decomposition, not made twice.
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
        w2, phi = modes = sla.eigh(K.toarray(), M.toarray())
        m = min(zeta.size, n)
        w = np.sqrt(np.maximum(w2[:m], 0.0))
        Mphi = M @ phi[:, :m]
        C = C + sp.csr_matrix(Mphi @ np.diag(2.0 * zeta[:m] * w) @ Mphi.T)
    return sp.csr_matrix(C), modes
