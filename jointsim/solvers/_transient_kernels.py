"""Numba kernels of the time-marching solver.

:func:`march_dense` is the fused generalized-alpha march of a dense model
(lumped and reduced models) with anchored slider banks and penalty normal
contact: the same scheme and the same scalar contact law as the Python
stepper of :mod:`jointsim.solvers.generalized_alpha`, without its per-step overhead.

The contact march kernels are compiled with ``parallel=True`` for harmonic
balance, where one call covers many samples and elements.  Time marching
calls them with one sample per Newton iteration, tens of thousands of times;
there, waking the thread pool costs far more than the work, and on a shared
machine a parallel launch can wait milliseconds for a descheduled worker.
:func:`single_threaded` runs such calls on the calling thread only.
"""
from __future__ import annotations

import contextlib

import numba
import numpy as np
from numba import njit

from ..contact._kernels import anchor_bank_point, normal_point
from ..contact.laws import FUSED_ANCHOR as T_ANCHOR
from ..contact.laws import FUSED_LINEAR as T_LINEAR
from ..contact.normal import FUSED_GIVEN as N_GIVEN
from ..contact.normal import FUSED_UNILATERAL as N_UNILATERAL


@contextlib.contextmanager
def single_threaded():
    """Run numba parallel kernels on one thread inside the block (thread-local)."""
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)


# --------------------------------------------------------------------------
# Fused march of dense models
# --------------------------------------------------------------------------
# The codes of ``tkind`` and ``nkind`` are the laws' ``fused_code``
# (jointsim.contact.laws and jointsim.contact.normal).


@njit(cache=True)
def _contact_sample(y, state, tkind, nkind, k, g, gap0, kn, N0, phi, duu, dug, dgg,
                    new_state, u_out, f_out, N_out):
    """Contact forces and tangent blocks at contact coordinates ``y`` (one sample).

    The tangential law is the anchored slider bank of
    :func:`jointsim.contact._kernels.anchor_bank_point` (or a linear spring),
    the normal load the penalty ``N = kn max(0, -g)`` (unilateral) or
    ``-kn g`` (bilateral), as in :func:`~jointsim.contact._kernels.normal_penalty`.
    Outputs are written into the given arrays; ``state`` is not modified.
    """
    ne = k.shape[0]
    for e in range(ne):
        ue = y[e]
        if nkind == N_GIVEN:
            Ne = N0[e]
            dNdg = 0.0
        else:
            Ne, dNdg = normal_point(gap0[e] + y[ne + e], kn[e], nkind == N_UNILATERAL, False)
        fe = 0.0
        de = 0.0
        dn = 0.0
        if tkind == T_ANCHOR:
            fe, de, dn = anchor_bank_point(ue, Ne, state[e], new_state[e], k[e], g[e])
        elif tkind == T_LINEAR:
            fe = k[e, 0] * ue
            de = k[e, 0]
        phi[e] = fe
        duu[e] = de
        u_out[e] = ue
        f_out[e] = fe
        N_out[e] = Ne
        if nkind != N_GIVEN:
            phi[ne + e] = -Ne
            dug[e] = dn * dNdg
            dgg[e] = -dNdg


@njit(cache=True)
def gap_correction(g0, N0, g1, N1, kn, c, dc):
    """Energy-consistent correction of the averaged unilateral normal force.

    The scheme averages the contact forces between the ends of a step.  For the
    unilateral penalty ``N = kn max(0, -g)`` that average does not match the
    energy stored in the penalty spring when the gap opens or closes within the
    step, and with stiff contacts the mismatch pumps energy into the structure.
    The averaged load ``(1 - af) N1 + af N0`` is therefore replaced by
    ``Nbar + (1/2 - af)(N1 - N0)``, where ``Nbar = -(P(g1) - P(g0)) / (g1 - g0)`` is
    the discrete gradient of the penalty energy ``P(g) = kn min(g, 0)^2 / 2``: the
    normal force then does exactly the work stored in the spring (and the
    ``af < 1/2`` part only dissipates).  Where both ends are in contact or both
    are open, ``Nbar = (N0 + N1) / 2`` and nothing changes.

    Parameters
    ----------
    g0, N0 : ndarray, shape (n_e,)
        Gap [m] and normal load [N] at the start of the step.
    g1, N1 : ndarray, shape (n_e,)
        The same at the trial end of the step.
    kn : ndarray, shape (n_e,)
        Penalty stiffness [N/m].
    c, dc : ndarray, shape (n_e,)
        Output: ``Nbar - (N0 + N1) / 2`` [N] and its derivative by ``g1`` [N/m].
    """
    for e in range(g0.shape[0]):
        a, b = g0[e], g1[e]
        if (a < 0.0) != (b < 0.0):
            d = b - a
            pa = 0.5 * kn[e] * min(a, 0.0) ** 2
            pb = 0.5 * kn[e] * min(b, 0.0) ** 2
            nbar = -(pb - pa) / d
            dnbar = (N1[e] * d + (pb - pa)) / (d * d)
            dN1 = -kn[e] if b < 0.0 else 0.0
            c[e] = nbar - 0.5 * (N0[e] + N1[e])
            dc[e] = dnbar - 0.5 * dN1
        else:
            c[e] = 0.0
            dc[e] = 0.0


@njit(cache=True)
def _force(t, omega, hnum, coef, out):
    """``out = sum_r basis_r(t) coef[r]`` with rows ``[0, 1c, 1s, 2c, 2s, ...]``."""
    out[:] = 0.0
    for r in range(hnum.shape[0]):
        h = hnum[r]
        if h == 0:
            b = 1.0
        elif r % 2 == 1:
            b = np.cos(h * omega * t)
        else:
            b = np.sin(h * omega * t)
        if b != 0.0:
            for j in range(out.shape[0]):
                out[j] += b * coef[r, j]


@njit(cache=True)
def march_dense(times, h, x0, v0, a0, phi0, state0,
                M, C, K, Sinv, B, Bt, Z, G, am, af, gam, bet,
                omega, hnum, coef,
                tkind, nkind, k, g, gap0, kn, N0,
                tol, max_iter):
    """Generalized-alpha steps of a dense model, fused (the scheme: :mod:`.generalized_alpha`).

    Marches from ``times[0]`` through ``times[1:]`` (equal steps), with Newton
    condensed on the contact coordinates and the state committed at the end of
    every step.  Stops at the first step whose Newton solve fails, so that
    the caller can cut that step.

    Parameters
    ----------
    times : ndarray, shape (n + 1,)
        ``times[0]`` is the time of the initial state [s]; the force is
        evaluated at these times.
    h : float
        The step size ``S`` was built for (equal to the spacing of ``times``
        up to round-off) [s].
    x0, v0, a0 : ndarray, shape (n_dof,)
    phi0 : ndarray, shape (n_c,)
        Contact forces at the initial state [N].
    state0 : ndarray, shape (n_e, n_s)
        Anchors of the sliders (anchor law) [m].
    M, C, K, Sinv : ndarray, shape (n_dof, n_dof)
        Matrices and the inverse of the step matrix ``S`` for this step size.
    B, Bt : ndarray, shapes (n_c, n_dof), (n_dof, n_c)
    Z, G : ndarray, shapes (n_dof, n_c), (n_c, n_c)
        ``S^-1 B^T`` and ``B S^-1 B^T``.
    am, af, gam, bet : float
        Generalized-alpha parameters.
    omega : float
        Forcing frequency [rad/s].
    hnum : ndarray of int, shape (n_coeff,)
        Harmonic of each row of ``coef``.
    coef : ndarray, shape (n_coeff, n_dof)
        External force coefficients ``[0, 1c, 1s, ...]`` [N].
    tkind, nkind : int
        Kernel codes (``T_*``, ``N_*``).
    k, g : ndarray, shape (n_e, n_s)
        Slider stiffnesses and slip forces per unit normal load.
    gap0, kn, N0 : ndarray, shape (n_e,)
    tol : float
        Relative Newton tolerance: a step converges when ``max |r|`` is at most
        ``tol`` times the largest contact coordinate of its iterate, its linear
        prediction and its start (a scale of the step alone).
    max_iter : int

    Returns
    -------
    n_done : int
        Steps completed (``n`` unless a Newton solve failed at step ``n_done``).
    iterations : int
        Newton iterations (linear solves).
    X, V, A : ndarray, shape (n + 1, n_dof)
        States at ``times[: n_done + 1]`` (later rows are undefined).
    PHI : ndarray, shape (n + 1, n_c)
    U, F, NN : ndarray, shape (n_e, n + 1)
        Slip, tangential force and normal load.
    state : ndarray, shape (n_e, n_s)
        Law state after step ``n_done``.
    """
    n = times.shape[0] - 1
    nd = x0.shape[0]
    nc = B.shape[0]
    ne = k.shape[0]
    X = np.empty((n + 1, nd))
    V = np.empty((n + 1, nd))
    A = np.empty((n + 1, nd))
    PHI = np.empty((n + 1, nc))
    U = np.zeros((ne, n + 1))
    F = np.zeros((ne, n + 1))
    NN = np.zeros((ne, n + 1))
    X[0] = x0
    V[0] = v0
    A[0] = a0
    PHI[0] = phi0
    state = state0.copy()
    trial = state0.copy()
    phi = np.zeros(nc)
    duu = np.zeros(ne)
    dug = np.zeros(ne)
    dgg = np.zeros(ne)
    ue = np.zeros(ne)
    fe = np.zeros(ne)
    Ne = np.zeros(ne)
    # contact outputs at the initial state
    if nc > 0:
        _contact_sample(B @ x0, state0, tkind, nkind, k, g, gap0, kn, N0, phi, duu, dug,
                        dgg, trial, ue, fe, Ne)
        U[:, 0] = ue
        F[:, 0] = fe
        NN[:, 0] = Ne
    f0 = np.empty(nd)
    f1 = np.empty(nd)
    coefc = 1.0 - af
    unilateral = nkind == N_UNILATERAL
    cvec = np.zeros(nc)
    ce = np.zeros(ne)
    dce = np.zeros(ne)
    g_start = np.zeros(ne)
    g_end = np.zeros(ne)
    J = np.empty((nc, nc))
    iters = 0
    _force(times[0], omega, hnum, coef, f0)
    for j in range(n):
        t1 = times[j + 1]
        x = X[j]
        v = V[j]
        a = A[j]
        _force(t1, omega, hnum, coef, f1)
        a_at = -v / (bet * h) - (0.5 / bet - 1.0) * a
        v_at = v + h * ((1.0 - gam) * a + gam * a_at)
        R = M @ ((1.0 - am) * a_at + am * a) + K @ x + C @ ((1.0 - af) * v_at + af * v) \
            - coefc * f1 - af * f0
        if nc > 0:
            R += af * (Bt @ PHI[j])
        xp = x - Sinv @ R
        if nc > 0:
            yp = B @ xp
            if unilateral:
                g_start[:] = gap0 + (B @ x)[ne:]
            y = B @ (x + h * v + 0.5 * h * h * a)
            refp = max(np.max(np.abs(yp)), np.max(np.abs(B @ x)))
            ok = False
            for it in range(max_iter + 1):
                _contact_sample(y, state, tkind, nkind, k, g, gap0, kn, N0, phi, duu, dug,
                                dgg, trial, ue, fe, Ne)
                if unilateral:
                    g_end[:] = gap0 + y[ne:]
                    gap_correction(g_start, NN[:, j], g_end, Ne, kn, ce, dce)
                    for q in range(ne):
                        cvec[ne + q] = -ce[q]
                r = y - yp + G @ (coefc * phi + cvec)
                err = np.max(np.abs(r))
                if not np.isfinite(err):
                    break
                ref = max(np.max(np.abs(y)), refp)
                if err <= tol * ref or err == 0.0:
                    ok = True
                    break
                if it == max_iter:
                    break
                for p in range(nc):
                    for q in range(ne):
                        J[p, q] = coefc * G[p, q] * duu[q]
                    if nkind != N_GIVEN:
                        for q in range(ne):
                            J[p, ne + q] = coefc * (G[p, q] * dug[q] + G[p, ne + q] * dgg[q])
                            if unilateral:
                                J[p, ne + q] -= G[p, ne + q] * dce[q]
                    J[p, p] += 1.0
                y = y + np.linalg.solve(J, -r)
                iters += 1
            if not ok:
                return j, iters, X, V, A, PHI, U, F, NN, state
            x1 = xp - Z @ (coefc * phi + cvec)
        else:
            x1 = xp
        a1 = (x1 - x - h * v) / (bet * h * h) - (0.5 / bet - 1.0) * a
        v1 = v + h * ((1.0 - gam) * a + gam * a1)
        if not (np.all(np.isfinite(x1)) and np.all(np.isfinite(v1))):
            return j, iters, X, V, A, PHI, U, F, NN, state
        X[j + 1] = x1
        V[j + 1] = v1
        A[j + 1] = a1
        if nc > 0:
            PHI[j + 1] = phi
            state[:, :] = trial
            U[:, j + 1] = ue
            F[:, j + 1] = fe
            NN[:, j + 1] = Ne
        f0[:] = f1
    return n, iters, X, V, A, PHI, U, F, NN, state
