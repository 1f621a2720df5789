"""Linear damping matrices from a scene's ``[damping]`` table."""
import numpy as np
import pytest
import scipy.sparse as sp

from jointsim.model import damping as dm
from jointsim.scene import Damping


def _chain(n):
    """A fixed-free spring-mass chain: ``K`` tridiagonal [N/m], ``M`` diagonal [kg]."""
    k = 1e4 * (1.0 + np.arange(n) / n)
    main = k + np.r_[k[1:], 0.0]
    K = sp.diags([main, -k[1:], -k[1:]], [0, 1, -1], format="csr")
    M = sp.diags(0.5 + np.arange(n) / n, format="csr")
    return K, M


def test_modal_damping_gives_each_mode_its_ratio():
    """Oracle: ``phi_i^T C phi_i = 2 zeta_i omega_i`` for the mass-normalised modes that
    have a ratio, zero for the others, and no coupling between modes."""
    import scipy.linalg as sla
    K, M = _chain(12)
    zeta = (0.01, 0.02, 0.005)
    C = dm.damping_matrix(M, K, Damping(kind="modal", zeta=zeta)).toarray()
    w2, phi = sla.eigh(K.toarray(), M.toarray())
    modal = phi.T @ C @ phi
    expected = np.zeros(12)
    expected[:3] = 2 * np.asarray(zeta) * np.sqrt(w2[:3])
    np.testing.assert_allclose(np.diag(modal), expected, rtol=1e-10, atol=1e-12 * expected.max())
    off = modal - np.diag(np.diag(modal))
    assert np.abs(off).max() <= 1e-10 * expected.max()


def test_modal_damping_refuses_a_model_above_its_limit_naming_its_size(monkeypatch):
    """Above ``MODAL_DAMPING_MAX_DOF`` (6,000; 2,000 before round 42, which the default
    scene at 504 Gauss points passed with 2,060 reduced DOFs) a clear error names the
    model's DOFs."""
    K, M = _chain(12)
    monkeypatch.setattr(dm, "MODAL_DAMPING_MAX_DOF", 10)
    with pytest.raises(NotImplementedError, match=r"more than 10 DOFs \(12\)"):
        dm.damping_matrix(M, K, Damping(kind="modal", zeta=(0.01,)))
