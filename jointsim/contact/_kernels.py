"""Numba kernels of the contact laws, over plain arrays.

Every tangential law is a *slider bank*: ``n_s`` Jenkins sliders in parallel,
slider ``i`` of element ``e`` with stiffness ``k[e, i]`` [N/m] and slip force
``g[e, i] * N`` [N] (``g`` is a slip force per unit normal load).  A Jenkins
element is a bank of one slider (``k = kt A``, ``g = mu``); the discretised
4-parameter Iwan element is a bank of ``n_sliders``.

Two reversal rules exist:

* ``anchor`` -- physical elastic dry friction (seed Eq. 1/3).  State: the
  anchor ``w`` of every slider.  Trial force ``k (u - w)``; if it exceeds
  ``g N`` the slider slips, ``f = g N sign`` and ``w = u - f / k``.  While
  ``N <= 0`` the element is separated: ``f = 0`` and ``w = u``.
* ``scaled`` -- the seed's Eq. 7 / condition 5.  At every reversal of ``u`` the
  kernel stores ``(u_r, N_r, f_r,i)``; then
  ``f_i = k_i (u - u_r) + f_r,i N / N_r``, clipped to ``+-g_i N`` (the
  reference term is 0 when ``N_r <= 0``).  The memory survives separation; the
  clip makes the force 0 while ``N <= 0``.

All march kernels take inputs ``u`` and ``N`` of shape ``(n_e, n_t)``, march
the samples in order from the given state, and return the force, its
tangents with respect to ``u`` and ``N`` at each sample (state at the start of
the sample held fixed: the consistent tangent of an implicit step), and the
final state.  State arrays are never modified in place.

Scalar ``*_step`` functions hold the law itself, with the full local
Jacobian (including the derivatives with respect to the state), so that
solvers that need derivatives through the history (AFT harmonic balance) use
exactly the same law.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

# Layout of the scaled-law state, per element: 5 shared entries, then per
# slider the previous force and the force at the last reversal.
SC_U_PREV, SC_N_PREV, SC_DIR, SC_U_R, SC_N_R = 0, 1, 2, 3, 4
SC_SHARED = 5

#: Work (elements x samples x sliders) from which the march kernels run on
#: threads.  Below it thread start-up and barrier waits cost more than the
#: work: on a loaded 2-core machine a threaded call on 17 elements x 1 sample
#: took 23 ms against 10 us serial.
PARALLEL_MIN_WORK = 200_000


#: Codes of the slider-bank laws in the shared march drivers (``_bank_serial``,
#: ``_bank_parallel``).
BANK_ANCHOR, BANK_SCALED, BANK_MANIFOLD = 0, 1, 2


def _threaded(u, k) -> bool:
    return u.shape[0] > 1 and u.size * k.shape[1] >= PARALLEL_MIN_WORK


@njit(cache=True, inline="always")
def slider_anchor_step(u, N, w, k, g):
    """One Jenkins slider with an anchor.

    Parameters
    ----------
    u : float
        Tangential displacement [m].
    N : float
        Normal load [N].
    w : float
        Anchor position at the start of the step [m].
    k : float
        Slider stiffness [N/m].
    g : float
        Slip force per unit normal load [-].

    Returns
    -------
    f, dfdu, dfdN, dfdw, w1, dw1du, dw1dN, dw1dw : float
        Force [N], its partial derivatives, the new anchor [m] and its partials.
    """
    if N <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, u, 1.0, 0.0, 0.0
    fs = g * N
    ft = k * (u - w)
    if ft > fs:
        return fs, 0.0, g, 0.0, u - fs / k, 1.0, -g / k, 0.0
    if ft < -fs:
        return -fs, 0.0, -g, 0.0, u + fs / k, 1.0, g / k, 0.0
    return ft, k, 0.0, -k, w, 0.0, 0.0, 1.0


@njit(cache=True, inline="always")
def slider_scaled_force(u, N, u_r, N_r, f_r, k, g):
    """One slider of the scaled-reversal law (seed Eq. 7).

    Returns
    -------
    f, dfdu, dfdN, dfdur, dfdNr, dfdfr : float
        Force [N] and its partial derivatives with respect to the inputs and
        the reversal memory.
    """
    if N <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    fs = g * N
    if N_r > 0.0:
        ratio = N / N_r
        ft = k * (u - u_r) + f_r * ratio
        dN = f_r / N_r
        dNr = -f_r * ratio / N_r
        dfr = ratio
    else:
        ft = k * (u - u_r)
        dN = 0.0
        dNr = 0.0
        dfr = 0.0
    if ft > fs:
        return fs, 0.0, g, 0.0, 0.0, 0.0
    if ft < -fs:
        return -fs, 0.0, -g, 0.0, 0.0, 0.0
    return ft, k, dN, -k, dNr, dfr


@njit(cache=True, inline="always")
def anchor_bank_point(u, N, w, w_new, k, g):
    """One sample of a bank of anchored sliders.

    Parameters
    ----------
    u, N : float
        Slip [m] and normal load [N].
    w, w_new : ndarray, shape (n_s,)
        Anchors before the sample and where to put them after it [m] (may be
        the same array).
    k, g : ndarray, shape (n_s,)

    Returns
    -------
    f, dfdu, dfdN : float
        Force [N] and its tangents at fixed anchors [N/m], [-].
    """
    fe = 0.0
    de = 0.0
    dn = 0.0
    for i in range(k.shape[0]):
        fi, dfi, dni, _dw, w1, _a, _b, _c = slider_anchor_step(u, N, w[i], k[i], g[i])
        w_new[i] = w1
        fe += fi
        de += dfi
        dn += dni
    return fe, de, dn





@njit(cache=True, inline="always")
def scaled_bank_point(e, ut, Nt, k, g, s):
    """One sample of element ``e`` of a bank of scaled-reversal sliders: the
    reversal memory in row ``e`` of ``s`` is updated; returns ``(f, dfdu, dfdN)``."""
    ns = k.shape[1]
    du = ut - s[e, SC_U_PREV]
    if du != 0.0:
        d = 1.0 if du > 0.0 else -1.0
        if s[e, SC_DIR] != 0.0 and d != s[e, SC_DIR]:
            # reversal at the previous sample
            s[e, SC_U_R] = s[e, SC_U_PREV]
            s[e, SC_N_R] = s[e, SC_N_PREV]
            for i in range(ns):
                s[e, SC_SHARED + ns + i] = s[e, SC_SHARED + i]
        s[e, SC_DIR] = d
    fe = 0.0
    de = 0.0
    dn = 0.0
    for i in range(ns):
        fi, dfi, dni, _a, _b, _c = slider_scaled_force(
            ut, Nt, s[e, SC_U_R], s[e, SC_N_R], s[e, SC_SHARED + ns + i],
            k[e, i], g[e, i])
        s[e, SC_SHARED + i] = fi
        fe += fi
        de += dfi
        dn += dni
    s[e, SC_U_PREV] = ut
    s[e, SC_N_PREV] = Nt
    return fe, de, dn



@njit(cache=True)
def linear_spring(u, k):
    """Linear tangential spring (the ``stuck`` law).

    Parameters
    ----------
    u : ndarray, shape (n_e, n_t)
        Tangential displacement [m].
    k : ndarray, shape (n_e,)
        Stiffness [N/m].

    Returns
    -------
    f, dfdu : ndarray, shape (n_e, n_t)
    """
    ne, nt = u.shape
    f = np.empty((ne, nt))
    dfdu = np.empty((ne, nt))
    for e in range(ne):
        for t in range(nt):
            f[e, t] = k[e] * u[e, t]
            dfdu[e, t] = k[e]
    return f, dfdu


@njit(cache=True, inline="always")
def normal_point(g, kn, can_open, closed_at_zero):
    """One sample of the normal penalty law: ``(N, dN/dg)``.

    ``N = kn max(0, -g)`` when the gap can open, else ``-kn g``; at ``g = 0``
    the derivative is the closed side's when ``closed_at_zero``, else 0.
    """
    if can_open and (g > 0.0 or (g == 0.0 and not closed_at_zero)):
        return 0.0, 0.0
    return -kn * g, -kn


@njit(cache=True)
def normal_penalty(g, kn, can_open, closed_at_zero):
    """Normal load from the gap: ``N = kn max(0, -g)`` (can open) or ``-kn g``.

    Parameters
    ----------
    g : ndarray, shape (n_e, n_t)
        Normal gap [m]; negative means interpenetration.
    kn : ndarray, shape (n_e,)
        Normal stiffness of the element (kn per area times area) [N/m].
    can_open : bool
        Allow separation (N = 0 for an open gap).
    closed_at_zero : bool
        Take the closed side's derivative at ``g = 0`` exactly.

    Returns
    -------
    N, dNdg : ndarray, shape (n_e, n_t)
        Normal load [N] (positive in compression) and its derivative [N/m].
    """
    ne, nt = g.shape
    N = np.empty((ne, nt))
    dNdg = np.empty((ne, nt))
    for e in range(ne):
        for t in range(nt):
            N[e, t], dNdg[e, t] = normal_point(g[e, t], kn[e], can_open, closed_at_zero)
    return N, dNdg


# --------------------------------------------------------------------------
# The manifold reversal law: seed Eq. 7's scaling with Masing's memory rule
# --------------------------------------------------------------------------
# Layout of the manifold-law state, per element: 6 shared entries, then a
# stack of MF_DEPTH open reversals, each (u_r [m], N_r [N], f_r [N]).
MF_U_PREV, MF_N_PREV, MF_DIR, MF_F_PREV, MF_TOP, MF_U0 = 0, 1, 2, 3, 4, 5
MF_SHARED = 6
#: Open reversals the manifold law remembers; on overflow the oldest (outermost)
#: is forgotten.  Each open reversal needs a nested, shrinking inner loop, so
#: 32 is only reached by 16 nested loops that have not closed.
MF_DEPTH = 32


@njit(cache=True, inline="always")
def _mf_pass(u, d, ur):
    """True when motion in direction ``d`` at ``u`` has reached or passed ``ur``."""
    return (d > 0.0 and u >= ur) or (d < 0.0 and u <= ur)


@njit(cache=True)
def _mf_drop_bottom(s, e, top, rows):
    """Forget the oldest open reversal (and its companion row in ``rows``)."""
    m = rows.shape[1]
    for j in range(top - 1):
        for q in range(3):
            s[e, MF_SHARED + 3 * j + q] = s[e, MF_SHARED + 3 * (j + 1) + q]
        for q in range(m):
            rows[j, q] = rows[j + 1, q]


@njit(cache=True, inline="always")
def manifold_direction(s, e, ut):
    """Direction of motion at sample ``ut`` of element ``e`` (no state change).

    Returns
    -------
    d : float
        -1, 1, or 0 when ``u`` did not move.
    reversed : bool
        The previous sample was a reversal (it will be pushed).
    """
    du = ut - s[e, MF_U_PREV]
    if du == 0.0:
        return 0.0, False
    d = 1.0 if du > 0.0 else -1.0
    return d, (s[e, MF_DIR] != 0.0 and d != s[e, MF_DIR])


@njit(cache=True, inline="always")
def manifold_closes(s, e, ut, d):
    """True when motion in direction ``d`` at ``ut`` closes an inner loop of
    element ``e`` (reaches the reversal below the governing one): the test of
    :func:`manifold_memory_rows` without a reversal at the previous sample."""
    top = int(s[e, MF_TOP])
    return d != 0.0 and top >= 2 and _mf_pass(ut, d, s[e, MF_SHARED + 3 * (top - 2)])


@njit(cache=True, inline="always")
def manifold_memory_rows(s, e, ut, rows, row):
    """Update the reversal stack of element ``e`` for the sample ``ut`` (in place).

    A reversal at the previous sample is pushed with the force there; then,
    Masing's memory rule: while the motion reaches or passes the reversal
    before the current one, the inner loop has closed and both are popped.
    With only two reversals left, the older is dropped when reached (the
    steady outer loop keeps its latest extremes, as the Masing check of
    :mod:`jointsim.masing` does).

    Parameters
    ----------
    s : ndarray, shape (n_e, MF_SHARED + 3 MF_DEPTH)
        Manifold-law state (see :func:`march_bank`); row ``e`` is updated.
    e : int
    ut : float
        Slip at the sample [m].
    rows : ndarray, shape (MF_DEPTH, m)
        Companion data of the stack entries (the AFT kernel keeps their
        derivatives there), moved along with the stack; ``m`` may be 0.
    row : ndarray, shape (m,)
        Companion data of the entry pushed at this sample, if any.

    Returns
    -------
    int
        Number of entries popped by closed inner loops (0, 2, 4, ...; the
        governing reversal changed when > 0).
    """
    d, rev = manifold_direction(s, e, ut)
    if d == 0.0:
        return 0
    top = int(s[e, MF_TOP])
    if rev:
        if top == MF_DEPTH:
            _mf_drop_bottom(s, e, top, rows)
            top -= 1
        b = MF_SHARED + 3 * top
        s[e, b] = s[e, MF_U_PREV]
        s[e, b + 1] = s[e, MF_N_PREV]
        s[e, b + 2] = s[e, MF_F_PREV]
        for q in range(rows.shape[1]):
            rows[top, q] = row[q]
        top += 1
    s[e, MF_DIR] = d
    popped = 0
    while top >= 2:
        ur = s[e, MF_SHARED + 3 * (top - 2)]
        if not _mf_pass(ut, d, ur):
            break
        if top >= 3:
            top -= 2
            popped += 2
        else:
            _mf_drop_bottom(s, e, top, rows)
            top = 1
    s[e, MF_TOP] = float(top)
    return popped


@njit(cache=True, inline="always")
def manifold_force(s, e, ut, Nt, k, g):
    """Force of element ``e`` of the manifold law at ``(ut, Nt)`` given its memory.

    ``f = f_r N / N_r + 2 sgn(u - u_r) f_bb(|u - u_r| / 2; N)`` from the top
    reversal ``(u_r, N_r, f_r)`` of the stack (the first term is 0 when
    ``N_r <= 0``), ``f = sgn(u - u_0) f_bb(|u - u_0|; N)`` before the first
    reversal, clipped to ``+-sum(g) N``; 0 while ``N <= 0``.

    Returns
    -------
    f, dfdu, dfdN : float
        Force [N] and its partial derivatives with the memory held fixed.
    dfdur, dfdNr, dfdfr : float
        Partial derivatives with respect to the governing reversal
        ``(u_r, N_r, f_r)`` (0 before the first reversal, where the force
        depends only on the fixed rest position ``u_0``).
    """
    if Nt <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    ns = k.shape[1]
    top = int(s[e, MF_TOP])
    if top == 0:
        delta = ut - s[e, MF_U0]
        x = abs(delta)
        c = 1.0
        f0 = 0.0
        dN0 = 0.0
        dNr = 0.0
        dfr = 0.0
    else:
        b = MF_SHARED + 3 * (top - 1)
        delta = ut - s[e, b]
        x = 0.5 * abs(delta)
        c = 2.0
        Nr = s[e, b + 1]
        if Nr > 0.0:
            dfr = Nt / Nr
            f0 = s[e, b + 2] * dfr
            dN0 = s[e, b + 2] / Nr
            dNr = -f0 / Nr
        else:
            f0 = 0.0
            dN0 = 0.0
            dNr = 0.0
            dfr = 0.0
    sg = 1.0 if delta > 0.0 else (-1.0 if delta < 0.0 else 0.0)
    bb = 0.0
    kst = 0.0
    gsl = 0.0
    gsum = 0.0
    for i in range(ns):
        a = k[e, i] * x
        q = g[e, i] * Nt
        gsum += g[e, i]
        if a < q:
            bb += a
            kst += k[e, i]
        else:
            bb += q
            gsl += g[e, i]
    f = f0 + c * sg * bb
    lim = gsum * Nt
    if f > lim:
        return lim, 0.0, gsum, 0.0, 0.0, 0.0
    if f < -lim:
        return -lim, 0.0, -gsum, 0.0, 0.0, 0.0
    dur = -kst if top > 0 else 0.0
    return f, kst, dN0 + c * sg * gsl, dur, dNr, dfr


@njit(cache=True, inline="always")
def manifold_point(e, ut, Nt, k, g, s, rows):
    """One sample of element ``e`` of the manifold law: the reversal stack in
    row ``e`` of ``s`` is updated (``rows``: empty companion rows, shape
    ``(MF_DEPTH, 0)``); returns ``(f, dfdu, dfdN)``."""
    # the common sample (no push, no pop) in line, as the AFT kernel does: the
    # full update on every sample took 2.7x as long (the control replay, Jenkins)
    d, rev = manifold_direction(s, e, ut)
    if rev or manifold_closes(s, e, ut, d):
        manifold_memory_rows(s, e, ut, rows, rows[0])
    elif d != 0.0:
        s[e, MF_DIR] = d
    fe, de, dn, _a, _b, _c = manifold_force(s, e, ut, Nt, k, g)
    s[e, MF_U_PREV] = ut
    s[e, MF_N_PREV] = Nt
    s[e, MF_F_PREV] = fe
    return fe, de, dn



@njit(cache=True)
def _bank_element(code, e, u, N, k, g, s, f, dfdu, dfdN):
    """March element ``e`` of the law ``code`` over all samples (state row ``e`` of ``s``)."""
    rows = np.zeros((MF_DEPTH, 0))
    for t in range(u.shape[1]):
        if code == BANK_ANCHOR:
            fe, de, dn = anchor_bank_point(u[e, t], N[e, t], s[e], s[e], k[e], g[e])
        elif code == BANK_SCALED:
            fe, de, dn = scaled_bank_point(e, u[e, t], N[e, t], k, g, s)
        else:
            fe, de, dn = manifold_point(e, u[e, t], N[e, t], k, g, s, rows)
        f[e, t] = fe
        dfdu[e, t] = de
        dfdN[e, t] = dn


@njit(cache=True)
def _bank_serial(code, u, N, k, g, s0):
    ne, nt = u.shape
    f, dfdu, dfdN = np.zeros((ne, nt)), np.zeros((ne, nt)), np.zeros((ne, nt))
    s = s0.copy()
    for e in range(ne):
        _bank_element(code, e, u, N, k, g, s, f, dfdu, dfdN)
    return f, dfdu, dfdN, s


@njit(cache=True, parallel=True)
def _bank_parallel(code, u, N, k, g, s0):
    ne, nt = u.shape
    f, dfdu, dfdN = np.zeros((ne, nt)), np.zeros((ne, nt)), np.zeros((ne, nt))
    s = s0.copy()
    for e in prange(ne):
        # prange's index is uint64: cast, so the element kernel keeps the one
        # compiled signature of the serial driver (a second costs 1 to 15 s cold)
        _bank_element(code, np.int64(e), u, N, k, g, s, f, dfdu, dfdN)
    return f, dfdu, dfdN, s


def march_bank(code, u, N, k, g, s0):
    """March every element of a slider-bank law over samples.

    On threads above a work threshold (:data:`PARALLEL_MIN_WORK`), else on the
    calling thread; the result does not depend on it.

    Parameters
    ----------
    code : int
        ``BANK_ANCHOR``, ``BANK_SCALED`` or ``BANK_MANIFOLD``.
    u, N : ndarray, shape (n_e, n_t)
        Tangential displacement [m] and normal load [N] at each sample.
    k, g : ndarray, shape (n_e, n_s)
        Slider stiffness [N/m] and slip force per unit normal load [-] (for the
        manifold law: of the bank whose backbone it follows).
    s0 : ndarray, shape (n_e, state size)
        State at the start (not modified).  Anchored: the anchor of every
        slider [m].  Scaled: previous u [m], previous N [N], direction of
        motion (-1, 0, 1), u_r [m], N_r [N], then the previous force of each
        slider and its force at the last reversal [N] (``5 + 2 n_s``).
        Manifold: previous u [m], previous N [N], direction, previous force
        [N], number of open reversals, rest position u_0 [m], then the stack of
        open reversals ``(u_r, N_r, f_r)``, oldest first
        (``MF_SHARED + 3 MF_DEPTH``).

    Returns
    -------
    f, dfdu, dfdN : ndarray, shape (n_e, n_t)
        Force [N] and its tangents [N/m], [-].
    s : ndarray, shape of ``s0``
        State after the last sample.
    """
    run = _bank_parallel if _threaded(u, k) else _bank_serial
    return run(code, u, N, k, g, s0)


@njit(cache=True)
def _manifold_periodic_element(e, u, N, k, g, s, scale, block, max_periods, tol, last,
                               change, periods):
    """March element ``e`` of the manifold law over whole periods until it repeats
    (:func:`march_manifold_periodic`); writes row ``e`` of ``s``, ``last``, ``change``
    and ``periods``."""
    n = u.shape[1]
    rows = np.zeros((MF_DEPTH, 0))
    prev = np.zeros(n)
    p = 0
    while True:
        for t in range(n):
            last[e, t] = manifold_point(e, u[e, t], N[e, t], k, g, s, rows)[0]
        p += 1
        if p % block == 0 or p >= max_periods:
            c = 0.0
            for t in range(n):
                c = max(c, abs(last[e, t] - prev[t]))
            c /= scale[e]
            if c <= tol or p >= max_periods:
                change[e] = c
                periods[e] = p
                return
        if (p + 1) % block == 0 or p + 1 >= max_periods:   # the reference of a check
            for t in range(n):
                prev[t] = last[e, t]


@njit(cache=True, parallel=True)
def _manifold_periodic_parallel(u, N, k, g, s0, scale, block, max_periods, tol):
    ne, n = u.shape
    s = s0.copy()
    last, change = np.zeros((ne, n)), np.zeros(ne)
    periods = np.zeros(ne, dtype=np.int64)
    for e in prange(ne):
        _manifold_periodic_element(np.int64(e), u, N, k, g, s, scale, block, max_periods,
                                   tol, last, change, periods)
    return last, change, periods, s


def march_manifold_periodic(u, N, k, g, s0, scale, block: int, max_periods: int,
                            tol: float):
    """March the manifold law over repeated periods of ``(u, N)`` until each element's
    force repeats.

    Every element marches whole periods from its state in ``s0``; after every
    ``block`` periods (and at ``max_periods``) the last period's force is compared
    with the one before it, and the element stops once
    ``max |f_last - f_before| / scale <= tol`` or ``max_periods`` were marched.
    An element stops on its own (the study's control replay: about a quarter
    of the 480 elements of a fine lap joint close within 20 periods, about 70 %
    never do and march all 400); always on threads (the work is periods x
    samples x elements), in one compiled driver, with nothing stored but the last
    two periods.

    Parameters
    ----------
    u, N : ndarray, shape (n_e, n)
        One period of tangential displacement [m] and normal load [N].
    k, g : ndarray, shape (n_e, n_s)
        The bank of the backbone (as :func:`march_bank`).
    s0 : ndarray, shape (n_e, MF_SHARED + 3 MF_DEPTH)
        Manifold-law state at the start (not modified).
    scale : ndarray, shape (n_e,)
        Force normalising the change [N] (> 0).
    block, max_periods : int
        Periods between checks, and at most.
    tol : float
        Relative change at which an element's force repeats.

    Returns
    -------
    f : ndarray, shape (n_e, n)
        Force over each element's last marched period [N].
    change : ndarray, shape (n_e,)
        Relative change of that period from the one before.
    periods : ndarray of int64, shape (n_e,)
        Periods marched.
    s : ndarray, shape of ``s0``
        State after the last period.
    """
    if block < 1 or max_periods < 1:
        raise ValueError(f"block and max_periods must be >= 1, got {block} and {max_periods}")
    return _manifold_periodic_parallel(
        np.ascontiguousarray(u, dtype=float), np.ascontiguousarray(N, dtype=float),
        np.ascontiguousarray(k, dtype=float), np.ascontiguousarray(g, dtype=float),
        np.ascontiguousarray(s0, dtype=float), np.ascontiguousarray(scale, dtype=float),
        int(block), int(max_periods), float(tol))
