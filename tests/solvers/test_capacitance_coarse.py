"""The coarse space of a split low-rank stage's capacitance system (round 56, issue 10):
``E = Z^T (I + L_r G) Z`` against the dense capacitance matrix, its place in the
preconditioner of the capacitance system, and what it saves on the FE lap joint."""

import numpy as np
import pytest
import scipy.linalg as sla

import jointsim.solvers.lowrank_stage as ls
import jointsim.solvers.preconditioner as pm
from jointsim.model import build_model
from jointsim.solvers.hbm import HBMSystem
from jointsim.solvers.lowrank_stage import (capacitance_blocks, capacitance_coarse,
                                            coarse_aggregates)
from jointsim.solvers.preconditioner import HarmonicPreconditioner

from .._scenes import four_dof


def _split_stage(sk, z, F, omega):
    """A loose, single-solve Jacobian of ``sk`` at ``z`` and its split preconditioner."""
    sk.krylov_rtol = 1e-3
    sk.preconditioner.single_solve = True
    J = sk.evaluate(z, omega, F).J
    P = HarmonicPreconditioner(J)
    assert P.lowrank is not None and P.capacitance_solves
    return J, P


@pytest.mark.parametrize("size", [1, 2])
def test_coarse_matrix_is_the_capacitance_system_on_the_aggregates(size, monkeypatch):
    """On the four-DOF chain (coupled normal load, stick, slip and separation), with
    aggregates of ``size`` row blocks: the coarse matrix ``E`` formed by harmonics equals
    ``Z^T (I + L_r G) Z`` of the dense capacitance matrix (:func:`capacitance_blocks`,
    itself checked against the dense ``G``), with ``Z`` the aggregates' constants per
    coefficient (``size = 1``: ``Z`` a permutation, ``E`` the whole matrix); an aggregate holds
    one kind of rows; and the preconditioner of the capacitance system is the element
    blocks' inverse plus ``Z E^-1 Z^T``."""
    monkeypatch.setattr(pm, "LOOSE_SPLIT_MIN", 0)
    monkeypatch.setattr(ls, "COARSE_ROW_BLOCKS", size)
    sk = HBMSystem(build_model(four_dof("jenkins", "anchor", "coupled")), (0, 1, 2, 3), 64,
                   linear_solver="krylov")
    F = sk.force_coefficients(0.3)
    z = np.random.default_rng(5).normal(size=sk.n_z) * 0.4
    J, P = _split_stage(sk, z, F, 1.1)
    lr = P.lowrank
    nc, nb, nrb = J.n_c, lr.nb, lr.Rrow.size
    assert nrb > size and lr.coarse is not None
    Lr4 = lr.Lr.reshape(nrb, nc, nb, nc)
    # the oracle: the dense I + L_r G from the same columns of P_h^-1
    cols = P._inverse_columns(lr.Rrow)
    C = np.eye(nrb * nc) + capacitance_blocks(J, cols, Lr4, lr.R, lr.block_element, float)
    kind = np.isin(lr.Rrow, J.n_row).astype(int)
    A, lu = capacitance_coarse(J, cols, Lr4, lr.R, lr.block_element, lr.Rrow, kind)
    agg = np.argmax(A, axis=1)
    assert np.array_equal(A.sum(axis=1), np.ones(nrb))          # one aggregate each
    assert A.sum(axis=0).max() <= size
    assert all(np.unique(kind[agg == a]).size == 1 for a in range(A.shape[1]))
    Z = np.kron(A, np.eye(nc))
    ref = Z.T @ C @ Z
    assert lu[0].shape[0] == ref.shape[0] == A.shape[1] * nc
    Einv = sla.lu_solve(lu, np.eye(ref.shape[0]))
    assert np.abs(Einv @ ref - np.eye(ref.shape[0])).max() <= 1e-10
    if size == 1:                   # Z a permutation: E is the whole matrix, reordered
        assert np.array_equal(Z.T @ Z, np.eye(C.shape[0]))
    # the preconditioner: element blocks plus the coarse correction
    r = np.random.default_rng(1).normal(size=(nrb * nc, 2))
    blocks_only = lr._replace(coarse=None).capacitance_inverse(r)
    want = blocks_only + Z @ np.linalg.solve(ref, Z.T @ r)
    got = lr.capacitance_inverse(r)
    assert np.abs(got - want).max() <= 1e-10 * np.abs(want).max()


def test_aggregates_are_neighbours_of_one_kind():
    """Row blocks on a line, two kinds: aggregates of at most four, each of one kind and
    a contiguous range of positions."""
    x = np.linspace(0.0, 1.0, 20)
    pos = np.concatenate([x, x])[:, None]
    kind = np.repeat([0, 1], 20)
    agg = coarse_aggregates(pos, kind, 4)
    for a in np.unique(agg):
        members = np.flatnonzero(agg == a)
        assert members.size <= 4 and np.unique(kind[members]).size == 1
        xs = np.sort(pos[members, 0])
        inside = (pos[:, 0] > xs[0]) & (pos[:, 0] < xs[-1]) & (kind == kind[members[0]])
        assert set(np.flatnonzero(inside)) <= set(members)      # no gap in the range
    assert np.unique(agg).size >= 10


def test_the_coarse_space_saves_capacitance_iterations_on_the_lap_joint(coarse_model,
                                                                        monkeypatch):
    """On the coarse FE lap joint (coupled normal load, H = 0..7, 34 contact coordinates)
    at a state where its elements slip (the static state plus a 2e-7 m perturbation:
    more row blocks than ``COARSE_ROW_BLOCKS``), the split stage's capacitance solve
    reaches its tolerance with and without the coarse space, the dense solution to 1e-3
    with it, and with it in fewer GMRES iterations: measured 61 against 149 (seeds 4 to
    6 of the state: 42 / 113, 50 / 135, 42 / 124)."""
    monkeypatch.setattr(pm, "LOOSE_SPLIT_MIN", 0)
    harmonics = tuple(range(8))
    sk = HBMSystem(coarse_model, harmonics, 128, linear_solver="krylov")
    sd = HBMSystem(coarse_model, harmonics, 128, linear_solver="direct")
    rng = np.random.default_rng(3)
    F = sk.force_coefficients(1.0)
    z = sk.static_coordinates() + rng.normal(size=sk.n_z) * 2e-7
    v = rng.normal(size=sk.n_z)
    xd = np.linalg.solve(sd.evaluate(z, 1000.0, F).J, v)
    out = {}
    for coarse in (0, ls.COARSE_ROW_BLOCKS):
        monkeypatch.setattr(ls, "COARSE_ROW_BLOCKS", coarse)
        J, P = _split_stage(sk, z, F, 1000.0)
        assert (P.lowrank.coarse is not None) == bool(coarse)
        assert P.lowrank.Rrow.size > ls.COARSE_ROW_BLOCKS or not coarse
        x, it = P.solve_capacitance(v, 1e-5)
        rel = np.linalg.norm(J.matvec(x) - v) / np.linalg.norm(v)
        out[coarse] = (it, rel, np.abs(x - xd).max() / np.abs(xd).max())
    (it0, rel0, _), (it1, rel1, err1) = out[0], out[ls.COARSE_ROW_BLOCKS]
    assert rel0 <= 1e-5 and rel1 <= 1e-5 and err1 <= 1e-3
    assert it1 <= 0.8 * it0, out


def test_a_large_tight_bordered_solve_is_built_as_a_loose_one(monkeypatch):
    """The EPMC's tight bordered solve (its preconditioner shifted) from
    ``SHIFTED_SPLIT_MIN_ROWS`` rows is built as a loose one: its harmonic stage from the
    stuck flexibility (no ``S_h``, single precision but the shifted and the static and
    fundamental blocks), its correction split when large, and its solve through the
    capacitance system refined on the bordered system to the tight tolerance: the dense
    solution to 1e-9.  Below that many rows (the limit above the chain's 4) the same
    solve keeps the inverted blocks in double and one LU.  Four-DOF Jenkins chain with
    coupled N, a state with slip and separation."""
    import jointsim.solvers.jacobian as jm
    from jointsim.solvers.epmc import EPMCSystem
    from jointsim.solvers.modes import elastic_mode
    model = build_model(four_dof("jenkins", "anchor", "coupled"))
    sk = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="krylov")
    assert sk.krylov_rtol < pm.SINGLE_LU_RTOL                 # a tight solve
    ep = EPMCSystem(sk, elastic_mode(model, 1).phi, sk.force_coefficients(0.0))
    rng = np.random.default_rng(5)
    y = np.concatenate([rng.normal(size=sk.n_z) * 0.4, [1.1, 0.01, 0.0]])
    A = jm.drop_last_column(ep.fun(y)[1])
    b = rng.normal(size=(A.shape[0], 2))
    xd = np.linalg.solve(A.to_dense(), b)
    monkeypatch.setattr(pm, "SHIFTED_SPLIT_MIN_ROWS", sk.n_r)
    monkeypatch.setattr(pm, "LOOSE_SPLIT_MIN", 0)
    monkeypatch.setattr(pm, "LOOSE_SPLIT_SHARED_MIN", 0)
    used, refine = [], jm._capacitance_refined
    monkeypatch.setattr(jm, "_capacitance_refined", lambda *a: used.append(a) or refine(*a))
    x = A.solve(b)
    P = sk.preconditioner.current
    assert P.loose and P.C2 is not None and P.modal and P.S is None
    assert P.Pinv.dtype == np.complex64 and P.capacitance_solves and P.lowrank.split
    assert used
    assert np.abs(x - xd).max() <= 1e-9 * np.abs(xd).max()
    for k in range(2):
        assert np.linalg.norm(A.matvec(x[:, k]) - b[:, k]) \
            <= sk.krylov_rtol * 10 * np.linalg.norm(b[:, k])
    # below the limit: inverted blocks in double, one LU, no capacitance solves
    monkeypatch.setattr(pm, "SHIFTED_SPLIT_MIN_ROWS", sk.n_r + 1)
    sk.preconditioner.forget(stage=True)
    x = A.solve(b)
    P = sk.preconditioner.current
    assert not P.loose and not P.capacitance_solves and P.lowrank.lu is not None
    assert P.Pinv is not None and P.Pinv.dtype == np.complex128
    assert np.abs(x - xd).max() <= 1e-9 * np.abs(xd).max()

