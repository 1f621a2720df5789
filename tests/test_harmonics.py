"""The coefficient order [0, 1c, 1s, ...] (jointsim.harmonics) and the loads (jointsim.loads)."""
from types import SimpleNamespace

import numpy as np
import pytest

from jointsim.harmonics import (HarmonicBasis, basis_functions, coefficient_harmonics,
                                coefficient_index, coefficient_kinds, dft_matrix,
                                harmonic_amplitude, harmonic_coefficients, n_coefficients, rows)
from jointsim.loads import LoadFunction, force_coefficients, static_load
from jointsim.scene import Harmonic, Signal

HS = (0, 1, 3)


def test_order_of_coefficients():
    assert coefficient_harmonics(HS).tolist() == [0, 1, 1, 3, 3]
    assert coefficient_kinds(HS).tolist() == [0, 0, 1, 0, 1]
    assert n_coefficients(HS) == 5 == n_coefficients((1, 0, 3))
    assert rows(HS) == {0: slice(0, 1), 1: slice(1, 3), 3: slice(3, 5)}
    assert coefficient_index(HS, 0) == (0, -1)
    assert coefficient_index(HS, 1) == (1, 2)
    assert coefficient_index(HS, 3) == (3, 4)
    assert coefficient_index((2, 1), 1) == (2, 3)
    with pytest.raises(KeyError):
        coefficient_index(HS, 2)


def test_dft_of_a_cos_sin_signal():
    """x(t) = 0.5 + 2 cos(wt) - 3 sin(wt) + 0.25 sin(3wt) has exactly these coefficients."""
    w, n = 7.0, 16
    t0 = 2 * (2 * np.pi / w)
    t = t0 + np.arange(n) * (2 * np.pi / w) / n
    x = 0.5 + 2 * np.cos(w * t) - 3 * np.sin(w * t) + 0.25 * np.sin(3 * w * t)
    X = dft_matrix(HS, n, w, t0) @ x
    np.testing.assert_allclose(X, [0.5, 2.0, -3.0, 0.0, 0.25], atol=1e-13)
    assert harmonic_amplitude(HS, X, 1) == pytest.approx(np.hypot(2, 3), rel=1e-14)
    assert harmonic_amplitude(HS, X, 0) == pytest.approx(0.5, rel=1e-14)
    with pytest.raises(ValueError):
        dft_matrix(HS, 6, w)


def test_round_trip_coefficients_samples():
    b = HarmonicBasis(HS, 12)
    X = np.random.default_rng(0).normal(size=(b.n_coeff, 4))
    np.testing.assert_allclose(b.P @ b.samples(X), X, atol=1e-13)
    np.testing.assert_allclose(b.Gam, basis_functions(HS, b.theta))
    E = dft_matrix(HS, 12, 1.0)          # same samples: theta_j = t_j at omega = 1
    np.testing.assert_allclose(E @ b.samples(X), X, atol=1e-13)
    assert b.index == {h: coefficient_index(HS, h) for h in HS}
    assert harmonic_amplitude(b, X, 3).shape == (4,)


def test_harmonic_coefficients_of_a_signal():
    sig = Signal(constant=1.5, harmonics=(Harmonic(h=1, cos=2.0, sin=-1.0),
                                          Harmonic(h=3, sin=0.5)))
    np.testing.assert_array_equal(harmonic_coefficients(sig, HS), [1.5, 2.0, -1.0, 0.0, 0.5])
    with pytest.raises(ValueError):
        harmonic_coefficients(sig, (0, 1))


def _model():
    sig = Signal(constant=1.5, harmonics=(Harmonic(h=1, cos=2.0, sin=-1.0),
                                          Harmonic(h=3, sin=0.5)))
    return SimpleNamespace(n_dof=2, f_static=np.array([0.25, -1.0]), load_dofs=np.array([1]),
                           load_signals=(sig,))


def test_the_three_load_views_agree():
    m, w = _model(), 3.0
    F = force_coefficients(m, HS, scale=2.0)
    np.testing.assert_array_equal(F[:, 0], [0.25, 0, 0, 0, 0])
    np.testing.assert_array_equal(F[:, 1], [0.5, 4.0, -2.0, 0.0, 1.0])
    np.testing.assert_array_equal(static_load(m), F[0])
    f = LoadFunction(m, w, scale=2.0)
    assert f.harmonics == (0, 1, 2, 3)
    for t in (0.0, 0.3, 1.7):
        np.testing.assert_allclose(f(t), basis_functions(HS, w * t) @ F, atol=1e-14)
    np.testing.assert_array_equal(f.static(), static_load(m))
    f0 = LoadFunction(m, 0.0)
    np.testing.assert_array_equal(f0.coefficients, static_load(m)[None, :])


def test_complex_amplitudes_of_every_harmonic_and_back():
    """``to_complex`` gives ``X_hc - i X_hs`` (``X_0`` at h = 0) harmonic by harmonic,
    as a sampled signal's DFT does; ``from_complex`` writes the rows back."""
    b = HarmonicBasis((0, 1, 3, 4), 32)
    X = np.random.default_rng(2).normal(size=(b.n_coeff, 3, 2))
    Y = b.to_complex(X)
    assert Y.shape == (4, 3, 2)
    x = b.samples(X)                                   # (n_t, 3, 2)
    dft = np.fft.fft(x, axis=0) / b.n_samples
    for j, h in enumerate(b.harmonics):
        # x(t) = Re(sum Y_h e^{i h t}) with Y_h = X_hc - i X_hs: the DFT's bin h is Y_h / 2
        ref = dft[0] if h == 0 else 2.0 * dft[h]
        np.testing.assert_allclose(Y[j], ref, rtol=0, atol=1e-14)
    back = np.zeros_like(X)
    b.from_complex(Y, back)
    assert np.array_equal(back, X)
