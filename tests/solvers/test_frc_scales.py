"""The FRC scale estimate (:func:`jointsim.solvers.frc.frc_scales`).

Its resonance solve only needs an order of magnitude: where it converges it is the
plain Newton solve (oracle: :func:`~jointsim.solvers.hbm.solve_point` to the same
tolerance, and to 1e-12); where it cannot (the coupled lap joint in gross slip at
its stuck resonance, whose static position drifts metres along the free slip) it
gives up within two steps and the scale is the stuck estimate (oracle: the stuck
linear responses solved independently).
"""
from __future__ import annotations

import numpy as np
import pytest

from jointsim.analyses.hbm import _system
from jointsim.model import build_model
from jointsim.scene import load_scene
from jointsim.solvers import frc as H
from jointsim.solvers.modes import stuck_modes

from .._scenes import MODELS


def _resonances(system, w0, w1):
    """The stuck linear resonances [rad/s] inside the range."""
    lo, hi = sorted((w0, w1))
    return [2 * np.pi * f for f in stuck_modes(system.model, min(system.model.n_dof, 40))
            .frequency_hz if lo < 2 * np.pi * f < hi]


def _stuck_estimate(system, F, w0, w1):
    """max |z - z0| of the stuck responses at 9 frequencies and the resonances."""
    z0 = system.static_coordinates()
    res = _resonances(system, w0, w1)
    q = 0.0
    for w in list(np.linspace(w0, w1, 9)) + res:
        ev = system.evaluate(z0, w, F, wrt=())
        q = max(q, float(np.abs(np.linalg.solve(ev.J, -ev.R)).max()))
    return q, res


def test_resonance_solve_that_converges_is_the_plain_newton_solve():
    scene = load_scene(MODELS / "hbm" / "chain2_jenkins.toml")
    a = scene.analysis.hbm
    system = _system(build_model(scene), a, parallel=False)
    F = system.force_coefficients(0.2)
    z0 = system.static_coordinates()
    q_lin, res = _stuck_estimate(system, F, a.omega_start, a.omega_end)
    assert len(res) == 1
    ev = system.evaluate(z0, res[0], F, wrt=())
    start = z0 + np.linalg.solve(ev.J, -ev.R)
    rref = 1.0
    q = H._resonance_response(system, res[0], F, start, z0, rref, 1e-6, 10 * q_lin)
    plain = H.solve_point(system, res[0], F, z0=start, tol=1e-6, max_iter=15, rscale=rref)
    tight = H.solve_point(system, res[0], F, z0=start, tol=1e-12, rscale=rref)
    assert plain.convergence.success and tight.convergence.success
    assert q == float(np.abs(plain.z - z0).max())
    assert q == pytest.approx(float(np.abs(tight.z - z0).max()), rel=1e-6)
    # friction damps: the nonlinear response at the stuck resonance is below the stuck one
    assert q < q_lin


def test_gross_slip_resonance_solve_gives_up_early(coarse_model, monkeypatch):
    a = load_scene(MODELS / "lap_joint_nodes.toml").analysis.hbm
    system = _system(coarse_model, a, parallel=False)
    F = system.force_coefficients(2.0)
    z0 = system.static_coordinates()
    res = _resonances(system, a.omega_start, a.omega_end)
    assert len(res) == 1
    ev = system.evaluate(z0, res[0], F, wrt=())
    q_res = float(np.abs(np.linalg.solve(ev.J, -ev.R)).max())    # the stuck resonance
    calls = []
    evaluate = system.evaluate
    monkeypatch.setattr(system, "evaluate", lambda *x, **k: calls.append(1) or evaluate(*x, **k))
    n = 2                                   # the range's ends, below the resonance's q
    scale, _ = H.frc_scales(system, F, a.omega_start, a.omega_end, n=n)
    # the stuck estimate, after at most two Newton steps (with their line searches)
    assert scale[0] == pytest.approx(q_res, rel=1e-10)
    assert len(calls) - (n + len(res)) <= 1 + 2 * 6


def test_a_branch_stopped_at_max_points_is_not_diagnosed(monkeypatch):
    """A branch that ends at its ``max_points`` stops by the user's limit: its message
    says so, and the search for undamped resonances (eigen-analyses of the linearised
    systems, 13 s on 480 Gauss points) that explains a physical failure is not run."""
    import dataclasses

    import jointsim.analyses.hbm as ah

    def forbidden(*args, **kw):
        raise AssertionError("a max_points stop was diagnosed")
    monkeypatch.setattr(ah, "explain_branch_failure", forbidden)
    scene = load_scene(MODELS / "hbm" / "chain2_jenkins.toml")
    a = dataclasses.replace(scene.analysis.hbm, max_points=4)
    system = ah._system(build_model(scene), a)
    out = []
    conv = ah._run_branch(ah._BranchJob(0, a.force_scale[-1], None), system=system, a=a,
                          dof=0, want_aft=False, n_branches=1, on_record=out.append,
                          progress=False)
    assert not conv.success and conv.message.startswith("stopped at max_points = 4")
    assert len(out) == 4


def test_single_precision_inverses_only_in_the_branch_continuation(monkeypatch):
    """The harmonic stage may be in single precision only in an FRC branch's
    continuation (``PreconditionerCache.single_inverses``): not in its scales' and
    first point's solves, and not after it (the peak refinement, a next branch's
    set-up).  Round 33 allowed it everywhere, which cost the EPMC and the 480-point
    set-up several times their time (docs/hbm.md, "Round 34")."""
    import dataclasses

    import jointsim.analyses.hbm as ah
    scene = load_scene(MODELS / "hbm" / "chain2_jenkins.toml")
    a = dataclasses.replace(scene.analysis.hbm, max_points=3)
    system = ah._system(build_model(scene), a)
    seen = {}
    for name in ("frc_scales", "first_point", "continue_branch"):
        orig = getattr(ah, name)

        def spy(*args, _orig=orig, _name=name, **kw):
            seen[_name] = system.preconditioner.single_inverses
            return _orig(*args, **kw)
        monkeypatch.setattr(ah, name, spy)
    system.preconditioner.single_inverses = True          # left over: reset first
    ah._run_branch(ah._BranchJob(0, a.force_scale[-1], None), system=system, a=a, dof=0,
                   want_aft=False, n_branches=1, on_record=lambda rec: None,
                   progress=False)
    assert seen == {"frc_scales": False, "first_point": False, "continue_branch": True}
    assert system.preconditioner.single_inverses is False


def test_resonance_solve_with_loose_linear_solves_keeps_the_scale(monkeypatch):
    """The resonance solve's linear solves stop at ``RESONANCE_RTOL``, one preconditioner
    each, so that a large low-rank stage is solved through its capacitance system
    instead of truncated.  On the default lap joint (96 Gauss points, Krylov path) at
    force scale 2, where the solve converges, the scale equals the one with tight
    solves (the Jacobian's 1e-11) to 1e-9; at force scale 20 (gross slip: it gives up,
    the stuck estimate is kept) the loose solves build split stages (at
    force 2 some too) and the scale is the same.  The system's tolerance and cache are restored after."""
    import jointsim.solvers.preconditioner as pm
    from jointsim.solvers.gmres import KRYLOV_RTOL
    scene = load_scene(MODELS / "lap_joint.toml")
    a = scene.analysis.hbm
    system = _system(build_model(scene), a, parallel=False)
    assert system.krylov
    built = []
    init = pm.HarmonicPreconditioner.__init__

    def record(self, jac, *args, **kw):
        init(self, jac, *args, **kw)
        built.append((jac.rtol, self.lowrank is not None and self.lowrank.split))
    monkeypatch.setattr(pm.HarmonicPreconditioner, "__init__", record)
    loose = H.RESONANCE_RTOL
    assert loose is not None and loose > KRYLOV_RTOL
    for force, converges in ((2.0, True), (20.0, False)):
        F = system.force_coefficients(force)
        scales, kinds = {}, {}
        for rtol in (loose, None):
            monkeypatch.setattr(H, "RESONANCE_RTOL", rtol)
            built.clear()
            q = []
            solve = H._resonance_response
            monkeypatch.setattr(H, "_resonance_response", lambda *x: q.append(solve(*x)) or q[-1])
            scales[rtol] = H.frc_scales(system, F, a.omega_start, a.omega_end)[0][0]
            monkeypatch.setattr(H, "_resonance_response", solve)
            kinds[rtol] = list(built)
            assert (q[0] is not None) == converges
            assert system.krylov_rtol == KRYLOV_RTOL and not system.preconditioner.single_solve
            assert system.preconditioner.current is None or rtol is None
        assert scales[loose] == pytest.approx(scales[None], rel=1e-9)
        assert kinds[loose] and all(r == loose for r, _ in kinds[loose])
        assert all(r == KRYLOV_RTOL and not split for r, split in kinds[None])
        assert any(split for _, split in kinds[loose]) or converges


def test_scales_from_the_stuck_flexibility_equal_the_modes_and_lu_ones(monkeypatch):
    """Where the Krylov path's preconditioners make the stuck flexibility, ``frc_scales``
    takes the stuck resonances from its modes and the stuck responses from its solves
    (refined against ``J``) instead of ``stuck_modes`` and the blocks' LU: on the default
    lap joint (96 Gauss points) at force scale 2 the scales agree to 3e-8, the
    resonances in the range to 1e-7, and the stuck responses form no ``S_h``.

    The scales' difference is the eigen-decomposition's round-off on a structure whose
    soft suspension makes its stiffness's condition number about 1e11: 8.5e-9 with round
    41's reduced matrices, 9.9e-9 with round 42's (the same products, formed on one side
    of the diagonal, and the preload's Jacobian formed sparse)."""
    import jointsim.solvers.preconditioner as pm
    scene = load_scene(MODELS / "lap_joint.toml")
    a = scene.analysis.hbm
    system = _system(build_model(scene), a, parallel=False)
    fl = system.lin.flexibility
    assert system.krylov and fl is not None
    f_flex = np.sqrt(fl.lam[:40]) / (2 * np.pi)
    f_arpack = stuck_modes(system.model, 40).frequency_hz
    in_range = (2 * np.pi * f_arpack > a.omega_start) & (2 * np.pi * f_arpack < a.omega_end)
    assert in_range.any()
    assert np.abs(f_flex[in_range] / f_arpack[in_range] - 1).max() <= 1e-7
    F = system.force_coefficients(2.0)
    formed = []
    schur = system.lin.schur_low_rank_damping
    monkeypatch.setattr(system.lin, "schur_low_rank_damping",
                        lambda *x, **k: formed.append(1) or schur(*x, **k))
    monkeypatch.setattr(H, "_resonance_response", lambda *x: None)   # the stuck part only
    flex = H.frc_scales(system, F, a.omega_start, a.omega_end)[0][0]
    assert not formed
    monkeypatch.setattr(pm, "MODAL_STAGE", False)
    lu = H.frc_scales(system, F, a.omega_start, a.omega_end)[0][0]
    assert formed
    assert flex == pytest.approx(lu, rel=3e-8)
