"""Stuck-joint modes, rigid-body (suspension) modes and the elastic mode numbering
(:mod:`jointsim.solvers.modes`) on the coarse FE lap joint and a lumped model."""
import numpy as np
import pytest

from jointsim.fem.reduction import dense_spd_factor
from jointsim.model import build_model
from jointsim.solvers.modes import elastic_mode, eigenmodes, rigid_body_modes, stuck_modes

from .._scenes import four_dof


@pytest.fixture
def coupled(coarse_lap_coupled):
    return coarse_lap_coupled


@pytest.fixture
def fixed(coarse_lap_fixed):
    return coarse_lap_fixed


def test_fixed_normal_load_linearises_like_the_coupled_joint(coupled, fixed):
    """Fixed N: normal springs only where the preload closed the interface, so the
    stuck linear modes are the coupled joint's."""
    fc = stuck_modes(coupled, 8).frequency_hz
    ff = stuck_modes(fixed, 8).frequency_hz
    assert np.allclose(fc[3:], ff[3:], rtol=1e-7, atol=0)
    # the suspension modes (w^2 ~ 1e-9 of the contact stiffness) to round-off
    assert np.allclose(fc[:3], ff[:3], rtol=1e-4, atol=0)
    Kc = coupled.linearisation.K.toarray()
    Kf = fixed.linearisation.K.toarray()
    assert np.abs(Kc - Kf).max() <= 1e-9 * np.abs(Kc).max()


def test_suspension_modes_are_detected(coupled):
    res = stuck_modes(coupled, 8)
    assert list(res.elastic) == [False, False, False] + [True] * 5
    assert "rigid-body share" in res.rigid_method
    assert res.frequency_hz[2] < 6.0 < 100.0 < res.frequency_hz[3]
    em = elastic_mode(coupled, 1)
    assert em.index == 3 and em.n_rigid == 3
    assert em.frequency_hz == pytest.approx(res.frequency_hz[3], rel=1e-8)  # eigh round-off
    assert em.phi @ (coupled.M @ em.phi) == pytest.approx(1.0, rel=1e-10)
    # an explicit cutoff decides instead
    mask, how = rigid_body_modes(coupled, res.frequency_hz, res.shapes, cutoff_hz=4.0)
    assert list(mask[:4]) == [True, True, False, False] and "below 4" in how
    assert elastic_mode(coupled, 2, rigid_cutoff_hz=4.0).index == 3


def test_rom_uses_the_spectral_gap_and_lumped_models_have_no_rigid_modes(coupled):
    import dataclasses
    rom_like = dataclasses.replace(coupled, fe=None)
    f, phi = eigenmodes(coupled.linearisation.K, coupled.M, 8)
    mask, how = rigid_body_modes(rom_like, f, phi)
    assert list(mask) == [True, True, True] + [False] * 5 and "gap" in how
    lumped = build_model(four_dof())
    f, phi = eigenmodes(lumped.K, lumped.M, 4)
    mask, _ = rigid_body_modes(lumped, np.array([0.01, 1.0, 1.2, 1.5]), phi)
    assert not mask.any()
    assert elastic_mode(lumped, 1).index == 0
    with pytest.raises(ValueError, match="elastic modes"):
        elastic_mode(lumped, 5)


def test_a_dense_model_stored_sparse_takes_the_dense_factor_and_the_same_modes(monkeypatch):
    """A reduced model is dense in its interface block: above ``DENSE_FILL`` stored
    entries the shift-invert Lanczos runs on a dense Cholesky factor, and gives the
    modes of the sparse LU's path and of a dense generalized ``eigh``; a singular
    stiffness still falls back to the dense solver."""
    import scipy.linalg as sla
    import scipy.sparse as sp

    import jointsim.solvers.modes as modes
    rng = np.random.default_rng(3)
    n = 700
    A = rng.standard_normal((n, n))
    K = A @ A.T + n * np.eye(n)
    B = rng.standard_normal((n, n)) / n
    M = np.diag(rng.uniform(0.5, 2.0, n)) + B @ B.T
    Ks, Ms = sp.csr_matrix(K), sp.csr_matrix(M)
    assert Ks.nnz >= modes.DENSE_FILL * n * n
    calls = []
    monkeypatch.setattr(modes, "dense_spd_factor",
                        lambda A: calls.append(A.shape) or dense_spd_factor(A))
    f, phi = eigenmodes(Ks, Ms, 8)
    assert calls == [(n, n)]
    monkeypatch.setattr(modes, "DENSE_FILL", 1.1)          # the sparse LU's path
    f_lu, phi_lu = eigenmodes(Ks, Ms, 8)
    assert len(calls) == 1
    w2 = sla.eigh(K, M, eigvals_only=True, subset_by_index=(0, 7))
    f_ref = np.sqrt(w2) / (2 * np.pi)
    assert np.allclose(f, f_ref, rtol=1e-12, atol=0)
    assert np.allclose(f, f_lu, rtol=1e-12, atol=0)
    assert np.abs(phi - phi_lu).max() <= 1e-8 * np.abs(phi).max()
    assert np.allclose(phi @ M @ phi.T, np.eye(8), atol=1e-10)
    # not positive definite: the factor says so, and the dense eigen-solver answers
    monkeypatch.setattr(modes, "DENSE_FILL", 0.25)
    Kz = K.copy()
    Kz[:, 0] = Kz[0, :] = 0.0
    with pytest.raises(RuntimeError, match="dense_spd_factor"):
        dense_spd_factor(Kz)
    fz, _ = eigenmodes(sp.csr_matrix(Kz), Ms, 3)
    assert fz[0] == pytest.approx(0.0, abs=1e-6 * fz[1]) and fz[1] > 0.0


def test_the_models_stuck_modes_are_the_eigensolvers(coarse_model):
    """A model whose modal damping decomposed its stuck structure (``model.stuck_modes``)
    gives its stuck modes from that decomposition: the same elastic frequencies (1e-8
    relative; the suspension modes, 600 times lower than the first bending mode, to
    1e-5: a dense decomposition knows a mode to about ``eps lam_max / lam``) and
    elastic shapes (1e-8, signs fixed alike) as the eigensolver's (shift-invert Lanczos
    on the reduced model)."""
    import dataclasses
    m = coarse_model
    assert m.stuck_modes is not None
    a = stuck_modes(m, 8)
    b = stuck_modes(dataclasses.replace(m, stuck_modes=None), 8)
    elastic = a.elastic & b.elastic
    assert np.array_equal(a.elastic, b.elastic) and elastic.sum() >= 4
    rel = np.abs(a.frequency_hz - b.frequency_hz) / b.frequency_hz
    assert rel[elastic].max() <= 1e-8 and rel.max() <= 1e-5
    assert np.abs(a.shapes[elastic] - b.shapes[elastic]).max() \
        <= 1e-8 * np.abs(b.shapes[elastic]).max()
