"""The anchor of a re-closing contact in the AFT march (issue 13 case 5): taken at the
closing instant interpolated between two samples, the stuck force converges at second
order in the sample count (against the analytic force of a prescribed motion), at
first order when taken at the last open sample; with the interval in which the contact
opens integrated up to the opening instant, the force coefficients of a contact that
never slips converge at second order too; the history Jacobian of both against central
differences."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from jointsim.contact._aft_kernels import anchor_aft, closing_anchor
from jointsim.contact.laws import AnchoredBank
from jointsim.contact.normal import UnilateralPenalty
from jointsim.harmonics import HarmonicBasis
from jointsim.model import ContactSet
from jointsim.solvers.aft import AFT

from .._aft_reference import aft_history_fd

C0, PHASE = 0.2, 0.7     # gap = C0 + cos(theta), slip u = sin(theta + PHASE)


def _stuck_force(nt, closing, mu=1e6):
    """Sampled AFT force of one slider (k = 1, kn = 1) under the prescribed motion,
    and the exact force of the never-slipping contact: 0 while open, ``u - u(theta_c)``
    while closed, ``theta_c = acos(-C0)`` the closing instant."""
    th = 2 * np.pi * np.arange(nt) / nt
    u = np.sin(th + PHASE)[None, :]
    gap = (C0 + np.cos(th))[None, :]
    N = np.maximum(0.0, -gap)
    dNdg = np.where(gap < 0.0, -1.0, 0.0)
    b = HarmonicBasis((0, 1, 2, 3), nt)
    f = anchor_aft(u, N, dNdg, np.ones((1, 1)), np.full((1, 1), mu), b.CP, b.Gam, 2, 50,
                   1e-12, True, False, gap=gap if closing == "interpolated" else None)[0]
    tc = np.arccos(-C0)
    exact = np.where(gap[0] < 0.0, np.sin(th + PHASE) - np.sin(tc + PHASE), 0.0)
    return f[0], exact


def test_closing_anchor_is_the_linear_interpolation():
    wc, d0, d1, dg0, dg1 = closing_anchor(1.0, 3.0, 0.5, -1.5)   # closes at 1/4
    assert wc == pytest.approx(1.5) and (d0, d1) == pytest.approx((0.75, 0.25))
    eps = 1e-7
    assert dg0 == pytest.approx((closing_anchor(1.0, 3.0, 0.5 + eps, -1.5)[0]
                                 - closing_anchor(1.0, 3.0, 0.5 - eps, -1.5)[0]) / (2 * eps))
    assert dg1 == pytest.approx((closing_anchor(1.0, 3.0, 0.5, -1.5 + eps)[0]
                                 - closing_anchor(1.0, 3.0, 0.5, -1.5 - eps)[0]) / (2 * eps))


def test_stuck_force_after_closing_converges_at_second_order():
    """mu = 1e6: the contact sticks from its closing on.  Interpolated anchor: every
    sample within the analytic bound of linear interpolation, ``dt^2 / 4`` (``dt^2 / 8``
    for the slip ``u`` and for the instant, ``|g''| / |g'| <= 1.02``, times
    ``|u'| <= 1``; measured 0.08-0.38 of it); at the last open sample the anchor is
    off by up to ``|u'| dt`` (measured 0.04-0.64 of it, not monotone in the sample
    count: it depends on where the closing falls between two samples)."""
    for nt in (50, 100, 200, 400, 800, 1600):
        dt = 2 * np.pi / nt
        f, exact = _stuck_force(nt, "interpolated")
        e_int = np.abs(f - exact).max()
        f, exact = _stuck_force(nt, "sample")
        e_smp = np.abs(f - exact).max()
        assert e_int <= dt * dt / 4, (nt, e_int)
        assert e_smp <= dt, (nt, e_smp)
        if nt >= 200:
            assert e_smp > 10 * e_int, (nt, e_smp, e_int)


def _exact_coefficients(harmonics):
    """Fourier coefficients (the ``P`` convention: mean, then ``(1/pi) int f cos``,
    ``(1/pi) int f sin``) of the exact never-slipping force under the prescribed
    motion: ``u - u(theta_c)`` while closed, ``theta_c < theta < 2 pi - theta_c``, 0
    while open; Gauss-Legendre on the closed interval, where it is smooth."""
    tc = np.arccos(-C0)
    x, w = np.polynomial.legendre.leggauss(200)
    th = np.pi + (np.pi - tc) * x
    w = w * (np.pi - tc)
    f = np.sin(th + PHASE) - np.sin(tc + PHASE)
    rows = []
    for h in harmonics:
        if h == 0:
            rows.append(w @ f / (2 * np.pi))
        else:
            rows += [w @ (f * np.cos(h * th)) / np.pi, w @ (f * np.sin(h * th)) / np.pi]
    return np.array(rows)


def _shifted_dft(b, f, shift):
    """Coefficients of samples ``f`` taken at ``2 pi t / n + shift``."""
    n = b.n_samples
    th = 2 * np.pi * np.arange(n) / n + shift
    rows = []
    for h in b.harmonics:
        if h == 0:
            rows.append(f.mean())
        else:
            rows += [2 * np.mean(f * np.cos(h * th)), 2 * np.mean(f * np.sin(h * th))]
    return np.array(rows)


def test_stuck_force_coefficients_converge_at_second_order_with_the_opening_quadrature():
    """The never-slipping contact (mu = inf) under the prescribed motion: it sticks from
    closing to opening, where the stuck force drops to 0.  With the closing instant and
    the opening quadrature the force coefficients converge at second order in the
    samples (largest error times n^2 bounded: 1.3-6.3 for n = 50..1,600, not
    growing); at the last open sample with plain samples, at first order (the jump at
    the opening and the anchor each cost up to one sample: error times n >= 0.5).  (mu = 1e6 differs from this limit by
    about 1e-6, so its error stalls there.)"""
    b0 = HarmonicBasis((0, 1, 2, 3), 64)
    P0 = b0.P
    # the basis convention of P: check it on a pure cosine
    th = 2 * np.pi * np.arange(64) / 64
    assert np.allclose(P0 @ np.cos(th), _shifted_dft(b0, np.cos(th), 0.0))
    exact = _exact_coefficients(b0.harmonics)
    for nt in (50, 100, 200, 400, 800, 1600):
        b = HarmonicBasis((0, 1, 2, 3), nt)
        th = 2 * np.pi * np.arange(nt) / nt
        u = np.sin(th + PHASE)[None, :]
        gap = (C0 + np.cos(th))[None, :]
        N = np.maximum(0.0, -gap)
        dNdg = np.where(gap < 0.0, -1.0, 0.0)
        err = {}
        for closing in ("interpolated", "sample"):
            dF = np.zeros((1, b.n_coeff))
            f = anchor_aft(u, N, dNdg, np.ones((1, 1)), np.full((1, 1), np.inf), b.CP,
                           b.Gam, 2, 50, 1e-12, True, False,
                           gap=gap if closing == "interpolated" else None, dF=dF)[0]
            err[closing] = np.abs(f @ b.P.T + dF - exact).max()
        assert err["interpolated"] * nt ** 2 <= 8.0, (nt, err)
        assert err["sample"] * nt >= 0.5, (nt, err)


@pytest.mark.parametrize("mu", [0.3, 1e3, 1e6, np.inf])
def test_aft_jacobian_with_closing_instants_matches_central_differences(mu):
    """Elements that separate and re-close in the period (mu = 1e3: they stick from the
    closing instant on, so the two-sample anchor derivative is exercised; 1e6 and inf:
    stuck up to the opening too, so the opening quadrature's derivatives by the opening
    instant, the two samples and the anchor's history are exercised)."""
    ne = 4
    b = HarmonicBasis((0, 1, 2, 3), 64)
    law = AnchoredBank(np.ones((ne, 1)), np.full((ne, 1), mu), np.full(ne, mu))
    eye = sp.identity(ne, format="csr")
    cs = ContactSet(eye, eye, np.full(ne, -0.3), np.ones(ne), np.ones(ne), law,
                    UnilateralPenalty(np.ones(ne)), np.zeros((ne, 2)))
    rng = np.random.default_rng(7)
    U = rng.normal(size=(b.n_coeff, ne)) * 0.5
    G = rng.normal(size=(b.n_coeff, ne)) * 0.4
    aft = AFT(cs, b, closing="interpolated")
    r = aft.evaluate(U, G)
    closes = (r.N > 0) & (np.roll(r.N, 1, axis=1) <= 0)
    assert closes.any()
    if mu > 1.0:    # stuck at the first closed sample
        assert np.any(closes & (np.abs(r.f) < 0.999 * mu * np.where(r.N > 0, r.N, 1.0)))
    if mu >= 1e6:   # stuck at the last closed sample, with a force that drops at opening
        opens = (r.N > 0) & (np.roll(r.N, -1, axis=1) <= 0)
        assert np.any(opens & (np.abs(r.f) > 1e-2))
    J = {"u": r.Juu, "g": r.Jug}
    for which, j, fd in aft_history_fd(aft, U, G, range(b.n_coeff)):
        for e in range(ne):
            assert np.abs(J[which][e, :, j] - fd[e]).max() <= 1e-6 * max(1.0, np.abs(fd[e]).max())


@pytest.mark.parametrize("closing", ["interpolated", "sample"])
def test_aft_equals_the_numpy_reference_with_both_closings(closing):
    """The kernel against the dense forward-mode NumPy reference (an independent
    implementation of both anchor rules), mu = 1e3 so that elements stick at closing;
    ``AFT(closing=None)`` takes the contact set's ``closing``."""
    import dataclasses

    from .._aft_reference import anchor_aft_numpy
    ne = 5
    b = HarmonicBasis((0, 1, 2, 3, 5), 96)
    k, g = np.ones((ne, 1)), np.full((ne, 1), 1e3)
    eye = sp.identity(ne, format="csr")
    cs = ContactSet(eye, eye, np.full(ne, -0.3), np.ones(ne), np.ones(ne),
                    AnchoredBank(k, g, np.full(ne, 1e3)), UnilateralPenalty(np.ones(ne)),
                    np.zeros((ne, 2)))
    cs = dataclasses.replace(cs, closing=closing)
    rng = np.random.default_rng(5)
    U = rng.normal(size=(b.n_coeff, ne)) * 0.5
    G = rng.normal(size=(b.n_coeff, ne)) * 0.3
    aft = AFT(cs, b)
    assert aft.closing == closing
    r = aft.evaluate(U, G)
    Ft, Nc, Juu, Jug, JNN = anchor_aft_numpy(U, G, cs.gap0, cs.kn, k, g, cs.N0, b, True,
                                             closing=closing)
    assert np.allclose(r.Ft, Ft, rtol=0, atol=1e-12)
    assert np.allclose(r.Juu, Juu, rtol=0, atol=1e-12)
    assert np.allclose(r.Jug, Jug, rtol=0, atol=1e-12)
