"""The geometry of an arclength step: tangent, bordered corrector, corners and folds.

Building blocks of :class:`jointsim.solvers.continuation.Continuation`, in the
scaled unknowns ``y = (z, lam)`` of that module:

* :func:`tangent`: the unit tangent from ``[J; t_prev^T] t = [0; 1]``;
* :func:`bordered`: ``R`` with the hyperplane row ``t . (y - yk) - h``, the
  corrector's system;
* :func:`corner_step`: a point beyond a corner of a piecewise-smooth branch,
  from the tangent of the piece beyond it;
* :func:`fold_step`: a turn at a non-smooth fold (a kink where the orientation
  ``sign det [J; t]`` changes; ``docs/hbm.md``).
"""
from __future__ import annotations

import numpy as np

from .jacobian import append_row, solve
from .newton import NewtonOptions, newton

#: Relative residual to which a structured ``[J; t_prev^T] t = [0; 1]`` is solved
#: (GMRES; its default, ``gmres.KRYLOV_RTOL = 1e-11``, lies below the round-off floor of
#: these systems, 2e-11 to 7e-11 at 480 Gauss points, so the reused preconditioner ran
#: out of iterations and each tangent built a new one).  The tangent is the predictor's
#: direction and the corrector's hyperplane; the corrector makes the point exact.  Round
#: 53 (docs/hbm.md): the 480-point FRC's first 25 points built 20 preconditioners instead
#: of 37, X equal to 2e-12.  Not for the EPMC's deflated systems, solved exactly as their
#: Newton steps are (``inexact_steps``): there it saved nothing and moved the branch by
#: 4e-9 at 480 points.
TANGENT_RTOL = 1e-9


def bordered(F, t, yk, h):
    """``F`` with the hyperplane row ``t . (y - yk) - h``, for :func:`newton`.

    Returns ``(fun, jacobian, measure)``: the extra of ``fun`` is ``F``'s
    ``(R, J, extra)`` and the measure is ``max|R|`` of ``F`` alone.
    """
    def fun(y):
        R, J, extra = F(y)
        return np.concatenate([R, [t @ (y - yk) - h]]), (R, J, extra)

    def jacobian(_y, _r, got):
        return append_row(got[1], t)

    def measure(_r, got):
        return np.abs(got[0]).max(initial=0.0)

    return fun, jacobian, measure


def tangent(J, t_prev):
    """Unit tangent of ``J t = 0`` oriented like ``t_prev`` (scaled variables): a
    structured ``J`` whose Newton steps may be inexact is solved to ``TANGENT_RTOL``."""
    n1 = J.shape[1]
    A = append_row(J, t_prev)
    rhs = np.zeros(n1)
    rhs[-1] = 1.0
    try:
        t = solve(A, rhs, rtol=TANGENT_RTOL if getattr(A, "inexact_steps", False) else None)
    except (np.linalg.LinAlgError, RuntimeError):
        return t_prev.copy()
    nt = np.linalg.norm(t)
    if not np.isfinite(nt) or nt == 0.0:
        return t_prev.copy()
    t /= nt
    if t @ t_prev < 0.0:
        t = -t
    return t


def corner_step(F, yk, t, h, tol, max_iter, max_jump=np.inf, stall=None):
    """Try to leave a corner at ``yk`` along the tangent of the piece beyond it.

    A direction whose Newton stalls (``stall`` iterations without a 10 % better residual,
    :class:`~.newton.NewtonOptions`) is given up.  Returns ``(y, R, J, extra,
    iterations)`` or None.
    """
    dirs = []
    for eps in (1e-7, 1e-5, 1e-3):   # the Jacobian just beyond the corner
        _R, Jb, _e = F(yk + eps * t)
        tb = tangent(Jb, t)
        if not any(abs(tb @ d) > 1 - 1e-6 for d in dirs):
            dirs += [tb, -tb]
    best = None
    for d in dirs:
        if d @ (-t) > 0.99:  # that is the branch we came along
            continue
        yk1 = yk + h * d
        fun, jac, measure = bordered(F, d, yk, h)
        res = newton(fun, yk1, NewtonOptions(tol, max_iter, line_search="none", stall=stall),
                     jacobian=jac, measure=measure)
        if res.success:
            yc, (R, J, extra) = res.x, res.extra
            back = (yc - yk) @ (-t) / max(np.linalg.norm(yc - yk), 1e-300) >= 0.99
            if not back and np.linalg.norm(yc - yk1) <= max_jump * h:
                best = (yc, R, J, extra, res.iterations)
        if best is not None:
            return best
    return None


def orientation(J, d):
    """Sign of ``det [J; d^T]`` (the orientation of the branch along ``d``); 0 when
    ``J`` is not finite (a diverged iterate has no orientation)."""
    A = append_row_dense(J, d)
    if not np.all(np.isfinite(A)):
        return 0
    return int(np.sign(np.linalg.slogdet(A)[0]))


def append_row_dense(J, d):
    """``[J; d^T]`` as a dense array (``J`` dense or with ``to_dense()``)."""
    Jd = J.to_dense() if hasattr(J, "to_dense") else np.asarray(J, dtype=float)
    return np.vstack([Jd, np.asarray(d, dtype=float)[None, :]])


#: :func:`fold_step`: the null directions of ``J`` on the two sides of a sign
#: change of ``det [J; t]`` that agree to this cosine belong to a smooth ``J``
#: (about 0.8 degrees; the kinks met differ by 20 degrees or more).
SMOOTH_COS = 0.9999


def fold_step(F, yk, t, h, tol, max_iter, n_bisect: int = 24):
    """Continue through a non-smooth fold between ``yk`` and ``yk + h t``.

    At a kink of the residual where the orientation ``sign det [J; t]``
    changes (the two pieces are not coherently oriented), the branch turns
    back: no hyperplane just beyond the kink cuts it, and Newton cycles
    between the pieces (:class:`jointsim.solvers.discontinuity.Fold`).  The
    branch goes on along the tangent of the piece beyond the kink oriented so
    that the orientation is kept (piecewise-linear continuation's rule): the
    kink is located by bisection on the sign, and Newton is run on the
    hyperplane ``d . (y - c) = h`` from ``c + h d``, ``c`` the first point
    beyond the kink.

    A sign change where the null directions of ``J`` on its two sides agree
    (``SMOOTH_COS``) is no kink: ``J`` is continuous there, and the stepper's
    other remedies apply (the coupled lap joint's EPMC at H = 0..11 meets one
    near its 1:10 internal resonance and passes it by a smaller step).

    Returns ``(y, R, J, extra, iterations)`` or None (no fold, or no point).
    """
    _R0, J0, _e0 = F(yk)
    s0 = orientation(J0, t)
    _R1, J1, _e1 = F(yk + h * t)
    if s0 == 0 or orientation(J1, t) != -s0:
        return None
    lo, hi = 0.0, h
    for _ in range(n_bisect):
        mid = 0.5 * (lo + hi)
        _R, Jm, _e = F(yk + mid * t)
        if orientation(Jm, t) == s0:
            lo, J0 = mid, Jm
        else:
            hi, J1 = mid, Jm
    c = yk + hi * t
    d = tangent(J1, t)
    if abs(float(d @ tangent(J0, t))) > SMOOTH_COS:
        # the null directions on the two sides agree: J is continuous there (a
        # smooth fold or a branch point seen off the branch), not a kink
        return None
    if orientation(J1, d) != s0:
        d = -d
    fun, jac, measure = bordered(F, d, c, h)
    res = newton(fun, c + h * d, NewtonOptions(tol, max_iter, line_search="decrease"),
                 jacobian=jac, measure=measure)
    if not res.success:
        return None
    yc, (R, J, extra) = res.x, res.extra
    if orientation(J, d) != s0:   # landed back on the piece before the kink
        return None
    return yc, R, J, extra, res.iterations
