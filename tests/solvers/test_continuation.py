"""Pseudo-arclength continuation (:mod:`jointsim.solvers.continuation`) on analytic curves."""
import numpy as np
import pytest

from jointsim.results import NON_FINITE, NOT_CONVERGED, STEP_TOO_SMALL
from jointsim.solvers.continuation import Continuation, continue_branch

# Duffing oscillator x'' + 2 zeta x' + x + gamma x^3 = F cos(w t), first harmonic:
# a^2 ((1 - w^2 + 3/4 gamma a^2)^2 + (2 zeta w)^2) = F^2, a fold pair for hardening.
ZETA, GAMMA, FORCE = 0.02, 1.0, 0.1


def duffing(y):
    """Residual (1,) and Jacobian (1, 2) of the Duffing amplitude curve in (a, w)."""
    a, w = y
    d = 1.0 - w * w + 0.75 * GAMMA * a * a
    c = 2.0 * ZETA * w
    R = a * a * (d * d + c * c) - FORCE ** 2
    dRda = 2.0 * a * (d * d + c * c) + a * a * 2.0 * d * 1.5 * GAMMA * a
    dRdw = a * a * (2.0 * d * (-2.0 * w) + 2.0 * c * 2.0 * ZETA)
    return np.array([R]), np.array([[dRda, dRdw]]), None


SETTINGS = dict(scale=np.ones(2), rscale=FORCE ** 2, step=0.02, step_min=1e-8,
                step_max=0.05, max_points=2000, tol=1e-12)


def duffing_start(w0=0.5):
    """The (single) solution at ``w0`` below the folds, as a start point."""
    a = FORCE / (1.0 - w0 * w0)
    return np.array([a, w0])


def test_duffing_folds_are_passed():
    """The hardening Duffing curve from w = 0.5 to 2.5: two turning points are passed,
    every point lies on the curve, and the branch closes exactly at w = 2.5."""
    br = continue_branch(duffing, duffing_start(), 2.5, progress=False, **SETTINGS)
    assert br.convergence.success and "reached" in br.convergence.message
    a, w = br.y[:, 0], br.y[:, 1]
    R = np.array([duffing(y)[0][0] for y in br.y])
    assert np.abs(R).max() <= 1e-12 * FORCE ** 2 * 10
    turns = np.flatnonzero(np.diff(np.sign(np.diff(w))) != 0)
    assert turns.size == 2
    # the peak: a = F / (2 zeta w) on the backbone w^2 = 1 + 3/4 gamma a^2
    a_pk = a.max()
    w_pk = w[np.argmax(a)]
    assert a_pk == pytest.approx(FORCE / (2 * ZETA * w_pk), rel=1e-3)
    assert w_pk ** 2 == pytest.approx(1.0 + 0.75 * GAMMA * a_pk ** 2, rel=1e-3)
    assert w[-1] == 2.5 and len(br.tangents) == a.size


def test_circle_turns_back_through_the_start():
    """R = z^2 + lam^2 - 1 from lam = -0.8 towards 2: the turning point at lam = 1 is
    passed and the branch leaves the range back through lam = -0.8."""
    def fun(y):
        z, lam = y
        return np.array([z * z + lam * lam - 1.0]), np.array([[2 * z, 2 * lam]]), None

    cont = Continuation(fun, np.array([0.6, -0.8]), 2.0, scale=np.ones(2), rscale=1.0,
                        step=0.05, step_min=1e-8, step_max=0.1, max_points=500, tol=1e-12)
    while cont.status == "running":
        cont.step()
    assert cont.status == "finished" and "turned back" in cont.message
    y = np.array(cont.points)
    assert np.abs(y[:, 0] ** 2 + y[:, 1] ** 2 - 1).max() <= 1e-12
    assert y[:, 1].max() == pytest.approx(1.0, abs=1e-2) and y[:, 0].min() < -0.5
    assert y[-1, 1] < -0.8


def _circle(y):
    z, lam = y
    return np.array([z * z + lam * lam - 1.0]), np.array([[2 * z, 2 * lam]]), None


def test_a_bending_branch_closes_at_the_end_without_tiny_steps(monkeypatch):
    """z^2 + lam^2 = 1 from lam = -0.8 to 0.95, before its turning point: the tangent
    overestimates what each step gains in lam, so the step aimed just past the end lands
    short of it.  That point is closed at lam = 0.95 (on the curve), with no extra points
    a hair short of the end (END_SHORT = 0 gives 0.9476, 0.94998, 0.95).  When the
    closing solve fails, the short point is kept and the branch goes on to the end."""
    import jointsim.solvers.continuation as cmod

    def run():
        cont = Continuation(_circle, np.array([0.6, -0.8]), 0.95, scale=np.ones(2),
                            rscale=1.0, step=0.05, step_min=1e-8, step_max=0.1,
                            max_points=500, tol=1e-12)
        while cont.status == "running":
            cont.step()
        assert cont.status == "finished" and "reached lam = 0.95" in cont.message
        y = np.array(cont.points)
        assert np.abs(y[:, 0] ** 2 + y[:, 1] ** 2 - 1).max() <= 1e-12
        assert y[-1, 1] == 0.95
        return y[:, 1]

    lam = run()
    assert 0.95 - lam[-2] > 0.02 and np.all(np.diff(lam) > 0)
    monkeypatch.setattr(cmod, "END_SHORT", 0.0)
    old = run()
    assert old.size == lam.size + 2 and 0.95 - old[-2] < 1e-4

    monkeypatch.setattr(cmod, "END_SHORT", 0.1)
    real, calls = Continuation._corrector_fixed, []

    def fail_first(self, yh, lam_h):
        """The fixed-lam corrector, failing its first solve at the end."""
        out = real(self, yh, lam_h)
        if lam_h != 0.95:
            return out
        calls.append(lam_h)
        return out[:-1] + (len(calls) > 1 and out[-1],)
    monkeypatch.setattr(Continuation, "_corrector_fixed", fail_first)
    kept = run()
    assert len(calls) == 2 and kept.size == lam.size + 1
    assert kept[-3] == lam[-2] and kept[-3] < kept[-2] < 0.95


def test_step_by_hand_equals_continue_branch():
    """Driving the stepper by hand gives the same points, bit for bit."""
    seen = []
    br = continue_branch(duffing, duffing_start(), 2.5, progress=False,
                         on_point=lambda i, y, info: seen.append((i, y.copy(), info.step)),
                         **SETTINGS)
    cont = Continuation(duffing, duffing_start(), 2.5, **SETTINGS)
    messages = []
    while cont.status == "running":
        messages.append(cont.step())
    mine = cont.branch
    assert np.array_equal(mine.y, br.y)
    assert np.array_equal(mine.step, br.step) and np.array_equal(mine.iterations,
                                                                 br.iterations)
    assert mine.convergence == br.convergence
    assert [s[0] for s in seen] == list(range(br.y.shape[0]))
    assert np.array_equal(np.array([s[1] for s in seen]), br.y)
    # step() answers None while the branch goes on, the reason when it ends
    assert all(m is None for m in messages[:-1]) and messages[-1] == cont.message
    assert cont.n_points == br.y.shape[0] and cont.nfev > cont.n_points
    with pytest.raises(RuntimeError):
        cont.step()


@pytest.mark.parametrize("failures, tried", [(1, [1.0, 4.0]), (2, [1.0, 4.0, 0.5])])
def test_a_failed_corrector_tries_one_longer_step_then_halves(failures, tried):
    """The first ``failures`` correctors of a step fail (on purpose): the step is retried
    once 4 times longer (a kink is passed by landing beyond it), then halved; the point
    is accepted at the last length tried.  (A 16 times longer try used to follow the 4
    times longer one: round 19, docs/hbm.md.)"""
    cont = Continuation(duffing, duffing_start(), 2.5, **dict(SETTINGS, step_max=0.5))
    cont.step()
    h, correct, calls = cont.h, cont._correct, []

    def failing(yk, t, hj, jump_limit=None):
        calls.append(hj)
        got = correct(yk, t, hj, jump_limit)
        return (False,) + got[1:] if len(calls) <= failures else got
    cont._correct = failing
    assert cont.step() is None
    np.testing.assert_allclose(np.array(calls) / h, tried, rtol=1e-12)
    assert cont.infos[-1].step == pytest.approx(tried[-1] * h, rel=1e-12)
    assert np.abs(duffing(cont.points[-1])[0]).max() <= SETTINGS["tol"] * FORCE ** 2


def test_failing_corrector_shrinks_the_step_and_stops_with_a_message():
    """Past lam = 0.5 the residual is not finite: the step shrinks below step_min, the
    branch keeps its points and says why."""
    def fun(y):
        z, lam = y
        if lam > 0.5:
            return np.array([np.nan]), np.array([[np.nan, np.nan]]), None
        return np.array([z - lam ** 2]), np.array([[1.0, -2 * lam]]), None

    cont = Continuation(fun, np.array([0.0, 0.0]), 1.0, scale=np.ones(2), rscale=1.0,
                        step=0.05, step_min=1e-5, step_max=0.1, max_points=500, tol=1e-12)
    steps = []
    while cont.status == "running":
        steps.append(cont.h)
        cont.step()
    assert cont.status == "failed"
    assert cont.convergence.status in (STEP_TOO_SMALL, NON_FINITE)
    assert "step_min" in cont.message and not cont.convergence.success
    assert cont.h < 1e-5 < max(steps) and cont.n_failed >= 10
    br = cont.branch
    assert br.y.shape[0] == cont.n_points >= 5
    assert 0.49 < br.y[-1, 1] <= 0.5
    assert np.abs(br.y[:, 0] - br.y[:, 1] ** 2).max() <= 1e-12


def test_first_point_that_does_not_converge_ends_the_branch():
    def fun(y):
        return np.array([y[0] ** 2 + 1.0]), np.array([[2 * y[0], 0.0]]), None

    cont = Continuation(fun, np.array([0.3, 0.0]), 1.0, scale=np.ones(2), rscale=1.0,
                        step=0.1, step_min=1e-6, step_max=0.1, max_points=10, tol=1e-12,
                        max_iter=8)
    assert cont.status == "failed" and cont.n_points == 0
    assert cont.convergence.status == NOT_CONVERGED and "first point" in cont.message
    assert cont.branch.y.shape == (0, 2)


def test_max_points_stops_the_branch():
    br = continue_branch(duffing, duffing_start(), 2.5, progress=False,
                         **dict(SETTINGS, max_points=7))
    assert br.y.shape[0] == 7
    assert not br.convergence.success and "max_points" in br.convergence.message


def _asymptote(y):
    """The curve lam = 1 - exp(-z): it approaches lam = 1 and never reaches it."""
    z, lam = y
    return np.array([lam - 1.0 + np.exp(-z)]), np.array([[-np.exp(-z), 1.0]]), None


@pytest.mark.parametrize("stall", [None, (20, 1e-4)])
def test_a_branch_that_stalls_in_lam_stops_and_says_so(stall):
    """Towards lam_end = 2 the branch runs along z while lam creeps up to 1.  Without
    ``lam_stall`` it goes on to max_points; with (20, 1e-4) it stops at the first point
    whose last 20 points advanced lam by less than 2e-4 (1e-4 of the range 2), keeping
    every point it found."""
    br = continue_branch(_asymptote, np.array([0.0, 0.0]), 2.0, scale=np.ones(2), rscale=1.0,
                         step=0.1, step_min=1e-8, step_max=0.5, max_points=400, tol=1e-12,
                         progress=False, lam_stall=stall)
    assert not br.convergence.success
    lam = br.y[:, -1]
    assert np.allclose(lam, 1.0 - np.exp(-br.y[:, 0]), atol=1e-11)
    if stall is None:
        assert len(br.y) == 400 and "max_points" in br.convergence.message
    else:
        assert "stalls" in br.convergence.message and len(br.y) < 400
        assert lam[-1] - lam[-21] < 2e-4 <= lam[-2] - lam[-22]
