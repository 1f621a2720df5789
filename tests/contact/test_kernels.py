"""The numba contact kernels against plain-NumPy references and finite differences."""
import numpy as np
import pytest

from jointsim.contact import _kernels as K
from jointsim.contact import iwan4_sliders
from jointsim.contact.laws import AnchoredBank, ScaledBank

from .. import _reference as ref

LAWS = {"bank_anchor": AnchoredBank, "bank_scaled": ScaledBank}


def random_path(rng, ne, nt, amp=1.0):
    """Random multi-harmonic paths with occasional dwell samples."""
    t = np.linspace(0, 2 * np.pi, nt, endpoint=False)
    u = np.zeros((ne, nt))
    for h in range(1, 5):
        u += amp / h * (rng.normal(size=(ne, 1)) * np.cos(h * t) + rng.normal(size=(ne, 1))
                        * np.sin(h * t))
    dwell = rng.random((ne, nt)) < 0.05
    for e in range(ne):
        for j in np.nonzero(dwell[e])[0]:
            if j > 0:
                u[e, j] = u[e, j - 1]
    return u


def random_N(rng, ne, nt, separating=True):
    t = np.linspace(0, 2 * np.pi, nt, endpoint=False)
    N = 3.0 + rng.normal(size=(ne, 1)) * np.sin(2 * t + rng.random((ne, 1)) * 6)
    N += rng.normal(size=(ne, 1)) * np.cos(t)
    if separating:
        N -= 1.5
    return N


def bank(rng, ne, ns):
    k = rng.uniform(0.5, 2.0, size=(ne, ns))
    g = rng.uniform(0.02, 0.2, size=(ne, ns))
    return k, g


@pytest.mark.parametrize("ns", [1, 7])
def test_anchor_kernel_matches_numpy(ns):
    rng = np.random.default_rng(1)
    u = random_path(rng, 6, 400)
    N = random_N(rng, 6, 400)
    k, g = bank(rng, 6, ns)
    w0 = rng.normal(scale=0.1, size=(6, ns))
    f, _dfdu, _dfdN, w = K.march_bank(K.BANK_ANCHOR, u, N, k, g, w0)
    f_ref, w_ref = ref.anchor_bank(u, N, k, g, w0)
    np.testing.assert_allclose(f, f_ref, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(w, w_ref, rtol=1e-13, atol=1e-13)
    assert np.all(w0 == w0.copy()), "the kernel must not modify its input state"


@pytest.mark.parametrize("ns", [1, 5])
def test_scaled_kernel_matches_numpy(ns):
    rng = np.random.default_rng(2)
    u = random_path(rng, 5, 300)
    N = random_N(rng, 5, 300)
    k, g = bank(rng, 5, ns)
    law = ScaledBank(k, g, g.sum(axis=1))
    s0 = law.rest_state(N[:, 0])
    f, _dfdu, _dfdN, _s = K.march_bank(K.BANK_SCALED, u, N, k, g, s0)
    np.testing.assert_allclose(f, ref.scaled_bank(u, N, k, g, N[:, 0]), rtol=1e-13, atol=1e-13)


def test_normal_and_linear_kernels_match_numpy():
    rng = np.random.default_rng(3)
    gap = rng.normal(size=(4, 50))
    kn = rng.uniform(1, 3, size=4)
    for unilateral in (True, False):
        N, dNdg = K.normal_penalty(gap, kn, unilateral, False)
        np.testing.assert_allclose(N, ref.normal(gap, kn, unilateral), rtol=1e-15)
        h = 1e-7
        fd = (ref.normal(gap + h, kn, unilateral) - ref.normal(gap - h, kn, unilateral)) / (2 * h)
        away = np.abs(gap) > 1e-5
        np.testing.assert_allclose(dNdg[away], fd[away], rtol=1e-7)
    u = rng.normal(size=(4, 30))
    f, dfdu = K.linear_spring(u, kn)
    np.testing.assert_allclose(f, kn[:, None] * u, rtol=1e-15)
    np.testing.assert_allclose(dfdu, np.broadcast_to(kn[:, None], u.shape))


def _one_step(kind, u, N, k, g, state):
    law = LAWS[kind](k, g, g.sum(axis=1))
    f, dfdu, dfdN, _ = law.march(np.array([[u]]), np.array([[N]]), state)
    return f[0, 0], dfdu[0, 0], dfdN[0, 0]


@pytest.mark.parametrize("kind", ["bank_anchor", "bank_scaled"])
def test_tangents_match_finite_differences(kind):
    """dfdu and dfdN at a fixed starting state, away from stick/slip switches."""
    rng = np.random.default_rng(4)
    ns = 4
    checked = 0
    for trial in range(300):
        k, g = bank(rng, 1, ns)
        law = LAWS[kind](k, g, g.sum(axis=1))
        # a state reached by a short random history
        hist_u = rng.normal(scale=0.3, size=(1, 6))
        hist_N = rng.uniform(1.0, 4.0, size=(1, 6))
        _, _, _, state = law.march(hist_u, hist_N, law.rest_state(hist_N[:, 0]))
        u = hist_u[0, -1] + rng.normal(scale=0.2)
        N = rng.uniform(0.5, 4.0)
        h = 1e-7
        f0, dfdu, dfdN = _one_step(kind, u, N, k, g, state)
        fu = [_one_step(kind, u + s * h, N, k, g, state)[0] for s in (-1, 1)]
        fN = [_one_step(kind, u, N + s * h, k, g, state)[0] for s in (-1, 1)]
        fd_u = (fu[1] - fu[0]) / (2 * h)
        fd_N = (fN[1] - fN[0]) / (2 * h)
        # skip points where a slider sits within the FD step of a switch: the one-sided
        # slopes then disagree
        one_sided_u = ((fu[1] - f0) / h, (f0 - fu[0]) / h)
        one_sided_N = ((fN[1] - f0) / h, (f0 - fN[0]) / h)
        if abs(one_sided_u[0] - one_sided_u[1]) > 1e-5 or \
                abs(one_sided_N[0] - one_sided_N[1]) > 1e-5:
            continue
        checked += 1
        assert dfdu == pytest.approx(fd_u, rel=1e-6, abs=1e-7)
        assert dfdN == pytest.approx(fd_N, rel=1e-6, abs=1e-7)
    assert checked > 150


def central_differences(fun, x, h):
    """Central differences of every output of ``fun(*x)`` by each input: a list,
    one array of output derivatives per input."""
    out = []
    for i in range(len(x)):
        xp, xm = list(x), list(x)
        xp[i] += h
        xm[i] -= h
        out.append((np.array(fun(*xp)) - np.array(fun(*xm))) / (2 * h))
    return out


def test_slider_step_full_jacobian():
    """slider_anchor_step's derivatives by u, N and the anchor w, incl. the new anchor."""
    rng = np.random.default_rng(5)
    h = 1e-7
    checked = 0
    for _ in range(400):
        u, w = rng.normal(scale=0.5, size=2)
        N = rng.uniform(-0.5, 3.0)
        k, g = rng.uniform(0.5, 2.0), rng.uniform(0.05, 0.3)
        out = np.array(K.slider_anchor_step(u, N, w, k, g))
        f, dfdu, dfdN, dfdw, w1, dw1du, dw1dN, dw1dw = out
        fdiff = central_differences(lambda *x: K.slider_anchor_step(*x, k, g), (u, N, w), h)
        # away from the switches |k(u-w)| = gN and N = 0
        if abs(abs(k * (u - w)) - g * max(N, 0)) < 1e-5 or abs(N) < 1e-5:
            continue
        checked += 1
        np.testing.assert_allclose([dfdu, dfdN, dfdw], [fdiff[0][0], fdiff[1][0], fdiff[2][0]],
                                   atol=1e-6)
        np.testing.assert_allclose([dw1du, dw1dN, dw1dw], [fdiff[0][4], fdiff[1][4], fdiff[2][4]],
                                   atol=1e-6)
    assert checked > 300


def test_scaled_force_full_jacobian():
    rng = np.random.default_rng(6)
    h = 1e-7
    checked = 0
    for _ in range(400):
        u, u_r = rng.normal(scale=0.5, size=2)
        N, N_r = rng.uniform(0.2, 3.0, size=2)
        k, g = rng.uniform(0.5, 2.0), rng.uniform(0.05, 0.3)
        f_r = rng.uniform(-1, 1) * g * N_r
        x = np.array([u, N, u_r, N_r, f_r])
        out = np.array(K.slider_scaled_force(*x, k, g))
        trial = k * (u - u_r) + f_r * N / N_r
        if abs(abs(trial) - g * N) < 1e-5:
            continue
        checked += 1
        fd = central_differences(lambda *y: K.slider_scaled_force(*y, k, g), x, h)
        np.testing.assert_allclose(out[1:6], [d[0] for d in fd], rtol=0, atol=1e-6)
    assert checked > 300


def test_iwan_discretisation_totals():
    k, fs = iwan4_sliders(KT=3.0, Fs=0.7, chi=-0.4, beta=0.3, n=50)
    assert k.sum() == pytest.approx(3.0, rel=1e-13)
    assert fs.sum() == pytest.approx(0.7, rel=1e-13)
    assert np.all(np.diff(fs[:-1] / k[:-1]) > 0), "slip displacements must increase"


@pytest.mark.parametrize("kind", ["anchor", "scaled"])
def test_threaded_and_serial_drivers_agree(kind):
    """Large batches run on threads; the result must not depend on it."""
    rng = np.random.default_rng(7)
    u = random_path(rng, 64, 50)
    N = random_N(rng, 64, 50)
    k, g = bank(rng, 64, 3)
    if kind == "anchor":
        s0 = rng.normal(scale=0.1, size=(64, 3))
        code = K.BANK_ANCHOR
    else:
        s0 = ScaledBank(k, g, g.sum(axis=1)).rest_state(N[:, 0])
        code = K.BANK_SCALED
    for a, b in zip(K._bank_serial(code, u, N, k, g, s0), K._bank_parallel(code, u, N, k, g, s0)):
        np.testing.assert_array_equal(a, b)
