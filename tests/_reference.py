"""Plain-NumPy reference implementations of the contact kernels.

Written independently of jointsim.contact._kernels, directly from DESIGN §2,
so that the numba kernels can be checked against them.
"""
from __future__ import annotations

import numpy as np


def anchor_bank(u, N, k, g, w0):
    """Parallel Jenkins sliders with anchors; arrays as in march_bank(BANK_ANCHOR, ...)."""
    u, N = np.atleast_2d(u), np.atleast_2d(N)
    w = np.array(w0, dtype=float, copy=True)
    f = np.zeros(u.shape)
    for t in range(u.shape[1]):
        ut, Nt = u[:, t:t + 1], N[:, t:t + 1]
        trial = k * (ut - w)
        limit = g * np.maximum(Nt, 0.0)
        force = np.clip(trial, -limit, limit)
        slipped = np.abs(trial) > limit
        w = np.where(slipped, ut - np.divide(force, k, out=np.zeros_like(force), where=k > 0), w)
        separated = np.broadcast_to(Nt <= 0.0, w.shape)
        w = np.where(separated, np.broadcast_to(ut, w.shape), w)
        force = np.where(separated, 0.0, force)
        f[:, t] = force.sum(axis=1)
    return f, w


def scaled_bank(u, N, k, g, N_start):
    """Scaled-reversal sliders (seed Eq. 7) from rest at u = 0."""
    u, N = np.atleast_2d(u), np.atleast_2d(N)
    ne, nt = u.shape
    f = np.zeros((ne, nt))
    for e in range(ne):
        u_prev, N_prev, direction = 0.0, N_start[e], 0.0
        u_r, N_r = 0.0, N_start[e]
        f_prev = np.zeros(k.shape[1])
        f_r = np.zeros(k.shape[1])
        for t in range(nt):
            du = u[e, t] - u_prev
            if du != 0.0:
                d = np.sign(du)
                if direction != 0.0 and d != direction:
                    u_r, N_r, f_r = u_prev, N_prev, f_prev.copy()
                direction = d
            Nt = N[e, t]
            ref = f_r * Nt / N_r if N_r > 0.0 else 0.0 * f_r
            lim = g[e] * max(Nt, 0.0)
            fi = np.clip(k[e] * (u[e, t] - u_r) + ref, -lim, lim)
            f_prev = fi
            u_prev, N_prev = u[e, t], Nt
            f[e, t] = fi.sum()
    return f


def manifold_bank(u, N, k, g, u0=None):
    """Manifold reversal law from its definition (DESIGN §2, issue 14), plain Python.

    Masing's memory as a Python list of open reversals ``(u_r, N_r, f_r)``:
    a reversal is pushed when the direction of ``u`` changes; an inner loop
    closes when ``u`` reaches the reversal before the current one (both are
    removed); with two left the older is removed when reached.  Force:
    ``f_r N/N_r + 2 s fbb(|u - u_r|/2; N)`` (backbone before the first
    reversal), clipped to ``+-sum(g) N``, 0 for ``N <= 0``.  Unbounded stack.
    """
    ne, nt = u.shape
    f = np.zeros((ne, nt))
    for e in range(ne):
        up = 0.0 if u0 is None else u0[e]
        base = up
        Np, fp, d = N[e, 0], 0.0, 0
        stack = []
        for t in range(nt):
            ut, Nt = u[e, t], N[e, t]
            if ut != up:
                dn = 1 if ut > up else -1
                if d != 0 and dn != d:
                    stack.append((up, Np, fp))
                d = dn
                while len(stack) >= 2 and (ut - stack[-2][0]) * d >= 0.0:
                    if len(stack) >= 3:
                        del stack[-2:]
                    else:
                        del stack[0]
            if Nt <= 0.0:
                ft = 0.0
            else:
                bb = lambda x: np.minimum(k[e] * x, g[e] * Nt).sum()  # noqa: E731
                if not stack:
                    ft = np.sign(ut - base) * bb(abs(ut - base))
                else:
                    ur, Nr, fr = stack[-1]
                    ft = (fr * (Nt / Nr) if Nr > 0.0 else 0.0) \
                        + 2.0 * np.sign(ut - ur) * bb(0.5 * abs(ut - ur))
                lim = g[e].sum() * Nt
                ft = min(max(ft, -lim), lim)
            f[e, t] = ft
            up, Np, fp = ut, Nt, ft
    return f


def normal(gap, kn, unilateral=True):
    N = -kn[:, None] * gap
    return np.where(gap >= 0.0, 0.0, N) if unilateral else N


def jenkins_describing(A, kt, Fs):
    """First-harmonic coefficients and dissipation of Jenkins under u = A cos(theta).

    DESIGN §5: f ~ c1 cos(theta) + s1 sin(theta), D = 4 Fs (A - Fs/kt).
    """
    if kt * A <= Fs:
        return kt * A, 0.0, 0.0
    beta = np.arccos(1.0 - 2.0 * Fs / (kt * A))
    c1 = kt * A / np.pi * (beta - np.sin(2.0 * beta) / 2.0)
    s1 = -4.0 * Fs / np.pi * (1.0 - Fs / (kt * A))
    D = 4.0 * Fs * (A - Fs / kt)
    return c1, s1, D


def loop_dissipation(u, f):
    """Work done on the element over one closed period, the trapezoidal integral of f du."""
    u1 = np.concatenate([u, u[:1]])
    f1 = np.concatenate([f, f[:1]])
    return float(np.sum(0.5 * (f1[1:] + f1[:-1]) * np.diff(u1)))
