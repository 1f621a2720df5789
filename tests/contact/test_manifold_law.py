"""The manifold reversal law against the Masing check on random multi-reversal paths.

Oracles: the check's manifold is the seed's Eq. 7 with its friction limit (the
Masing construction clipped to ``+-mu N(t)``, issue 14), recomputed here by an
independent predictor (a plain Python loop over the samples with its own
reversal stack and its own slider backbone) that must reproduce the check's
deviations to 1e-13 on the anchor law's loops.  The manifold law is then on
its manifold to round-off on every path, separating ones included, while Eq. 7
("scaled") is off it on some, inside the friction limit.
"""
import numpy as np
import pytest

from jointsim.contact.select import tangential_law
from jointsim.masing import check_loops
from jointsim.scene import Joint

NT, PERIODS = 1000, 4
JOINT = dict(mu=0.1, kt=1.0, chi=-0.5, beta=0.2, n_sliders=40)


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


def law(name, reversal):
    return tangential_law(name, reversal, Joint(law=name, reversal=reversal, **JOINT), [1.0])


def last_period(lw, u, N):
    f = lw.march(u[None], N[None], lw.rest_state([N[0]]))[0]
    sl = slice(-NT, None)
    return u[sl], f[0, sl], N[sl]


def predictor(u, f, N, k, g, mu):
    """Independent Masing predictions of one loop, sample by sample.

    Returns ``(dev_manifold, dev_masing, manifold_excess)`` as defined in the
    README ("The Masing-manifold check"): the period starts at the global
    maximum of u; a reversal is pushed where the motion changes direction; an
    inner loop closes (both its reversals popped) when u passes the reversal
    before the current one, the two outer reversals staying; the manifold
    prediction is clipped to +-mu N_k, the classical Masing one is not.
    """
    n = len(u)
    i0 = max(range(n), key=lambda i: u[i])
    u, f, N = [[float(x) for x in list(a[i0:]) + list(a[:i0])] for a in (u, f, N)]
    k, g = [float(x) for x in k], [float(x) for x in g]
    Nbar = sum(N) / n

    def backbone(x, load):
        load = max(load, 0.0)
        return sum(min(ki * x, gi * load) for ki, gi in zip(k, g))

    stack = [min(range(n), key=lambda i: u[i]), 0]
    going = -1
    lim = [mu * max(v, 0.0) for v in N]
    dman = dmas = exc = 0.0
    for j in range(n):
        if j > 0 and u[j] != u[j - 1]:
            step = 1 if u[j] > u[j - 1] else -1
            if step != going:
                stack.append(j - 1)
                going = step
            while len(stack) > 3 and (u[j] - u[stack[-2]]) * going > 0:
                del stack[-2:]
        r = stack[-1]
        d = u[j] - u[r]
        sg = (d > 0) - (d < 0)
        x = abs(d) / 2
        ref = f[r] * max(N[j], 0.0) / N[r] if N[r] > 0 else 0.0
        man = ref + 2 * sg * backbone(x, N[j])
        mas = f[r] + 2 * sg * backbone(x, Nbar)
        exc = max(exc, abs(man) - lim[j])
        man = min(max(man, -lim[j]), lim[j])
        dman = max(dman, abs(f[j] - man))
        dmas = max(dmas, abs(f[j] - mas))
    top = max(lim)
    return dman / top, dmas / top, max(exc, 0.0) / top


@pytest.mark.parametrize("name", ["jenkins", "iwan4"])
def test_manifold_law_is_on_the_clipped_manifold_on_every_path(name):
    """dev_manifold < 1e-12 on all 30 paths (10 separating), although on many the
    unclipped construction leaves +-mu N; Eq. 7 is off where it is, inside mu N."""
    man, sca = law(name, "manifold"), law(name, "scaled")
    multi, clipped, sep, scaled_off, scaled_off_inside = 0, 0, 0, 0, 0
    for u, N, separates in random_paths():
        u1, f1, N1 = last_period(man, u, N)
        r = check_loops(u1[None], f1[None], N1[None], man)
        assert (N1 <= 0).any() == separates
        assert r.dev_manifold[0] < 1e-12
        multi += int(r.n_reversals[0] > 2)
        clipped += int(r.manifold_excess[0] > 1e-12)
        sep += int(separates)
        us, fs, Ns = last_period(sca, u, N)
        rs = check_loops(us[None], fs[None], Ns[None], sca)
        # the deviation compares two forces inside +-mu N: the excess is not its reason
        assert np.all(np.abs(fs) <= sca.slip_force(Ns[None])[0] * (1 + 1e-12) + 1e-15)
        assert np.all(np.abs(rs.f_manifold) <= sca.slip_force(Ns[None]) * (1 + 1e-12) + 1e-15)
        if not rs.on_manifold[0]:
            scaled_off += 1
            scaled_off_inside += int(rs.manifold_excess[0] < 1e-12)
    print(name, "multi", multi, "clipped", clipped, "scaled off", scaled_off,
          "of which with the construction inside mu N", scaled_off_inside)
    assert multi >= 28 and sep == 10
    assert clipped >= 10          # the clip is what puts these paths on the manifold
    assert scaled_off > 0 and scaled_off_inside > 0


@pytest.mark.parametrize("name", ["jenkins", "iwan4"])
def test_check_against_an_independent_predictor_on_the_anchor_law(name):
    """The physical law's deviations from the clipped manifold and from classical
    Masing, and the manifold's excess, match a plain-Python predictor to 1e-13."""
    lw = law(name, "anchor")
    k, g, mu = lw.k[0], lw.g[0], float(lw.mu[0])
    worst = 0.0
    off = 0
    for u, N, _ in random_paths():
        u1, f1, N1 = last_period(lw, u, N)
        r = check_loops(u1[None], f1[None], N1[None], lw)
        dman, dmas, exc = predictor(u1, f1, N1, k, g, mu)
        worst = max(worst, abs(r.dev_manifold[0] - dman), abs(r.dev_masing[0] - dmas),
                    abs(r.manifold_excess[0] - exc))
        off += int(not r.on_manifold[0])
    assert worst < 1e-13
    assert off > 0   # the physical law leaves the manifold under varying N


@pytest.mark.parametrize("name", ["jenkins", "iwan4"])
def test_clip_is_a_no_op_at_constant_normal_load(name):
    """At constant N the Masing construction of a loop saturates at +-mu N by itself."""
    lw = law(name, "anchor")
    for i, (u, _, _) in enumerate(random_paths(n=8)):
        N = np.full_like(u, 5.0)
        u1, f1, N1 = last_period(lw, u, N)
        r = check_loops(u1[None], f1[None], N1[None], lw)
        assert r.manifold_excess[0] < 1e-12 and r.masing_excess[0] < 1e-12
        assert r.dev_manifold[0] < 1e-12 and r.dev_masing[0] < 1e-12


def test_harmonic_balance_accepts_the_manifold_law():
    """The law has an AFT kernel (tests/contact/test_manifold_aft.py): HBM and EPMC
    scenes with it load; prescribed motion with it runs too (the seed Fig. 3 scenes)."""
    from jointsim.contact.select import select_kernels
    from jointsim.scene import load_scene
    scene = load_scene("models/hbm/chain2_friction_fold.toml",
                       overrides=["joint.reversal=manifold"])
    assert select_kernels(scene).tangential == "bank_manifold"
    assert load_scene("models/seed_fig3/sep.toml", overrides=["joint.reversal=manifold"])
