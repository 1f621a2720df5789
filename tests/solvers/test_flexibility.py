"""The harmonic stage from the stuck joint's flexibility
(:class:`jointsim.solvers.flexibility.StuckFlexibility`, ``preconditioner.MODAL_STAGE``).

Oracles: the inverses of the harmonic blocks ``S_h + diag(k)`` formed from the
condensation (``ReducedLinear``'s Schur complements) and inverted by LU; the AFT's
tangent at the static state for ``k``; the dense solve of ``J x = b``.
"""
from __future__ import annotations

import numpy as np
import pytest

import jointsim.solvers.flexibility as fx
import jointsim.solvers.preconditioner as pm
from jointsim.model import build_model
from jointsim.solvers.frequency_blocks import FrequencyBlocks
from jointsim.solvers.hbm import HBMSystem
from jointsim.solvers.jacobian import gmres
from jointsim.solvers.preconditioner import HarmonicPreconditioner

from .._scenes import four_dof


def _blocks(lin, k, nus, xi):
    """``S_h + diag(k)`` at each frequency, from the condensation (the oracle)."""
    return [FrequencyBlocks(lin, [1], nu, xi).schur(0) + np.diag(k) for nu in nus]


def _check_inverses(system, nus, xi, rtol):
    fl = system.lin.flexibility
    assert fl is not None
    Y = fl.inverses(nus, xi)
    for P, Yh in zip(_blocks(system.lin, fl.k, nus, xi), Y):
        ref = np.linalg.inv(P)
        assert np.abs(Yh - ref).max() <= rtol * np.abs(ref).max()
    return fl


def _stuck_tangent(system):
    """The AFT's tangent of each contact coordinate at the static state (slip rows:
    ``Juu``, gap rows: ``-JNN``, harmonic 0)."""
    J = system.evaluate(system.static_coordinates(), 1.0, system.force_coefficients(0.0),
                        wrt=()).J
    k = np.zeros(system.n_r)
    k[system.t_row] = J.Juu[:, 0, 0]
    if J.JNN is not None:
        k[system.n_row] = -J.JNN[:, 0, 0]
    return k


@pytest.mark.parametrize("normal", ["coupled", "fixed"])
def test_flexibility_of_a_lumped_joint_is_the_inverse_of_its_blocks(normal):
    """On the 4-DOF joint (mass-proportional damping) the flexibility equals the inverted
    blocks to round-off at rest, between, at and far above the resonances, with and
    without self-excitation; ``k`` is the stuck linearisation's (``kt``, and ``kn`` with
    a coupled normal load, on every closed element), which is the AFT's tangent at the
    static state except on an element that rests at its slip limit (the second one
    with a coupled normal load: its AFT tangent is 0, and the low-rank stage keeps it)."""
    system = HBMSystem(build_model(four_dof("jenkins", "anchor", normal)), (0, 1, 2, 3), 64,
                       linear_solver="krylov")
    fl = _check_inverses(system, [0.0, 0.7, 1.1, 2.2, 3.3], 0.0, 1e-11)
    _check_inverses(system, [0.0, 1.1, 2.2, 3.3], 0.05, 1e-11)
    wn = np.sqrt(np.sort(fl.lam))
    _check_inverses(system, wn[:2] * (1 + 1e-3), 0.0, 1e-10)
    lin = system.model.linearisation
    assert lin.closed.all()
    assert np.allclose(fl.k[system.t_row], 0.8, rtol=1e-13)
    if normal == "coupled":
        assert np.allclose(fl.k[system.n_row], 1.0, rtol=1e-13)
    aft = _stuck_tangent(system)
    at_limit = np.zeros(system.n_r, dtype=bool)
    if normal == "coupled":
        at_limit[system.t_row[1]] = True
    assert np.abs(fl.k - aft)[~at_limit].max() <= 1e-13 and np.all(aft[at_limit] == 0.0)


def test_rayleigh_damping_is_a_block_of_damped_modes(monkeypatch):
    """Rayleigh damping with a stiffness part is not diagonal in the stuck modes (the
    stuck joint's springs are not in ``K``): the modes it reaches (here all four) are
    inverted as one block, exactly; beyond ``FLEX_DAMPED_MAX`` such modes there is no
    flexibility and the preconditioner inverts its blocks.  A condensation without
    ``K_stuck`` has none either."""
    K = np.array([[2, -1, 0, 0], [-1, 2, -0.5, 0], [0, -0.5, 1, -0.3], [0, 0, -0.3, 1]])
    C = (0.01 * np.diag([1.0, 1.0, 2.0, 1.0]) + 0.02 * K).tolist()
    model = build_model(four_dof("jenkins", "anchor", "coupled", C=C))
    system = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="krylov")
    fl = _check_inverses(system, [0.0, 0.7, 1.1, 2.2, 3.3], 0.05, 1e-11)
    assert fl.damped.size == 4
    monkeypatch.setattr(fx, "FLEX_DAMPED_MAX", 3)
    system = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="krylov")
    assert system.lin.flexibility is None
    z = np.random.default_rng(5).normal(size=system.n_z) * 0.4
    J = system.evaluate(z, 1.1, system.force_coefficients(0.3)).J
    assert not HarmonicPreconditioner(J).modal
    from jointsim.solvers.condensation import ReducedLinear
    assert ReducedLinear(model.M, model.K, model.C, system.T).flexibility is None


def test_the_models_stuck_modes_serve_the_flexibility(coarse_model):
    """The coarse lap joint's modal damping decomposed its stuck structure
    (``model.stuck_modes``): the condensation checks them (:func:`~jointsim.solvers.
    flexibility.modes_of`) and its flexibility takes them instead of a decomposition of
    its own.  Both give the same stuck frequencies (1e-9), the same damped modes and
    the same inverses (to the stuck modes' accuracy, 1e-6 as against the blocks).  Modes
    of another stiffness, unnormalised ones and ones of another size are refused: a
    model given them drops them, and a condensation decomposes the structure itself."""
    import dataclasses

    from jointsim.solvers.condensation import ReducedLinear
    m = coarse_model
    assert m.stuck_modes is not None
    system = HBMSystem(m, (0, 1, 2, 3), 64, linear_solver="krylov")
    assert system.lin.stuck_modes is not None
    own = HBMSystem(dataclasses.replace(m, stuck_modes=None), (0, 1, 2, 3), 64,
                    linear_solver="krylov")
    assert own.lin.stuck_modes is None
    given, made = system.lin.flexibility, own.lin.flexibility
    assert np.abs(given.lam - made.lam).max() <= 1e-9 * np.abs(made.lam).max()
    assert np.array_equal(given.damped, made.damped)
    nus = [0.0, 900.0, 2700.0]
    A, B = given.inverses(nus, 0.3), made.inverses(nus, 0.3)
    assert np.abs(A - B).max() <= 1e-6 * np.abs(B).max()
    lam, phi = m.stuck_modes
    K_stuck = m.linearisation.K
    assert fx.modes_of((lam, phi), K_stuck, m.M)
    assert not fx.modes_of((lam, phi), m.K, m.M)                  # without the joint
    assert not fx.modes_of((lam, 2.0 * phi), K_stuck, m.M)
    assert not fx.modes_of((lam[:-1], phi[:, :-1]), K_stuck, m.M)
    assert dataclasses.replace(m, stuck_modes=(lam, 2.0 * phi)).stuck_modes is None
    wrong = ReducedLinear(m.M, m.K, m.C, system.T, K_stuck=K_stuck,
                          positions=system.lin.positions, stuck_modes=(lam, 2.0 * phi))
    assert wrong.stuck_modes is None
    assert np.abs(wrong.flexibility.lam - made.lam).max() <= 1e-9 * np.abs(made.lam).max()


def test_flexibility_of_the_coarse_lap_joint(coarse_model):
    """On the coarse lap joint (modal damping of the stuck joint: a block of damped modes,
    the quasi-static series above the frequency) the flexibility equals the inverted
    blocks to the accuracy of the stuck modes (about eps lam_max / lam of the low ones:
    1e-6 here, 1e-5 at a stuck resonance), and ``k`` is the AFT's stuck tangent (0 on
    the open elements' gaps)."""
    system = HBMSystem(coarse_model, (0, 1, 2, 3), 64, linear_solver="krylov")
    fl = _check_inverses(system, [0.0, 900.0, 2700.0, 6300.0], 0.0, 1e-6)
    _check_inverses(system, [900.0, 2700.0], 0.8, 1e-6)
    assert fl.damped.size == 12                     # the scene's 12 damped stuck modes
    w1 = np.sqrt(np.sort(fl.lam)[3])                 # the first bending mode
    _check_inverses(system, [w1], 0.0, 1e-4)
    assert np.abs(fl.k - _stuck_tangent(system)).max() <= 1e-12 * np.abs(fl.k).max()


def test_series_is_made_again_for_higher_frequencies(coarse_model, monkeypatch):
    """A series made for one frequency serves below ``FLEX_MARGIN`` times it; a higher
    one makes it again (more modes summed exactly), and either equals the sum over all
    modes without a series."""
    system = HBMSystem(coarse_model, (0, 1, 2, 3), 64, linear_solver="krylov")
    fl = system.lin.flexibility
    Y1 = fl.inverses([1000.0])
    cap = fl._series[0]
    assert cap == pytest.approx(fx.FLEX_MARGIN * 1000.0)
    n1 = fl.n_summed
    Y2 = fl.inverses([1000.0, 20000.0])
    assert fl._series[0] == pytest.approx(fx.FLEX_MARGIN * 20000.0) and fl.n_summed > n1
    monkeypatch.setattr(fx, "FLEX_RATIO", 1e12)     # every mode summed
    exact = fx.StuckFlexibility(fl.lam, fl.Psi, fl.k, fl.damped, fl.Cd)
    Ye = exact.inverses([1000.0, 20000.0])
    assert not np.any(exact._series[3])             # no quasi-static modes left
    for Y, ref in ((Y1[0], Ye[0]), (Y2[0], Ye[0]), (Y2[1], Ye[1])):
        assert np.abs(Y - ref).max() <= 1e-10 * np.abs(ref).max()


def test_prepare_forks_makes_the_series_for_the_highest_harmonic_once(coarse_model,
                                                                     monkeypatch):
    """``HBMSystem.prepare_forks`` makes the series for ``h_max omega_max``: the solves
    of every harmonic up to it then make nothing again, and equal the sum over all
    modes without a series to 1e-10."""
    system = HBMSystem(coarse_model, (0, 1, 2, 3), 64, linear_solver="krylov")
    system.prepare_forks(1100.0)
    fl = system.lin.flexibility
    series = fl._series
    assert series[0] == pytest.approx(fx.FLEX_MARGIN * 3 * 1100.0)
    B = np.random.default_rng(1).standard_normal((3, fl.n_r)) + 0j
    nus = [900.0, 1800.0, 3300.0]
    Y = fl.solve(nus, B)
    assert fl._series is series                       # not made again
    monkeypatch.setattr(fx, "FLEX_RATIO", 1e12)     # every mode summed
    exact = fx.StuckFlexibility(fl.lam, fl.Psi, fl.k, fl.damped, fl.Cd)
    Ye = exact.solve(nus, B)
    assert not np.any(exact._series[3])             # no quasi-static modes left
    for i in range(3):
        assert np.abs(Y[i] - Ye[i]).max() <= 1e-10 * np.abs(Ye[i]).max()


def test_indicators_prepare_forks_makes_one_series_for_both_systems(coarse_model,
                                                                    monkeypatch):
    """``ErrorEstimator.prepare_forks`` makes the series (and, on a large interface, its
    HODLR) for the extended harmonics, up to ``2 h_max + 1``, before indicator workers
    fork; the point system's ``prepare_forks`` after it and the solves of both systems
    then make nothing again, and the point system's solves equal those of a flexibility
    with its own, lower series (to the HODLR's 1e-8; both to the sum over all modes)."""
    from jointsim.solvers.indicators import ErrorEstimator
    monkeypatch.setattr(fx, "FLEX_HODLR_MIN_ROWS", 0)
    monkeypatch.setattr(fx, "FLEX_HODLR_LEAF", 8)
    system = HBMSystem(coarse_model, (0, 1, 2, 3), 64, linear_solver="krylov")
    estimator = ErrorEstimator(system, parallel=False)
    for s in (estimator, system):
        s.prepare_forks(1100.0)
    fl = system.lin.flexibility
    series, hodlr = fl._series, fl._series_hodlr()
    assert max(estimator.harmonics) == 7 and hodlr is not None
    assert series[0] == pytest.approx(fx.FLEX_MARGIN * 7 * 1100.0)
    B = np.random.default_rng(2).standard_normal((3, fl.n_r)) + 0j
    Y = fl.solve([1100.0, 2200.0, 3300.0], B)
    fl.solve([4400.0, 6600.0, 7700.0], B)
    assert fl._series is series and fl._series_hodlr()[1] is hodlr[1]     # not made again
    own = fx.StuckFlexibility(fl.lam, fl.Psi, fl.k, fl.damped, fl.Cd)
    own.prepare(3300.0)
    assert own._series[0] < series[0] and own._series_hodlr() is None
    Yo = own.solve([1100.0, 2200.0, 3300.0], B)
    assert np.abs(Y - Yo).max() <= 1e-8 * np.abs(Yo).max()


@pytest.mark.parametrize("law,normal", [("jenkins", "coupled"), ("iwan4", "coupled"),
                                        ("jenkins", "fixed")])
def test_modal_preconditioner_is_the_inverse_of_the_jacobian(law, normal, monkeypatch):
    """At a state with stick, slip and separation the preconditioner from the stuck
    flexibility (its low-rank stage correcting every element whose tangent is not the
    stuck one) is the inverse of ``J``: the dense solve, GMRES in one iteration.  Where
    its low-rank stage would be truncated the blocks are inverted instead.  With a shift
    (the EPMC's bordered solves) it is taken only from ``SHIFTED_FLEX_MIN_ROWS`` rows and
    near the stuck joint (few elements off the stuck tangent), the shifted harmonic's
    block from the flexibility too (:class:`~jointsim.solvers.flexibility.ShiftedBlock`):
    there it is the same preconditioner of ``J + C2 R2`` as the inverted blocks'."""
    model = build_model(four_dof(law, "anchor", normal))
    sd = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="direct")
    sk = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="krylov")
    F = sk.force_coefficients(0.3)
    z = np.random.default_rng(5).normal(size=sk.n_z) * 0.4
    J = sk.evaluate(z, 1.1, F).J
    P = HarmonicPreconditioner(J)
    assert P.modal and P.S is None and P.lowrank is not None and not P.truncated
    v = np.random.default_rng(6).normal(size=sk.n_z)
    xd = np.linalg.solve(sd.evaluate(z, 1.1, F).J, v)
    assert np.abs(P.solve(v) - xd).max() <= 1e-10 * np.abs(xd).max()
    x, it, _, _ = gmres(J.matvec, v, P.solve, rtol=1e-11)
    assert it == 1 and np.abs(x - xd).max() <= 1e-10 * np.abs(xd).max()
    # one vector through the blocks' upper triangles, two through the whole blocks
    both = P.solve(np.column_stack([v, 2.0 * v]))
    assert P.Ppacked is not None
    assert np.abs(both[:, 1] - 2.0 * xd).max() <= 2e-10 * np.abs(xd).max()
    u = np.linspace(1.0, 2.0, sk.n_r) * np.exp(0.3j)
    Jstuck = sk.evaluate(z * 1e-7, 1.1, F).J
    assert not HarmonicPreconditioner(Jstuck, shift=(1, u, u.conj())).modal   # small
    monkeypatch.setattr(pm, "SHIFTED_FLEX_MIN_ROWS", 0)
    assert not HarmonicPreconditioner(J, shift=(1, u, u.conj())).modal
    Ps = HarmonicPreconditioner(Jstuck, shift=(1, u, u.conj()))
    monkeypatch.setattr(pm, "MODAL_STAGE", False)
    # the inverted blocks shifted with the same scale (the flexibility's is not P's)
    shift = pm.HarmonicPreconditioner._shift
    monkeypatch.setattr(pm.HarmonicPreconditioner, "_shift", lambda self, scale, i, u, ell:
                        shift(self, Ps.shift_scale, i, u, ell))
    Pd = HarmonicPreconditioner(Jstuck, shift=(1, u, u.conj()))
    monkeypatch.setattr(pm, "MODAL_STAGE", True)
    assert Ps.modal and not Pd.modal and Ps.lowrank is None
    assert np.allclose(Ps.C2, Pd.C2, rtol=1e-12, atol=0.0)
    xs, xd = Ps.solve(v), Pd.solve(v)
    assert np.abs(xs - xd).max() <= 1e-10 * np.abs(xd).max()
    monkeypatch.setattr(pm, "LOWRANK_MIN", 0)
    monkeypatch.setattr(pm, "LOWRANK_MAX", sk.n_c)        # one row block: truncated
    Pt = HarmonicPreconditioner(J)
    assert Pt.truncated and not Pt.modal and Pt.S is not None


def test_a_loose_solves_stage_is_the_flexibility_applied_by_solves(monkeypatch):
    """A loose solve (the error indicators' GMRES tolerance) whose low-rank stage keeps at
    most ``SOLVED_STAGE_COLUMNS n_r`` row blocks takes the flexibility applied by solves
    (:class:`~jointsim.solvers.flexibility.FlexibilitySolve`, no inverse formed).  At a
    stuck state (no low-rank stage) the preconditioner is the inverse of ``J`` (the dense
    solve, 1e-10); with a low-rank stage, to the single precision of its LU (a loose
    solve's, ``SINGLE_LU_RTOL``).  A state with more row blocks forms the inverses instead.  The choice is made from each
    Jacobian alone: a state gets the same stage before and after another one."""
    model = build_model(four_dof("jenkins", "anchor", "coupled"))
    sd = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="direct")
    sk = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="krylov")
    sk.krylov_rtol = pm.SOLVED_STAGE_RTOL
    monkeypatch.setattr(pm, "FLEX_SOLVE_MIN_ROWS", 0)
    monkeypatch.setattr(pm, "SOLVED_STAGE_COLUMNS", 0.5)       # 2 of the 4 row blocks
    F = sk.force_coefficients(0.3)
    rng = np.random.default_rng(5)
    z_stuck, z_slip = 1e-4 * rng.normal(size=sk.n_z), 0.4 * rng.normal(size=sk.n_z)
    v = rng.normal(size=sk.n_z)
    kinds = []
    for z in (z_stuck, z_slip, z_stuck):
        J = sk.evaluate(z, 1.1, F).J
        P = HarmonicPreconditioner(J)
        kinds.append(isinstance(P.Psolve, fx.FlexibilitySolve))
        assert P.modal and P.S is None and (P.Pinv is None) == kinds[-1]
        if kinds[-1]:
            xd = np.linalg.solve(sd.evaluate(z, 1.1, F).J, v)
            assert np.abs(P.solve(v) - xd).max() <= 1e-10 * np.abs(xd).max()
            assert P.Psolve.apply_flops > 0.0 and P.build_flops < 1e3
    assert kinds == [True, False, True]
    # enough columns allowed: solves at the slipping state too, its low-rank stage's LU
    # in single precision (a loose solve, SINGLE_LU_RTOL)
    monkeypatch.setattr(pm, "SOLVED_STAGE_COLUMNS", 1.0)
    P = HarmonicPreconditioner(sk.evaluate(z_slip, 1.1, F).J)
    assert isinstance(P.Psolve, fx.FlexibilitySolve) and P.lowrank is not None
    xd = np.linalg.solve(sd.evaluate(z_slip, 1.1, F).J, v)
    assert np.abs(P.solve(v) - xd).max() <= 1e-5 * np.abs(xd).max()


def test_no_flexibility_where_its_modes_cost_more_than_they_save(coarse_model, monkeypatch):
    """Above ``FLEX_SMALL_DOF`` DOFs a structure with more than ``FLEX_DOF_RATIO`` DOFs per
    contact coordinate gets no flexibility (its eigen-decomposition, ``9 n^3``, would cost
    more than the harmonic inverses it saves): the coarse lap joint (108 DOFs, 34
    coordinates) has one, but not with both limits lowered below it."""
    def flexibility():
        return HBMSystem(coarse_model, (0, 1), 16, linear_solver="krylov").lin.flexibility
    assert flexibility() is not None
    monkeypatch.setattr(fx, "FLEX_SMALL_DOF", 100)
    assert flexibility() is not None                # 108 / 34 = 3.2 <= 6
    monkeypatch.setattr(fx, "FLEX_DOF_RATIO", 3.0)
    assert flexibility() is None


def test_solve_is_the_inverses_applied(coarse_model):
    """``StuckFlexibility.solve`` (no inverse formed) equals ``inverses(nus) @ b`` for one
    and for several right-hand sides, with and without self-excitation; the inverses at
    the frequencies of the last call are kept (the same read-only array), a zero
    frequency's block is real."""
    system = HBMSystem(coarse_model, (0, 1, 2, 3), 64, linear_solver="krylov")
    fl = system.lin.flexibility
    rng = np.random.default_rng(3)
    nus = np.array([0.0, 900.0, 2700.0, 6300.0])
    for xi in (0.0, 0.8):
        Y = fl.inverses(nus, xi)
        assert not Y.flags.writeable and fl.inverses(nus, xi) is Y
        assert not np.any(Y[0].imag)
        B = rng.normal(size=(4, fl.n_r, 3)) + 1j * rng.normal(size=(4, fl.n_r, 3))
        ref = Y @ B
        X = fl.solve(nus, B, xi)
        assert np.abs(X - ref).max() <= 1e-10 * np.abs(ref).max()
        X1 = fl.solve(nus, B[:, :, 0], xi)
        assert X1.shape == (4, fl.n_r)
        assert np.abs(X1 - ref[:, :, 0]).max() <= 1e-10 * np.abs(ref[:, :, 0]).max()
    assert fl.inverses(nus[:2]) is not fl.inverses(nus)
    # in single precision: the same operator to about its round-off, kept beside the
    # double one (a build in both precisions at one frequency forms each once)
    for xi in (0.0, 0.8):
        Y, Ys = fl.inverses(nus, xi), fl.inverses(nus, xi, single=True)
        assert Ys.dtype == np.complex64 and not Ys.flags.writeable
        assert fl.inverses(nus, xi, single=True) is Ys and fl.inverses(nus, xi) is Y
        assert not np.any(Ys[0].imag)
        B = rng.normal(size=(4, fl.n_r, 3)) + 1j * rng.normal(size=(4, fl.n_r, 3))
        for h in range(4):
            ref = Y[h] @ B[h]
            assert np.abs(Ys[h] @ B[h] - ref).max() <= 1e-5 * np.abs(ref).max()


def test_stuck_solve_by_the_flexibility_is_the_lu_solve(coarse_model, monkeypatch):
    """``HBMJacobian.solve_uncoupled`` with the flexibility (refined against ``J``) equals
    the LU solve of the blocks, off and at a stuck resonance, and forms no ``S_h``; with
    a flexibility that is not the Jacobian's (its eigenvalues 5 % high) and no refinement
    it falls back to the LU solve."""
    import jointsim.solvers.jacobian as jm
    system = HBMSystem(coarse_model, (0, 1, 2, 3), 64, linear_solver="krylov")
    fl = system.lin.flexibility
    z0, F = system.static_coordinates(), system.force_coefficients(2.0)
    w1 = np.sqrt(np.sort(fl.lam)[3])                 # the first bending mode
    for w in (900.0, w1):
        ev = system.evaluate(z0, w, F, wrt=())
        b, J = -ev.R, ev.J
        x = J.solve_uncoupled(b, flexibility=fl)
        assert all(S is None for S in J._S)          # (S_h are shared per frequency)
        x_lu = J.solve_uncoupled(b)
        assert all(S is not None for S in J._S[:2])
        assert np.abs(x - x_lu).max() <= 1e-7 * np.abs(x_lu).max()
        assert np.abs(J.matvec(x) - b).max() <= 1e-8 * np.abs(b).max()
    monkeypatch.setattr(jm, "UNCOUPLED_REFINE", 0)
    wrong = fx.StuckFlexibility(1.05 * fl.lam, fl.Psi, fl.k, fl.damped, fl.Cd)
    ev = system.evaluate(z0, 1100.0, F, wrt=())
    b, J = -ev.R, ev.J
    x = J.solve_uncoupled(b, flexibility=wrong)
    assert any(S is not None for S in J._S)            # the LU path
    assert np.abs(J.matvec(x) - b).max() <= 1e-8 * np.abs(b).max()


def test_compressed_series_solves_and_gives_columns_like_the_inverses(coarse_model,
                                                                        monkeypatch):
    """``StuckFlexibility.compressed``: from ``FLEX_HODLR_MIN_ROWS`` coordinates (lowered
    to the coarse lap joint's 34, leaves of 8) the series' sums are kept as one HODLR.
    ``solve`` and ``columns`` then equal the formed inverses to 1e-8 (the truncation,
    1e-10 of each sum's norm); uncompressed, ``columns`` slices them to round-off.
    Below the limit, or without the coordinates' positions, nothing is compressed."""
    system = HBMSystem(coarse_model, (0, 1, 2, 3), 64, linear_solver="krylov")
    fl = system.lin.flexibility
    nus = np.array([0.0, 900.0, 2700.0, 6300.0])
    cols = np.array([0, 5, 33, 12])
    rng = np.random.default_rng(11)
    B = rng.normal(size=(4, fl.n_r, 2)) + 1j * rng.normal(size=(4, fl.n_r, 2))
    assert fl.compressed(nus.max()) is None                    # 34 < 800 coordinates
    for xi in (0.0, 0.8):
        Y = np.array(fl.inverses(nus, xi))
        got = fl.columns(nus, cols, xi)
        assert np.abs(got - Y[:, :, cols]).max() <= 1e-12 * np.abs(Y).max()
    monkeypatch.setattr(fx, "FLEX_HODLR_MIN_ROWS", 0)
    monkeypatch.setattr(fx, "FLEX_HODLR_LEAF", 8)
    fl.positions, kept = None, fl.positions
    assert fl.compressed(nus.max()) is None
    fl.positions = kept
    nu_max, _, H = fl.compressed(nus.max())
    assert fl.compressed(nus.max())[2] is H                   # made once
    for xi in (0.0, 0.8):
        Y = np.array(fl.inverses(nus, xi))
        ref = Y @ B
        X = fl.solve(nus, B, xi)
        assert np.abs(X - ref).max() <= 1e-8 * np.abs(ref).max()
        assert np.abs(X - ref).max() > 0.0                     # the HODLR, not the sums
        got = fl.columns(nus, cols, xi)
        assert np.abs(got - Y[:, :, cols]).max() <= 1e-8 * np.abs(Y).max()
        rows = np.array([30, 2, 2, 17, 0])                     # some rows, in any order
        assert np.abs(fl.columns(nus, cols, xi, rows) - got[:, rows]).max() \
            <= 1e-14 * np.abs(Y).max()
    # a series made for a higher frequency drops the old HODLR until asked again
    fl.prepare(4.0 * nu_max)
    assert fl._series_hodlr() is None and fl.compressed(4.0 * nu_max)[2] is not H


def test_a_tight_solves_stage_is_the_compressed_flexibility(coarse_model, monkeypatch):
    """With the series compressed (``FLEX_HODLR_MIN_ROWS`` lowered), a tight solve whose
    low-rank stage keeps few row blocks takes the flexibility applied by solves too: at a
    stuck state and at a slipping one (its low-rank stage's columns read from the HODLR)
    the preconditioner, exact but for the truncation, solves ``J`` like the dense solve
    (to 1e-8 stuck, 1e-4 slipping), and GMRES on it to 1e-8.  Without the compression the stage forms its
    inverses."""
    sd = HBMSystem(coarse_model, (0, 1, 2, 3), 64, linear_solver="direct")
    sk = HBMSystem(coarse_model, (0, 1, 2, 3), 64, linear_solver="krylov")
    monkeypatch.setattr(pm, "FLEX_SOLVE_MIN_ROWS", 0)
    monkeypatch.setattr(pm, "SOLVED_STAGE_COLUMNS", 1.0)
    F = sk.force_coefficients(20.0)
    z0 = sk.static_coordinates()
    rng = np.random.default_rng(12)
    v = rng.normal(size=sk.n_z)
    z_slip = z0 + 3e-6 * rng.normal(size=sk.n_z)
    P = HarmonicPreconditioner(sk.evaluate(z0, 950.0, F).J)
    assert P.Psolve is None and P.Pinv is not None             # not compressed: inverses
    monkeypatch.setattr(fx, "FLEX_HODLR_MIN_ROWS", 0)
    monkeypatch.setattr(fx, "FLEX_HODLR_LEAF", 8)
    for z in (z0, z_slip):
        J = sk.evaluate(z, 950.0, F).J
        P = HarmonicPreconditioner(J)
        assert isinstance(P.Psolve, fx.FlexibilitySolve) and P.Pinv is None
        assert sk.lin.flexibility._series_hodlr() is not None
        xd = np.linalg.solve(sd.evaluate(z, 950.0, F).J, v)
        # no stage truncated: P is J's inverse but for the HODLR's truncation (1e-10 of
        # the sums), which the slipping state's Woodbury correction, on the columns read
        # from the HODLR, amplifies (measured 1.8e-5; wrong columns would be O(1) off)
        assert not P.truncated
        rtol = 1e-8 if P.lowrank is None else 1e-4
        assert np.abs(P.solve(v) - xd).max() <= rtol * np.abs(xd).max()
        x = J.solve(v)
        assert np.abs(x - xd).max() <= 1e-8 * np.abs(xd).max()
    assert P.lowrank is not None                                # the slipping state's


def _shift_rows(jac, i, ell) -> np.ndarray:
    """``R2`` (2, n_z): ``Re`` and ``Im`` of ``ell^T (X_c - i X_s)`` over the ``i``-th
    harmonic, so that the shifted preconditioner's matrix is ``J + C2 R2``."""
    R2 = np.zeros((2, jac.n_c, jac.n_r), dtype=complex)
    R2[:, jac._ic[i]] = ell
    if not jac._h0[i]:
        R2[:, jac._is[i]] = -1j * ell
    R2[1] *= -1j                                # Im z = Re(-i z)
    return R2.real.reshape(2, -1)


def test_a_loose_solves_stage_is_the_compressed_flexibility_for_any_columns(coarse_model,
                                                                         monkeypatch):
    """With the series compressed, a loose solve (the error indicators') takes the
    flexibility applied by solves whatever its low-rank stage keeps, shifted too (the
    EPMC's bordered solves: its shifted harmonic's block from
    :class:`~jointsim.solvers.flexibility.ShiftedBlock`).  Where the
    stage keeps many row blocks only their rows ``R`` of its columns are read and the
    correction is a solve (``PinvR`` not formed).  The preconditioner then solves ``J``
    (``J + C2 R2`` with the shift) like the dense solve: exact but for the HODLR's
    truncation and the capacitance LU in single precision (1e-4, measured 6e-6 and
    1.7e-5), as the formed inverses' stage does.  (Harmonics 1..3: with harmonic 0 the
    slipping joint's static block makes ``J`` ill-conditioned, 1e9, and both stages'
    single-precision LU leave 20 % there.)"""
    sd = HBMSystem(coarse_model, (1, 2, 3), 64, linear_solver="direct")
    sk = HBMSystem(coarse_model, (1, 2, 3), 64, linear_solver="krylov")
    sk.krylov_rtol = 1e-3                                      # a loose solve
    monkeypatch.setattr(pm, "FLEX_SOLVE_MIN_ROWS", 0)
    F = sk.force_coefficients(20.0)
    rng = np.random.default_rng(13)
    z = sk.static_coordinates() + 3e-6 * rng.normal(size=sk.n_z)
    v = rng.normal(size=sk.n_z)
    u = rng.normal(size=sk.n_r) + 1j * rng.normal(size=sk.n_r)
    J, Jd = sk.evaluate(z, 950.0, F).J, sd.evaluate(z, 950.0, F).J
    formed = [HarmonicPreconditioner(J, shift) for shift in (None, (0, u, u.conj()))]
    assert all(P.Psolve is None and P.PinvR is not None for P in formed)
    monkeypatch.setattr(fx, "FLEX_HODLR_MIN_ROWS", 0)
    monkeypatch.setattr(fx, "FLEX_HODLR_LEAF", 8)
    for shift, P0 in zip((None, (0, u, u.conj())), formed):
        P = HarmonicPreconditioner(J, shift)
        assert isinstance(P.Psolve, fx.FlexibilitySolve) and P.Pinv is None
        assert (P.Psolve.shifted is None) == (shift is None)
        assert P.lowrank.Rrow.size > pm.SOLVED_STAGE_COLUMNS * sk.n_r and P.PinvR is None
        A = Jd if shift is None else Jd + P.C2 @ _shift_rows(J, 0, u.conj())
        xd = np.linalg.solve(A, v)
        for Q in (P, P0):
            assert np.abs(Q.solve(v) - xd).max() <= 1e-4 * np.abs(xd).max()


@pytest.mark.parametrize("case", ["lumped", "undamped", "lap"])
def test_shifted_block_is_the_inverse_where_the_stuck_block_is_singular(case, request):
    """At a stuck resonance of the self-excited mode (``nu = omega_j`` and ``xi = c_j``:
    the EPMC's linear range) ``S_h + diag(k)`` is singular; with the shift ``u ell'`` it
    is not, and :class:`~jointsim.solvers.flexibility.ShiftedBlock` is its inverse (the
    oracle: the condensation's block plus the shift, inverted by LU) to the flexibility's
    accuracy: its columns, on some rows, and its solves.  The resonant mode is a damped
    one (mass-proportional damping: every mode damped; the lap joint: 12 of them) or an
    undamped low one (no damping)."""
    if case == "lap":
        model, rtol = request.getfixturevalue("coarse_model"), 1e-5
    else:
        C = np.zeros((4, 4)).tolist() if case == "undamped" else None
        model, rtol = build_model(four_dof("jenkins", "anchor", "coupled", C=C)), 1e-10
    system = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="krylov")
    fl = system.lin.flexibility
    j = int(np.argsort(fl.lam)[3 if case == "lap" else 0])   # lap: the first bending mode
    nu = float(np.sqrt(fl.lam[j]))
    xi = 0.0 if j not in fl.damped else float(fl.Cd[np.flatnonzero(fl.damped == j)[0]] @ (
        fl.damped == j))
    A = _blocks(system.lin, fl.k, [nu], xi)[0]
    assert np.linalg.cond(A) > (1e3 if case == "lap" else 1e10)     # (nearly) singular
    rng = np.random.default_rng(3)
    u, ell = (rng.standard_normal((2, fl.n_r)) + 1j * rng.standard_normal((2, fl.n_r)))
    u *= np.abs(np.diag(A)).max() / (np.linalg.norm(u) * np.linalg.norm(ell))
    ref = np.linalg.inv(A + np.outer(u, ell))
    block = fx.ShiftedBlock(fl, nu, xi, u, ell)
    assert np.abs(block.columns(np.arange(fl.n_r)) - ref).max() <= rtol * np.abs(ref).max()
    cols, rows = np.array([fl.n_r - 1, 0]), np.array([1, fl.n_r - 1])
    assert np.abs(block.columns(cols, rows) - ref[np.ix_(rows, cols)]).max() \
        <= rtol * np.abs(ref).max()
    Y = rng.standard_normal((fl.n_r, 3)) + 0j
    assert np.abs(block.solve(Y) - ref @ Y).max() <= rtol * np.abs(ref @ Y).max()
    # as the shifted harmonic of a stage applied by solves (its regular part solved with
    # the other harmonics')
    nus = np.array([0.5 * nu, nu, 2.0 * nu])
    stage = fx.FlexibilitySolve(fl, nus, xi, (1, block))
    Y3 = rng.standard_normal((3, fl.n_r, 2)) + 0j
    out, plain = stage.solve(Y3), fl.solve(nus, Y3, xi)
    assert np.abs(out[1] - ref @ Y3[1]).max() <= rtol * np.abs(ref @ Y3[1]).max()
    assert np.array_equal(out[[0, 2]], plain[[0, 2]])
    C, Cp = stage.columns(cols, rows), fl.columns(nus, cols, xi, rows)
    assert np.abs(C[1] - ref[np.ix_(rows, cols)]).max() <= rtol * np.abs(ref).max()
    assert np.array_equal(C[[0, 2]], Cp[[0, 2]])
