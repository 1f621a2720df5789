"""Hypothesis properties of the contact laws and of the Masing check."""
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from jointsim.contact import tangential_law
from jointsim.masing import check_loops
from jointsim.scene import Joint
from jointsim.solvers.prescribed import march_prescribed

from .. import _reference as ref

# example count and deadline from the hypothesis profile (tests/conftest.py)
SETTINGS = settings(suppress_health_check=[HealthCheck.too_slow])

LAWS = [("jenkins", "anchor"), ("jenkins", "scaled"), ("iwan4", "anchor"), ("iwan4", "scaled")]


def make_law(name, reversal, kt=1.0, mu=0.2, n_sliders=12):
    j = Joint(law=name, reversal=reversal, mu=mu, kt=kt, chi=-0.4, beta=0.3,
              n_sliders=n_sliders)
    return tangential_law(name, reversal, j, [1.0])


@st.composite
def periodic_inputs(draw, n=96, varying_N=True, separating=False):
    """One period of a random multi-harmonic path and normal load."""
    t = 2 * np.pi * np.arange(n) / n
    H = draw(st.integers(1, 5))
    cu = draw(st.lists(st.floats(-1, 1), min_size=2 * H, max_size=2 * H))
    u = sum(cu[2 * h] * np.cos((h + 1) * t) + cu[2 * h + 1] * np.sin((h + 1) * t)
            for h in range(H))
    N0 = draw(st.floats(1.0, 5.0))
    N = np.full(n, N0)
    if varying_N:
        cn = draw(st.lists(st.floats(-1, 1), min_size=4, max_size=4))
        N = N + N0 * (0.4 * cn[0] * np.cos(t) + 0.4 * cn[1] * np.sin(t)
                      + 0.4 * cn[2] * np.cos(2 * t) + 0.4 * cn[3] * np.sin(2 * t))
    if separating:
        N = N - N0 * draw(st.floats(0.3, 1.0))
    return u, N


def march_periods(law, u, N, periods=4):
    n = u.size
    U = np.tile(u, periods)[None, :]
    Nn = np.tile(N, periods)[None, :]
    return march_prescribed(U, Nn, law, n, 1.0)


@SETTINGS
@given(periodic_inputs(separating=True), st.sampled_from(LAWS))
def test_force_within_slip_limit_and_zero_while_separated(inputs, law_spec):
    u, N = inputs
    law = make_law(*law_spec)
    res = march_periods(law, u, N)
    limit = law.slip_force(res.N)
    assert np.all(np.abs(res.f) <= limit * (1 + 1e-12) + 1e-15)
    assert np.all(res.f[res.N <= 0.0] == 0.0)


@SETTINGS
@given(periodic_inputs(separating=True), st.sampled_from(["jenkins", "iwan4"]))
def test_dissipation_per_closed_loop_is_nonnegative(inputs, name):
    """Physical (anchor) laws dissipate on every steady closed loop."""
    u, N = inputs
    law = make_law(name, "anchor")
    res = march_periods(law, u, N)
    u1, f1, _ = res.last_period()
    # stick and slip are exact at the samples; the trapezoidal area is only off on
    # segments that switch, by at most kt du^2 each
    slack = law.kt[0] * np.max(np.diff(np.append(u1[0], u1[0, 0])) ** 2) * u1.shape[1]
    assert ref.loop_dissipation(u1[0], f1[0]) >= -slack


@SETTINGS
@given(periodic_inputs(varying_N=False), st.sampled_from(["jenkins", "iwan4"]))
def test_scaled_equals_anchor_at_constant_normal_load(inputs, name):
    """With N constant, condition 5 changes nothing: both reversal rules agree."""
    u, N = inputs
    a = march_periods(make_law(name, "anchor"), u, N)
    s = march_periods(make_law(name, "scaled"), u, N)
    np.testing.assert_allclose(a.f, s.f, rtol=1e-12, atol=1e-13)


@SETTINGS
@given(periodic_inputs(separating=True), st.sampled_from(LAWS),
       st.lists(st.integers(0, 95), min_size=1, max_size=10))
def test_rate_independence_dwell(inputs, law_spec, where):
    """Holding u and N still for a while (re-timing the path) changes no force."""
    u, N = inputs
    law = make_law(*law_spec)
    base = march_periods(law, u, N, periods=2)
    reps = np.ones(u.size, dtype=int)
    reps[where] += 3
    slow = march_prescribed(np.repeat(np.tile(u, 2), np.tile(reps, 2))[None, :],
                            np.repeat(np.tile(N, 2), np.tile(reps, 2))[None, :],
                            law, int(reps.sum()), 1.0)
    keep = np.cumsum(np.tile(reps, 2)) - 1  # the last copy of every original sample
    np.testing.assert_allclose(slow.f[0, keep], base.f[0], rtol=1e-12, atol=1e-14)


@SETTINGS
@given(periodic_inputs(varying_N=False), st.sampled_from(LAWS), st.integers(2, 5))
def test_rate_independence_refined_path(inputs, law_spec, m):
    """Sampling the same piecewise-linear path more finely (constant N) changes no force."""
    u, N = inputs
    law = make_law(*law_spec)
    base = march_periods(law, u, N, periods=2)
    uu = np.tile(u, 2)
    prev = np.concatenate([[0.0], uu[:-1]])  # the path starts at rest at u = 0
    frac = np.arange(1, m + 1) / m
    fine = (prev[:, None] + frac[None, :] * (uu - prev)[:, None]).ravel()
    res = march_prescribed(fine[None, :], np.full((1, fine.size), N[0]), law,
                           u.size * m, 1.0)
    np.testing.assert_allclose(res.f[0, m - 1::m], base.f[0], rtol=1e-12, atol=1e-13)


@SETTINGS
@given(periodic_inputs(n=128, varying_N=False), st.sampled_from(["jenkins", "iwan4"]))
def test_masing_exact_at_constant_normal_load(inputs, name):
    """Jenkins and Iwan at constant N obey Masing (with the memory rule) exactly."""
    u, N = inputs
    law = make_law(name, "anchor", n_sliders=8)
    res = march_periods(law, u, N)
    u1, f1, N1 = res.last_period()
    rep = check_loops(u1, f1, N1, law)
    assert rep.dev_masing[0] < 1e-12
    assert rep.dev_manifold[0] < 1e-12


@SETTINGS
@given(periodic_inputs(n=128, varying_N=True, separating=True))
def test_scaled_jenkins_stays_on_manifold_when_slipping_at_reversals(inputs):
    """Seed condition 5: with the scaled law, a single-harmonic loop that slips
    before each reversal lies on its manifold for any N(t) that is positive at
    the reversals; separation elsewhere included (N <= 0 counts as no load).
    The reference force is measured from the far reversal, so a slip limit
    that rises faster than kt (Eq. 6) cannot make this law stick again before
    a reversal.  (An element separated at a reversal restarts on its virgin
    curve, which DESIGN's manifold, with reference term 0, does not describe.)"""
    u, N = inputs
    t = 2 * np.pi * np.arange(u.size) / u.size
    u = 3.0 * np.cos(t + 0.3)  # large enough to slip: kt A = 3 > 2 mu max(N)
    assume(N[np.argmax(u)] > 0 and N[np.argmin(u)] > 0)
    law = make_law("jenkins", "scaled", kt=1.0, mu=0.2)
    res = march_periods(law, u, N)
    rep = check_loops(*res.last_period(), law)
    assert rep.dev_manifold[0] < 1e-12


def test_masing_memory_rule_is_needed():
    """Without popping closed inner loops a minor loop looks like a departure."""
    n = 400
    t = 2 * np.pi * np.arange(n) / n
    u = np.cos(t) + 0.6 * np.cos(3 * t)  # an outer loop with two minor loops
    law = make_law("jenkins", "anchor", mu=0.1)
    res = march_periods(law, u, np.full(n, 2.0))
    u1, f1, N1 = res.last_period()
    rep = check_loops(u1, f1, N1, law)
    assert rep.n_reversals[0] == 6
    assert rep.dev_masing[0] < 1e-12
    # the same loop predicted from the last reversal only, with no memory rule
    uu, ff, NN = (np.roll(a[0], -int(np.argmax(u1[0]))) for a in (u1, f1, N1))
    r, d, naive = 0, -1.0, np.empty(n)
    for k in range(n):
        if k and uu[k] != uu[k - 1] and np.sign(uu[k] - uu[k - 1]) != d:
            r, d = k - 1, -d
        x = 0.5 * abs(uu[k] - uu[r])
        naive[k] = ff[r] + 2 * np.sign(uu[k] - uu[r]) * law.backbone([[x]], [[NN[k]]])[0, 0]
    assert np.max(np.abs(naive - ff)) / 0.2 > 0.1


@pytest.mark.parametrize("name", ["jenkins", "iwan4"])
def test_masing_sampling_order_invariant(name):
    """Rolling the period (starting it elsewhere) does not change the deviations."""
    n = 256
    t = 2 * np.pi * np.arange(n) / n
    u = np.sin(t) + 0.2 * np.sin(2 * t + 1)
    N = 2 + 0.6 * np.sin(2 * t)
    law = make_law(name, "anchor")
    res = march_periods(law, u, N)
    u1, f1, N1 = res.last_period()
    a = check_loops(u1, f1, N1, law)
    b = check_loops(np.roll(u1, 37, 1), np.roll(f1, 37, 1), np.roll(N1, 37, 1), law)
    assert a.dev_manifold[0] == pytest.approx(b.dev_manifold[0], rel=1e-12)
    assert a.dev_masing[0] == pytest.approx(b.dev_masing[0], rel=1e-12)
    np.testing.assert_allclose(np.roll(a.f_manifold, 37, 1), b.f_manifold, atol=1e-14)
