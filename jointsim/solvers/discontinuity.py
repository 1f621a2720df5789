"""Find a jump of a residual along a segment (why a continuation gave up).

A law without path continuity (seed Eq. 7, the ``manifold`` reversal law)
gives a residual that is discontinuous in the unknowns: its force jumps by a
finite amount when a reversal crosses a separation instant (the reference
term ``f_r N / N_r`` is ``+-mu N`` for ``N_r -> 0+`` and 0 at ``N_r = 0``) or
when a micro-reversal appears (it re-scales the reference force).  Newton
cannot converge across such a jump, and the continuation shrinks its step
until it gives up.  :func:`residual_jump` locates the jump along the segment
the continuation was about to take and measures it, so that the failure can
say what happened.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Jump:
    """A jump of ``|R|`` between two nearby points of a segment.

    Attributes
    ----------
    s_before, s_after : float
        Segment parameters bracketing the jump (``y = y0 + s (y1 - y0)``) [-].
    dy : float
        ``|y(s_after) - y(s_before)|`` (2-norm, in the units of ``y``).
    r_before, r_after : float
        ``|R|`` (2-norm) on either side.
    """

    s_before: float
    s_after: float
    dy: float
    r_before: float
    r_after: float

    def describe(self) -> str:
        return (f"the residual jumps from |R| = {self.r_before:.3g} to {self.r_after:.3g} "
                f"over |dy| = {self.dy:.3g}")


def residual_jump(fun, y0, y1, n_scan: int = 64, n_bisect: int = 60,
                  ratio: float = 1e3, floor: float = 1e-12) -> Jump | None:
    """Look for a discontinuity of ``|fun(y)|`` on the segment ``y0 -> y1``.

    The segment is scanned at ``n_scan + 1`` points; the first interval whose
    end value exceeds ``ratio`` times its start value (and ``floor``) is
    bisected ``n_bisect`` times, keeping the jump inside.  A continuous
    residual (Lipschitz along the segment) shrinks the bracketed increase with
    the interval; a jump keeps it, down to the last bit of ``y``.

    Parameters
    ----------
    fun : callable
        ``fun(y) -> R`` (ndarray); only ``|R|`` is used.
    y0, y1 : ndarray, shape (n,)
        Segment ends; ``y0`` is typically the last converged point.
    n_scan, n_bisect : int
    ratio : float
        Growth of ``|R|`` within one interval that counts as a jump.
    floor : float
        ``|R|`` at or below this is treated as converged.

    Returns
    -------
    Jump or None
        None when no interval grows by ``ratio`` or the growth vanishes under
        bisection (a steep but continuous residual).
    """
    y0 = np.asarray(y0, dtype=float)
    d = np.asarray(y1, dtype=float) - y0

    def norm(s):
        return float(np.linalg.norm(fun(y0 + s * d)))

    s = np.linspace(0.0, 1.0, n_scan + 1)
    r = [norm(s[0])]
    for i in range(1, s.size):
        r.append(norm(s[i]))
        lo, hi, r_lo, r_hi = s[i - 1], s[i], r[-2], r[-1]
        if r_hi > ratio * max(r_lo, floor):
            for _ in range(n_bisect):
                mid = 0.5 * (lo + hi)
                if mid in (lo, hi):
                    break
                r_mid = norm(mid)
                if r_mid > ratio * max(r_lo, floor):
                    hi, r_hi = mid, r_mid
                else:
                    lo, r_lo = mid, r_mid
            dy = float(np.linalg.norm((hi - lo) * d))
            if r_hi > ratio * max(r_lo, floor):
                return Jump(float(lo), float(hi), dy, r_lo, r_hi)
            return None
    return None


def explain_failure(message: str, advice: str, fun, y_prev, y_last, n_scan: int = 64) -> str:
    """A continuation's failure message, with the residual jump ahead and ``advice``.

    When ``advice`` is empty (the law is path-continuous) the message is
    returned unchanged and nothing is evaluated.  Otherwise the segment from
    the last converged point ``y_last`` one secant step on
    (``2 y_last - y_prev``) is searched with :func:`residual_jump`.

    Parameters
    ----------
    message : str
        The continuation's message.
    advice : str
        Why the law can stop a continuation and what to do
        (:func:`jointsim.contact.laws.continuation_advice`).
    fun : callable
        ``fun(y) -> R`` of the continuation's unknowns.
    y_prev, y_last : ndarray, shape (n,) or None
        The last two converged points (None: no search).
    """
    if not advice:
        return message
    found = ""
    if y_prev is not None and y_last is not None:
        y_last = np.asarray(y_last, dtype=float)
        jump = residual_jump(fun, y_last, 2.0 * y_last - np.asarray(y_prev, dtype=float),
                             n_scan=n_scan)
        if jump is not None:
            found = (f" (one secant step past the last point {jump.describe()}, at "
                     f"s = {jump.s_after:.6g} of the step)")
    return f"{message}; {advice}{found}"
