"""Numba AFT kernel of the manifold reversal law, with history derivatives.

The law (:class:`jointsim.contact.laws.ManifoldBank`) is the seed's Eq. 7
scaling with the Masing manifold's own memory: after the governing reversal
``(u_r, N_r, f_r)`` (the top of a stack that is popped when an inner loop
closes) the element force is

    f = f_r N / N_r + 2 sgn(u - u_r) f_bb(|u - u_r| / 2; N),

clipped to ``+-mu N`` and 0 while ``N <= 0``.  This module marches it over
one period of samples, period after period from rest until the state
repeats, exactly as :func:`jointsim.contact._aft_kernels.scaled_aft` does for
Eq. 7, with the same scalar law (:func:`jointsim.contact._kernels.manifold_force`)
and the same memory rule (:func:`jointsim.contact._kernels.manifold_memory_rows`)
as the time-marching kernel, so the forces are the time march's.

Derivatives through the history
-------------------------------
With ``u(t) = Gam[t] @ U`` and the normal load ``N(g(t))``, ``g(t) = Gam[t]
@ G + gap0``, the reversal data of a stack entry pushed at sample ``r`` have
the derivatives ``du_r = Gam[r]`` (u part), ``dN_r = N'(g_r) Gam[r]`` (g
part) and ``df_r`` = the total derivative of the force at ``r``: its
instantaneous tangents times ``Gam[r]`` plus the partials by its own
governing reversal's data times *that* entry's derivatives (a dense vector
of ``2 n_c`` per entry, kept in a companion row that moves with the stack).
When inner loops close the stack pops and the force at later samples follows
an older entry, whose stored derivatives then apply.  Between changes of the
governing entry the per-sample weights ``P[:, t] df_t/d(u_r, N_r, f_r)`` are
summed (``O(n_c)`` per sample) and flushed as outer products with the
entry's derivatives when it changes (``O(n_c^2)`` per change), in the last
period only.  Pops depend on ``u`` alone and the clip sets the memory
partials to zero, so away from kinks (reversals, pops, slip onset, the clip
and separation switching) the Jacobian is exact.

The law is element-level (one backbone ``f_bb = sum_i min(k_i x, g_i N)`` of
the whole slider bank), so Jenkins (one slider) and the discretised Iwan
element (many sliders) share this kernel; a slider adds ``O(1)`` per sample.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from ._aft_kernels import _alloc, _threaded
from ._kernels import (MF_DEPTH, MF_DIR, MF_F_PREV, MF_N_PREV, MF_SHARED, MF_TOP, MF_U0,
                       MF_U_PREV, manifold_closes, manifold_direction, manifold_force,
                       manifold_memory_rows)


@njit(cache=True, inline="always")
def _flush(Juu, Jug, e, Gam, Aur, ANr, Afr, row, coupled):
    """Add the summed weights times the derivatives of stack entry ``row``.

    ``row`` is ``[df_r/dU (n_c), df_r/dG (n_c), r, N'(g_r)]``.
    """
    nc = Gam.shape[1]
    r = int(row[2 * nc])
    cN = row[2 * nc + 1]
    for kk in range(nc):
        x_ur = Aur[kk]
        x_Nr = ANr[kk] * cN
        x_fr = Afr[kk]
        if x_ur == 0.0 and x_Nr == 0.0 and x_fr == 0.0:
            continue
        for j in range(nc):
            Juu[e, kk, j] += x_ur * Gam[r, j] + x_fr * row[j]
            if coupled:
                Jug[e, kk, j] += x_Nr * Gam[r, j] + x_fr * row[nc + j]
        Aur[kk] = 0.0
        ANr[kk] = 0.0
        Afr[kk] = 0.0


@njit(cache=True)
def _manifold_one(e, u, N, dNdg, k, g, P, Gam, min_periods, max_periods, tol, coupled,
                  f, au, ag, Juu, Jug, periods, change):
    """One element of :func:`manifold_aft` (outputs written in place)."""
    nt = u.shape[1]
    nc = Gam.shape[1]
    nstate = MF_SHARED + 3 * MF_DEPTH
    ke = k[e:e + 1]
    ge = g[e:e + 1]
    st = np.zeros((1, nstate))
    st[0, MF_N_PREV] = N[e, 0]
    st0 = np.zeros(nstate)
    rows = np.zeros((MF_DEPTH, 2 * nc + 2))
    row = np.zeros(2 * nc + 2)
    Aur = np.zeros(nc)
    ANr = np.zeros(nc)
    Afr = np.zeros(nc)
    # partials of the force at the previous sample
    pu = 0.0
    pN = 0.0
    pur = 0.0
    pNr = 0.0
    pfr = 0.0
    tprev = 0
    # scales of the periodicity test: u, N and f entries separately
    uscale = 0.0
    nscale = 0.0
    for t in range(nt):
        uscale = max(uscale, abs(u[e, t]))
        nscale = max(nscale, abs(N[e, t]))
    gsum = 0.0
    for i in range(k.shape[1]):
        gsum += g[e, i]
    fscale = gsum * nscale
    uscale = uscale if uscale > 0.0 else 1.0
    nscale = nscale if nscale > 0.0 else 1.0
    fscale = fscale if fscale > 0.0 else 1.0
    for p in range(max_periods):
        Juu[e, :, :] = 0.0
        Jug[e, :, :] = 0.0
        for kk in range(nc):
            Aur[kk] = 0.0
            ANr[kk] = 0.0
            Afr[kk] = 0.0
        for q in range(nstate):
            st0[q] = st[0, q]
        # the Jacobian of a period that cannot be the last is not needed (the
        # derivatives of the stack entries are, in every period)
        acc = p + 1 >= min_periods
        for t in range(nt):
            ut = u[e, t]
            Nt = N[e, t]
            dn = dNdg[e, t]
            top0 = int(st[0, MF_TOP])
            _d, rev = manifold_direction(st, 0, ut)
            if rev:
                # the previous sample becomes a stack entry: flush the weights
                # of the governing entry, then the total derivative of f there
                gov = top0 - 1
                if gov >= 0 and acc:
                    _flush(Juu, Jug, e, Gam, Aur, ANr, Afr, rows[gov], coupled)
                dnp = dNdg[e, tprev]
                for j in range(nc):
                    gj = Gam[tprev, j]
                    row[j] = pu * gj
                    row[nc + j] = pN * dnp * gj
                if gov >= 0 and (pur != 0.0 or pNr != 0.0 or pfr != 0.0):
                    r = int(rows[gov, 2 * nc])
                    cN = rows[gov, 2 * nc + 1]
                    for j in range(nc):
                        gr = Gam[r, j]
                        row[j] += pur * gr + pfr * rows[gov, j]
                        row[nc + j] += pNr * cN * gr + pfr * rows[gov, nc + j]
                row[2 * nc] = tprev
                row[2 * nc + 1] = dnp
            # the common sample (no push, no pop) in line: with the full update
            # on every sample the march took 1.7x as long (Jenkins, H = 7)
            if rev or manifold_closes(st, 0, ut, _d):
                popped = manifold_memory_rows(st, 0, ut, rows, row)
            else:
                popped = 0
                if _d != 0.0:
                    st[0, MF_DIR] = _d
            if popped > 0 and not rev and acc:
                # an inner loop closed: the old governing entry (intact above
                # the new top) has had its last sample
                _flush(Juu, Jug, e, Gam, Aur, ANr, Afr, rows[top0 - 1], coupled)
            fe, pu, pN, pur, pNr, pfr = manifold_force(st, 0, ut, Nt, ke, ge)
            if acc and (pur != 0.0 or pNr != 0.0 or pfr != 0.0):
                for kk in range(nc):
                    pk = P[kk, t]
                    Aur[kk] += pk * pur
                    ANr[kk] += pk * pNr
                    Afr[kk] += pk * pfr
            st[0, MF_U_PREV] = ut
            st[0, MF_N_PREV] = Nt
            st[0, MF_F_PREV] = fe
            tprev = t
            f[e, t] = fe
            au[e, t] = pu
            ag[e, t] = pN * dn
        top = int(st[0, MF_TOP])
        if top > 0 and acc:
            _flush(Juu, Jug, e, Gam, Aur, ANr, Afr, rows[top - 1], coupled)
        # periodicity of the state, each entry against the scale of its unit
        if top != int(st0[MF_TOP]) or st[0, MF_DIR] != st0[MF_DIR]:
            rel = np.inf
        else:
            rel = max(abs(st[0, MF_U_PREV] - st0[MF_U_PREV]) / uscale,
                      abs(st[0, MF_U0] - st0[MF_U0]) / uscale,
                      abs(st[0, MF_N_PREV] - st0[MF_N_PREV]) / nscale,
                      abs(st[0, MF_F_PREV] - st0[MF_F_PREV]) / fscale)
            for j in range(top):
                b = MF_SHARED + 3 * j
                rel = max(rel, abs(st[0, b] - st0[b]) / uscale,
                          abs(st[0, b + 1] - st0[b + 1]) / nscale,
                          abs(st[0, b + 2] - st0[b + 2]) / fscale)
        periods[e] = p + 1
        change[e] = rel
        if p + 1 >= min_periods and rel <= tol:
            break


@njit(cache=True)
def _manifold_serial(u, N, dNdg, k, g, P, Gam, min_periods, max_periods, tol, coupled,
                     f, au, ag, Juu, Jug, periods, change):
    for e in range(u.shape[0]):
        _manifold_one(e, u, N, dNdg, k, g, P, Gam, min_periods, max_periods, tol, coupled,
                      f, au, ag, Juu, Jug, periods, change)


@njit(cache=True, parallel=True)
def _manifold_parallel(u, N, dNdg, k, g, P, Gam, min_periods, max_periods, tol, coupled,
                       f, au, ag, Juu, Jug, periods, change):
    for e in prange(u.shape[0]):
        # prange's index is uint64: cast, so the element kernel keeps the one
        # compiled signature of the serial driver (a second costs 1 to 15 s cold)
        _manifold_one(np.int64(e), u, N, dNdg, k, g, P, Gam, min_periods, max_periods, tol,
                      coupled, f, au, ag, Juu, Jug, periods, change)


def manifold_aft(u, N, dNdg, k, g, P, Gam, min_periods, max_periods, tol, coupled,
                 parallel=True):
    """Periodic march of manifold-law elements with history derivatives.

    Parameters
    ----------
    u, N, dNdg : ndarray, shape (n_e, n_t)
        Tangential displacement [m], normal load [N] and ``dN/dg`` [N/m] at
        the samples of one period.
    k, g : ndarray, shape (n_e, n_s)
        Slider stiffness [N/m] and slip force per unit normal load [-] of the
        bank whose backbone the law follows.
    P : ndarray, shape (n_c, n_t)
        DFT matrix (coefficients from samples).
    Gam : ndarray, shape (n_t, n_c)
        Inverse DFT matrix (samples from coefficients).
    min_periods, max_periods : int
        Periods marched at least / at most.
    tol : float
        Periodicity tolerance: the largest change of a state entry over a
        period relative to ``max |u|``, ``max |N|`` or ``mu max |N|`` (by its
        unit); the number of open reversals must repeat exactly.
    coupled : bool
        Compute the derivatives with respect to the gap coefficients.
    parallel : bool
        Allow numba threads (on enough work, see
        :func:`jointsim.contact._aft_kernels._threaded`).

    Returns
    -------
    f, au, ag : ndarray, shape (n_e, n_t)
        Force [N] over the last period and its instantaneous tangents
        ``df/du`` [N/m] and ``df/dN * dN/dg`` [N/m].
    Juu, Jug : ndarray, shape (n_e, n_c, n_c)
        History part of ``dF/dU`` and ``dF/dG`` (``F = P f``).
    periods : ndarray of int, shape (n_e,)
        Periods marched.
    change : ndarray, shape (n_e,)
        Relative state change over the last period (``inf`` when the number
        of open reversals or the direction did not repeat).
    """
    ne, nt = u.shape
    out = _alloc(ne, nt, Gam.shape[1])
    run = _manifold_parallel if _threaded(parallel, ne, u.shape[1], Gam.shape[1]) \
        else _manifold_serial
    run(np.ascontiguousarray(u, dtype=float), np.ascontiguousarray(N, dtype=float),
        np.ascontiguousarray(dNdg, dtype=float), np.ascontiguousarray(k, dtype=float),
        np.ascontiguousarray(g, dtype=float), np.ascontiguousarray(P), np.ascontiguousarray(Gam),
        int(min_periods), int(max_periods), float(tol), bool(coupled), *out)
    return out
