"""The study's third column on prescribed loops: replay through the manifold law (issue 14).

Oracles: the seed's Fig. 3 cases (the manifold law is on its manifold to
round-off, the physical ``sin1`` loop leaves it with both conditions held:
condition 5); the stored physical force itself (the replayed physical law must
reproduce it); the closed form of a stuck element's manifold drift.
"""
import numpy as np
import pytest

from jointsim.contact.select import tangential_law
from jointsim.masing import (CAUSE_CONDITION5, CAUSE_CONTROL_OFF, CAUSE_ON, check_loops,
                             replay_control)
from jointsim.scene import Joint

NT = 1024
T = np.linspace(0.0, 2 * np.pi, NT, endpoint=False)


def physical(u, N, mu=0.1, kt=1.0):
    law = tangential_law("jenkins", "anchor", Joint(mu=mu, kt=kt), [1.0])
    uu, NN = np.tile(u, 3)[None], np.tile(N, 3)[None]
    f = law.march(uu, NN, law.rest_state([N[0]]))[0][:, -NT:]
    return law, f, check_loops(u[None], f, N[None], law)


@pytest.mark.parametrize("case", ["const", "sin1", "sin2"])
def test_seed_fig3_control_on_its_manifold_and_attribution(case):
    u = np.sin(T)
    N = {"const": 5.0 + 0 * T, "sin1": 5.0 + np.sin(T), "sin2": 5.0 + np.sin(2 * T)}[case]
    law, f, rep = physical(u, N)
    c = replay_control(u[None], f, N[None], law, rep)
    assert c.replay_error[0] < 1e-13          # the replayed physical law is the stored one
    assert c.periodicity[0] < 1e-12
    assert c.excess[0] < 1e-12
    assert c.report.dev_manifold[0] < 1e-12   # condition 5 with memory: on by construction
    if case == "const":
        assert c.cause[0] == CAUSE_ON
    if case == "sin1":
        # the physical loop leaves the manifold with Eq. 4 and Eq. 6 held (seed 3.1)
        assert not rep.on_manifold[0] and rep.eq4_ok[0] and rep.eq6_ok[0]
        assert c.cause[0] == CAUSE_CONDITION5


def test_stuck_element_under_varying_n_closes_its_manifold_loop_only_at_mu_n():
    """u = 0.1 cos t never slips at mu N >= 0.3; with N = 5 + 2 cos t (7 at the maximum
    of u, 3 at its minimum) the manifold law's reference drifts until its manifold
    reaches mu N: there is no closed loop on the manifold inside the limit, and the
    loop that closes does so on the clipped branch (seed Eq. 7, second case)."""
    u, N = 0.1 * np.cos(T), 5.0 + 2.0 * np.cos(T)
    law, f, rep = physical(u, N)
    assert not rep.on_manifold[0]
    c = replay_control(u[None], f, N[None], law, rep)
    assert c.excess[0] > 0.01                     # the unclipped construction leaves mu N
    assert c.periodicity[0] < 1e-12               # ... and the clipped loop closes
    assert c.report.dev_manifold[0] < 1e-12       # on the clipped manifold
    assert c.cause[0] != CAUSE_CONTROL_OFF
    # closed form of the drift while stuck: over one cycle max -> min -> max the force at
    # the maximum changes by kt (max u - min u) (1 - N_max / N_min) = 0.2 (1 - 7/3)
    law_m = tangential_law("jenkins", "manifold", Joint(reversal="manifold", mu=0.1, kt=1.0),
                           [1.0])
    f2 = law_m.march(np.tile(u, 3)[None], np.tile(N, 3)[None], law_m.rest_state([N[0]]))[0][0]
    drift = f2[2 * NT] - f2[NT]
    assert drift == pytest.approx(0.2 * (1.0 - 7.0 / 3.0), rel=1e-9)
    # closed form of the closed loop: it slips at the minimum of u (f = -mu N_min = -0.3)
    # and the branch up from there ends at -0.3 N_max / N_min + kt 0.2 = -0.5
    assert c.f[0, 0] == pytest.approx(-0.5, abs=1e-12)
    assert c.f[0, NT // 2] == pytest.approx(-0.3, abs=1e-12)


def test_law_without_slip_has_no_control():
    law = tangential_law("stuck", "anchor", Joint(law="stuck", kt=1.0), [1.0])
    u, N = np.cos(T)[None], (5.0 + 0 * T)[None]
    f = law.march(u, N, law.rest_state([5.0]))[0]
    assert replay_control(u, f, N, law, check_loops(u, f, N, law)) is None


def test_periodic_manifold_march_stops_each_element_on_its_own():
    """Two elements, one that closes at once (constant N) and one that drifts for about
    14 periods (the stuck element above, with N = 5 + 0.3 cos t): each stops at its own
    check, its last period is bit for bit the tiled march's of as many periods and its
    change that march's; a cap ends the drifting one."""
    from jointsim.contact._kernels import march_manifold_periodic
    n = 256
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    u = np.stack([np.sin(t), 0.1 * np.cos(t)])
    N = np.stack([5.0 + 0 * t, 5.0 + 0.3 * np.cos(t)])
    law = tangential_law("jenkins", "manifold", Joint(reversal="manifold", mu=0.1, kt=1.0),
                         [1.0, 1.0])
    s0 = law.rest_state(N[:, 0])
    scale = law.slip_force(N).max(axis=1)
    for block, cap in ((5, 400), (3, 7)):
        f, change, periods, _ = march_manifold_periodic(u, N, law.k, law.g, s0, scale,
                                                        block, cap, 1e-12)
        assert periods[0] == block                       # closed at its first check
        for e in range(2):
            p = periods[e]
            ref = law.march(np.tile(u[e:e + 1], p), np.tile(N[e:e + 1], p), s0[e:e + 1])[0]
            np.testing.assert_array_equal(f[e], ref[0, -n:])
            before = np.abs(ref[0, -n:] - ref[0, -2 * n:-n]).max() / scale[e]
            assert change[e] == before
        if cap == 7:
            assert periods[1] == 7 and change[1] > 1e-6  # stopped by the cap, not closed
        else:
            assert block < periods[1] < cap and change[1] <= 1e-12
