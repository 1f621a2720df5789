"""The scaled reversal laws are not path-continuous under a varying normal load (issue 14).

Oracles: the anchored (physical) law on the same two nearby paths, whose
forces agree to the size of the perturbation; the closed form of the jump of
Eq. 7 (``mu N`` at a reversal that crosses a separation instant,
``kt (u_m - u_r) (N / N_m - 1)`` after a micro-reversal in a stuck phase).
"""
import numpy as np
import pytest

from jointsim.contact.laws import continuation_advice
from jointsim.contact.select import tangential_law
from jointsim.scene import Joint
from jointsim.solvers.discontinuity import explain_failure, residual_jump

MU, KT = 0.3, 1.0


def law(reversal):
    return tangential_law("jenkins", reversal, Joint(law="jenkins", reversal=reversal,
                                                      mu=MU, kt=KT), [1.0])


def march(lw, u, N):
    return lw.march(u[None], N[None], lw.rest_state([N[0]]))[0][0]


def separation_paths(n=400):
    """u = cos t over two periods; N = 5 (1 + cos t) touches 0 at the reversal t = pi,
    exactly 0 there in one path and 1e-300 in the other (N_r = 0 against N_r -> 0+)."""
    t = np.linspace(0.0, 4 * np.pi, 2 * n, endpoint=False)
    u = np.cos(t)
    N = 5.0 * (1.0 + np.cos(t))
    i = np.abs(t - np.pi).argmin()
    u[i], N[i] = -1.0, 0.0
    N2 = N.copy()
    N2[i] = 1e-300
    return t, u, N, N2


@pytest.mark.parametrize("reversal", ["scaled", "manifold"])
def test_reversal_at_separation_jumps_by_mu_n(reversal):
    t, u, N, N2 = separation_paths()
    f1, f2 = march(law(reversal), u, N), march(law(reversal), u, N2)
    # N_r -> 0+ with f_r = -mu N_r gives the reference term -mu N on reloading, while
    # N_r = 0 gives none: the forces differ by mu N(t) up to the next reversal
    half = slice(len(t) // 4, len(t) // 2)
    assert np.abs(f1 - f2)[half] == pytest.approx(MU * N[half], rel=1e-9, abs=1e-12)
    fa1, fa2 = march(law("anchor"), u, N), march(law("anchor"), u, N2)
    assert np.abs(fa1 - fa2).max() < 1e-15


def micro_reversal_paths(eps, n=2000):
    """u = cos t, with (second path) a micro-reversal of depth eps at t = 1.2 pi,
    in the stuck phase after the reversal at t = pi; N = 1 + 0.5 sin t."""
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    u = np.cos(t)
    N = 1.0 + 0.5 * np.sin(t)
    u2 = u.copy()
    im = np.abs(t - 1.2 * np.pi).argmin()
    u2[im + 1] = u[im] - eps    # back by eps, then on along u
    return t, u, u2, N


@pytest.mark.parametrize("eps", [1e-4, 1e-7])
def test_micro_reversal_jump_does_not_vanish_with_its_size(eps):
    t, u1, u2, N = micro_reversal_paths(eps)
    lw = law("scaled")
    f1, f2 = march(lw, u1, N), march(lw, u2, N)
    # the micro-reversal at u_m (N_m) re-bases the reference: later the force differs by
    # kt (u_m - u_r) (N / N_m - 1) (closed form of Eq. 7 in the stuck phase)
    k = np.argmax(t > 1.25 * np.pi)   # still stuck there
    im = np.abs(t - 1.2 * np.pi).argmin()
    predicted = KT * (u1[im] - u1[np.abs(t - np.pi).argmin()]) * (N[k] / N[im] - 1.0)
    assert abs(predicted) > 1e-3
    assert f2[k] - f1[k] == pytest.approx(predicted, rel=0.05)
    fa1, fa2 = march(law("anchor"), u1, N), march(law("anchor"), u2, N)
    assert abs(fa2[k] - fa1[k]) <= 2 * KT * eps   # anchored: continuous in the path


def test_residual_jump_finds_a_step_and_not_a_steep_slope():
    step = lambda y: np.array([1e-12 + (y[0] > 0.3) * 0.05])
    j = residual_jump(step, np.zeros(1), np.ones(1))
    assert j is not None and j.s_before <= 0.3 < j.s_after and j.dy < 1e-15
    assert j.r_after == pytest.approx(0.05) and j.dr == pytest.approx(0.05)
    # a jump on top of a large, sloped residual (an unconverged or unscaled one)
    sloped = lambda y: np.array([24.0 + 40.0 * y[0] + (y[0] > 0.61) * 0.5, 3.0])
    j = residual_jump(sloped, np.zeros(1), np.ones(1))
    assert j is not None and j.s_before <= 0.61 < j.s_after and j.dr == pytest.approx(0.5)
    steep = lambda y: np.array([1e-12 + 1e3 * max(y[0] - 0.3, 0.0)])
    assert residual_jump(steep, np.zeros(1), np.ones(1)) is None
    kink = lambda y: np.array([1e3 * abs(y[0] - 0.123)])
    assert residual_jump(kink, np.zeros(1), np.ones(1)) is None


def test_advice_only_for_scaled_laws_with_varying_normal_load():
    assert continuation_advice(law("anchor"), True) == ""
    assert continuation_advice(law("scaled"), False) == ""
    assert "not path-continuous" in continuation_advice(law("scaled"), True)
    assert "not path-continuous" in continuation_advice(law("manifold"), True)
    calls = []
    msg = explain_failure("gave up", "", lambda y: calls.append(y), None, np.zeros(1))
    assert msg == "gave up" and not calls


@pytest.mark.slow
@pytest.mark.parametrize("reversal", ["scaled", "manifold"])
def test_scaled_fold_continuation_stops_with_the_jump_and_the_advice(tmp_path, reversal):
    """models/hbm/chain2_friction_fold.toml with Eq. 7 or the manifold law: the FRC
    stops at omega = 2.137 (after 121 points, kept in the file), and the message
    names the residual jump and the remedy."""
    import h5py

    from jointsim.run import run_scene
    from jointsim.scene import load_scene

    scene = load_scene("models/hbm/chain2_friction_fold.toml", [f'joint.reversal="{reversal}"'])
    with pytest.raises(RuntimeError) as err:
        run_scene(scene, tmp_path / "x.h5")
    msg = str(err.value)
    assert "not path-continuous" in msg and "joint.reversal = 'anchor'" in msg
    assert "the residual jumps by" in msg and f"bank_{reversal}" in msg
    with h5py.File(tmp_path / "x.h5") as h5:
        assert h5["hbm/omega"][-1] == pytest.approx(2.137, abs=2e-3)
        assert h5["hbm/omega"].size >= 100


def closure_jumps(lw, u, N):
    """Largest difference, over the inner-loop closures of the second period, between
    the force of the closing (inner) branch and of the branch it returns to, both at
    the reversal reached, relative to mu N."""
    from jointsim.contact import _kernels as K
    s = lw.rest_state([N[0]])
    half = u.size // 2
    s = lw.march(u[None, :half], N[None, :half], s)[3]
    worst, closures = 0.0, 0
    for i in range(half, u.size):
        top0 = int(s[0, K.MF_TOP])
        before = s.copy()
        s = lw.march(u[None, i:i + 1], N[None, i:i + 1], s)[3]
        if s[0, K.MF_TOP] <= top0 - 2:
            uB = before[0, K.MF_SHARED + 3 * (top0 - 2)]
            f_in = K.manifold_force(before, 0, uB, N[i], lw.k, lw.g)[0]
            f_out = K.manifold_force(s, 0, uB, N[i], lw.k, lw.g)[0]
            worst = max(worst, abs(f_in - f_out) / (lw.mu[0] * N[i]))
            closures += 1
    return worst, closures


def test_manifold_law_jumps_where_an_inner_loop_closes_under_varying_normal_load():
    """Mechanism (iii): nested loops u = e(t) cos(12 t); at constant N the inner branch
    meets the older one where it closes (Masing), under varying N it does not (the two
    branches scale their reference forces by different N/N_r), so the force jumps."""
    t = 2 * np.pi * np.arange(8000) / 4000
    u = (0.55 + 0.45 * np.cos(t + 0.3 * np.sin(t))) * np.cos(12 * t + 0.17)
    lw = law("manifold")
    const, n_c = closure_jumps(lw, u, np.full_like(t, 2.0))
    vary, n_v = closure_jumps(lw, u, 2.0 + 0.5 * np.cos(3 * t + 1.0))
    assert n_c == n_v == 11
    assert const < 1e-12
    assert vary > 0.1


@pytest.mark.parametrize("name", ["jenkins", "iwan4"])
def test_closure_jumps_on_the_random_paths(name):
    """The 30 random paths of test_manifold_law.py (N = 5 + N1 cos(h t + p)): how many
    have a jump > 1e-3 mu N where an inner loop closes (README: Continuation with the
    scaled laws, mechanism (iii))."""
    from .test_manifold_law import NT, random_paths
    joint = Joint(law=name, reversal="manifold", mu=0.1, kt=1.0, chi=-0.5, beta=0.2,
                  n_sliders=40)
    lw = tangential_law(name, "manifold", joint, [1.0])
    worst = np.array([closure_jumps(lw, u[-2 * NT:], N[-2 * NT:])[0]
                      for u, N, _sep in random_paths()])
    print(name, "paths with a closure jump > 1e-3 mu N:", int(np.sum(worst > 1e-3)),
          "largest", worst.max())
    assert np.sum(worst > 1e-3) >= 10 and worst.max() > 0.3
