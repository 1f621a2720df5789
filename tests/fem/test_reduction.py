"""Craig-Bampton reduction of the FE lap joint (ROM files: ``tests/io/test_rom.py``)."""

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from jointsim.fem.build import reduce_structure, retained_dofs
from jointsim.model import build_model
from jointsim.fem.reduction import craig_bampton
from jointsim.scene import load_scene
from jointsim.solvers.modes import eigenmodes, full_stuck_stiffness, stuck_modes

from .._scenes import ROOT

SCENE = ROOT / "models" / "lap_joint_nodes.toml"


def scene_for(mesh="coarse", extra=()):
    return load_scene(SCENE, [f"model.mesh='../meshes/lap_joint_{mesh}.msh'", *extra])


@pytest.mark.parametrize("n_modes", [0, 12])
def test_craig_bampton_is_exact_for_static_loads_on_retained_dofs(coarse_structure, n_modes):
    st = coarse_structure
    B, _ = retained_dofs(st)
    cb = craig_bampton(st.K, st.M, B, n_modes)
    rng = np.random.default_rng(3)
    f = np.zeros(st.n_dof)
    f[B] = rng.standard_normal(B.size)
    x = spla.spsolve(st.K.tocsc(), f)
    xr = np.linalg.solve(cb.K, cb.T.T @ f)
    # exact = the expanded reduced solution satisfies the full equations to
    # round-off: normwise backward error ~ eps; the forward error is that times
    # cond(K) ~ 1e11 (soft suspension springs under a load with a resultant)
    xe = cb.T @ xr
    backward = np.linalg.norm(st.K @ xe - f, 1) / (
        spla.norm(st.K, 1) * np.linalg.norm(xe, 1) + np.linalg.norm(f, 1))
    assert backward < 1e-13
    np.testing.assert_allclose(xr[:B.size], x[B], rtol=0, atol=1e-5 * np.abs(x).max())
    np.testing.assert_allclose(cb.T @ xr, x, rtol=0, atol=1e-5 * np.abs(x).max())
    # the modal coordinates carry no static load
    if n_modes:
        assert np.abs(xr[B.size:]).max() < 1e-9 * np.abs(xr).max()
    # basis identity on retained DOFs, mass-normalised fixed-interface modes
    np.testing.assert_array_equal(cb.T[B, :B.size], np.eye(B.size))
    np.testing.assert_allclose(np.diag(cb.M)[B.size:], 1.0, rtol=1e-9)


@pytest.mark.parametrize("mesh", ["coarse", "default"])
def test_reduced_frequencies_match_the_full_model(mesh):
    """First 5 elastic stuck-joint frequencies within 0.1 % with the default n_modes."""
    model = build_model(scene_for(mesh))
    assert model.fe.cb.n_modes == 30
    red = stuck_modes(model, 12, suspension_hz=20.0)
    f_full, _ = eigenmodes(full_stuck_stiffness(model), model.fe.structure.M, 12)
    el = red.elastic
    assert el.sum() >= 5 and not el[:3].any()  # three suspension modes first
    err = np.abs(red.frequency_hz[el][:5] / f_full[el][:5] - 1)
    assert np.all(err < 1e-3), err
    # Craig-Bampton frequencies are upper bounds that converge with n_modes
    assert np.all(red.frequency_hz[el][:5] >= f_full[el][:5] * (1 - 1e-9))


def test_more_fixed_interface_modes_converge(coarse_structure):
    st = coarse_structure
    f_ref, _ = eigenmodes(st.K, st.M, 10)
    errs = []
    for n in (0, 5, 20):
        rom, cb = reduce_structure(st, n)
        f, _ = eigenmodes(rom.K, rom.M, 10)
        errs.append(np.abs(f[3:8] / f_ref[3:8] - 1).max())
    assert errs[0] > errs[1] > errs[2]


def test_craig_bampton_modes_are_deterministic(coarse_structure):
    """Two reductions of the same structure are identical, mode signs included
    (the eigensolver's start vector is fixed, each mode's largest entry is positive)."""
    st = coarse_structure
    B, _ = retained_dofs(st)
    a = craig_bampton(st.K, st.M, B, 12)
    b = craig_bampton(st.K, st.M, B, 12)
    np.testing.assert_array_equal(a.T, b.T)
    modes = a.T[:, B.size:]
    assert np.all(modes[np.argmax(np.abs(modes), axis=0), np.arange(modes.shape[1])] > 0)


def test_spd_lu_solves_the_stiffness_with_less_fill(coarse_structure):
    """The symmetric ordering solves ``K_II`` as SuperLU's default does (oracle: the
    default factor's solution, to round-off) with at most its fill; a matrix with a
    zero leading pivot (not positive definite) falls back to the pivoting default."""
    import scipy.sparse as sp

    from jointsim.fem.reduction import spd_lu
    st = coarse_structure
    B, _ = retained_dofs(st)
    inner = np.ones(st.n_dof, bool)
    inner[B] = False
    K_II = sp.csc_matrix(st.K.tocsr()[inner][:, inner])
    b = np.random.default_rng(1).standard_normal((K_II.shape[0], 3))
    ref = spla.splu(K_II)
    lu = spd_lu(K_II)
    x, x_ref = lu.solve(b), ref.solve(b)
    assert np.abs(x - x_ref).max() <= 1e-9 * np.abs(x_ref).max()
    assert np.linalg.norm(K_II @ x - b) <= 1e-10 * np.linalg.norm(b)
    assert lu.L.nnz + lu.U.nnz <= ref.L.nnz + ref.U.nnz
    swap = sp.csc_matrix(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 2.0]]))
    np.testing.assert_allclose(swap @ spd_lu(swap).solve(np.array([1.0, 2.0, 3.0])),
                               [1.0, 2.0, 3.0], rtol=1e-15)


def test_constraint_modes_on_threads_equal_one_solve(coarse_structure, monkeypatch):
    """The constraint modes solved in column blocks on threads (beside the Lanczos
    iterations) equal one solve of every column, to the round-off of the blocking."""
    import jointsim.fem.reduction as red
    st = coarse_structure
    B, _ = retained_dofs(st)
    blocked = craig_bampton(st.K, st.M, B, 12)
    monkeypatch.setattr(red, "CONSTRAINT_BLOCKS", 1)
    whole = craig_bampton(st.K, st.M, B, 12)
    assert B.size >= 2      # two non-empty column blocks: the comparison is not trivial
    psi = slice(0, B.size)
    scale = np.abs(whole.T[:, psi]).max()
    assert np.abs(blocked.T[:, psi] - whole.T[:, psi]).max() <= 1e-13 * scale
    np.testing.assert_array_equal(blocked.T[:, B.size:], whole.T[:, B.size:])


def test_constraint_modes_and_projections_by_chunks_equal_whole_ones(coarse_structure,
                                                                    monkeypatch):
    """Solved ``SOLVE_COLUMNS`` right-hand sides at a time into ``T``, and projected
    ``PROJECT_COLUMNS`` columns at a time (uneven chunks here, on threads), the basis
    equals that of single chunks and ``K``, ``M`` equal ``T^T A T`` formed whole, to
    round-off; the threads change nothing."""
    import jointsim.fem.reduction as red
    st = coarse_structure
    B, _ = retained_dofs(st)
    for name in ("SOLVE_COLUMNS", "PROJECT_COLUMNS"):
        monkeypatch.setattr(red, name, 10 ** 6)
    whole = craig_bampton(st.K, st.M, B, 12)
    monkeypatch.setattr(red, "SOLVE_COLUMNS", 3)
    monkeypatch.setattr(red, "PROJECT_COLUMNS", 7)
    chunked = craig_bampton(st.K, st.M, B, 12)
    assert B.size > 2 * 3 and whole.T.shape[1] > 2 * 7   # several chunks of each
    scale = np.abs(whole.T).max()
    assert np.abs(chunked.T - whole.T).max() <= 1e-13 * scale
    for A, got in ((st.K, chunked.K), (st.M, chunked.M)):
        ref = chunked.T.T @ (A @ chunked.T)
        ref = 0.5 * (ref + ref.T)
        # one triangle against the mean of both: the round-off of the stiffness's
        # cancelling retained block (2.8e-13 of its largest entry; the mass 1e-17)
        assert np.abs(got - ref).max() <= 1e-12 * np.abs(ref).max()
        np.testing.assert_array_equal(got, got.T)
        # the threads do not change the projection
        np.testing.assert_array_equal(chunked.project(A, threads=1), got)


def test_reduced_stiffness_is_the_schur_complement(coarse_structure):
    """The reduced stiffness's retained block is the Schur complement ``K_BB - K_BI
    K_II^-1 K_IB`` to the whole product's round-off, and the modes decouple from the
    constraint modes.

    Oracle: the Schur complement from constraint modes refined with extended-precision
    residuals, formed in extended precision.  ``cond K_II`` is about 5e6 here (soft
    suspension), and the complement cancels most of ``K_BB``: the product ``T^T K T`` is
    within 1.1e-12 of it (of the largest entry); ``K_BB + K_BI Psi``, the complement
    from the same ``Psi`` (tried in round 42, not kept), 2.3e-12, and 4.7e-11 against
    5.2e-12 at 96 Gauss points.
    """
    import scipy.linalg as sla
    st = coarse_structure
    B, _ = retained_dofs(st)
    cb = craig_bampton(st.K, st.M, B, 12)
    K = st.K.tocsr()
    inner = np.ones(st.n_dof, bool)
    inner[B] = False
    K_II = K[inner][:, inner].toarray()
    K_IB = K[inner][:, B].toarray()
    ext = np.longdouble
    Psi = sla.solve(K_II, -K_IB, assume_a="pos")
    for _ in range(3):
        residual = (K_II.astype(ext) @ Psi.astype(ext) + K_IB).astype(float)
        Psi -= sla.solve(K_II, residual, assume_a="pos")
    schur = (K[B][:, B].toarray() + K_IB.T.astype(ext) @ Psi.astype(ext)).astype(float)
    nb = B.size
    scale = np.abs(schur).max()
    assert np.abs(cb.K[:nb, :nb] - schur).max() <= 2e-12 * scale
    assert np.abs(cb.K[:nb, nb:]).max() <= 1e-9 * scale       # Psi^T K Phi = 0
