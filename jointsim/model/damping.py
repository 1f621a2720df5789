"""Linear damping matrices from a scene's ``[damping]`` table (Rayleigh or modal)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


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
    """
    n = M.shape[0]
    C = sp.csr_matrix((n, n)) if C0 is None else sp.csr_matrix(C0)
    if damping.kind == "rayleigh":
        C = C + damping.alpha * M + damping.beta * K
    elif damping.kind == "modal":
        zeta = np.asarray(damping.zeta, dtype=float)
        if zeta.size == 0:
            raise ValueError("damping.zeta must list at least one modal damping ratio")
        if n > 2000:
            raise NotImplementedError("modal damping of a model with more than 2000 DOFs: "
                                      "reduce it first (Craig-Bampton) or use Rayleigh damping")
        import scipy.linalg as sla
        w2, phi = sla.eigh(K.toarray(), M.toarray())
        m = min(zeta.size, n)
        w = np.sqrt(np.maximum(w2[:m], 0.0))
        Mphi = M @ phi[:, :m]
        C = C + sp.csr_matrix(Mphi @ np.diag(2.0 * zeta[:m] * w) @ Mphi.T)
    return sp.csr_matrix(C)
