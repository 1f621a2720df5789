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

from .arclength import orientation, tangent


@dataclass(frozen=True)
class Jump:
    """A jump of the residual between two nearby points of a segment.

    Attributes
    ----------
    s_before, s_after : float
        Segment parameters bracketing the jump (``y = y0 + s (y1 - y0)``) [-].
    dy : float
        ``|y(s_after) - y(s_before)|`` (2-norm, in the units of ``y``).
    dr : float
        ``|R(s_after) - R(s_before)|`` (2-norm): the size of the jump.
    r_before, r_after : float
        ``|R|`` (2-norm) on either side.
    """

    s_before: float
    s_after: float
    dy: float
    dr: float
    r_before: float
    r_after: float

    def describe(self) -> str:
        return (f"the residual jumps by |dR| = {self.dr:.3g} (|R| from {self.r_before:.3g} "
                f"to {self.r_after:.3g}) over |dy| = {self.dy:.3g}")


def residual_jump(fun, y0, y1, n_scan: int = 64, n_bisect: int = 60,
                  noise: float = 1e-9) -> Jump | None:
    """Look for a discontinuity of ``fun`` on the segment ``y0 -> y1``.

    The segment is scanned at ``n_scan + 1`` points.  The interval with the
    largest change ``|R(s_i+1) - R(s_i)|`` is bisected ``n_bisect`` times,
    keeping the half that changes more.  A continuous residual's change
    shrinks with the interval; a jump's does not, down to the last bit of
    ``y``: the interval holds a jump when its final change keeps at least half
    of the interval's excess over the median change and exceeds ``noise``
    times ``|R|``.

    Parameters
    ----------
    fun : callable
        ``fun(y) -> R`` (ndarray).
    y0, y1 : ndarray, shape (n,)
        Segment ends; ``y0`` is typically the last converged point.
    n_scan, n_bisect : int
    noise : float
        Relative size of a change that counts as round-off.

    Returns
    -------
    Jump or None
        None when the largest change vanishes under bisection (a steep but
        continuous residual, or a kink).
    """
    y0 = np.asarray(y0, dtype=float)
    d = np.asarray(y1, dtype=float) - y0

    def at(s):
        return np.asarray(fun(y0 + s * d), dtype=float).ravel()

    s = np.linspace(0.0, 1.0, n_scan + 1)
    R = [at(x) for x in s]
    change = np.array([np.linalg.norm(R[i + 1] - R[i]) for i in range(n_scan)])
    if not np.all(np.isfinite(change)):
        return None
    i = int(np.argmax(change))
    med = float(np.median(change))
    if change[i] == 0.0:
        return None
    lo, hi, R_lo, R_hi = s[i], s[i + 1], R[i], R[i + 1]
    for _ in range(n_bisect):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        R_mid = at(mid)
        if np.linalg.norm(R_mid - R_lo) >= np.linalg.norm(R_hi - R_mid):
            hi, R_hi = mid, R_mid
        else:
            lo, R_lo = mid, R_mid
    dr = float(np.linalg.norm(R_hi - R_lo))
    size = max(float(np.linalg.norm(R_lo)), float(np.linalg.norm(R_hi)))
    if dr < 0.5 * (change[i] - med) or dr <= noise * size:
        return None
    return Jump(float(lo), float(hi), float(np.linalg.norm((hi - lo) * d)), dr,
                float(np.linalg.norm(R_lo)), float(np.linalg.norm(R_hi)))


@dataclass(frozen=True)
class Fold:
    """A kink of the residual across which the bordered Jacobian changes orientation.

    On a segment ``y = y0 + s d`` the sign of ``det [J(y); d^T]`` is constant
    on each smooth piece of a piecewise-smooth residual.  When it differs on
    the two sides of a kink, the pieces are not coherently oriented: the
    solution curve turns back at the kink (a *non-smooth fold*), a
    pseudo-arclength hyperplane just beyond the kink cuts neither piece's
    solution, and Newton cycles between the two pieces (each linearisation's
    root lies on the other piece).

    Attributes
    ----------
    s_before, s_after : float
        Segment parameters bracketing the kink [-].
    sign_before, sign_after : int
        Sign of ``det [J; d^T]`` on either side.
    cos_pieces : float
        Cosine of the angle between the two pieces' unit tangents, each
        oriented along ``d`` (near 1: the branch beyond turns back by nearly
        180 degrees, a cusp).
    """

    s_before: float
    s_after: float
    sign_before: int
    sign_after: int
    cos_pieces: float

    def describe(self) -> str:
        turn = float(np.degrees(np.arccos(-np.clip(self.cos_pieces, -1.0, 1.0))))
        return (f"the residual is continuous but has a kink where det [J; d] changes sign "
                f"({self.sign_before:+d} to {self.sign_after:+d}): a non-smooth fold, where "
                f"the branch turns back by about {turn:.0f} degrees, so no solution lies on "
                f"the hyperplanes just beyond the kink and Newton cycles between the two "
                f"pieces")


def _orientation(J, d):
    """Sign of ``det [J; d^T]`` and the unit tangent of ``J`` oriented along ``d``."""
    return orientation(J, d), tangent(J, d)


def orientation_fold(jac, y0, y1, n_scan: int = 8, n_bisect: int = 40,
                     scale=None) -> Fold | None:
    """Look for a non-smooth fold (:class:`Fold`) on the segment ``y0 -> y1``.

    The sign of ``det [J(y); d^T]`` (``d = y1 - y0``) is sampled at
    ``n_scan + 1`` points; the first change is bisected ``n_bisect`` times.
    The sign depends on the bordering row, so it is taken in the variables the
    continuation steps in: ``J diag(scale)`` bordered by ``d / scale``.

    Parameters
    ----------
    jac : callable
        ``jac(y) -> J``, shape (n, n + 1): the Jacobian of the ``n`` equations
        in the ``n + 1`` unknowns of the branch.
    y0, y1 : ndarray, shape (n + 1,)
    n_scan, n_bisect : int
    scale : ndarray, shape (n + 1,) or None
        Scales of the continuation's variables (``y = scale * yh``; None: 1).

    Returns
    -------
    Fold or None
        None when the orientation is the same along the segment.
    """
    y0 = np.asarray(y0, dtype=float)
    d = np.asarray(y1, dtype=float) - y0
    sc = np.ones_like(d) if scale is None else np.asarray(scale, dtype=float)
    dn = d / sc
    dn /= max(np.linalg.norm(dn), 1e-300)

    def at(s):
        return _orientation(np.asarray(jac(y0 + s * d), dtype=float) * sc[None, :], dn)

    s = np.linspace(0.0, 1.0, n_scan + 1)
    prev = at(s[0])
    for i in range(1, n_scan + 1):
        cur = at(s[i])
        if cur[0] != prev[0] and cur[0] != 0 and prev[0] != 0:
            lo, hi, o_lo, o_hi = s[i - 1], s[i], prev, cur
            for _ in range(n_bisect):
                mid = 0.5 * (lo + hi)
                if mid in (lo, hi):
                    break
                o = at(mid)
                if o[0] == o_lo[0]:
                    lo, o_lo = mid, o
                else:
                    hi, o_hi = mid, o
            return Fold(float(lo), float(hi), o_lo[0], o_hi[0], float(o_lo[1] @ o_hi[1]))
        prev = cur
    return None


def explain_failure(message: str, advice: str, fun, y_prev, y_last, n_scan: int = 64,
                    jac=None, y_ahead=None, scale=None) -> str:
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
    jac : callable or None
        ``jac(y) -> J`` (n_eq, n): when no jump is found, the segment from
        ``y_last`` to ``y_ahead`` is searched for a non-smooth fold
        (:func:`orientation_fold`).
    y_ahead : ndarray, shape (n,) or None
        End of that segment: the continuation's last predictor (default: one
        secant step, ``2 y_last - y_prev``).
    scale : ndarray, shape (n,) or None
        The continuation's variable scales (see :func:`orientation_fold`).
    """
    if not advice:
        return message
    found = ""
    if y_prev is not None and y_last is not None:
        y_last = np.asarray(y_last, dtype=float)
        jump = residual_jump(fun, y_last, 2.0 * y_last - np.asarray(y_prev, dtype=float),
                             n_scan=n_scan)
        if jump is not None:
            found = (f" (found: one secant step past the last point {jump.describe()}, "
                     f"at s = {jump.s_after:.6g} of the step)")
        else:
            fold = None
            if jac is not None:
                end = (2.0 * y_last - np.asarray(y_prev, dtype=float) if y_ahead is None
                       else np.asarray(y_ahead, dtype=float))
                fold = orientation_fold(jac, y_last, end, scale=scale)
            if fold is not None:
                found = (f" (no jump found within one secant step past the last point; at "
                         f"s = {fold.s_after:.3g} of the step to the last predictor "
                         f"{fold.describe()}: the law's "
                         "kinks are not coherently oriented, README: Continuation with the "
                         "scaled laws)")
            else:
                found = (" (no jump found within one secant step past the last point: this "
                         "failure may also have another cause)")
    return f"{message}; {advice}{found}"


def steepness(fun, jac, y0, y1, n_scan: int = 24) -> float:
    """How much faster the residual changes along a segment than its Jacobian at ``y0`` says.

    A residual that is smooth but nearly discontinuous (a slip force ``mu N``
    with a huge ``mu`` switching an element between free and stuck within a
    tiny change of ``N`` at a clap) has a correct Jacobian at the last point and
    a change of ``R`` just beyond it that no linear model predicts; Newton's
    region of convergence then shrinks with that band, and so does the step.

    Parameters
    ----------
    fun : callable
        ``fun(y) -> R``, shape (n_r,).
    jac : callable
        ``jac(y) -> dR/dy``, shape (n_r, n).
    y0, y1 : ndarray, shape (n,)
        Segment ends (``y0``: the last converged point).
    n_scan : int
        Geometrically spaced samples ``s`` in ``[1e-3, 1]``.

    Returns
    -------
    float
        ``max_s |R(y0 + s d) - R(y0) - s J d| / (s |J d|)`` [-]: about 0 where the
        linear model holds over the segment, >> 1 in a steep band.
    """
    y0 = np.asarray(y0, dtype=float)
    d = np.asarray(y1, dtype=float) - y0
    R0 = np.asarray(fun(y0), dtype=float)
    Jd = np.asarray(jac(y0), dtype=float) @ d
    nJd = float(np.linalg.norm(Jd))
    if nJd == 0.0:
        return 0.0
    worst = 0.0
    for s in np.geomspace(1e-3, 1.0, n_scan):
        Rs = np.asarray(fun(y0 + s * d), dtype=float)
        worst = max(worst, float(np.linalg.norm(Rs - R0 - s * Jd)) / (s * nJd))
    return worst
