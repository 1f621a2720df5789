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


def test_modal_damping_keeps_the_modes_it_is_defined_on():
    """``damping_and_modes``: the modes are M-orthonormal eigenvectors of ``(K, M)`` and
    ``C = M phi_m diag(2 zeta w) phi_m^T M`` on the first ones; ``hold_for`` accepts their
    own pencil and refuses a stiffness or a mass changed by 1e-6 in one entry (the
    probe of a model changed after its build).  Rayleigh damping keeps none."""
    K, M = _chain(12)
    zeta = (0.01, 0.02)
    C, basis = dm.damping_and_modes(M, K, Damping(kind="modal", zeta=zeta))
    phi, lam = basis.phi, basis.lam
    Kd, Md = K.toarray(), M.toarray()
    assert np.abs(phi.T @ Md @ phi - np.eye(12)).max() <= 1e-12
    assert np.abs(Kd @ phi - (Md @ phi) * lam).max() <= 1e-10 * np.abs(Kd).max()
    W = Md @ phi[:, :2]
    expected = (W * (2 * np.asarray(zeta) * np.sqrt(lam[:2]))) @ W.T
    assert np.abs(C.toarray() - expected).max() <= 1e-14 * np.abs(expected).max()
    assert basis.hold_for(K, M)
    for dK, dM in ((1e-6 * 1e4, 0.0), (0.0, 1e-6)):
        K2, M2 = K.tolil(), M.tolil()
        K2[3, 3] += dK
        M2[5, 5] += dM
        assert not basis.hold_for(K2.tocsr(), M2.tocsr())
    assert not basis.hold_for(K[:11, :11], M[:11, :11])
    assert dm.damping_and_modes(M, K, Damping(kind="rayleigh", alpha=0.1, beta=1e-4))[1] \
        is None


def test_the_lap_joints_modal_basis_holds_and_a_changed_model_drops_it(coarse_model):
    """The built lap joint carries the modes of its modal damping, which hold for its
    stuck linearisation (the preload's tangent, the same pencil); with ``K`` changed
    after the build (``dataclasses.replace``, the linearisation made again) they no longer
    do, and ``held_modal_basis`` gives None."""
    import dataclasses
    assert coarse_model.modal_basis is not None
    assert dm.held_modal_basis(coarse_model) is coarse_model.modal_basis
    changed = dataclasses.replace(coarse_model, K=coarse_model.K * (1 + 1e-6),
                                  linearisation=None)
    assert dm.held_modal_basis(changed) is None
