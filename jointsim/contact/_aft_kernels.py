"""Numba kernels of the AFT harmonic balance: periodic march of the contact
laws with forward-mode derivatives through the history.

Every kernel works on one period of samples of the element inputs (the
inputs are periodic, so sample ``t`` of any period is sample ``t`` of the
first), marches the law from its rest state period after period until the
state at the end of a period equals the state at its start (at least
``min_periods`` periods), and returns the force over the last period.

Derivatives
-----------
The force at sample ``t`` depends on the inputs at ``t`` (the instantaneous
tangents ``au = df/du`` and ``ag = df/dN * dN/dg``, returned per sample) and,
through the law's state, on the inputs at earlier samples (the *history*
terms).  The unknowns are the harmonic coefficients ``U`` of ``u`` and ``G``
of the normal gap, with ``u(t) = Gam[t] @ U``.  The history part of the
Jacobian of the force coefficients ``F = P @ f``,
``sum_t P[:, t] (df_t/dstate) (dstate/d(U, G))``, is accumulated here, in
the last period only, as outer products:

* ``bank_anchor`` -- the derivative of a slider's anchor is always
  ``a Gam[s] (u part) + b Gam[s] (g part)`` with ``s`` the last sample where
  the slider slipped or was separated (``dw1/dw = 0`` there); while it sticks
  ``df/dw = -k``.  A stick run ``[t0, t1)`` contributes
  ``-k (CP[:, t1] - CP[:, t0]) (x) (a Gam[s], b Gam[s])`` with ``CP`` the
  prefix sums of the columns of ``P``: ``O(n_c^2)`` per run, not per sample.
* ``bank_scaled`` -- the reversal memory ``(u_r, N_r, f_r)`` changes only at
  reversals; ``du_r`` and ``dN_r`` are single rows of ``Gam`` and ``df_r``
  is a dense vector per slider, updated at each reversal by the chain rule
  through the law's partials.  Between reversals the per-sample weights are
  summed (``O(n_c)`` per sample) and flushed as outer products at the next
  reversal.

The instantaneous part ``P diag(a) Gam`` is assembled from the Fourier sums
of the tangents up to harmonic ``2 max(h)`` (:func:`jointsim._harmonic_kernels.add_diag_products`), so no
``n_c x n_t x n_c`` product is formed per element.

With the gap samples (``joint.closing = "interpolated"``) the anchored march also
places the anchor of a re-closing contact at the closing instant
(:func:`closing_anchor`) and integrates the interval in which a contact opens up to
the opening instant (:func:`opening_weights`; its correction of ``P f`` is returned in
``dF``, its derivatives go to the history blocks).

The laws themselves are the scalar functions of
:mod:`jointsim.contact._kernels` (``slider_anchor_step``,
``slider_scaled_force``); this module only marches them.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

#: Elements from which the drivers run in parallel threads (below, thread start-up
#: and barrier waits cost more than the work, badly so on a loaded machine).
PARALLEL_MIN = 64
#: ... and work (elements x samples x coefficients, the history Jacobian's size)
#: from which they do.  Measured on the 2-core machine shared with other jobs
#: (load 16 to 20), the 121-pair lap joint's AFT with its Jacobian: H = 0..7,
#: 128 samples (2.3e5): 4.5 ms on one thread against 190 ms threaded; the error
#: indicators' H = 0..15, 512 samples (1.9e6): 260 ms against 775 ms (a parallel
#: region waits at its barrier for a descheduled thread, as threaded BLAS does,
#: see :func:`jointsim.blas.limit_blas_threads`).
PARALLEL_MIN_WORK = 4_000_000

from ._kernels import (SC_DIR, SC_N_PREV, SC_N_R, SC_SHARED, SC_U_PREV, SC_U_R,
                                slider_anchor_step, slider_scaled_force)


def _threaded(parallel: bool, ne: int, nt: int, nc: int) -> bool:
    """Whether a driver runs on numba threads (``PARALLEL_MIN``, ``PARALLEL_MIN_WORK``)."""
    return bool(parallel) and ne >= PARALLEL_MIN and ne * nt * nc >= PARALLEL_MIN_WORK


@njit(cache=True, inline="always")
def _flush_run(Juu, Jug, e, CP, Gam, t0, t1, coef, s, a, b, coupled, s2=-1, a2=0.0, b2=0.0):
    """Add ``coef * (CP[:, t1] - CP[:, t0]) (x) (a Gam[s] + a2 Gam[s2], b Gam[s] + b2 Gam[s2])``
    (the second row only when ``s2 >= 0``: an anchor taken at a closing instant
    between the samples ``s`` and ``s2``)."""
    if s < 0 or t1 <= t0:
        return
    nc = Gam.shape[1]
    for kk in range(nc):
        pk = coef * (CP[kk, t1] - CP[kk, t0])
        if pk == 0.0:
            continue
        pa = pk * a
        pb = pk * b
        for j in range(nc):
            Juu[e, kk, j] += pa * Gam[s, j]
            if coupled:
                Jug[e, kk, j] += pb * Gam[s, j]
        if s2 >= 0:
            pa = pk * a2
            pb = pk * b2
            for j in range(nc):
                Juu[e, kk, j] += pa * Gam[s2, j]
                if coupled:
                    Jug[e, kk, j] += pb * Gam[s2, j]


@njit(cache=True, inline="always")
def closing_anchor(u0, u1, g0, g1):
    """Anchor at the closing instant between two samples, and its partials.

    The gap falls from ``g0 >= 0`` (open) to ``g1 < 0`` (closed); linear
    interpolation puts the closing at the fraction ``th = g0 / (g0 - g1)`` of the
    interval, where the slip is ``wc = u0 + th (u1 - u0)``: the anchor a
    separated slider takes when the contact closes.

    Returns
    -------
    wc, dwdu0, dwdu1, dwdg0, dwdg1 : float
        Anchor [m] and its partial derivatives by the slips [-] and gaps [-].
    """
    d = g0 - g1
    th = g0 / d
    du = u1 - u0
    return u0 + th * du, 1.0 - th, th, -du * g1 / (d * d), du * g0 / (d * d)


@njit(cache=True, inline="always")
def opening_weights(F0, D, S, phi, c0, c1):
    """Sub-sample quadrature of a slider's force over the interval in which its
    contact opens, and its partials.

    Between the last closed sample (``s = 0``) and the first open one (``s = 1``,
    ``s`` the fraction of the sample interval) the inputs are linear: the trial
    (stuck) force is ``F0 + s D`` and the slip limit ``S (1 - s / phi)``, zero at
    the opening instant ``s = phi``.  With linear inputs the Jenkins slider's
    force is exactly ``clip(F0 + s D, -S (1 - s/phi), S (1 - s/phi))`` on
    ``[0, phi]`` (once it reaches the falling limit it stays on it) and 0 after:
    stuck up to ``s1`` and then on the limit, ``s1 -> phi`` as mu -> infinity (the
    stuck force then drops to 0 at the opening instant).  Returned is
    ``Q = int_0^phi f(s) (c0 + c1 s) ds``.

    Parameters
    ----------
    F0 : float
        Force at the last closed sample, ``k (u_t - w)`` [N], ``|F0| <= S``.
    D : float
        Change of the trial force over the interval, ``k (u_{t+1} - u_t)`` [N].
    S : float
        Slip force at the last closed sample, ``g N_t`` [N], > 0.
    phi : float
        Opening instant, fraction of the interval, in (0, 1].
    c0, c1 : float
        Weight ``c0 + c1 s``.

    Returns
    -------
    Q, dQdF0, dQdD, dQdS, dQdphi : float
        The integral [N] and its partial derivatives (the stick/slip switch ``s1``
        needs none: ``f`` is continuous there; with ``S = inf``, never slipping,
        ``f`` drops to 0 at ``phi`` and ``dQ/dphi`` is that jump times the weight).
    """
    tr = F0 + phi * D
    sg = 1.0 if tr > 0.0 else (-1.0 if tr < 0.0 else 0.0)
    L = 0.0                                   # phi - s1: length of the slip part
    if sg != 0.0:
        L = tr / (D + sg * S / phi)
        L = min(max(L, 0.0), phi)
    s1 = phi - L
    m0 = s1
    m1 = s1 * s1 / 2.0
    m2 = s1 * s1 * s1 / 3.0
    dF0 = c0 * m0 + c1 * m1
    dD = c0 * m1 + c1 * m2
    q = F0 * dF0 + D * dD
    dS = 0.0
    dphi = 0.0
    if L > 0.0:
        # slip part, r = phi - s in [0, L]: int sg S (r / phi) (c0 + c1 phi - c1 r) dr
        cc = c0 + c1 * phi
        L2 = L * L
        L3 = L2 * L
        dS = sg * (cc * L2 / 2.0 - c1 * L3 / 3.0) / phi
        q += S * dS
        # d/dphi at fixed s1: int sg S (s / phi^2) (c0 + c1 s) ds, s = phi - r
        dphi = sg * S * (phi * cc * L - cc * L2 / 2.0 - c1 * phi * L2 / 2.0
                         + c1 * L3 / 3.0) / (phi * phi)
    else:
        # stuck up to the opening (S = inf, the never-slipping limit): the force
        # jumps to 0 at s = phi, whose derivative is the boundary term
        dphi = tr * (c0 + c1 * phi)
    return q, dF0, dD, dS, dphi


@njit(cache=True, inline="always")
def _add_outer(Jx, e, v, c, Gam, s):
    """``Jx[e] += v (x) c Gam[s]`` (nothing when ``s < 0`` or ``c == 0``)."""
    if s < 0 or c == 0.0:
        return
    nc = Gam.shape[1]
    for kk in range(nc):
        pk = v[kk] * c
        if pk == 0.0:
            continue
        for j in range(nc):
            Jx[e, kk, j] += pk * Gam[s, j]


@njit(cache=True, inline="always")
def _opening(e, t, tn, u, gap, dn, k, g, Nt, w, s, a, b, s2, a2, b2, CP, Gam, coupled, dF,
             Juu, Jug, Pt, Pn, vw, cut, cun, cgt, cgn):
    """Opening-interval correction of :func:`_anchor_one` (see :func:`anchor_aft`):
    ``dF[e] += P_t (A - f_t / 2) + P_tn B`` over the sliders, with ``A``, ``B`` the
    quadrature of the force against the weights ``2 - 3 s`` and ``3 s - 1`` (the
    linear weights for which the trapezoid rule is the integral of the linear
    interpolant of ``f``), and its exact derivatives: by ``u_t``, ``u_tn``
    (``Juu``), by ``N_t`` and the opening instant ``phi = g_t / (g_t - g_tn)``
    (``Jug``) and, through the anchor's history rows, by the earlier samples."""
    nc = Gam.shape[1]
    g0 = gap[e, t]
    g1 = gap[e, tn]
    d = g0 - g1
    phi = g0 / d
    dpg0 = -g1 / (d * d)
    dpg1 = g0 / (d * d)
    ut = u[e, t]
    un = u[e, tn]
    for kk in range(nc):
        Pt[kk] = CP[kk, t + 1] - CP[kk, t]
        Pn[kk] = CP[kk, tn + 1] - CP[kk, tn]
        cut[kk] = 0.0
        cun[kk] = 0.0
        cgt[kk] = 0.0
        cgn[kk] = 0.0
    for i in range(k.shape[1]):
        ki = k[e, i]
        F0 = ki * (ut - w[i])
        D = ki * (un - ut)
        S = g[e, i] * Nt
        qa, aF, aD, aS, aP = opening_weights(F0, D, S, phi, 2.0, -3.0)
        qb, bF, bD, bS, bP = opening_weights(F0, D, S, phi, -1.0, 3.0)
        # dS/dg; 0 when the slider sticks up to the opening (so that g = inf, the
        # never-slipping limit, stays finite)
        cS = g[e, i] * dn if (aS != 0.0 or bS != 0.0) else 0.0
        for kk in range(nc):
            dF[e, kk] += Pt[kk] * (qa - 0.5 * F0) + Pn[kk] * qb
            vF = Pt[kk] * (aF - 0.5) + Pn[kk] * bF
            vD = Pt[kk] * aD + Pn[kk] * bD
            vS = Pt[kk] * aS + Pn[kk] * bS
            vP = Pt[kk] * aP + Pn[kk] * bP
            cut[kk] += ki * (vF - vD)
            cun[kk] += ki * vD
            cgt[kk] += cS * vS + dpg0 * vP
            cgn[kk] += dpg1 * vP
            vw[kk] = -ki * vF
        # the anchor after sample t: a Gam[s] + a2 Gam[s2] (u), b ... (gap)
        _add_outer(Juu, e, vw, a[i], Gam, s[i])
        _add_outer(Juu, e, vw, a2[i], Gam, s2[i])
        if coupled:
            _add_outer(Jug, e, vw, b[i], Gam, s[i])
            _add_outer(Jug, e, vw, b2[i], Gam, s2[i])
    _add_outer(Juu, e, cut, 1.0, Gam, t)
    _add_outer(Juu, e, cun, 1.0, Gam, tn)
    if coupled:
        _add_outer(Jug, e, cgt, 1.0, Gam, t)
        _add_outer(Jug, e, cgn, 1.0, Gam, tn)


@njit(cache=True)
def _anchor_one(e, u, N, dNdg, k, g, CP, Gam, min_periods, max_periods, tol, coupled,
                gap, interpolate, dF, f, au, ag, Juu, Jug, periods, change):
    """One element of :func:`anchor_aft` (outputs written in place)."""
    nt = u.shape[1]
    ns = k.shape[1]
    nc = Gam.shape[1]
    # opening quadrature: DFT columns of the two samples and derivative vectors (one
    # allocation, and a dummy without interpolation: this runs per element)
    work = np.zeros((7, nc if interpolate else 1))
    Pt = work[0]
    Pn = work[1]
    vw = work[2]
    cut = work[3]
    cun = work[4]
    cgt = work[5]
    cgn = work[6]
    w = np.zeros(ns)
    wstart = np.zeros(ns)
    s = np.full(ns, -1, dtype=np.int64)
    a = np.zeros(ns)
    b = np.zeros(ns)
    s2 = np.full(ns, -1, dtype=np.int64)
    a2 = np.zeros(ns)
    b2 = np.zeros(ns)
    start = np.zeros(ns, dtype=np.int64)
    umax = 0.0
    for t in range(nt):
        umax = max(umax, abs(u[e, t]))
    for p in range(max_periods):
        Juu[e, :, :] = 0.0
        Jug[e, :, :] = 0.0
        dF[e, :] = 0.0
        for i in range(ns):
            start[i] = 0
            wstart[i] = w[i]
        for t in range(nt):
            ut = u[e, t]
            Nt = N[e, t]
            dn = dNdg[e, t]
            fe = 0.0
            de = 0.0
            dg = 0.0
            tp = t - 1 if t > 0 else nt - 1
            if interpolate and Nt > 0.0 and N[e, tp] <= 0.0 and gap[e, tp] > gap[e, t]:
                # the contact closed between the samples tp and t: every slider
                # (separated at tp, w = u there) takes its anchor at the closing
                # instant, and a stick run starts at t itself
                wc, dwu0, dwu1, dwg0, dwg1 = closing_anchor(u[e, tp], ut, gap[e, tp],
                                                            gap[e, t])
                for i in range(ns):
                    _flush_run(Juu, Jug, e, CP, Gam, start[i], t, -k[e, i], s[i], a[i],
                               b[i], coupled, s2[i], a2[i], b2[i])
                    w[i] = wc
                    s[i] = tp
                    a[i] = dwu0
                    b[i] = dwg0
                    s2[i] = t
                    a2[i] = dwu1
                    b2[i] = dwg1
                    start[i] = t
            for i in range(ns):
                fi, dfi, dni, _dfw, w1, dw1du, dw1dN, dw1dw = slider_anchor_step(
                    ut, Nt, w[i], k[e, i], g[e, i])
                if dw1dw == 0.0:
                    # slipped or separated: the anchor follows the inputs at t
                    _flush_run(Juu, Jug, e, CP, Gam, start[i], t, -k[e, i], s[i],
                               a[i], b[i], coupled, s2[i], a2[i], b2[i])
                    s[i] = t
                    a[i] = dw1du
                    b[i] = dw1dN * dn
                    s2[i] = -1
                    start[i] = t + 1
                w[i] = w1
                fe += fi
                de += dfi
                dg += dni * dn
            f[e, t] = fe
            au[e, t] = de
            ag[e, t] = dg
            tn = t + 1 if t < nt - 1 else 0
            if interpolate and Nt > 0.0 and N[e, tn] <= 0.0 and gap[e, tn] > gap[e, t]:
                # the contact opens between the samples t and tn: the force of the
                # interval [t, tn] by sub-sample quadrature (opening_weights) instead
                # of the trapezoid's P_t f_t / 2, so the coefficients are continuous
                # when an opening instant crosses a sample (a stuck force drops to 0
                # at the opening instant as mu -> infinity)
                _opening(e, t, tn, u, gap, dn, k, g, Nt, w, s, a, b, s2, a2, b2, CP, Gam,
                         coupled, dF, Juu, Jug, Pt, Pn, vw, cut, cun, cgt, cgn)
        wmax = 0.0
        ch = 0.0
        for i in range(ns):
            _flush_run(Juu, Jug, e, CP, Gam, start[i], nt, -k[e, i], s[i], a[i], b[i],
                       coupled, s2[i], a2[i], b2[i])
            ch = max(ch, abs(w[i] - wstart[i]))
            wmax = max(wmax, abs(w[i]))
        scale = umax + wmax
        rel = ch / scale if scale > 0.0 else 0.0
        periods[e] = p + 1
        change[e] = rel
        if p + 1 >= min_periods and rel <= tol:
            break


def _alloc(ne, nt, nc):
    return (np.zeros((ne, nt)), np.zeros((ne, nt)), np.zeros((ne, nt)), np.zeros((ne, nc, nc)),
            np.zeros((ne, nc, nc)), np.zeros(ne, dtype=np.int64), np.zeros(ne))


@njit(cache=True)
def _anchor_serial(u, N, dNdg, k, g, CP, Gam, min_periods, max_periods, tol, coupled,
                   gap, interpolate, dF, f, au, ag, Juu, Jug, periods, change):
    for e in range(u.shape[0]):
        _anchor_one(e, u, N, dNdg, k, g, CP, Gam, min_periods, max_periods, tol, coupled,
                    gap, interpolate, dF, f, au, ag, Juu, Jug, periods, change)


@njit(cache=True, parallel=True)
def _anchor_parallel(u, N, dNdg, k, g, CP, Gam, min_periods, max_periods, tol, coupled,
                     gap, interpolate, dF, f, au, ag, Juu, Jug, periods, change):
    for e in prange(u.shape[0]):
        # prange's index is uint64: cast, so the element kernel keeps the one
        # compiled signature of the serial driver (a second costs 1 to 15 s cold)
        _anchor_one(np.int64(e), u, N, dNdg, k, g, CP, Gam, min_periods, max_periods, tol,
                    coupled, gap, interpolate, dF, f, au, ag, Juu, Jug, periods, change)


def anchor_aft(u, N, dNdg, k, g, CP, Gam, min_periods, max_periods, tol, coupled,
               parallel=True, gap=None, dF=None):
    """Periodic march of banks of anchored sliders with history derivatives.

    Parameters
    ----------
    u, N, dNdg : ndarray, shape (n_e, n_t)
        Tangential displacement [m], normal load [N] and ``dN/dg`` [N/m] at
        the samples of one period.
    k, g : ndarray, shape (n_e, n_s)
        Slider stiffness [N/m] and slip force per unit normal load [-].
    CP : ndarray, shape (n_c, n_t + 1)
        Prefix sums of the columns of the DFT matrix ``P`` (``n_c x n_t``).
    Gam : ndarray, shape (n_t, n_c)
        Inverse DFT matrix (samples from coefficients).
    min_periods, max_periods : int
        Periods marched at least / at most.
    tol : float
        Periodicity tolerance on the anchors, relative to ``max |u| + max |w|``.
    coupled : bool
        Compute the derivatives with respect to the gap coefficients.
    parallel : bool
        Allow numba threads (from ``PARALLEL_MIN`` elements); False marches on
        the calling thread (e.g. in a worker process).
    gap : ndarray, shape (n_e, n_t), optional
        Normal gap [m] at the samples (``N > 0`` where ``gap < 0``).  Given, a
        slider that was separated at the sample before a closed one takes its
        anchor at the closing instant between them (:func:`closing_anchor`, linear
        in the gap) instead of at the last open sample, so the force is
        continuous in the inputs when a closing instant crosses a sample; and the
        interval in which a contact opens (closed at ``t``, open at ``t + 1``) is
        integrated by sub-sample quadrature up to the opening instant (linear in
        the gap, :func:`opening_weights`), its difference from the sampled
        ``P f`` written to ``dF``, so the force coefficients are continuous when an
        opening instant crosses a sample (a stuck force that drops to 0 there).
        None: the anchor of the last open sample (``u`` there), plain samples.
    dF : ndarray, shape (n_e, n_c), optional
        Output (overwritten): the opening-interval quadrature's correction of
        the force coefficients, ``Ft = P f + dF`` (its derivatives are in
        ``Juu`` and ``Jug``); zero without ``gap``.

    Returns
    -------
    f, au, ag : ndarray, shape (n_e, n_t)
        Force [N] over the last period (at the samples) and its instantaneous
        tangents ``df/du`` [N/m] and ``df/dN * dN/dg`` [N/m].
    Juu, Jug : ndarray, shape (n_e, n_c, n_c)
        History part of ``dF/dU`` and ``dF/dG`` (``F = P f + dF``), with the
        derivatives of the opening quadrature.
    periods : ndarray of int, shape (n_e,)
        Periods marched.
    change : ndarray, shape (n_e,)
        Largest anchor change over the last period, relative [-].
    """
    ne, nt = u.shape
    nc = Gam.shape[1]
    out = _alloc(ne, nt, nc)
    interpolate = gap is not None
    gap = (np.ascontiguousarray(gap, dtype=float) if interpolate else np.zeros((ne, nt)))
    if dF is None:
        dF = np.zeros((ne, nc))
    elif dF.shape != (ne, nc) or dF.dtype != np.float64 or not dF.flags.c_contiguous:
        raise ValueError(f"dF must be a C-contiguous float array of shape {(ne, nc)}")
    run = _anchor_parallel if _threaded(parallel, ne, nt, nc) else _anchor_serial
    run(u, N, dNdg, k, g, CP, Gam, int(min_periods), int(max_periods), float(tol),
        bool(coupled), gap, interpolate, dF, *out)
    return out


@njit(cache=True)
def _scaled_one(e, u, N, dNdg, k, g, N_rest, P, Gam, min_periods, max_periods, tol,
                coupled, f, au, ag, Juu, Jug, periods, change):
    """One element of :func:`scaled_aft` (outputs written in place)."""
    nt = u.shape[1]
    ns = k.shape[1]
    nc = Gam.shape[1]
    nstate = SC_SHARED + 2 * ns
    st = np.zeros(nstate)
    st[SC_N_PREV] = N_rest[e]
    st[SC_N_R] = N_rest[e]
    st0 = np.zeros(nstate)
    # reversal memory derivatives: du_r = Gam[r] (u part), dN_r = cN Gam[r] (g part)
    r = -1
    cN = 0.0
    DFu = np.zeros((ns, nc))      # d f_r / dU per slider
    DFg = np.zeros((ns, nc))      # d f_r / dG per slider
    # partials of each slider's force at the previous sample
    pu = np.zeros(ns)
    pN = np.zeros(ns)
    pur = np.zeros(ns)
    pNr = np.zeros(ns)
    pfr = np.zeros(ns)
    tprev = -1
    # per-slider sums of P[:, t] times the partials, since the last reversal
    Aur = np.zeros((ns, nc))
    ANr = np.zeros((ns, nc))
    Afr = np.zeros((ns, nc))
    newu = np.zeros(nc)
    newg = np.zeros(nc)
    for p in range(max_periods):
        Juu[e, :, :] = 0.0
        Jug[e, :, :] = 0.0
        for i in range(ns):
            for kk in range(nc):
                Aur[i, kk] = 0.0
                ANr[i, kk] = 0.0
                Afr[i, kk] = 0.0
        for q in range(nstate):
            st0[q] = st[q]
        for t in range(nt):
            ut = u[e, t]
            Nt = N[e, t]
            dn = dNdg[e, t]
            du = ut - st[SC_U_PREV]
            if du != 0.0:
                d = 1.0 if du > 0.0 else -1.0
                if st[SC_DIR] != 0.0 and d != st[SC_DIR]:
                    # reversal at the previous sample: flush the sums, then
                    # move the memory (and its derivatives) to that sample
                    for i in range(ns):
                        _flush_scaled(Juu, Jug, e, Gam, Aur[i], ANr[i], Afr[i], DFu[i],
                                      DFg[i], r, cN, coupled)
                        for kk in range(nc):
                            Aur[i, kk] = 0.0
                            ANr[i, kk] = 0.0
                            Afr[i, kk] = 0.0
                    for i in range(ns):
                        dnp = dNdg[e, tprev]
                        for j in range(nc):
                            gu = Gam[tprev, j]
                            vu = pu[i] * gu + pfr[i] * DFu[i, j]
                            vg = pN[i] * dnp * gu + pfr[i] * DFg[i, j]
                            if r >= 0:
                                vu += pur[i] * Gam[r, j]
                                vg += pNr[i] * cN * Gam[r, j]
                            newu[j] = vu
                            newg[j] = vg
                        for j in range(nc):
                            DFu[i, j] = newu[j]
                            DFg[i, j] = newg[j]
                    r = tprev
                    cN = dNdg[e, tprev]
                    st[SC_U_R] = st[SC_U_PREV]
                    st[SC_N_R] = st[SC_N_PREV]
                    for i in range(ns):
                        st[SC_SHARED + ns + i] = st[SC_SHARED + i]
                st[SC_DIR] = d
            fe = 0.0
            de = 0.0
            dg = 0.0
            for i in range(ns):
                fi, dfi, dni, dur, dNr, dfr = slider_scaled_force(
                    ut, Nt, st[SC_U_R], st[SC_N_R], st[SC_SHARED + ns + i], k[e, i],
                    g[e, i])
                st[SC_SHARED + i] = fi
                pu[i] = dfi
                pN[i] = dni
                pur[i] = dur
                pNr[i] = dNr
                pfr[i] = dfr
                if dur != 0.0 or dNr != 0.0 or dfr != 0.0:
                    for kk in range(nc):
                        pk = P[kk, t]
                        Aur[i, kk] += pk * dur
                        ANr[i, kk] += pk * dNr
                        Afr[i, kk] += pk * dfr
                fe += fi
                de += dfi
                dg += dni * dn
            st[SC_U_PREV] = ut
            st[SC_N_PREV] = Nt
            tprev = t
            f[e, t] = fe
            au[e, t] = de
            ag[e, t] = dg
        for i in range(ns):
            _flush_scaled(Juu, Jug, e, Gam, Aur[i], ANr[i], Afr[i], DFu[i], DFg[i], r,
                          cN, coupled)
        ch = 0.0
        big = 0.0
        for q in range(nstate):
            ch = max(ch, abs(st[q] - st0[q]))
            big = max(big, abs(st[q]))
        rel = ch / big if big > 0.0 else 0.0
        periods[e] = p + 1
        change[e] = rel
        if p + 1 >= min_periods and rel <= tol:
            break


@njit(cache=True)
def _scaled_serial(u, N, dNdg, k, g, N_rest, P, Gam, min_periods, max_periods, tol, coupled,
                   f, au, ag, Juu, Jug, periods, change):
    for e in range(u.shape[0]):
        _scaled_one(e, u, N, dNdg, k, g, N_rest, P, Gam, min_periods, max_periods, tol,
                    coupled, f, au, ag, Juu, Jug, periods, change)


@njit(cache=True, parallel=True)
def _scaled_parallel(u, N, dNdg, k, g, N_rest, P, Gam, min_periods, max_periods, tol, coupled,
                     f, au, ag, Juu, Jug, periods, change):
    for e in prange(u.shape[0]):
        # prange's index is uint64: cast, so the element kernel keeps the one
        # compiled signature of the serial driver (a second costs 1 to 15 s cold)
        _scaled_one(np.int64(e), u, N, dNdg, k, g, N_rest, P, Gam, min_periods, max_periods,
                    tol, coupled, f, au, ag, Juu, Jug, periods, change)


def scaled_aft(u, N, dNdg, k, g, N_rest, P, Gam, min_periods, max_periods, tol, coupled,
               parallel=True):
    """Periodic march of banks of scaled-reversal sliders with history derivatives.

    Parameters
    ----------
    u, N, dNdg : ndarray, shape (n_e, n_t)
        As for :func:`anchor_aft`.
    k, g : ndarray, shape (n_e, n_s)
    N_rest : ndarray, shape (n_e,)
        Normal load of the rest state (the reference ``N_r`` before the first
        reversal) [N].
    P : ndarray, shape (n_c, n_t)
        DFT matrix (coefficients from samples).
    Gam : ndarray, shape (n_t, n_c)
    min_periods, max_periods : int
    tol : float
        Periodicity tolerance on the state, relative to its largest entry.
    coupled : bool
    parallel : bool

    Returns
    -------
    f, au, ag, Juu, Jug, periods, change
        As for :func:`anchor_aft`.
    """
    ne, nt = u.shape
    out = _alloc(ne, nt, Gam.shape[1])
    run = _scaled_parallel if _threaded(parallel, ne, u.shape[1], Gam.shape[1]) \
        else _scaled_serial
    run(u, N, dNdg, k, g, N_rest, P, Gam, int(min_periods), int(max_periods), float(tol),
        bool(coupled), *out)
    return out


@njit(cache=True, inline="always")
def _flush_scaled(Juu, Jug, e, Gam, Aur, ANr, Afr, DFu, DFg, r, cN, coupled):
    """Outer products of the summed weights with the memory derivatives."""
    nc = Gam.shape[1]
    for kk in range(nc):
        x_ur = Aur[kk]
        x_Nr = ANr[kk]
        x_fr = Afr[kk]
        if x_ur == 0.0 and x_Nr == 0.0 and x_fr == 0.0:
            continue
        for j in range(nc):
            vu = x_fr * DFu[j]
            if r >= 0:
                vu += x_ur * Gam[r, j]
            Juu[e, kk, j] += vu
            if coupled:
                vg = x_fr * DFg[j]
                if r >= 0:
                    vg += x_Nr * cN * Gam[r, j]
                Jug[e, kk, j] += vg
