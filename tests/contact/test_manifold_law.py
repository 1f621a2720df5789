"""The manifold reversal law against the Masing check on random multi-reversal paths.

Oracle: :func:`jointsim.masing.check_loops` (validated against an independent
predictor, issue 14).  The law is the manifold's formula with the check's own
memory rule, clipped to the friction limit, so its deviation must equal the
manifold's excess over ``mu N`` (normalised) to round-off on every path, and
be at round-off wherever the manifold lies inside the limit.  Eq. 7
("scaled") on the same paths is off the manifold where it is.
"""
import numpy as np
import pytest

from jointsim.contact.select import tangential_law
from jointsim.masing import check_loops
from jointsim.scene import Joint

NT, PERIODS = 1000, 4


def random_paths(n=30, seed=14, amp=3.0):
    """``n`` random 5-harmonic periodic paths u(t), N = 5 + N1 cos(h t + p).

    Every third path has N1 > 5 (separation).
    """
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 2 * np.pi * PERIODS, NT * PERIODS, endpoint=False)
    for p in range(n):
        u = np.zeros_like(t)
        for h in (1, 2, 3, 4, 5):
            u += amp / h ** 0.5 * (rng.normal() * np.cos(h * t) + rng.normal() * np.sin(h * t))
        h = rng.integers(1, 4)
        N1 = rng.uniform(6.0, 9.0) if p % 3 == 0 else rng.uniform(0.5, 4.5)
        yield u, 5.0 + N1 * np.cos(h * t + rng.uniform(0.0, 6.0)), p % 3 == 0


def last_period_check(law, u, N):
    f = law.march(u[None], N[None], law.rest_state([N[0]]))[0]
    sl = slice(-NT, None)
    return check_loops(u[None, sl], f[:, sl], N[None, sl], law), N[None, sl]


@pytest.mark.parametrize("name", ["jenkins", "iwan4"])
def test_manifold_law_is_on_the_manifold_wherever_it_is_admissible(name):
    joint = dict(law=name, mu=0.1, kt=1.0, chi=-0.5, beta=0.2, n_sliders=40)
    man = tangential_law(name, "manifold", Joint(reversal="manifold", **joint), [1.0])
    sca = tangential_law(name, "scaled", Joint(reversal="scaled", **joint), [1.0])
    on, sep_on, scaled_off, multi = 0, 0, 0, 0
    for u, N, separates in random_paths():
        r, Nl = last_period_check(man, u, N)
        assert (Nl <= 0).any() == separates
        multi += int(r.n_reversals[0] > 2)
        slip = man.slip_force(Nl)
        excess = np.maximum(np.abs(r.f_manifold) - slip, 0.0).max() / slip.max()
        # the law departs from its manifold exactly where the manifold leaves mu N
        assert abs(r.dev_manifold[0] - excess) < 1e-12
        if excess < 1e-12:
            assert r.dev_manifold[0] < 1e-12
            on += 1
            sep_on += int(separates)
            rs, _ = last_period_check(sca, u, N)
            scaled_off += int(not rs.on_manifold[0])
    assert multi >= 28
    print(name, "on", on, "of which separating", sep_on, "scaled off there", scaled_off)
    assert on >= 12 and sep_on >= 1
    assert scaled_off >= 3     # Eq. 7 is off on paths where the manifold law is on


def test_harmonic_balance_accepts_the_manifold_law():
    """The law has an AFT kernel (tests/contact/test_manifold_aft.py): HBM and EPMC
    scenes with it load; prescribed motion with it runs too (the seed Fig. 3 scenes)."""
    from jointsim.contact.select import select_kernels
    from jointsim.scene import load_scene
    scene = load_scene("models/hbm/chain2_friction_fold.toml",
                       overrides=["joint.reversal=manifold"])
    assert select_kernels(scene).tangential == "bank_manifold"
    assert load_scene("models/seed_fig3/sep.toml", overrides=["joint.reversal=manifold"])
