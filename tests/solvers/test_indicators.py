"""Error indicators of HBM and EPMC points against the true error.

True error (:mod:`jointsim.solvers.indicators`): the relative error of the
retained harmonic coefficients against a converged refined solve of the same
point (same frequency / same modal amplitude) at H = 0..63 and N_t = 4096
(lumped) or H = 0..31, N_t = 2048 (FE joint), normalised by the retained
harmonics h >= 1 of the reference.  Its two parts are checked separately:
the truncation error is that of (H, N_ref) against the reference, the
aliasing error that of (H, N_t) against (H, N_ref).
"""
from __future__ import annotations

from dataclasses import astuple

import numpy as np
import pytest

from jointsim.model import build_model
from jointsim.scene import load_scene
from jointsim.solvers.condensation import dense_array
from jointsim.solvers.epmc import EPMCSystem
from jointsim.solvers.hbm import HBMSystem, solve_point
from jointsim.solvers import indicators
from jointsim.solvers.indicators import ErrorEstimator
from jointsim.solvers.modes import elastic_mode
from jointsim.solvers.newton import NewtonOptions, newton

from .._scenes import CHAIN2, COUPLED, FIXED, MODELS, NO_FULL, lap_scene

FOLD = MODELS / "hbm" / "chain2_friction_fold.toml"


def _point(model, H, nt, fs, w, z0=None):
    s = HBMSystem(model, tuple(range(H + 1)), nt)
    F = s.force_coefficients(fs)
    p = solve_point(s, w, F, z0=z0, tol=1e-12, max_iter=60)
    assert p.convergence.success, p.convergence.message
    return s, F, p


def _embed(s, z, H):
    """Contact coefficients of ``s`` into the harmonics 0..H (zeros above)."""
    out = np.zeros((2 * H + 1, s.n_r))
    out[:s.n_c] = np.asarray(z).reshape(s.n_c, s.n_r)
    return out.ravel()


def _rel(X, Xref, s):
    n = s.n_c
    return float(np.linalg.norm(X - Xref[:n]) / np.linalg.norm(Xref[:n][s.basis.hk > 0]))


def _check(est, true, what):
    """Each within a factor of 3, and the same order."""
    est, true = np.asarray(est), np.asarray(true)
    ratio = est / true
    assert np.all((ratio > 1 / 3) & (ratio < 3)), f"{what}: estimate/true = {ratio}"
    assert np.array_equal(np.argsort(est), np.argsort(true)), \
        f"{what}: order differs: estimates {est}, true {true}"


def _check_epmc_ladder(runs, ep_ref, y_ref, label):
    """Check each EPMC indicator (state, frequency, damping ratio) of ``runs``, a list
    of ``(system, epmc, y)`` at the same modal amplitude, against the true error from the
    reference point ``(ep_ref, y_ref)`` with :func:`_check`."""
    Xr = ep_ref.coefficients(y_ref)
    wr, zr = y_ref[-3], y_ref[-2] / (2 * y_ref[-3])
    est, true = {"X": [], "w": [], "z": []}, {"X": [], "w": [], "z": []}
    for s, ep, y in runs:
        ind = ErrorEstimator(s).epmc(ep, y)
        est["X"].append(ind.estimate)
        true["X"].append(_rel(ep.coefficients(y), Xr, s))
        est["w"].append(ind.frequency)
        true["w"].append(abs(y[-3] - wr) / wr)
        est["z"].append(ind.damping)
        true["z"].append(abs(y[-2] / (2 * y[-3]) - zr) / abs(zr))
    for k, what in (("X", "state"), ("w", "frequency"), ("z", "damping ratio")):
        _check(est[k], true[k], f"{label}: {what}")


class _Case:
    """A forced point: its refined solutions and indicators at several settings."""

    def __init__(self, model, fs, w, href, nref):
        self.model, self.fs, self.w, self.href, self.nref = model, fs, w, href, nref
        s, _, p = _point(model, 7, 128, fs, w)
        self.ref = _point(model, href, nref, fs, w, z0=_embed(s, p.z, href))[2].X

    def truncation(self, Hs):
        est, true = [], []
        for H in Hs:
            s, F, p = _point(self.model, H, self.nref, self.fs, self.w)
            est.append(ErrorEstimator(s).hbm(p.z, self.w, F, p.X).truncation)
            true.append(_rel(p.X, self.ref, s))
        return est, true

    def aliasing(self, H, nts):
        est, true = [], []
        fine = _point(self.model, H, self.nref, self.fs, self.w)[2].X
        for nt in nts:
            s, F, p = _point(self.model, H, nt, self.fs, self.w)
            est.append(ErrorEstimator(s).hbm(p.z, self.w, F, p.X).aliasing)
            true.append(_rel(p.X, fine, s))
        return est, true

    def total(self, settings):
        est, true = [], []
        for H, nt in settings:
            s, F, p = _point(self.model, H, nt, self.fs, self.w)
            est.append(ErrorEstimator(s).hbm(p.z, self.w, F, p.X).estimate)
            true.append(_rel(p.X, self.ref, s))
        return est, true


@pytest.fixture(scope="module")
def chain():
    """2-DOF Jenkins chain, force x 0.2 just above its peak (slipping)."""
    return _Case(build_model(load_scene(CHAIN2)), 0.2, 1.05, 63, 4096)


@pytest.fixture(scope="module")
def fold():
    """2-DOF coupled-normal friction fold scene, force x 0.1 at omega = 1.2."""
    return _Case(build_model(load_scene(FOLD)), 0.1, 1.2, 63, 4096)


def test_truncation_indicator_tracks_the_true_truncation_error(chain, fold):
    for case, name in ((chain, "chain"), (fold, "fold")):
        _check(*case.truncation((3, 5, 7, 11)), f"{name} truncation")


def test_aliasing_indicator_tracks_the_true_aliasing_error(chain, fold):
    _check(*chain.aliasing(7, (32, 128, 512)), "chain aliasing")
    _check(*fold.aliasing(7, (32, 128, 512)), "fold aliasing")


def test_error_estimate_tracks_the_true_error(chain, fold):
    _check(*chain.total(((3, 128), (7, 128), (15, 1024))), "chain total")
    _check(*fold.total(((7, 32), (3, 128), (15, 1024))), "fold total")


def _across_branch_point(s, z, w, F, ref, Fr):
    """Oracle of the error across the branch: the point of the refined branch (system
    ``ref``, forces ``Fr``) on the hyperplane through ``(z, w)`` normal to the branch of
    ``s`` there, in the coordinates relative to the point's vibration and frequency
    (dense Newton on the refined residual plus that hyperplane).  Returns
    ``(X_ref, w_ref)``."""
    zv = np.asarray(z).reshape(s.n_c, s.n_r)[s.basis.hk > 0]
    sz = float(np.linalg.norm(zv))
    ev = s.evaluate(z, w, F)
    A = np.column_stack([ev.J, ev.dR["omega"]]) * np.append(np.full(s.n_z, sz), w)
    t = np.linalg.svd(A)[2][-1]                   # the branch's direction, scaled
    row = np.zeros(ref.n_z + 1)
    row[:s.n_z] = t[:-1] / sz
    row[-1] = t[-1] / w
    z_start = np.zeros(ref.n_z)
    z_start[:s.n_z] = z

    def fun(y):
        J = np.zeros((ref.n_z + 1, ref.n_z + 1))
        e = ref.evaluate(y[:-1], y[-1], Fr, J_out=J[:-1, :-1])
        J[:-1, -1] = e.dR["omega"]
        J[-1] = row
        return np.append(e.R, row @ (y - np.append(z_start, w))), J, e

    res = newton(fun, np.append(z_start, w), NewtonOptions(1e-10, 60, line_search="decrease",
                                                             max_tries=8))
    if not res.success:                 # a kink of the refined laws stalls Newton
        return None, None
    return ref.reconstruct(res.x[:-1], res.x[-1], Fr), res.x[-1]


def test_error_across_the_branch_tracks_the_refined_branch(tmp_path):
    """Fold chain, force x 0.1, H = 0..3, N_t = 64, through its resonance and folds (241
    points, 181 of them with a fixed-frequency estimate above the run's error_tol 1e-2,
    up to 7.7): at every tenth of those and at the largest, the error across the branch
    (``error_curve``) is within a factor 4 of its true value, the distance to the refined
    branch (H = 0..15, N_t = 512) on the hyperplane normal to the branch, and about equal
    to it in the median.  Measured at the 180 of the 181 where the oracle's Newton
    converges: within a factor 3 at 175, median 0.95; 0.25 to 0.33 at five points near
    omega = 1.351, where the extended step changes which samples slip.  The
    fixed-frequency estimate is more than 100 times that true distance at the largest
    (1,150 times: the error at the same frequency, not the curve's)."""
    import h5py

    from jointsim.run import run_scene

    m = build_model(load_scene(FOLD))
    sc = load_scene(FOLD, ["analysis.hbm.harmonics=[0, 1, 2, 3]", "analysis.hbm.n_samples=64",
                           "analysis.hbm.omega_start=1.25", "analysis.hbm.omega_end=1.5",
                           "analysis.hbm.error_tol=1e-2"])
    out = tmp_path / "fold.h5"
    run_scene(sc, out, overwrite=True)
    with h5py.File(out, "r") as h5:
        g = h5["hbm"]
        q, om = g["q"][()], g["omega"][()]
        fixed, curve = g["error_estimate"][()], g["error_curve"][()]
        shift = g["error_curve_frequency"][()]
    solved = fixed > 1e-2
    assert np.all(curve[~solved] == fixed[~solved]) and np.all(shift[~solved] == 0.0)
    assert np.all(curve[solved] <= fixed[solved] * (1 + 1e-9))
    s = HBMSystem(m, tuple(range(4)), 64)
    ref = HBMSystem(m, tuple(range(16)), 512)
    F, Fr = s.force_coefficients(0.1), ref.force_coefficients(0.1)
    pts = np.flatnonzero(solved)
    assert pts.size >= 100
    pts = np.append(pts[::10], np.argmax(fixed))
    got = [(p,) + _across_branch_point(s, q[p], om[p], F, ref, Fr) for p in pts]
    got = [(p, Xr, wr) for p, Xr, wr in got if Xr is not None]
    assert len(got) >= 0.8 * pts.size
    pts = np.array([p for p, _, _ in got])
    true = np.array([_rel(s.reconstruct(q[p], om[p], F), Xr, s) for p, Xr, _ in got])
    true_shift = np.array([abs(wr - om[p]) / om[p] for p, _, wr in got])
    ratio = curve[pts] / true
    assert np.all((ratio > 1 / 4) & (ratio < 4)), (om[pts], curve[pts], true)
    assert 0.7 < np.median(ratio) < 1.4, ratio
    assert pts[-1] == np.argmax(fixed) and fixed[pts[-1]] / true[-1] > 100
    # the frequency shifts are of the same order (the hyperplane is the estimator's)
    assert np.median(shift[pts] / true_shift) == pytest.approx(1.0, rel=0.5)


def _with_and_without_linear_shortcut(monkeypatch, fn):
    """``fn()`` as it is, and with the linear-point shortcut off (the extended solve)."""
    short = fn()
    with monkeypatch.context() as mp:
        mp.setattr(indicators, "LINEAR_FORCE_TOL", -1.0)
        full = fn()
    return short, full


def test_a_stuck_point_has_a_negligible_error(monkeypatch):
    """Below the slip limit the joint is linear: no force tail, no aliasing.  The
    shortcut reports 0; the extended solve it saves gives round-off."""
    m = build_model(load_scene(CHAIN2))
    s, F, p = _point(m, 7, 128, 0.01, 1.0)
    est = ErrorEstimator(s)
    short, full = _with_and_without_linear_shortcut(
        monkeypatch, lambda: est.hbm(p.z, 1.0, F, p.X))
    assert short.estimate == 0.0 and short.force_tail < 1e-12
    assert full.estimate < 1e-12 and full.force_tail < 1e-12


@pytest.mark.parametrize("scene", [COUPLED, FIXED], ids=["coupled", "fixed"])
def test_fe_joint_linear_points_skip_the_extended_solve(scene, monkeypatch):
    """FE lap joint (coarse mesh, H = 0..7, N_t = 128).  At a stuck point (force x 0.02,
    below and at the stuck resonance) the shortcut's 0 stands for an extended solve
    that gives at most 1e-12 (round-off); at a slipping point (force x 2 near its
    peak) the shortcut is not taken and the indicators are unchanged.  The points are
    solved with exact Newton steps (forcing 0), so that their own residual is round-off
    too: with inexact ones the extended solve's aliasing step also corrects that
    residual (1.2e-10 at the stuck resonance, tolerance 1e-10)."""
    m = build_model(lap_scene(scene))
    s = HBMSystem(m, tuple(range(8)), 128, linear_solver="krylov")
    est = ErrorEstimator(s)
    for fs, w, stuck in ((0.02, 900.0, True), (0.02, 1029.0, True), (2.0, 1004.0, False)):
        F = s.force_coefficients(fs)
        p = solve_point(s, w, F, tol=1e-10, max_iter=60, forcing=0.0)
        assert p.convergence.success, p.convergence.message
        short, full = _with_and_without_linear_shortcut(
            monkeypatch, lambda: est.hbm(p.z, w, F, p.X))
        if stuck:
            assert short.estimate == 0.0 and full.estimate < 1e-12, (fs, w, full)
        else:
            assert full.estimate > 1e-4
            for name in ("truncation", "aliasing", "force_tail"):
                assert getattr(short, name) == pytest.approx(getattr(full, name), rel=1e-4)


def test_krylov_path_gives_the_direct_indicators():
    """The extended solve on the structured (GMRES) path equals the dense one."""
    m = build_model(load_scene(FOLD))
    s, F, p = _point(m, 5, 64, 0.1, 1.2)
    d = ErrorEstimator(s).hbm(p.z, 1.2, F, p.X)
    sk = HBMSystem(m, tuple(range(6)), 64, linear_solver="krylov")
    k = ErrorEstimator(sk).hbm(p.z, 1.2, F, p.X)
    assert sk.krylov and ErrorEstimator(sk).ext.krylov
    for name in ("truncation", "aliasing", "force_tail", "curve", "curve_truncation",
                 "curve_aliasing", "curve_frequency"):
        assert getattr(k, name) == pytest.approx(getattr(d, name), rel=1e-5)


def test_frc_indicators_through_the_capacitance_system(monkeypatch):
    """An FRC point's extended solve builds its preconditioner for that one solve
    (``single_solve``): a large low-rank stage is split (``I + L_r G`` kept by element
    blocks) and the solve goes
    through its capacitance system (``LOOSE_SPLIT_MIN``, forced here on the fold
    chain's small one; :meth:`~.HarmonicPreconditioner.solve_capacitance`, refined on
    the system).  The indicators equal the dense solve's to the GMRES tolerance's
    effect (``INDICATOR_RTOL``; measured 5e-5), also at this point near the fold,
    where they moved by 29 % when GMRES iterated on the whole system with this split
    as its preconditioner (before round 34)."""
    import jointsim.solvers.jacobian as jm
    import jointsim.solvers.preconditioner as pm
    m = build_model(load_scene(FOLD))
    s, F, p = _point(m, 5, 64, 0.1, 1.2)
    d = ErrorEstimator(s).hbm(p.z, 1.2, F, p.X)
    sizes, steps = [], []
    build = pm.HarmonicPreconditioner._lowrank
    refine = jm._capacitance_refined

    def spy(self):
        build(self)
        sizes.append(self.lowrank.split)

    def spy_refine(*args):
        steps.append(refine(*args))
        return steps[-1]
    monkeypatch.setattr(pm.HarmonicPreconditioner, "_lowrank", spy)
    monkeypatch.setattr(jm, "_capacitance_refined", spy_refine)
    sk = HBMSystem(m, tuple(range(6)), 64, linear_solver="krylov")
    ErrorEstimator(sk).hbm(p.z, 1.2, F, p.X)
    assert not sizes[-1] and not steps              # at most LOOSE_SPLIT_MIN: one LU
    monkeypatch.setattr(pm, "LOOSE_SPLIT_MIN", 0)
    est = ErrorEstimator(sk)
    k = est.hbm(p.z, 1.2, F, p.X)
    assert est.ext.preconditioner.single_solve and sizes[-1] and steps
    assert d.estimate > 1e-4
    for name in ("truncation", "aliasing", "force_tail", "curve", "curve_truncation",
                 "curve_aliasing"):
        assert getattr(k, name) == pytest.approx(getattr(d, name), rel=1e-3), name


def _fold_points():
    m = build_model(load_scene(FOLD))
    sk = HBMSystem(m, tuple(range(6)), 64, linear_solver="krylov")
    F = sk.force_coefficients(0.1)
    pts = [solve_point(sk, w, F, tol=1e-12, max_iter=60) for w in (1.2, 1.22)]
    assert all(p.convergence.success for p in pts)
    return sk, lambda est, i: est.hbm(pts[i].z, pts[i].omega, F, pts[i].X)


def _mode_points():
    m = build_model(load_scene(MODELS / "hbm" / "sdof_jenkins_epmc.toml"))
    s, ep, y1 = _mode_point(m, 7, 64, 1.5)
    y2 = _mode_point(m, 7, 64, 2.0, y1[:-1])[2]
    sk = HBMSystem(m, s.basis.harmonics, 64, linear_solver="krylov")
    epk = EPMCSystem(sk, ep.phi, ep.F)
    return sk, lambda est, i: est.epmc(epk, (y1, y2)[i])


@pytest.mark.parametrize("points", [_fold_points, _mode_points], ids=["hbm", "epmc"])
def test_a_point_builds_its_own_extended_preconditioner(points):
    """On the GMRES path a point's extended solve does not reuse the last point's
    preconditioner (``REUSE_ACROSS_POINTS``; on the lap joint the last point's cost 7 to
    20 iterations, more than a build): its indicators are those of the point alone, to
    the bit, with one build.  (Reused, the second point's solve here takes 4 to 12
    GMRES iterations and moves its indicators by up to 2e-3, relative.)  Fold chain,
    omega 1.2 then 1.22 (H = 0..5, N_t = 64); SDOF Jenkins EPMC, a = 1.5 then 2."""
    sk, indicators_of = points()
    alone = indicators_of(ErrorEstimator(sk), 1)
    est = ErrorEstimator(sk)
    assert est.ext.krylov
    indicators_of(est, 0)
    assert est.ext.stats.take()[2] == 1
    after = indicators_of(est, 1)
    assert est.ext.stats.take()[2] == 1
    np.testing.assert_array_equal(astuple(after), astuple(alone))     # NaN == NaN here


def _sdof_mode_builds(monkeypatch):
    """The SDOF Jenkins EPMC's points at a = 1.5 and 2 (H = 0..7, N_t = 64), the dense
    path's indicators of the second, the Krylov system and its EPMC system, and the
    list every :class:`~jointsim.solvers.preconditioner.HarmonicPreconditioner` built
    from then on is appended to.  Its extended Newton makes steps past the first (the
    lumped case's first step is in the quadratic region, where one residual evaluation
    ends it)."""
    import jointsim.solvers.preconditioner as pm
    monkeypatch.setattr(indicators, "EPMC_CHANGE_TOL", 1e-6)
    m = build_model(load_scene(MODELS / "hbm" / "sdof_jenkins_epmc.toml"))
    s, ep, y1 = _mode_point(m, 7, 64, 1.5)
    y2 = _mode_point(m, 7, 64, 2.0, y1[:-1])[2]
    d = ErrorEstimator(s).epmc(ep, y2)
    sk = HBMSystem(m, s.basis.harmonics, 64, linear_solver="krylov")
    built = []
    init = pm.HarmonicPreconditioner.__init__

    def spy(self, jac, shift=None, base=None):
        init(self, jac, shift, base)
        built.append(self)
    monkeypatch.setattr(pm.HarmonicPreconditioner, "__init__", spy)
    return y1, y2, d, sk, EPMCSystem(sk, ep.phi, ep.F), built


def test_an_epmc_points_newton_steps_share_its_harmonic_stage(monkeypatch):
    """The extended EPMC Newton steps of one point that build a preconditioner each (the
    refresh threshold forced to 0 here; on the 480-point lap joint three of a point's
    four builds) keep the first build's harmonic stage, with its shift, and build only
    their low-rank stages (``PreconditionerCache.share_within_point``).  The indicators
    equal those of the dense path to the GMRES tolerance's effect, and the next point
    starts with a full build of its own.  SDOF Jenkins EPMC at a = 2 (H = 0..7)."""
    import jointsim.solvers.preconditioner as pm
    y1, y2, d, sk, epk, built = _sdof_mode_builds(monkeypatch)

    def same_stage(P, Q):
        return all(a is b for a, b in ((P.Pinv, Q.Pinv), (P.Plu, Q.Plu), (P.Psolve, Q.Psolve)))
    est = ErrorEstimator(sk)
    est.ext.preconditioner.refresh_iterations = 0
    k = est.epmc(epk, y2)
    assert len(built) >= 3 and not built[0].partial and built[0].C2 is not None
    for P in built[1:]:
        assert P.partial and same_stage(P, built[0]) and P.C2 is built[0].C2
    assert d.estimate > 1e-6 and d.damping > 1e-4
    for name in ("truncation", "aliasing", "estimate", "frequency", "damping"):
        assert getattr(k, name) == pytest.approx(getattr(d, name), rel=1e-3), name
    first = built[0]
    built.clear()
    est.epmc(epk, y1)
    assert not built[0].partial and all(P.partial for P in built[1:])
    assert not same_stage(built[0], first)
    with pytest.raises(ValueError, match="shared only"):
        pm.HarmonicPreconditioner(first.jac, None, base=first)


def test_an_epmc_points_loose_bordered_stage_is_the_stuck_flexibility(monkeypatch):
    """The extended EPMC Newton steps (loose, bordered: a shifted preconditioner) take
    their harmonic stage from the stuck flexibility wherever it exists, not only near
    the stuck joint: the low-rank stage of a loose solve is never truncated, and the
    stage needs no ``S_h`` and no ``n_r^3`` LU (the 480-point lap joint's indicators in
    gross slip: docs/hbm.md, "Round 51"), and below ``SHIFTED_FLEX_MIN_ROWS`` rows too.
    Here the SDOF Jenkins EPMC at a = 2 (H = 0..7), where its one element slips (more
    than ``SOLVED_STAGE_COLUMNS n_r`` row blocks, which round 50 took for the inverted
    blocks): the indicators equal those of the dense path to 1e-6.  A correction above
    ``LOOSE_SPLIT_SHARED_MIN`` coordinates is split (``I + L_r G`` by element blocks,
    solved through its capacitance system) instead of one LU: to 1e-4."""
    import jointsim.solvers.preconditioner as pm
    y1, y2, d, sk, epk, built = _sdof_mode_builds(monkeypatch)
    assert sk.lin.flexibility is not None
    k = ErrorEstimator(sk).epmc(epk, y2)
    first = built[0]
    assert first.C2 is not None and first.modal and first.S is None
    assert first.lowrank is not None and not first.truncated
    assert d.estimate > 1e-6 and d.damping > 1e-4
    for name in ("truncation", "aliasing", "estimate", "frequency", "damping"):
        assert getattr(k, name) == pytest.approx(getattr(d, name), rel=1e-6), name
    assert not first.lowrank.split                  # one LU
    # a large correction (LOOSE_SPLIT_SHARED_MIN, lowered below this one's coordinates)
    # is split and solved through its capacitance system, to the same
    built.clear()
    monkeypatch.setattr(pm, "LOOSE_SPLIT_MIN", 0)
    monkeypatch.setattr(pm, "LOOSE_SPLIT_SHARED_MIN", 30)
    k = ErrorEstimator(sk).epmc(epk, y2)
    first = built[0]
    assert first.modal and first.capacitance_solves and not first.truncated
    assert first.lowrank.split and sum(first.lowrank.sizes) > 30
    for name in ("truncation", "aliasing", "estimate", "frequency", "damping"):
        assert getattr(k, name) == pytest.approx(getattr(d, name), rel=1e-4), name


W_NEAR_FOLD = 1.415


def test_error_across_the_branch_is_the_nearest_point_of_the_linearised_branch():
    """At a steep point of the fold chain (H = 0..3, N_t = 64, force x 0.1, omega = 1.415,
    near the fold of the lower branch) the across-branch parts are the minimum over ``t`` of ``||X(z + d + w t, omega + t) - X_0||^2 / ||X_0,vib||^2 + (t / omega)^2``,
    found here by a scalar minimisation of the exact reconstruction (the estimator takes
    ``t`` from the linearisation in ``t`` and a central difference in ``omega``), with the
    steps ``d`` and the direction ``w`` from a dense solve of the extended system."""
    from scipy.optimize import minimize_scalar

    m = build_model(load_scene(FOLD))
    s = HBMSystem(m, tuple(range(4)), 64)
    F = s.force_coefficients(0.1)
    est = ErrorEstimator(s)
    z = None
    for om in (1.40, 1.41, W_NEAR_FOLD):       # up the lower branch, near its fold (1.4156)
        p = solve_point(s, om, F, z0=z, tol=1e-12, max_iter=60)
        assert p.convergence.success, p.convergence.message
        z = p.z
    ind = est.hbm(p.z, W_NEAR_FOLD, F, p.X)
    assert ind.estimate > 5 * ind.curve > 0           # a steep point
    ext, nz = est.ext, s.n_z
    ze = est._embed(p.z.reshape(s.n_c, s.n_r)).ravel()
    ev = ext.evaluate(ze, W_NEAR_FOLD, est._embed(F))
    J = ev.J
    w = np.linalg.solve(J, -ev.dR["omega"])
    X0 = s.reconstruct(p.z, W_NEAR_FOLD, F)
    ref2 = np.sum(X0[s.basis.hk > 0] ** 2)
    for part, rows in (("curve_aliasing", slice(0, nz)), ("curve_truncation", slice(nz, None))):
        r = np.zeros_like(ev.R)
        r[rows] = ev.R[rows]
        d = np.linalg.solve(J, -r)

        def f(t):
            X = s.reconstruct(p.z + (d + w * t)[:nz], W_NEAR_FOLD + t, F)
            return np.sum((X - X0) ** 2) / ref2 + (t / W_NEAR_FOLD) ** 2

        t = minimize_scalar(f, bracket=(-1e-3, 1e-3), tol=1e-12).x
        X = s.reconstruct(p.z + (d + w * t)[:nz], W_NEAR_FOLD + t, F)
        true = np.linalg.norm(X - X0) / np.sqrt(ref2)
        assert getattr(ind, part) == pytest.approx(true, rel=1e-3), part


def test_extended_system_shares_the_condensation_of_the_point():
    """The extended system reuses the point's ``ReducedLinear`` (it does not depend on the
    harmonics; at 481 pairs a second one cost 9 s and a GB) and gives the indicators of
    one built afresh; a condensation of other coordinates is refused."""
    m = build_model(load_scene(FOLD))
    s, F, p = _point(m, 5, 64, 0.1, 1.2)
    est = ErrorEstimator(s)
    assert est.ext.lin is s.lin
    shared = est.hbm(p.z, 1.2, F, p.X)
    est.ext = HBMSystem(m, est.harmonics, est.n_samples, linear_solver="direct")
    assert est.ext.lin is not s.lin
    fresh = est.hbm(p.z, 1.2, F, p.X)
    for name in ("truncation", "aliasing", "force_tail"):
        assert getattr(shared, name) == pytest.approx(getattr(fresh, name), rel=1e-12)
    other = HBMSystem(build_model(load_scene(CHAIN2)), (0, 1), 16)   # 1 contact coordinate
    assert other.lin.n_r != s.lin.n_r
    with pytest.raises(ValueError, match="condenses"):
        HBMSystem(m, (0, 1), 16, lin=other.lin)


# -- EPMC ---------------------------------------------------------------------------
def _mode_point(model, H, nt, amp, y0=None):
    """EPMC solution at modal amplitude ``amp`` (Newton at fixed amplitude)."""
    s = HBMSystem(model, tuple(range(H + 1)), nt)
    em = elastic_mode(model, 1, None)
    ep = EPMCSystem(s, em.phi, s.force_coefficients(0.0))
    lam = np.log10(amp)
    if y0 is None:
        Q = np.zeros((s.n_c, s.n_r))
        Q[s.basis.index[1][0]] = s.T @ em.phi
        xi0 = float(em.phi @ dense_array(model.C) @ em.phi)
        y0 = np.concatenate([Q.ravel(), [em.omega, xi0]])

    def fun(x):
        R, J, ev = ep.fun(np.append(x, lam))
        return R, J[:, :-1], ev

    res = newton(fun, y0, NewtonOptions(1e-12, 80, line_search="decrease", max_tries=8))
    assert res.success, res.message
    return s, ep, np.append(res.x, lam)


@pytest.mark.parametrize("amp", [1.5, 5.0])
def test_epmc_indicators_track_the_true_error(amp):
    """SDOF Jenkins oscillator in microslip and macroslip: state, frequency, damping."""
    m = build_model(load_scene(MODELS / "hbm" / "sdof_jenkins_epmc.toml"))
    s7, _, y7 = _mode_point(m, 7, 128, amp)
    nz = s7.n_z
    _, epr, yr = _mode_point(m, 63, 4096, amp, np.append(_embed(s7, y7[:nz], 63),
                                                          y7[nz:nz + 2]))
    runs = [_mode_point(m, H, nt, amp) for H, nt in ((3, 128), (7, 32), (7, 512))]
    _check_epmc_ladder(runs, epr, yr, f"epmc at a = {amp}")


def test_epmc_stuck_point_skips_the_extended_solve(monkeypatch):
    """SDOF Jenkins oscillator below its slip amplitude (0.8): the mode is linear; the
    shortcut's zeros stand for an extended Newton solve that changes nothing beyond
    round-off."""
    m = build_model(load_scene(MODELS / "hbm" / "sdof_jenkins_epmc.toml"))
    s, ep, y = _mode_point(m, 7, 128, 0.5)
    est = ErrorEstimator(s)
    short, full = _with_and_without_linear_shortcut(monkeypatch, lambda: est.epmc(ep, y))
    assert (short.estimate, short.frequency, short.damping) == (0.0, 0.0, 0.0)
    assert full.estimate < 1e-12 and full.frequency < 1e-12


# -- the FE joint ------------------------------------------------------------------------
@pytest.mark.slow
def test_fe_joint_error_estimate_tracks_the_true_error():
    """Fixed-N lap joint on its default 25-pair mesh, 20 N at 1000 rad/s (microslip, near
    the peak); reference H = 0..63, Nt = 4096.

    Measured (README): true / estimate 6.8e-3 / 5.9e-3 (H = 3, Nt = 512), 1.08e-3 /
    9.8e-4 (H = 7, Nt = 128), 9.2e-4 / 7.4e-4 (H = 7, Nt = 512).  The true error is not
    monotone in H at this point: H = 5 (2.0e-4) and H = 11 (6.3e-4) are closer to the
    reference than H = 7, and there the estimate is 4.2x and 5.8x too high.
    """
    m = build_model(load_scene(FIXED, NO_FULL))
    case = _Case(m, 2.0, 1000.0, 63, 4096)
    _check(*case.total(((3, 512), (7, 128), (7, 512))), "FE total")


@pytest.mark.slow
def test_fe_joint_aliasing_indicator_tracks_the_true_aliasing_error():
    """Fixed-N lap joint, coarse mesh, 200 N at 960 rad/s (microslip), H = 0..5: the error
    of Nt = 16, 32, 128 against Nt = 2048 (measured 1.2e-2, 6.3e-3, 4.1e-4; estimates
    7.5e-3, 6.0e-3, 4.6e-4; Nt = 64, 3.0e-4 / 4.2e-4, also ranks right)."""
    m = build_model(lap_scene(FIXED))
    case = _Case.__new__(_Case)
    case.model, case.fs, case.w, case.nref = m, 20.0, 960.0, 2048
    _check(*case.aliasing(5, (16, 32, 128)), "FE aliasing")


def _fe_mode_point(model, em, H, nt, lam, y0=None, steps=6):
    """EPMC solution of the FE joint at ``log10 a = lam``: Newton at fixed amplitude,
    from the linear mode at a = 1e-5 in ``steps`` amplitudes, or from ``y0``
    (``(zh, omega, xi)``) in one; residual scaled as the EPMC runner scales it."""
    from jointsim.analyses.epmc import _scales
    s = HBMSystem(model, tuple(range(H + 1)), nt, linear_solver="direct")
    ep = EPMCSystem(s, em.phi, s.force_coefficients(0.0))
    if y0 is None:
        Q = np.zeros((s.n_c, s.n_r))
        Q[s.basis.index[1][0]] = s.T @ em.phi
        y0 = np.concatenate([Q.ravel(), [em.omega, float(em.phi @ dense_array(model.C)
                                                          @ em.phi)]])
        lams = np.linspace(-5.0, lam, steps)
    else:
        lams = [lam]
    _, rscale = _scales(ep, np.append(y0, lams[0]), em.omega)

    def measure(R, _ev):
        return max(np.abs(R[:-2]).max() / rscale, np.abs(R[-2:]).max())
    for lt in lams:
        def fun(x, lt=lt):
            R, J, ev = ep.fun(np.append(x, lt))
            return R, J[:, :-1], ev
        res = newton(fun, y0, NewtonOptions(1e-11, 80, line_search="decrease", max_tries=8),
                     measure=measure)
        assert res.success, f"H = {H}, Nt = {nt}, log10 a = {lt}: {res.message}"
        y0 = res.x
    return s, ep, np.append(y0, lam)


def _fe_epmc_check(scene, lam, settings, href=31, nref=2048):
    """EPMC indicators (state, frequency, damping ratio) of the FE joint at ``settings``
    against a refined solve at the same amplitude (H = 0..href, Nt = nref)."""
    model = build_model(scene)
    em = elastic_mode(model, 1, scene.analysis.epmc.rigid_cutoff_hz)
    s7, _, y7 = _fe_mode_point(model, em, 7, 128, lam)
    nz = s7.n_z
    _, epr, yr = _fe_mode_point(model, em, href, nref, lam,
                                np.append(_embed(s7, y7[:nz], href), y7[nz:nz + 2]))
    Q7 = y7[:nz].reshape(s7.n_c, s7.n_r)
    runs = []
    for H, nt in settings:
        g = _embed(s7, y7[:nz], H) if H >= 7 else Q7[:2 * H + 1].ravel()
        runs.append(_fe_mode_point(model, em, H, nt, lam, np.append(g, y7[nz:nz + 2])))
    _check_epmc_ladder(runs, epr, yr, f"FE epmc at log10 a = {lam}")


@pytest.mark.slow
def test_fe_joint_epmc_indicators_track_the_true_error_coupled_n():
    """Coupled-N lap joint, coarse mesh, a = 10^-3.5 (clapping microslip); reference
    H = 0..31, Nt = 2048 (README "How accurate is a point?").  Measured true / estimate:
    state 3.95e-3 / 3.06e-3, 2.25e-3 / 1.85e-3, 2.31e-3 / 1.90e-3; frequency 5.88e-3 /
    3.77e-3, 1.17e-3 / 6.15e-4, 2.01e-3 / 1.40e-3; damping ratio 0.308 / 0.255, 0.217 /
    0.172, 1.73e-2 / 3.69e-2 (H = 3, Nt = 128; H = 7, Nt = 32; H = 7, Nt = 128).  The
    linear step alone (``max_iter=1``) gave 4.32e-3 for the frequency and 0.31 for the
    damping at H = 7, Nt = 128 (2x and 18x too high)."""
    _fe_epmc_check(lap_scene(COUPLED, ("modes", "epmc"), NO_FULL), -3.5,
                   ((3, 128), (7, 32), (7, 128)))


@pytest.mark.slow
def test_fe_joint_epmc_indicators_track_the_true_error_fixed_n():
    """Fixed-N lap joint, coarse mesh, a = 1e-3 (microslip, damping ratio 1.3 %);
    reference H = 0..31, Nt = 2048.  Measured true / estimate: state 9.1e-5 / 6.8e-5,
    1.51e-4 / 1.53e-4, 1.07e-4 / 1.04e-4; frequency 1.66e-4 / 1.09e-4, 2.74e-4 /
    2.82e-4, 4.8e-5 / 6.7e-5; damping ratio 1.48e-2 / 9.0e-3, 2.14e-2 / 2.26e-2,
    5.1e-3 / 6.9e-3 (H = 3, 5, 7 at Nt = 128: the true error is not monotone in H,
    and the estimates follow it)."""
    _fe_epmc_check(lap_scene(FIXED, ("modes", "epmc"), NO_FULL), -3.0,
                   ((3, 128), (5, 128), (7, 128)))


# -- in the result file, info, figures and warnings --------------------------------------
def test_runs_store_show_mark_and_warn(tmp_path, caplog):
    """An FRC and an EPMC run write error_* per point (unit, doc), info shows them, the
    figures mark the points above tolerance, and each branch warns once."""
    import logging

    import h5py

    from jointsim.post.hbm_plots import error_flags, plot_epmc, plot_frc
    from jointsim.post.tables import info_text
    from jointsim.run import run_scene

    sc = load_scene(CHAIN2, ["analysis.hbm.force_scale=[0.05, 0.2]", "analysis.hbm.workers=1",
                             "analysis.hbm.omega_start=0.95", "analysis.hbm.omega_end=1.1",
                             "analysis.hbm.error_tol=1e-4"])
    out = tmp_path / "frc.h5"
    with caplog.at_level(logging.WARNING, logger="jointsim.solvers.indicators"):
        run_scene(sc, out, overwrite=True)
    warned = [r for r in caplog.records if "error_tol" in r.getMessage()]
    with h5py.File(out, "r") as h5:
        g = h5["hbm"]
        n = g["omega"].shape[0]
        for k in ("error_estimate", "error_truncation", "error_aliasing", "error_force_tail",
                  "error_curve", "error_curve_frequency"):
            assert g[k].shape == (n,) and g[k].attrs["unit"] == "1" and g[k].attrs["doc"]
        e = g["error_estimate"][()]
        assert np.all(np.isfinite(e)) and np.allclose(
            e, g["error_truncation"][()] + g["error_aliasing"][()])
        c = g["error_curve"][()]        # solved above the tolerance only, and at most e
        assert np.all(c[e <= 1e-4] == e[e <= 1e-4]) and np.all(c <= e * (1 + 1e-9))
        bad = error_flags(g)
        above = {int(b) for b in np.unique(g["branch"][()][bad])}
        assert len(warned) == len(above) >= 1      # once per branch above tolerance
        assert plot_frc(h5, tmp_path)
    text = info_text(out)
    assert "error estimate up to" in text and "points above error_tol = 0.0001" in text

    sc = load_scene(MODELS / "hbm" / "sdof_jenkins_epmc.toml",
                    ["analysis.epmc.log10_amplitude_end=0.5", "analysis.epmc.error_tol=1e-3"])
    out = tmp_path / "epmc.h5"
    run_scene(sc, out, overwrite=True)
    with h5py.File(out, "r") as h5:
        g = h5["epmc"]
        for k in ("error_estimate", "error_frequency", "error_damping"):
            assert g[k].shape == g["omega"].shape and g[k].attrs["doc"]
        assert plot_epmc(h5, tmp_path)
    assert "backbone: error estimate up to" in info_text(out)


class _ScalarEPMC:
    """An extended EPMC system of one structural row, ``atan(z - c)``, and two linear rows
    (frequency and self-excitation follow ``z``): Newton's method on ``atan`` converges
    from ``|z - c| < 1.39`` and diverges, alternating, beyond.  Counts its Jacobians."""

    def __init__(self, c):
        self.c, self.jacobians = c, 0
        self.s = type("S", (), {"n_z": 1})()

    def residual(self, y):
        z, w, xi, _ = y
        return np.array([np.arctan(z - self.c), w - 1.0 - 0.1 * z, xi - 0.2 - 0.05 * z])

    def fun(self, y):
        self.jacobians += 1
        J = np.array([[1.0 / (1.0 + (y[0] - self.c) ** 2), 0, 0, 0],
                      [-0.1, 1, 0, 0], [-0.05, 0, 1, 0]])
        return self.residual(y), J, None


@pytest.mark.parametrize("start, settles", [(0.9, True), (1.6, False)])
def test_extended_epmc_newton_gives_up_when_its_residual_stops_falling(start, settles):
    """The extended EPMC Newton of the error indicators settles where Newton converges
    (``atan`` from 0.9: its change from the point is the root's to ``EPMC_CHANGE_TOL``),
    and where it diverges (from 1.6, the residual growing at every step) it gives up
    after ``EPMC_STALL`` steps without a 10 % fall of its best residual, not after
    ``EPMC_MAX_ITER``: the first step is then reported."""
    c = 2.0
    epx = _ScalarEPMC(c)
    x0 = np.array([c - 3.0, 1.0 + 0.1 * (c - 3.0), 0.2 + 0.05 * (c - 3.0)])  # the point
    z1 = c - start
    x1 = np.array([z1, 1.0 + 0.1 * z1, 0.2 + 0.05 * z1])                       # its first step
    sol = ErrorEstimator._epmc_newton(epx, x0, x1, 0.0, indicators.EPMC_MAX_ITER, 1.0)
    if settles:
        assert sol is not None
        assert abs(sol[0] - c) <= indicators.EPMC_CHANGE_TOL * abs(c - x0[0])
        assert abs(sol[1] - (1.0 + 0.1 * sol[0])) <= 1e-12       # the linear rows hold
    else:
        assert sol is None
        assert epx.jacobians == 1 + indicators.EPMC_STALL < indicators.EPMC_MAX_ITER
