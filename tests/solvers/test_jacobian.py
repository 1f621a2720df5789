"""Structured HBM Jacobian and its Krylov path (issue 10): against the dense reference."""

import h5py
import numpy as np
import pytest

from jointsim.analyses.hbm import _BranchJob, _run_branch, _system
from jointsim.model import build_model
from jointsim.run import run_scene
from jointsim.scene import load_scene
from jointsim.solvers.hbm import HBMSystem, solve_point
from jointsim.solvers.gmres import KRYLOV_RTOL
from jointsim.solvers.jacobian import BorderedJacobian, gmres, gmres_columns
from jointsim.solvers.lowrank_stage import capacitance_blocks, capacitance_element_blocks
from jointsim.solvers.preconditioner import HarmonicPreconditioner

from .._scenes import ROOT, four_dof, lap_scene

MODELS = ROOT / "models" / "hbm"


def _pair(model, harmonics=(0, 1, 2, 3), n_samples=64):
    return (HBMSystem(model, harmonics, n_samples, linear_solver="direct"),
            HBMSystem(model, harmonics, n_samples, linear_solver="krylov"))


@pytest.mark.parametrize("law,normal", [("jenkins", "coupled"), ("iwan4", "coupled"),
                                        ("jenkins", "fixed")])
def test_structured_products_equal_the_dense_jacobian(law, normal):
    """The residual and its derivatives (all harmonics at once on the Krylov path with a
    modal condensation), J v, J^T v, to_dense, max_abs and the (bordered) GMRES solves
    of the structured Jacobian against the direct path's, at a state with stick, slip
    and separation."""
    sd, sk = _pair(build_model(four_dof(law, "anchor", normal)))
    F = sd.force_coefficients(0.3)
    rng = np.random.default_rng(1)
    z = rng.normal(size=sd.n_z) * 0.4
    ed = sd.evaluate(z, 1.1, F, xi=0.05, wrt=("omega", "xi"))
    ek = sk.evaluate(z, 1.1, F, xi=0.05, wrt=("omega", "xi"))
    assert np.abs(ed.R - ek.R).max() <= 1e-14 * np.abs(ed.R).max()
    for p in ("omega", "xi"):
        assert np.abs(ed.dR[p] - ek.dR[p]).max() <= 1e-13 * np.abs(ed.dR[p]).max()
    Jd, Jk = ed.J, ek.J
    assert not isinstance(Jk, np.ndarray)
    v = rng.normal(size=sd.n_z)
    ref = np.abs(Jd).max() * np.abs(v).sum()
    assert np.abs(Jk.matvec(v) - Jd @ v).max() <= 1e-13 * ref
    assert np.abs(Jk.rmatvec(v) - Jd.T @ v).max() <= 1e-13 * ref
    assert np.abs(Jk.to_dense() - Jd).max() <= 1e-14 * np.abs(Jd).max()
    assert Jk.max_abs() == pytest.approx(np.abs(Jd).max(), rel=1e-14)
    x = Jk.solve(v)
    assert np.abs(Jd @ x - v).max() <= 1e-9 * np.abs(v).max()
    # bordered: [J, c; t^T, 0] with a scaling of the columns, as in the continuation
    c = ed.dR["omega"]
    t = rng.normal(size=sd.n_z + 1)
    col = rng.uniform(0.5, 2.0, sd.n_z + 1)
    Bk = BorderedJacobian(Jk, c).with_row(t).scaled(col)
    Bd = np.vstack([np.column_stack([Jd, c]), t[None, :]]) * col[None, :]
    assert np.abs(Bk.to_dense() - Bd).max() <= 1e-14 * np.abs(Bd).max()
    b = rng.normal(size=sd.n_z + 1)
    xb = Bk.solve(b)
    xd = np.linalg.solve(Bd, b)
    assert np.abs(xb - xd).max() <= 1e-7 * np.abs(xd).max()


@pytest.mark.parametrize("normal", ["coupled", "fixed"])
def test_max_abs_reads_the_entries_the_tangents_reach(normal):
    """``max_abs`` against the formed Jacobian where its largest entries are ones the
    element tangents reach: each tangent made to cancel ``S_h`` where it adds (the
    largest of ``S_h`` is then not an entry of ``J``), and made the largest entry."""
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", normal)))
    F = sd.force_coefficients(0.3)
    z = np.random.default_rng(2).normal(size=sd.n_z) * 0.4
    Jk = sk.evaluate(z, 1.1, F, xi=0.05, wrt=()).J
    S0 = Jk.schur(0).real
    t, n = Jk.t_row, Jk.n_row
    # cancel: the tangent of every kind is minus S_0 where it adds, at every coefficient
    # pair of harmonic 0, so those entries of J vanish
    i0 = Jk._ic[0]
    for J, r, c, sign in ((Jk.Juu, t, t, 1.0), (Jk.Jug, t, n, 1.0), (Jk.JNN, n, n, -1.0)):
        if J is not None:
            J[:, i0, i0] = -sign * S0[r, c]
    dense = Jk.to_dense()
    assert Jk.max_abs() == np.abs(dense).max()
    o = i0 * Jk.n_r
    assert not np.any(dense[o + t, o + t])
    assert Jk.JNN is None or not np.any(dense[o + n, o + n])
    # the largest: one tangent entry between two harmonics' coefficients
    assert Jk.basis.hk[0] != Jk.basis.hk[1]
    Jk.Juu[0, 0, 1] = 1e3 * np.abs(dense).max()
    assert Jk.max_abs() == np.abs(Jk.to_dense()).max() == Jk.Juu[0, 0, 1]


@pytest.mark.parametrize("normal,damping,kind", [("fixed", "diagonal", "modal"),
                                                 ("fixed", "full", "direct"),
                                                 ("coupled", "diagonal", "direct")])
def test_stacked_linear_part_equals_the_per_harmonic_one(normal, damping, kind):
    """A small structure's linear part of every harmonic at once (the blocks stacked)
    against the per-harmonic blocks: the residual, the dense Jacobian and the
    derivatives by omega and xi.  Diagonal ``E`` (modal condensation), full ``E`` (a
    damping that couples the modes) and no ``E`` (the coupled joint: every DOF a
    contact coordinate)."""
    C = ([[0.03, 0.01, 0, 0], [0.01, 0.02, 0.005, 0], [0, 0.005, 0.02, 0], [0, 0, 0, 0.01]]
         if damping == "full" else None)
    s = HBMSystem(build_model(four_dof("jenkins", "anchor", normal, C=C)), (0, 1, 2, 3, 5), 64,
                  linear_solver="direct")
    assert s.stacked and s.lin.kind == kind
    assert s.lin.n_y == (0 if normal == "coupled" else 2)
    F = s.force_coefficients(0.3)
    z = np.random.default_rng(4).normal(size=s.n_z) * 0.4
    got = s.evaluate(z, 1.1, F, xi=0.05, wrt=("omega", "xi"))
    s.stacked = False
    s.omega_cache.clear()
    ref = s.evaluate(z, 1.1, F, xi=0.05, wrt=("omega", "xi"))
    assert np.abs(got.R - ref.R).max() <= 1e-14 * np.abs(ref.R).max()
    assert np.abs(got.J - ref.J).max() <= 1e-14 * np.abs(ref.J).max()
    for p in ("omega", "xi"):
        assert np.abs(got.dR[p] - ref.dR[p]).max() <= 1e-14 * np.abs(ref.dR[p]).max()
    assert np.abs(ref.dR["xi"]).max() > 0


def test_preconditioner_is_exact_for_linear_contact():
    """With a constant contact tangent (stuck law, fixed normal load) the harmonic
    preconditioner is the inverse of J: GMRES converges in one iteration."""
    _sd, sk = _pair(build_model(four_dof("stuck", "anchor", "fixed")))
    F = sk.force_coefficients(0.3)
    z = np.random.default_rng(2).normal(size=sk.n_z)
    J = sk.evaluate(z, 1.3, F).J
    P = HarmonicPreconditioner(J)
    v = np.random.default_rng(3).normal(size=sk.n_z)
    assert np.abs(J.matvec(P.solve(v)) - v).max() <= 1e-12 * np.abs(v).max()
    x, it, rel, _ = gmres(J.matvec, v, P.solve, rtol=1e-12)
    assert it == 1 and rel <= 1e-12


@pytest.mark.parametrize("law,normal", [("jenkins", "coupled"), ("iwan4", "coupled"),
                                        ("jenkins", "fixed")])
def test_lowrank_preconditioner_is_exact_at_stick_slip_and_separation(law, normal,
                                                                       monkeypatch):
    """With the low-rank (Woodbury) stage over the elements whose tangent couples
    harmonics, the preconditioner is the inverse of J at a state with stick, slip and
    separation (against the dense solve: GMRES in one iteration); capped to fewer
    elements it is not exact and GMRES still reaches the dense solution."""
    import jointsim.solvers.preconditioner as jm
    sd, sk = _pair(build_model(four_dof(law, "anchor", normal)))
    F = sd.force_coefficients(0.3)
    rng = np.random.default_rng(5)
    z = rng.normal(size=sd.n_z) * 0.4
    Jd = sd.evaluate(z, 1.1, F).J
    Jk = sk.evaluate(z, 1.1, F).J
    v = rng.normal(size=sd.n_z)
    xd = np.linalg.solve(Jd, v)
    P = HarmonicPreconditioner(Jk)
    assert P.lowrank is not None and not P.truncated
    assert np.abs(P.solve(v) - xd).max() <= 1e-10 * np.abs(xd).max()
    x, it, rel, _ = gmres(Jk.matvec, v, P.solve, rtol=1e-12)
    assert it == 1 and np.abs(x - xd).max() <= 1e-10 * np.abs(xd).max()
    nb = 2 if normal == "coupled" else 1
    monkeypatch.setattr(jm, "LOWRANK_MAX", nb * sk.n_c)          # nb row blocks only
    Pt = HarmonicPreconditioner(Jk)
    assert Pt.truncated and Pt.lowrank.Rrow.size == nb
    x, it, rel, _ = gmres(Jk.matvec, v, lambda u: Pt.apply(u, Jk), rtol=1e-12)
    assert it > 1 and np.abs(x - xd).max() <= 1e-9 * np.abs(xd).max()


@pytest.mark.parametrize("normal", ["coupled", "fixed"])
def test_a_stuck_joint_has_no_lowrank_stage(normal):
    """Every element stuck (and closed) over the period: the tangent does not couple
    harmonics, so what is left of it after the harmonic projection is the AFT's
    round-off, far below LOWRANK_NEGLIGIBLE of the largest tangent entry, and no
    low-rank stage is built (it once was: the threshold was taken relative to that
    round-off itself); the harmonic stage alone is then exact (the dense solve)."""
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", normal)))
    F = sd.force_coefficients(1e-6)
    rng = np.random.default_rng(9)
    z = rng.normal(size=sd.n_z) * 1e-9
    Jk = sk.evaluate(z, 1.1, F).J
    P = HarmonicPreconditioner(Jk)
    assert P.lowrank is None and not P.truncated
    v = rng.normal(size=sd.n_z)
    xd = np.linalg.solve(sd.evaluate(z, 1.1, F).J, v)
    assert np.abs(P.solve(v) - xd).max() <= 1e-10 * np.abs(xd).max()


def test_the_cache_raises_the_lowrank_limit_after_failed_truncations(monkeypatch):
    """Two fresh truncated preconditioners whose GMRES needed more than
    RAISE_ITERATIONS iterations raise the cache's low-rank limit (a partial one counts:
    its low-rank stage is truncated as a full one's); the next build is then exact:
    GMRES in one iteration, to the dense solution."""
    import jointsim.solvers.preconditioner as pm
    import jointsim.solvers.preconditioner_cache as pc
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", "coupled")))
    F = sd.force_coefficients(0.3)
    rng = np.random.default_rng(5)
    z = rng.normal(size=sd.n_z) * 0.4
    J = sk.evaluate(z, 1.1, F).J
    v = rng.normal(size=sd.n_z)
    xd = np.linalg.solve(sd.evaluate(z, 1.1, F).J, v)
    monkeypatch.setattr(pm, "LOWRANK_MAX", 2 * sk.n_c)             # two row blocks
    monkeypatch.setattr(pc, "LOWRANK_MAX_RAISED", sk.n_z)
    cache = sk.preconditioner
    P = cache.refresh(J, full=True)
    assert P.truncated and cache.lowrank_max == 2 * sk.n_c
    _, it, _, _ = gmres(J.matvec, v, lambda u: P.apply(u, J), rtol=1e-12)
    assert it > 1
    monkeypatch.setattr(pc, "RAISE_ITERATIONS", it - 1)
    cache.after_solve(it, fresh=True)
    cache.after_solve(it - 1, fresh=True)                    # not more than the limit
    cache.after_solve(it, fresh=False)                       # a reused one
    assert cache.failed_truncations == 1 and cache.lowrank_max == 2 * sk.n_c
    P = cache.refresh(J)                                     # a partial one
    assert P.partial and P.truncated
    cache.after_solve(it, fresh=True)
    assert cache.failed_truncations == 2 and cache.lowrank_max == sk.n_z
    P = cache.refresh(J, full=True)
    assert not P.truncated
    x, it, rel, _ = gmres(J.matvec, v, lambda u: P.apply(u, J), rtol=1e-12)
    assert it == 1 and np.abs(x - xd).max() <= 1e-10 * np.abs(xd).max()


@pytest.mark.parametrize("law,normal", [("jenkins", "coupled"), ("iwan4", "coupled"),
                                        ("jenkins", "fixed")])
def test_a_shared_harmonic_stage_is_exact_at_its_frequency(law, normal, monkeypatch):
    """A preconditioner built for another tangent at the frequency of the last full
    build keeps that build's harmonic stage (the same inverses) and builds only its
    low-rank stage, which corrects for the whole change of the tangent: it is the
    inverse of J (the dense solve).  At a frequency 2e-4 away (within
    SHARE_HARMONIC_STAGE) it is not exact and GMRES still reaches the dense solution;
    farther away, for a loose solve, or with the sharing off, the build is full."""
    import jointsim.solvers.preconditioner as pm
    import jointsim.solvers.preconditioner_cache as pc
    monkeypatch.setattr(pm, "MODAL_STAGE", False)     # a stage of inverted blocks
    sd, sk = _pair(build_model(four_dof(law, "anchor", normal)))
    F = sd.force_coefficients(0.3)
    rng = np.random.default_rng(7)
    z1, z2 = (rng.normal(size=sd.n_z) * 0.4 for _ in range(2))
    v = rng.normal(size=sd.n_z)
    cache = sk.preconditioner
    P1 = cache.refresh(sk.evaluate(z1, 1.1, F).J)
    assert not P1.partial
    J2 = sk.evaluate(z2, 1.1, F).J
    P2 = cache.refresh(J2)
    assert P2.partial and P2.Pinv is P1.Pinv and P2.lowrank is not None
    xd = np.linalg.solve(sd.evaluate(z2, 1.1, F).J, v)
    assert np.abs(P2.solve(v) - xd).max() <= 1e-10 * np.abs(xd).max()
    w = 1.1 * (1.0 + 2e-4)
    J3 = sk.evaluate(z2, w, F).J
    P3 = cache.refresh(J3)
    assert P3.partial and P3.Pinv is P1.Pinv
    xd = np.linalg.solve(sd.evaluate(z2, w, F).J, v)
    assert np.abs(P3.solve(v) - xd).max() > 1e-8 * np.abs(xd).max()
    x, it, rel, _ = gmres(J3.matvec, v, P3.solve, rtol=1e-12)
    assert it > 1 and np.abs(x - xd).max() <= 1e-10 * np.abs(xd).max()
    J3.rtol = pm.SINGLE_LU_RTOL               # a loose solve (error indicators): full
    assert not cache.refresh(J3).partial
    assert not cache.refresh(sk.evaluate(z2, 1.1 * (1.0 + 2 * pc.SHARE_HARMONIC_STAGE),
                                         F).J).partial
    monkeypatch.setattr(pc, "SHARE_HARMONIC_STAGE", 0.0)
    assert not cache.refresh(J2).partial


@pytest.mark.parametrize("stage", ["inverted", "flexibility"])
def test_a_shifted_harmonic_stage_is_shared_with_its_shift(stage, monkeypatch):
    """The EPMC's bordered solves precondition ``J + C2 R2`` (a shift on the
    fundamental's block).  A build at a frequency within ``SHARE_HARMONIC_STAGE`` of the
    last full shifted one keeps that stage and its shift ``C2``, builds only its low-rank
    stage, and the bordered solve with it still equals the dense solve to 1e-8.  An
    unshifted build does not share a shifted stage.  So for a stage of inverted blocks
    and for one from the stuck flexibility with its shifted block inverted (a tight
    bordered solve built as a loose one, ``SHIFTED_SPLIT_MIN_ROWS``; its low-rank stage
    split and solved through its capacitance system), which an unshifted stage from the
    flexibility is not (it is cheap to make).  Four-DOF Jenkins chain, coupled N, a state
    with slip and separation, omega 1.1 and 1.1 (1 + 1e-3)."""
    import jointsim.solvers.jacobian as jm
    import jointsim.solvers.preconditioner as pm
    from jointsim.solvers.epmc import EPMCSystem
    from jointsim.solvers.modes import elastic_mode
    model = build_model(four_dof("jenkins", "anchor", "coupled"))
    sk = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="krylov")
    if stage == "inverted":
        monkeypatch.setattr(pm, "MODAL_STAGE", False)
    else:
        monkeypatch.setattr(pm, "SHIFTED_SPLIT_MIN_ROWS", sk.n_r)
        monkeypatch.setattr(pm, "LOOSE_SPLIT_MIN", 0)
        monkeypatch.setattr(pm, "LOOSE_SPLIT_SHARED_MIN", 0)
    ep = EPMCSystem(sk, elastic_mode(model, 1).phi, sk.force_coefficients(0.0))
    rng = np.random.default_rng(5)
    z = rng.normal(size=sk.n_z) * 0.4
    cache = sk.preconditioner
    b = rng.normal(size=sk.n_z + 2)
    stages = []
    for w in (1.1, 1.1 * (1.0 + 1e-3)):
        A = jm.drop_last_column(ep.fun(np.concatenate([z, [w, 0.01, 0.0]]))[1])
        cache.forget()                              # a build for each (the stage kept)
        x = A.solve(b)
        xd = np.linalg.solve(A.to_dense(), b)
        assert np.abs(x - xd).max() <= 1e-8 * np.abs(xd).max()
        stages.append(cache.current)
    full, partial = stages
    assert not full.partial and full.C2 is not None and cache.stage is full
    assert partial.partial and partial.Pinv is full.Pinv and partial.C2 is full.C2
    assert partial.omega == 1.1
    assert full.modal == full.loose == (stage == "flexibility")
    assert partial.capacitance_solves == (stage == "flexibility")
    J = sk.evaluate(z, 1.1, sk.force_coefficients(0.0)).J
    assert not cache.refresh(J).partial
    if stage == "flexibility":
        assert cache.stage.modal and cache.stage.C2 is None
        assert not cache.refresh(J).partial


def test_single_precision_harmonic_inverses_but_the_fundamental(monkeypatch):
    """From ``SINGLE_INVERSE_MIN`` rows (forced down to 1 here), where the cache allows it
    (``single_inverses``: an FRC branch's continuation), the harmonic stage's
    inverses are complex64, except the fundamental's (double, applied from
    ``Pinv_double``): applying the stage equals the double-precision one to
    single-precision round-off for the other harmonics (and not exactly) and to
    double round-off for the fundamental; GMRES with it still reaches the dense
    solution to 1e-10."""
    import jointsim.solvers.preconditioner as pm
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", "coupled")))
    F = sd.force_coefficients(0.3)
    rng = np.random.default_rng(11)
    z = rng.normal(size=sd.n_z) * 0.4
    J = sk.evaluate(z, 1.1, F).J
    P64 = HarmonicPreconditioner(J)
    assert P64.Pinv.dtype == complex and not P64.Pinv_double
    monkeypatch.setattr(pm, "SINGLE_INVERSE_MIN", 1)
    assert HarmonicPreconditioner(J).Pinv.dtype == complex     # not unless the cache allows
    sk.preconditioner.single_inverses = True
    P32 = HarmonicPreconditioner(J)
    h1 = list(sk.basis.harmonics).index(1)
    assert P32.Pinv.dtype == np.complex64 and list(P32.Pinv_double) == [h1]
    X = rng.normal(size=(len(sk.basis.harmonics), sk.n_r, 2)) \
        + 1j * rng.normal(size=(len(sk.basis.harmonics), sk.n_r, 2))
    Y64, Y32 = P64._inverse_times(X), P32._inverse_times(X)
    for i in range(len(sk.basis.harmonics)):
        err = np.abs(Y32[i] - Y64[i]).max() / np.abs(Y64[i]).max()
        assert (err <= 1e-13) if i == h1 else (1e-12 < err <= 1e-5)
    v = rng.normal(size=sd.n_z)
    xd = np.linalg.solve(sd.evaluate(z, 1.1, F).J, v)
    x, it, rel, _ = gmres(J.matvec, v, lambda u: P32.apply(u, J), rtol=1e-12)
    assert np.abs(x - xd).max() <= 1e-10 * np.abs(xd).max()


@pytest.mark.parametrize("normal", ["coupled", "fixed"])
def test_uncoupled_solve_of_the_stuck_joint_equals_the_dense_solve(normal):
    """At the static state (every element stuck over the period) the tangent couples no
    harmonics: the harmonic-by-harmonic solve of the forced harmonics equals the dense
    solve and forms only their S_h; at a state that slips it declines (None)."""
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", normal)))
    F = sd.force_coefficients(0.3)
    z0 = sk.static_coordinates()
    ek = sk.evaluate(z0, 1.1, F)
    b = -ek.R
    xd = np.linalg.solve(sd.evaluate(z0, 1.1, F).J, b)
    x = ek.J.solve_uncoupled(b)
    assert x is not None and np.abs(x - xd).max() <= 1e-12 * np.abs(xd).max()
    formed = [S is not None for S in ek.J._S]
    assert formed[list(sk.basis.harmonics).index(1)] and sum(formed) < len(formed)
    col = np.random.default_rng(3).uniform(0.5, 2.0, sk.n_z)       # a scaled J
    xs = ek.J.scaled(col).solve_uncoupled(b)
    assert np.abs(xs * col - xd).max() <= 1e-12 * np.abs(xd).max()
    z = np.random.default_rng(5).normal(size=sk.n_z) * 0.4
    assert sk.evaluate(z, 1.1, F).J.solve_uncoupled(b) is None


def test_a_partial_preconditioner_that_misses_its_budget_is_rebuilt_in_full(monkeypatch):
    """A Jacobian far from the shared harmonic stage's frequency (the sharing forced
    on): the reused preconditioner and then the partial one miss their budgets, a full
    one is built and the solve equals the dense one; it is the new shared stage."""
    import jointsim.solvers.preconditioner as pm
    import jointsim.solvers.preconditioner_cache as pc
    monkeypatch.setattr(pc, "SHARE_HARMONIC_STAGE", 1.0)
    monkeypatch.setattr(pm, "MODAL_STAGE", False)     # a stage of inverted blocks
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", "coupled")))
    F = sd.force_coefficients(0.3)
    rng = np.random.default_rng(8)
    z = rng.normal(size=sd.n_z) * 0.4
    v = rng.normal(size=sd.n_z)
    cache = sk.preconditioner
    cache.refresh_iterations = 1
    sk.evaluate(z, 1.1, F).J.solve(v)
    assert sk.stats.take()[2] == 1 and cache.stage_iterations == 1
    J = sk.evaluate(z, 1.6, F).J
    x = J.solve(v)
    xd = np.linalg.solve(sd.evaluate(z, 1.6, F).J, v)
    assert np.abs(x - xd).max() <= 1e-9 * np.abs(xd).max()
    assert sk.stats.take()[2] == 2            # the partial one, then the full one
    assert cache.current is cache.stage and not cache.stage.partial
    assert cache.stage.omega == 1.6


@pytest.mark.parametrize("normal", ["coupled", "fixed"])
def test_lowrank_product_by_harmonics_equals_the_dense_one(normal):
    """``L_r G`` formed by harmonics (``capacitance_blocks``) equals ``L_r`` times the
    dense ``G = E_c^T P^-1 E_r`` in real coefficients, built here from the harmonic
    inverses."""
    _, sk = _pair(build_model(four_dof("jenkins", "anchor", normal)))
    F = sk.force_coefficients(0.3)
    z = np.random.default_rng(5).normal(size=sk.n_z) * 0.4
    Jk = sk.evaluate(z, 1.1, F).J
    P = HarmonicPreconditioner(Jk)
    lr = P.lowrank
    nc, nb = Jk.n_c, lr.nb
    nrb, nl = lr.Rrow.size, lr.R.size // lr.nb
    # P^-1 in real coefficients: (coefficient, coordinate) x (coefficient, coordinate)
    Pr = np.zeros((nc, Jk.n_r, nc, Jk.n_r))
    for i, h in enumerate(Jk.basis.harmonics):
        ic, is_ = Jk._ic[i], Jk._is[i]
        Q = P.Pinv[i]
        Pr[ic, :, ic, :] = Q.real
        if h:
            Pr[ic, :, is_, :], Pr[is_, :, ic, :], Pr[is_, :, is_, :] = Q.imag, -Q.imag, Q.real
    # G: rows (column element l, kind b, coefficient k), columns (row block j, coefficient)
    G = Pr[:, lr.R][:, :, :, lr.Rrow]                     # (k, b nl + l, k', j)
    G = G.reshape(nc, nb, nl, nc, nrb).transpose(2, 1, 0, 4, 3).reshape(nl, nb * nc, -1)
    dense = np.concatenate([lr.Lr[j] @ G[lr.block_element[j]] for j in range(nrb)])
    fast = capacitance_blocks(P.jac, P.PinvR, lr.Lr.reshape(nrb, nc, nb, nc), lr.R,
                              lr.block_element, float)
    assert fast.shape == dense.shape == (nrb * nc, nrb * nc)
    assert np.abs(fast - dense).max() <= 1e-13 * np.abs(dense).max()
    # the element blocks of I + L_r G (a split stage's preconditioner of its capacitance
    # system): each the inverse of the dense one's rows and columns of an element's row
    # blocks, and together every coordinate once
    blocks = capacitance_element_blocks(P.jac, P.PinvR, lr.Lr.reshape(nrb, nc, nb, nc),
                                        lr.R, lr.block_element, float)
    C = np.eye(nrb * nc) + dense
    seen = []
    for coords, inv in blocks:
        for e, idx in enumerate(coords):
            assert np.unique(lr.block_element[idx // nc]).size == 1        # one element
            ref = np.linalg.inv(C[np.ix_(idx, idx)])
            assert np.abs(inv[e] - ref).max() <= 1e-12 * np.abs(ref).max()
            seen.extend(idx.tolist())
    assert sorted(seen) == list(range(nrb * nc))
    # an element with both row blocks (slip and gap rows) keeps both in one block
    assert normal == "fixed" or max(inv.shape[1] for _, inv in blocks) == nb * nc


@pytest.mark.parametrize("normal", ["coupled", "fixed"])
def test_loose_solves_keep_single_precision_factors_of_the_harmonic_stage(normal, monkeypatch):
    """For a Jacobian solved to a loose tolerance (the error indicators' extended
    systems) the harmonic stage of inverted blocks keeps single-precision LU factors
    instead of inverses (``FACTORED_LOOSE_STAGE``): its columns and its preconditioner
    equal the inverses' to single precision, and, exact on this state, it solves ``J x =
    b`` to the dense solution's 1e-5 with the same low-rank stage."""
    import jointsim.solvers.preconditioner as pm
    monkeypatch.setattr(pm, "MODAL_STAGE", False)
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", normal)))
    F = sd.force_coefficients(0.3)
    z = np.random.default_rng(5).normal(size=sd.n_z) * 0.4
    tight = HarmonicPreconditioner(sk.evaluate(z, 1.1, F).J)
    sk.krylov_rtol = 1e-3
    Jl = sk.evaluate(z, 1.1, F).J
    loose = HarmonicPreconditioner(Jl)
    assert tight.Plu is None and loose.Pinv is None and len(loose.Plu) == 4
    cols = np.array([0, sk.n_r - 1])
    ref = tight._inverse_columns(cols)
    assert np.abs(loose._inverse_columns(cols) - ref).max() <= 1e-5 * np.abs(ref).max()
    assert loose.lowrank is not None and not loose.truncated
    b = np.random.default_rng(6).normal(size=sd.n_z)
    xd = np.linalg.solve(sd.evaluate(z, 1.1, F).J, b)
    for P in (tight, loose):
        assert np.abs(P.solve(b) - xd).max() <= 1e-5 * np.abs(xd).max()


def test_a_factored_stage_keeps_the_columns_it_solved(monkeypatch):
    """A harmonic stage of single-precision LU factors (a loose solve) keeps the columns
    of ``P_h^-1`` its low-rank stages solved for, and the partial builds on that stage
    (an EPMC point's extended Newton steps) read them instead of solving them again:
    only the columns not yet kept are solved, and what is read equals a fresh solve of
    every column to single precision.  A new stage starts empty."""
    import jointsim.solvers.preconditioner as pm
    monkeypatch.setattr(pm, "MODAL_STAGE", False)
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", "coupled")))
    F = sd.force_coefficients(0.3)
    z = np.random.default_rng(5).normal(size=sd.n_z) * 0.4
    sk.krylov_rtol = 1e-3
    P = HarmonicPreconditioner(sk.evaluate(z, 1.1, F).J)
    Q = HarmonicPreconditioner(sk.evaluate(1.01 * z, 1.1, F).J, base=P)
    assert P.Plu is not None and Q.partial and Q._columns is P._columns
    nh, nr = len(sk.basis.harmonics), sk.n_r
    E = np.broadcast_to(np.eye(nr, dtype=complex), (nh, nr, nr)).copy()
    ref = P._inverse_times(E)                       # every column, solved afresh
    solved = []
    inner = pm.HarmonicPreconditioner._inverse_times
    monkeypatch.setattr(pm.HarmonicPreconditioner, "_inverse_times",
                        lambda self, X: solved.append(X.shape[2]) or inner(self, X))
    kept = np.flatnonzero(P._columns[0])
    assert kept.size > 0                            # the low-rank stage's rows
    cols = np.unique(np.concatenate([kept, [0, nr - 1]]))
    new = np.setdiff1d(cols, kept)
    expected = [new.size] if new.size else []      # one solve, of the new columns only
    got = Q._inverse_columns(cols)
    assert solved == expected
    assert np.abs(got - ref[:, :, cols]).max() <= 1e-6 * np.abs(ref).max()
    assert np.array_equal(Q._inverse_columns(cols[::-1]), got[:, :, ::-1])
    assert solved == expected                       # all kept now: nothing solved again
    assert HarmonicPreconditioner(sk.evaluate(z, 1.2, F).J)._columns is not P._columns


def test_lowrank_stage_keeps_only_the_rows_that_couple_harmonics():
    """An element that slips but stays closed has a constant normal tangent: the
    low-rank stage keeps its slip rows only (one row block of n_c coordinates, against
    2 n_c for the whole element) and is still the exact inverse of J (against the
    dense solve; GMRES in one iteration)."""
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", "coupled")))
    F = sd.force_coefficients(0.3)
    Z = np.zeros((sk.n_c, sk.n_r))             # rows: slip 0, 1; gap 2, 3 (elements 0, 1)
    Z[0, 2:] = -5.0                            # both closed by a static gap
    Z[1, 0] = 3.0                              # element 0 slips (cosine of harmonic 1)
    Z[1, 2] = 0.05                             # ... with a small normal vibration
    Z[2, 1] = 0.03                             # element 1 sticks
    z = Z.ravel()
    Jk = sk.evaluate(z, 1.1, F).J
    P = HarmonicPreconditioner(Jk)
    lr = P.lowrank
    assert not P.truncated
    assert lr.Rrow.tolist() == [0] and lr.R.tolist() == [0, 2]   # slip rows of element 0
    assert lr.sizes == [sk.n_c]
    v = np.random.default_rng(0).normal(size=sk.n_z)
    xd = np.linalg.solve(sd.evaluate(z, 1.1, F).J, v)
    assert np.abs(P.solve(v) - xd).max() <= 1e-12 * np.abs(xd).max()
    x, it, rel, _ = gmres(Jk.matvec, v, P.solve, rtol=1e-12)
    assert it == 1 and np.abs(x - xd).max() <= 1e-10 * np.abs(xd).max()


def test_lowrank_lu_is_single_precision_for_a_loose_solve_or_a_large_stage(monkeypatch):
    """A Jacobian solved to a loose tolerance (the error indicators', rtol 1e-3) gets
    its low-rank LU in single precision: the preconditioner is then the inverse of J to
    single-precision round-off (against the dense solve) and GMRES still needs one
    iteration; at the default tolerance a small LU stays in double precision.  A large
    one (``SINGLE_LU_MIN`` coordinates, here lowered to this stage's size) is single
    at the tight tolerance too, and GMRES still reaches the dense solution there, in
    a few more iterations."""
    import jointsim.solvers.preconditioner as pm
    from jointsim.solvers.preconditioner import SINGLE_LU_RTOL
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", "coupled")))
    F = sd.force_coefficients(0.3)
    rng = np.random.default_rng(5)
    z = rng.normal(size=sd.n_z) * 0.4
    v = rng.normal(size=sd.n_z)
    xd = np.linalg.solve(sd.evaluate(z, 1.1, F).J, v)
    Jk = sk.evaluate(z, 1.1, F).J
    assert Jk.rtol < SINGLE_LU_RTOL
    assert HarmonicPreconditioner(Jk).lowrank.lu[0].dtype == np.float64
    Jk.rtol = 1e-3
    P = HarmonicPreconditioner(Jk)
    assert P.lowrank.lu[0].dtype == np.float32 and not P.truncated
    err = np.abs(P.solve(v) - xd).max() / np.abs(xd).max()
    assert 1e-12 < err <= 1e-4
    x, it, rel, _ = gmres(Jk.matvec, v, P.solve, rtol=1e-3)
    assert it == 1 and rel <= 1e-3 and P.solve(v).dtype == np.float64
    Jk.rtol = KRYLOV_RTOL
    m, = P.lowrank.sizes
    assert m < pm.SINGLE_LU_MIN
    monkeypatch.setattr(pm, "SINGLE_LU_MIN", m)
    P = HarmonicPreconditioner(Jk)
    assert P.lowrank.lu[0].dtype == np.float32
    x, it, rel, _ = gmres(Jk.matvec, v, P.solve, rtol=KRYLOV_RTOL)
    assert 1 < it <= 4 and rel <= KRYLOV_RTOL
    assert np.abs(x - xd).max() <= 1e-9 * np.abs(xd).max()


@pytest.mark.parametrize("normal", ["coupled", "fixed"])
def test_loose_split_lowrank_stage_and_its_capacitance_solve(normal, monkeypatch):
    """A loose solve's low-rank stage above ``LOOSE_SPLIT_MIN`` coordinates, built for
    one solve (``PreconditionerCache.single_solve``), keeps every row block and splits
    ``I + L_r G`` into its element blocks: as a preconditioner (``G`` between elements
    left out) it is not the inverse of J; its capacitance solve is (to single
    precision), and refined on J it reaches the dense solution (the oracle) to the
    tolerance asked."""
    import jointsim.solvers.jacobian as jm
    import jointsim.solvers.preconditioner as pm
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", normal)))
    F = sd.force_coefficients(0.3)
    rng = np.random.default_rng(5)
    z = rng.normal(size=sd.n_z) * 0.4
    v = rng.normal(size=sd.n_z)
    xd = np.linalg.solve(sd.evaluate(z, 1.1, F).J, v)
    sk.krylov_rtol = 1e-3
    Jl = sk.evaluate(z, 1.1, F).J
    one = HarmonicPreconditioner(Jl)
    m = sum(one.lowrank.sizes)
    assert not one.lowrank.split and m <= pm.LOOSE_SPLIT_MIN
    assert not one.capacitance_solves
    assert np.abs(one.solve(v) - xd).max() <= 1e-4 * np.abs(xd).max()
    monkeypatch.setattr(pm, "LOOSE_SPLIT_MIN", 0)
    assert not HarmonicPreconditioner(Jl).lowrank.split  # not for several solves
    sk.preconditioner.single_solve = True
    P = HarmonicPreconditioner(Jl)
    lr = P.lowrank
    assert lr.split and sum(lr.sizes) == m and not P.truncated
    assert P.capacitance_solves and lr.lu is None
    assert np.array_equal(lr.Lr, one.lowrank.Lr)       # the whole L_r, no LU of I + L_r G
    # one block per column element (all its row blocks): more than one, fewer than the
    # row blocks where an element slips and separates
    assert len(lr.sizes) == lr.R.size // lr.nb > 1
    assert len(lr.sizes) < lr.Rrow.size or normal == "fixed"
    assert np.abs(P.solve(v) - xd).max() > 1e-3 * np.abs(xd).max()
    xc, it = P.solve_capacitance(v, 1e-10)
    assert it > 1 and np.abs(xc - xd).max() <= 1e-4 * np.abs(xd).max()
    def step(r, tau):
        dx, it = P.solve_capacitance(r, tau)
        return dx / Jl.col, it
    for rtol in (1e-3, 1e-9):
        x, _ = jm._capacitance_refined(step, Jl.matvec, v, rtol)
        assert np.linalg.norm(Jl.matvec(x) - v) <= rtol * np.linalg.norm(v)
    assert np.abs(x - xd).max() <= 1e-7 * np.abs(xd).max()
    # and through the solve itself (two columns)
    sk.preconditioner.forget()
    used = []
    refine = jm._capacitance_refined
    monkeypatch.setattr(jm, "_capacitance_refined", lambda *a: used.append(1) or refine(*a))
    x = Jl.solve(np.column_stack([v, 2.0 * v]))
    assert used
    assert np.linalg.norm(Jl.matvec(x[:, 1]) - 2.0 * v) <= 2e-3 * np.linalg.norm(v)
    # a capacitance solve that fails (not finite): GMRES on J from zero still solves
    sk.preconditioner.forget()
    monkeypatch.setattr(pm.HarmonicPreconditioner, "solve_capacitance",
                        lambda self, b, rtol: (np.full(np.shape(b), np.nan), 1))
    x = Jl.solve(v)
    assert np.linalg.norm(Jl.matvec(x) - v) <= 1e-3 * np.linalg.norm(v)
    monkeypatch.setattr(pm, "LOOSE_SPLIT_MIN", np.inf)                # off: one group
    assert not HarmonicPreconditioner(Jl).lowrank.split


@pytest.mark.parametrize("modal", [False, True])
def test_a_loose_stage_keeps_the_static_and_fundamental_blocks_in_double(modal, monkeypatch):
    """A loose solve's single-precision harmonic stage (LU factors, or the stuck
    flexibility's inverses) keeps the blocks of ``LOOSE_DOUBLE_HARMONICS`` (0 and 1) in
    double, and so do the columns of ``P_h^-1`` it keeps and ``G`` of its capacitance
    system (``Q_double``): those harmonics' columns equal the inverse of the double
    block (the oracle: the dense inverse of ``P_h``, or the flexibility's double
    inverses) to round-off, the others only to single precision."""
    import jointsim.solvers.preconditioner as pm
    from jointsim.solvers.tangent_projection import add_projected_tangent
    monkeypatch.setattr(pm, "MODAL_STAGE", modal)
    monkeypatch.setattr(pm, "LOOSE_SPLIT_MIN", 0)
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", "coupled")))
    F = sd.force_coefficients(0.3)
    z = np.random.default_rng(5).normal(size=sd.n_z) * 0.4
    sk.krylov_rtol = 1e-3
    sk.preconditioner.single_solve = True
    J = sk.evaluate(z, 1.1, F).J
    P = HarmonicPreconditioner(J)
    h = np.asarray(sk.basis.harmonics)
    dbl = np.flatnonzero(np.isin(h, (0, 1)))
    assert P.modal == modal and (P.Plu is not None) != modal and P.capacitance_solves
    assert sorted(P._double_harmonics()) == dbl.tolist()
    nh, nr = len(h), sk.n_r
    cols = np.arange(nr)
    got = P._inverse_columns(cols)
    if modal:
        nus = h * J.freq.omega
        ref = np.empty((nh, nr, nr), dtype=complex)
        ref[dbl] = J.lin.flexibility.inverses(nus[dbl], J.freq.xi)
        ref[~np.isin(h, (0, 1))] = J.lin.flexibility.inverses(nus, J.freq.xi)[
            ~np.isin(h, (0, 1))]
    else:
        ref = np.empty((nh, nr, nr), dtype=complex)
        for i in range(nh):
            B = np.array(P.S[i], dtype=complex)
            add_projected_tangent(B, J, i, P.proj)
            ref[i] = np.linalg.inv(B)
    for i in range(nh):
        err = np.abs(got[i] - ref[i]).max() / np.abs(ref[i]).max()
        if i in dbl:
            assert err <= 1e-12, (h[i], err)
        else:
            assert 1e-12 < err <= 1e-5, (h[i], err)
    lr = P.lowrank
    assert sorted(lr.Q_double) == dbl.tolist()
    # the correction keeps the inverses' columns in their precision (the LU factors'
    # solved ones in double)
    assert P.PinvR.dtype == (np.complex64 if modal else complex)
    assert sorted(P.PinvR_double) == (dbl.tolist() if modal else [])
    for i, Qd in lr.Q_double.items():
        C = P.PinvR_double.get(i, P.PinvR[i])
        assert Qd.dtype == complex and C.dtype == complex and np.array_equal(Qd, C[lr.R])
        assert np.array_equal(P.PinvR[i], C.astype(P.PinvR.dtype))
    monkeypatch.setattr(pm, "LOOSE_DOUBLE_HARMONICS", ())
    assert HarmonicPreconditioner(J)._double_harmonics() == []


def test_a_truncated_loose_bordered_solve_goes_through_the_capacitance_system(monkeypatch):
    """An EPMC point's extended Newton step (loose, bordered, its preconditioner shifted)
    whose low-rank correction would be truncated keeps every row block, split by
    harmonics, and does the bordering with capacitance solves of ``M = J + C2 R2``: the
    dense solution to the tolerance asked, two columns at once, GMRES on the system
    finishing in a few iterations.  The split preconditioner is then kept for that
    Jacobian only.  Four-DOF Jenkins chain with coupled N, a state with slip and
    separation; the limits lowered so that the chain's correction would be truncated."""
    import jointsim.solvers.jacobian as jm
    import jointsim.solvers.preconditioner as pm
    from jointsim.solvers.epmc import EPMCSystem
    from jointsim.solvers.modes import elastic_mode
    model = build_model(four_dof("jenkins", "anchor", "coupled"))
    sk = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="krylov")
    sk.krylov_rtol = 1e-3
    ep = EPMCSystem(sk, elastic_mode(model, 1).phi, sk.force_coefficients(0.0))
    rng = np.random.default_rng(5)
    y = np.concatenate([rng.normal(size=sk.n_z) * 0.4, [1.1, 0.01, 0.0]])
    A = jm.drop_last_column(ep.fun(y)[1])
    assert A.deflate is not None
    b = rng.normal(size=(A.shape[0], 2))
    xd = np.linalg.solve(A.to_dense(), b)
    monkeypatch.setattr(pm, "LOWRANK_MIN", 0)
    monkeypatch.setattr(pm, "LOWRANK_MAX", sk.n_c)        # one row block: truncated
    monkeypatch.setattr(pm, "LOOSE_SPLIT_MIN", 0)
    used, refine = [], jm._capacitance_refined
    monkeypatch.setattr(jm, "_capacitance_refined", lambda *a: used.append(a) or refine(*a))
    iterations = []
    count = jm.gmres_columns
    monkeypatch.setattr(jm, "gmres_columns",
                        lambda *a, **kw: iterations.append(count(*a, **kw)) or iterations[-1])
    x = A.solve(b)
    P = sk.preconditioner.current
    assert used and P.C2 is not None and P.capacitance_solves and not P.truncated
    assert P.lowrank.split
    for k in range(2):
        assert np.linalg.norm(A.matvec(x[:, k]) - b[:, k]) <= 1e-3 * np.linalg.norm(b[:, k])
        assert np.abs(x[:, k] - xd[:, k]).max() <= 1e-2 * np.abs(xd[:, k]).max()
    assert max(c.iterations for c in iterations[-1]) <= 3
    # one step of the bordering, its capacitance solves to 1e-10: the dense solution to
    # the single precision of the split stage
    x1, _ = used[0][0](b, 1e-10)
    assert np.abs(x1 - xd).max() <= 1e-4 * np.abs(xd).max()
    assert sk.preconditioner.exclusive             # not offered to the next Jacobian
    # without the lowered limits the chain's correction is whole: no split, one LU
    monkeypatch.undo()
    sk.preconditioner.forget()
    A.solve(b)
    assert not sk.preconditioner.current.capacitance_solves


def test_lowrank_stage_is_exact_up_to_its_fraction_and_truncated_beyond(monkeypatch):
    """The low-rank stage keeps every element that couples harmonics while they need at
    most LOWRANK_EXACT_FRACTION n_z coordinates (exact: one GMRES iteration); beyond,
    only the largest, LOWRANK_MAX_FRACTION n_z of them (GMRES does the rest and still
    reaches the dense solution)."""
    import jointsim.solvers.preconditioner as pm
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", "coupled")))
    F = sd.force_coefficients(0.3)
    rng = np.random.default_rng(5)
    z = rng.normal(size=sd.n_z) * 0.4
    Jd, Jk = sd.evaluate(z, 1.1, F).J, sk.evaluate(z, 1.1, F).J
    v = rng.normal(size=sd.n_z)
    xd = np.linalg.solve(Jd, v)
    monkeypatch.setattr(pm, "LOWRANK_MIN", 0)
    d = 2 * sk.n_c                               # coordinates of one element
    assert sk.n_z == 2 * d                       # both elements slip and separate: m = n_z
    # (exact fraction, truncated fraction, coordinates kept / d): all fit / half is cut
    for exact, kept_fraction, kept in ((1.0, 0.35, 2), (0.9, 0.5, 1)):
        monkeypatch.setattr(pm, "LOWRANK_EXACT_FRACTION", exact)
        monkeypatch.setattr(pm, "LOWRANK_MAX_FRACTION", kept_fraction)
        P = HarmonicPreconditioner(Jk)
        assert P.truncated == (kept < 2) and P.lowrank.sizes == [kept * d]
        x, it, rel, _ = gmres(Jk.matvec, v, lambda u: P.apply(u, Jk), rtol=1e-12)
        assert (it == 1) == (not P.truncated)
        assert np.abs(x - xd).max() <= 1e-9 * np.abs(xd).max()


def test_gmres_solves_a_nonsymmetric_system():
    """The GMRES (with restarts) against a dense solve, unpreconditioned."""
    rng = np.random.default_rng(4)
    A = np.eye(150) * 4 + rng.normal(size=(150, 150)) / 10
    b = rng.normal(size=150)
    x, it, rel, _ = gmres(lambda v: A @ v, b, lambda v: v, rtol=1e-12, restart=20, maxiter=500)
    assert rel <= 1e-12 and it > 20
    assert np.abs(x - np.linalg.solve(A, b)).max() <= 1e-10 * np.abs(x).max()


def test_gmres_columns_equals_gmres_column_by_column():
    """The lockstep GMRES of several right-hand sides: a column's iterations, residual
    and solution do not depend on the other columns (against each column alone, with
    restarts, a start, a zero column and an iteration limit), the operator is applied
    to blocks of columns, and every column reaches the dense solution."""
    rng = np.random.default_rng(11)
    n = 150
    A = np.eye(n) * 4 + rng.normal(size=(n, n)) / 10
    A[:, :5] *= 30.0                               # columns of different difficulty
    dinv = 1.0 / np.diag(A)
    B = rng.normal(size=(n, 4))
    B[:, 1] = 0.0
    B[:, 3] = A @ rng.normal(size=n)
    X0 = np.zeros((n, 4))
    X0[:, 2] = np.linalg.solve(A, B[:, 2]) + 1e-3 * rng.normal(size=n)
    widths = []

    def matvec(V):
        widths.append(V.shape[1] if V.ndim == 2 else 1)
        return A @ V
    for maxiter in (500, 7):
        cols = gmres_columns(matvec, B, lambda V: dinv[:, None] * V, rtol=1e-12,
                             restart=15, maxiter=maxiter, X0=X0)
        for c in range(4):
            one = gmres(lambda v: A @ v, B[:, c], lambda v: dinv * v, rtol=1e-12,
                        restart=15, maxiter=maxiter, x0=X0[:, c])
            assert cols[c].iterations == one.iterations
            assert cols[c].at_floor == one.at_floor
            assert cols[c].relres == pytest.approx(one.relres, rel=1e-6, abs=1e-15)
            scale = max(np.abs(one.x).max(), 1e-300)
            assert np.abs(cols[c].x - one.x).max() <= 1e-10 * scale
        if maxiter == 500:
            assert all(r.relres <= 1e-12 for r in cols) and cols[1].iterations == 0
            for c in (0, 2, 3):
                xd = np.linalg.solve(A, B[:, c])
                assert np.abs(cols[c].x - xd).max() <= 1e-10 * np.abs(xd).max()
        else:
            assert cols[0].iterations == 7 and cols[0].relres > 1e-12
    # all four columns only in the residual of the start (once per call); the zero
    # column is never iterated
    assert widths.count(4) == 2 and max(widths) == 4 and 3 in widths


def test_structured_jacobian_and_preconditioner_take_blocks_of_columns():
    """``J V``, ``P^-1 V`` (exact and truncated two-stage) and the bordered solve of a
    block of columns equal the column-by-column results (and the dense solve)."""
    import jointsim.solvers.preconditioner as pm
    sd, sk = _pair(build_model(four_dof("jenkins", "anchor", "coupled")))
    F = sd.force_coefficients(0.3)
    rng = np.random.default_rng(5)
    z = rng.normal(size=sd.n_z) * 0.4
    ed = sd.evaluate(z, 1.1, F, wrt=("omega",))
    Jk = sk.evaluate(z, 1.1, F, wrt=("omega",)).J.scaled(rng.uniform(0.5, 2.0, sd.n_z))
    V = rng.normal(size=(sd.n_z, 3))
    JV = Jk.matvec(V)
    assert JV.shape == V.shape
    for c in range(3):
        assert np.abs(JV[:, c] - Jk.matvec(V[:, c])).max() <= 1e-13 * np.abs(JV).max()
    for cap in (None, sk.n_c):                       # exact, and truncated (two-stage)
        old = pm.LOWRANK_MAX
        try:
            if cap is not None:
                pm.LOWRANK_MAX = cap
            P = HarmonicPreconditioner(Jk)
        finally:
            pm.LOWRANK_MAX = old
        assert P.truncated == (cap is not None)
        PV = P.apply(V, Jk)
        for c in range(3):
            assert np.abs(PV[:, c] - P.apply(V[:, c], Jk)).max() <= 1e-12 * np.abs(PV).max()
    c_om = ed.dR["omega"]
    t = rng.normal(size=sd.n_z + 1)
    Bk = BorderedJacobian(sk.evaluate(z, 1.1, F).J, c_om).with_row(t)
    Bd = np.vstack([np.column_stack([ed.J, c_om]), t[None, :]])
    Bb = rng.normal(size=(sd.n_z + 1, 2))
    Xb = Bk.solve(Bb)
    assert np.abs(Xb - np.linalg.solve(Bd, Bb)).max() <= 1e-8 * np.abs(Xb).max()


def test_gmres_goes_on_from_a_start():
    """GMRES from ``x0`` (the result of an attempt that ran out of iterations) reaches
    the dense solution; from the solution itself it takes no iteration."""
    rng = np.random.default_rng(6)
    A = np.eye(120) * 4 + rng.normal(size=(120, 120)) / 10
    b = rng.normal(size=120)
    xd = np.linalg.solve(A, b)
    x5, it5, rel5, _ = gmres(lambda v: A @ v, b, lambda v: v, rtol=1e-12, maxiter=5)
    assert it5 == 5 and rel5 > 1e-6
    x, it, rel, _ = gmres(lambda v: A @ v, b, lambda v: v, rtol=1e-12, x0=x5)
    assert rel <= 1e-12 and np.abs(x - xd).max() <= 1e-10 * np.abs(xd).max()
    _x, it0, _rel, _ = gmres(lambda v: A @ v, b, lambda v: v, rtol=1e-8, x0=xd)
    assert it0 == 0


def test_gmres_reports_the_round_off_floor():
    """Asked for a residual below round-off, GMRES stops where its own residual got
    there and the true one cannot: ``at_floor``, with the solution to round-off."""
    rng = np.random.default_rng(8)
    A = np.eye(60) * 3 + rng.normal(size=(60, 60)) / 10
    b = rng.normal(size=60)
    x, it, rel, at_floor = gmres(lambda v: A @ v, b, lambda v: v, rtol=1e-18)
    assert at_floor and 1e-18 < rel <= 1e-14
    xd = np.linalg.solve(A, b)
    assert np.abs(x - xd).max() <= 1e-13 * np.abs(xd).max()
    *_, at_floor = gmres(lambda v: A @ v, b, lambda v: v, rtol=1e-10)
    assert not at_floor


@pytest.mark.parametrize("law", ["stuck", "jenkins"])
def test_a_reused_preconditioner_at_the_round_off_floor_is_not_rebuilt(law, monkeypatch):
    """Jacobians at nearby frequencies reuse one preconditioner; a solve that stops at
    the round-off floor (tolerance below it) is accepted, not rebuilt, and equals the
    dense solve; refusing the floor (FLOOR_FACTOR 0) rebuilds for the same solves."""
    import jointsim.solvers.jacobian as jm
    model = build_model(four_dof(law, "anchor", "fixed"))
    builds, default = {}, jm.FLOOR_FACTOR
    for factor in (default, 0.0):
        monkeypatch.setattr(jm, "FLOOR_FACTOR", factor)
        sk = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="krylov")
        sk.krylov_rtol = 1e-17
        F = sk.force_coefficients(0.3)
        rng = np.random.default_rng(2)
        z = rng.normal(size=sk.n_z) * 0.4
        for w in (1.3, 1.3005, 1.301, 1.31):
            J = sk.evaluate(z, w, F).J
            v = rng.normal(size=sk.n_z)
            x = J.solve(v)
            xd = np.linalg.solve(J.to_dense(), v)
            assert np.abs(x - xd).max() <= 1e-13 * np.abs(xd).max()
        builds[factor] = sk.stats.factorizations
    assert builds[default] == 1 < builds[0.0]


@pytest.mark.parametrize("law,normal", [("jenkins", "coupled"), ("jenkins", "fixed")])
def test_frequency_cache_is_bit_identical(law, normal):
    """The blocks and S_h kept per frequency (HBMSystem.harmonic_blocks): a second
    evaluation at the same frequency gives the same residual, products and
    reconstruction bit for bit as a system that forms everything afresh, shares the
    formed S_h, and at most OMEGA_CACHE frequencies are kept."""
    from jointsim.solvers import hbm as hbm_mod
    model = build_model(four_dof(law, "anchor", normal))
    _sd, sk = _pair(model)
    _sd2, fresh = _pair(model)
    F = sk.force_coefficients(0.3)
    rng = np.random.default_rng(7)
    z1, z2 = rng.normal(size=sk.n_z) * 0.4, rng.normal(size=sk.n_z) * 0.4
    e1 = sk.evaluate(z1, 1.1, F, xi=0.05, wrt=("omega", "xi"))
    e1.J.form_schur()
    e2 = sk.evaluate(z2, 1.1, F, xi=0.05, wrt=("omega", "xi"))
    assert e2.J._S is e1.J._S and all(S is not None for S in e2.J._S)
    f2 = fresh.evaluate(z2, 1.1, F, xi=0.05, wrt=("omega", "xi"))
    assert np.array_equal(e2.R, f2.R)
    assert all(np.array_equal(e2.dR[p], f2.dR[p]) for p in ("omega", "xi"))
    v = rng.normal(size=sk.n_z)
    f2.J.form_schur()
    assert np.array_equal(e2.J.matvec(v), f2.J.matvec(v))
    fresh.omega_cache.clear()          # reconstruct at a frequency not kept
    assert np.array_equal(sk.reconstruct(z2, 1.1, F, xi=0.05),
                          fresh.reconstruct(z2, 1.1, F, xi=0.05))
    for w in (1.2, 1.3, 1.4):
        sk.evaluate(z1, w, F)
    assert len(sk.omega_cache) == hbm_mod.OMEGA_CACHE


def test_krylov_residual_needs_no_blocks_on_the_lap_joint(monkeypatch):
    """With the low-rank damping condensation of the coarse lap joint, the Krylov path's
    residual, its derivatives and J v (every harmonic at once, DynamicProducts) equal
    the direct path's to round-off without forming the per-harmonic blocks, and so does
    forming S_h for a preconditioner of inverted blocks (Woodbury's formula with the
    low-rank damping, self-excitation included: ``ReducedLinear.schur_low_rank_damping``);
    one from the stuck flexibility forms no ``S_h`` at all."""
    import jointsim.solvers.preconditioner as pm
    model = build_model(lap_scene(ROOT / "models" / "lap_joint_nodes.toml"))
    sd = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="direct")
    sk = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="krylov")
    assert sk.lin.kind == "lowrank"
    rng = np.random.default_rng(0)
    z = rng.normal(size=sk.n_z) * 1e-6
    F = sk.force_coefficients(1.0)
    ed = sd.evaluate(z, 1000.0, F, xi=3.0, wrt=("omega", "xi"))
    ek = sk.evaluate(z, 1000.0, F, xi=3.0, wrt=("omega", "xi"))
    assert np.abs(ed.R - ek.R).max() <= 1e-14 * np.abs(ed.R).max()
    for p in ("omega", "xi"):
        assert np.abs(ed.dR[p] - ek.dR[p]).max() <= 1e-13 * np.abs(ed.dR[p]).max()
    v = rng.normal(size=sk.n_z)
    assert np.abs(ek.J.matvec(v) - ed.J @ v).max() <= 1e-13 * np.abs(ed.J @ v).max()
    assert not ek.J.freq.formed
    assert HarmonicPreconditioner(ek.J).modal
    assert not ek.J.freq.formed and all(S is None for S in ek.J.freq.S)
    monkeypatch.setattr(pm, "MODAL_STAGE", False)
    assert not HarmonicPreconditioner(ek.J).modal
    assert not ek.J.freq.formed and all(S is not None for S in ek.J.freq.S)


def test_frequency_cache_reconstructs_bit_identically_on_the_lap_joint():
    """With the low-rank damping condensation of the coarse lap joint, the
    reconstruction from the kept blocks equals one from blocks formed afresh bit for
    bit (and so does a second residual at that frequency)."""
    model = build_model(lap_scene(ROOT / "models" / "lap_joint_nodes.toml"))
    sk = HBMSystem(model, (0, 1, 2, 3), 64, linear_solver="krylov")
    assert sk.lin.kind == "lowrank"
    F = sk.force_coefficients(1.0)
    z = sk.static_coordinates() + np.random.default_rng(8).normal(size=sk.n_z) * 1e-7
    w = 2 * np.pi * 150.0
    e1 = sk.evaluate(z, w, F)
    X = sk.reconstruct(z, w, F)
    assert (w, 0.0) in sk.omega_cache
    sk.omega_cache.clear()
    assert np.array_equal(X, sk.reconstruct(z, w, F))
    assert np.array_equal(e1.R, sk.evaluate(z, w, F).R)


def _run(tmp_path, path, solver):
    scene = load_scene(path, [f"analysis.{'epmc' if 'epmc' in path.name else 'hbm'}"
                              f".linear_solver='{solver}'"])
    out = run_scene(scene, tmp_path / f"{path.stem}_{solver}.h5")
    return h5py.File(out, "r")


@pytest.mark.parametrize("path", [pytest.param(p, marks=pytest.mark.slow)
                                  if p.stem in ("sdof_clearance_fold", "chain2_jenkins") else p
                                  for p in sorted(MODELS.glob("*.toml"))], ids=lambda p: p.stem)
def test_krylov_path_equals_direct_path_on_lumped_cases(tmp_path, path):
    """Every lumped HBM/EPMC scene (two with turning points) forced onto the Krylov
    path gives the branch of the dense direct path, point by point, to 1e-8 in X."""
    with _run(tmp_path, path, "direct") as fd, _run(tmp_path, path, "krylov") as fk:
        g = "epmc" if "epmc" in fd else "hbm"
        assert fd[g].attrs["linear_solver"] == "direct"
        assert fk[g].attrs["linear_solver"] == "krylov"
        Xd, Xk = fd[f"{g}/X"][()], fk[f"{g}/X"][()]
        if g == "hbm":        # branches computed in worker processes interleave
            Xd = Xd[np.argsort(fd["hbm/branch"][()], kind="stable")]
            Xk = Xk[np.argsort(fk["hbm/branch"][()], kind="stable")]
        assert Xd.shape == Xk.shape
        scale = np.abs(Xd).max(axis=(1, 2))[:, None, None]
        assert np.abs(Xd - Xk).max() <= 1e-8 * scale.max()
        assert (np.abs(Xd - Xk) <= 1e-8 * scale).all()
        assert fk[f"{g}/krylov_iterations"][()].sum() > 0
        assert fd[f"{g}/krylov_iterations"][()].sum() == 0


def test_krylov_path_equals_direct_path_on_the_coarse_lap_joint():
    """The coarse FE lap joint (coupled N with separation): an FRC branch piece through
    microslip, and fixed-frequency solves at the high force level, direct vs Krylov."""
    recs = {}
    for solver in ("direct", "krylov"):
        sc = lap_scene(ROOT / "models" / "lap_joint_nodes.toml", ("modes", "hbm"),
                       ["analysis.hbm.max_points=6", "analysis.hbm.harmonics=[0,1,2,3]",
                        "analysis.hbm.n_samples=64", "analysis.hbm.step=0.05",
                        f"analysis.hbm.linear_solver='{solver}'"])
        m = build_model(sc)
        a = sc.analysis.hbm
        s = _system(m, a)
        assert s.linear_solver == solver
        out = []
        _run_branch(_BranchJob(0, 2.0, None), system=s, a=a, dof=0, want_aft=False,
                    n_branches=1, on_record=out.append, progress=False)
        F = s.force_coefficients(20.0)
        pts = [solve_point(s, w, F) for w in (900.0, 960.0)]
        recs[solver] = ([r["X"] for r in out], [p.X for p in pts],
                        [p.convergence.iterations for p in pts])
    (bd, pd, itd), (bk, pk, itk) = recs["direct"], recs["krylov"]
    assert len(bd) == len(bk) == 6
    for Xd, Xk in zip(bd + pd, bk + pk):
        assert np.abs(Xd - Xk).max() <= 1e-8 * np.abs(Xd).max()
    assert itd == itk and max(itd) > 2          # nonlinear points, same Newton path


def test_krylov_epmc_in_the_linear_range_of_the_coarse_lap_joint(tmp_path, monkeypatch):
    """EPMC from the stuck (linear) range, where ``dR/dz`` is singular (the mode is its
    null vector): the bordered solve with the deflated preconditioner converges in a
    few GMRES iterations per solve and gives the dense path's points to 1e-8 in X."""
    import jointsim.solvers.jacobian as jm
    per_solve, bordered = [], []
    orig, orig_solve = jm.gmres, BorderedJacobian.solve

    def counting(*args, **kw):
        out = orig(*args, **kw)
        per_solve.append(out[1])
        return out

    def keep(self, b, **kw):
        bordered.append((self, b))
        return orig_solve(self, b, **kw)
    monkeypatch.setattr(jm, "gmres", counting)
    monkeypatch.setattr(BorderedJacobian, "solve", keep)
    X = {}
    for solver in ("direct", "krylov"):
        sc = lap_scene(ROOT / "models" / "lap_joint_nodes.toml", ("modes", "epmc"),
                       ["analysis.epmc.max_points=5", "analysis.epmc.loop_amplitudes=[]",
                        "analysis.epmc.error_indicators=false",
                        f"analysis.epmc.linear_solver='{solver}'"])
        try:
            run_scene(sc, tmp_path / f"{solver}.h5")
        except RuntimeError:
            pass                                  # max_points: the points are kept
        with h5py.File(tmp_path / f"{solver}.h5", "r") as f:
            assert f["epmc"].attrs["linear_solver"] == solver
            X[solver] = f["epmc/X"][()]
    assert X["direct"].shape == X["krylov"].shape and len(X["krylov"]) >= 5
    scale = np.abs(X["direct"]).max()
    assert np.abs(X["direct"] - X["krylov"]).max() <= 1e-8 * scale
    # without the deflation the first solves took the 400-iteration limit (121 pairs)
    assert per_solve and max(per_solve) <= 40
    # the mechanism, on the first bordered system: J's harmonic-1 block is singular up to
    # the round-off of the point's frequency (condition 7e10 here, above 1e12 on other
    # machines' BLAS), the shifted one is well conditioned (about 8e2), and the solve is
    # the dense one
    A, b = bordered[0]
    i1, ell = A.deflate
    J = A.J
    c = A.C[:, 0].reshape(J.n_c, J.n_r)
    u = c[J._ic[i1]] - 1j * c[J._is[i1]]
    plain = HarmonicPreconditioner(J)
    shifted = HarmonicPreconditioner(J, (i1, u, ell))
    c_plain, c_shifted = np.linalg.cond(plain.Pinv[i1]), np.linalg.cond(shifted.Pinv[i1])
    assert c_plain > 1e10 and c_shifted < 1e8 and c_plain > 1e6 * c_shifted
    x = orig_solve(A, b)
    xd = np.linalg.solve(A.to_dense(), b)
    assert np.abs(x - xd).max() <= 1e-6 * np.abs(xd).max()


def test_chord_cost_model_from_its_size_keeps_the_branch(monkeypatch):
    """From ``COST_REUSE_MIN_ROWS`` rows a tightly solved system's preconditioner is kept
    by the chord cost model (at 480 Gauss points its builds cost more than the GMRES
    iterations they save): on the coarse lap joint, with the size lowered to its own,
    other builds and GMRES iterations (here more builds: why it waits for the size) and
    the same FRC branch piece to 1e-8 in X; the error indicators' loose systems keep
    the fixed threshold."""
    import jointsim.solvers.preconditioner_cache as pc
    runs = {}
    for rows in (10 ** 9, 0):
        monkeypatch.setattr(pc, "COST_REUSE_MIN_ROWS", rows)
        sc = lap_scene(ROOT / "models" / "lap_joint_nodes.toml", ("modes", "hbm"),
                       ["analysis.hbm.max_points=10", "analysis.hbm.harmonics=[0,1,2,3]",
                        "analysis.hbm.n_samples=64", "analysis.hbm.step=0.05",
                        "analysis.hbm.linear_solver='krylov'"])
        s = _system(build_model(sc), sc.analysis.hbm)
        out, by_cost = [], []
        keep = pc.PreconditionerCache.after_solve

        def noted(self, iterations, fresh):      # (cost model used, a loose system)
            by_cost.append((self._by_cost(), self.current.jac.rtol >= pc.SINGLE_LU_RTOL))
            return keep(self, iterations, fresh)
        monkeypatch.setattr(pc.PreconditionerCache, "after_solve", noted)
        _run_branch(_BranchJob(0, 20.0, None), system=s, a=sc.analysis.hbm, dof=0,
                    want_aft=False, n_branches=1, on_record=out.append, progress=False)
        monkeypatch.setattr(pc.PreconditionerCache, "after_solve", keep)
        runs[rows] = ([r["X"] for r in out], sum(r["preconditioners"] for r in out),
                      sum(r["krylov_iterations"] for r in out), by_cost)
    (X_off, b_off, it_off, c_off), (X_on, b_on, it_on, c_on) = runs[10 ** 9], runs[0]
    assert not any(c for c, _ in c_off) and all(c == (not lo) for c, lo in c_on)
    assert any(not lo for _, lo in c_on)
    assert len(X_off) == len(X_on) == 10
    for a, b in zip(X_off, X_on):
        assert np.abs(a - b).max() <= 1e-8 * np.abs(a).max()
    assert (b_on, it_on) != (b_off, it_off)


@pytest.mark.parametrize("law", ["jenkins", "iwan4"])
def test_structured_tangent_to_its_tolerance_equals_the_dense_one(law, monkeypatch):
    """The branch tangent of ``[J, dR/domega]`` solved by GMRES to ``TANGENT_RTOL``
    (looser than the Newton steps' 1e-11, which lies below the round-off floor of large
    systems) equals the dense LU's tangent to about that tolerance, and GMRES is asked
    for it; not for a deflated (EPMC) system."""
    import jointsim.solvers.arclength as arc
    import jointsim.solvers.jacobian as jm
    sd, sk = _pair(build_model(four_dof(law, "anchor", "coupled")))
    F = sk.force_coefficients(0.3)
    rng = np.random.default_rng(11)
    z = rng.normal(size=sk.n_z) * 0.4
    asked = []
    solve = jm.krylov_solve

    def spy(*a, rtol=None, **k):
        asked.append(rtol)
        return solve(*a, rtol=rtol, **k)
    monkeypatch.setattr(jm, "krylov_solve", spy)
    for w in (1.1, 1.6):
        ek, ed = (s.evaluate(z, w, F, wrt=("omega",)) for s in (sk, sd))
        t_prev = rng.normal(size=sk.n_z + 1)
        t_k = arc.tangent(BorderedJacobian(ek.J, C=ek.dR["omega"]), t_prev)
        t_d = arc.tangent(np.column_stack([ed.J, ed.dR["omega"]]), t_prev)
        assert np.abs(t_k - t_d).max() <= 10 * arc.TANGENT_RTOL * np.abs(t_d).max()
    assert asked and all(r == arc.TANGENT_RTOL for r in asked)
    # a deflated (EPMC) system is solved to its own tolerance, as its Newton steps are
    asked.clear()
    ell = np.ones(sk.n_r, dtype=complex)
    arc.tangent(BorderedJacobian(ek.J, C=ek.dR["omega"], deflate=(1, ell)), t_prev)
    assert asked == [None]


def test_capacitance_refinement_stops_on_a_poor_step_and_undoes_a_harmful_one():
    """The capacitance steps' refinement (``_capacitance_refined``) keeps a step that
    gains, stops after one that leaves more than ``CAPACITANCE_GAIN`` of the residual,
    and undoes one that raises it; GMRES on the system then goes on from the result."""
    import jointsim.solvers.jacobian as jm
    rng = np.random.default_rng(5)
    A = np.diag(rng.uniform(1.0, 2.0, 12))
    b = rng.normal(size=(12, 1))
    x_true = np.linalg.solve(A, b)

    def run(gains):
        """Steps that leave ``gains[k]`` of the residual (``dx = (1 - g) A^-1 r``);
        returns (x, steps taken, GMRES iterations)."""
        calls = []

        def step(r, tau):
            g = gains[len(calls)]
            calls.append(tau)
            return (1.0 - g) * np.linalg.solve(A, r), 7
        x, it = jm._capacitance_refined(step, lambda v: A @ v, b, 1e-3)
        return x, len(calls), it
    # two good steps (0.1 each), then a poor one (0.9): kept, and the refinement stops
    x, n, it = run([0.1, 0.1, 0.9, 0.1])
    assert n == 3 and it == 21
    np.testing.assert_allclose(b - A @ x, 0.9 * 0.01 * b, rtol=1e-12)
    # a good step, then one that doubles the residual: undone, and the refinement stops
    x, n, _ = run([0.1, 2.0, 0.1])
    assert n == 2
    np.testing.assert_allclose(b - A @ x, 0.1 * b, rtol=1e-12)
    # good steps only: on to the tolerance asked (CAPACITANCE_MARGIN 1e-3 of |b|)
    x, n, _ = run([0.03] * jm.CAPACITANCE_REFINE)
    assert np.linalg.norm(b - A @ x) <= jm.CAPACITANCE_MARGIN * 1e-3 * np.linalg.norm(b)
    assert np.abs(x - x_true).max() <= 1e-4 * np.abs(x_true).max()
