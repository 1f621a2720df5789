"""How a continuation branch loses its way, and the guard against one way of it.

Pure functions used by :class:`jointsim.solvers.continuation.Continuation`:

* :func:`runs_back`: whether a step runs against the one before (negative cosine
  of the two secants).  The stepper records such *reversals* of its accepted
  points, and checks the orientation only of landings that run back.
* :func:`orientation_sign`: ``sign det [J; t]`` of the scaled bordered Jacobian.
  Along a branch of regular points, folds included, with ``t`` the tangent in the
  direction of travel, it does not change; it changes between two accepted points
  only at a branch point, at a non-smooth fold (passed by
  :func:`jointsim.solvers.arclength.fold_step`, which keeps the orientation and is
  not checked), or when the corrector landed on a nearby piece of the branch that
  runs the other way.  The coupled lap joint's 20 N FRC at H = 0..11, Nt = 256 did
  that twice near 1033 rad/s (J regular at both points, smallest singular values
  2.6 and 2.5; the landing came from a corner step, which tries both orientations
  of the tangent beyond a corner) and then ran back along itself until the step
  fell below ``step_min``.  The stepper (``keep_orientation``) rejects a remedy
  point (a longer step, a corner step) that runs back *and* flips the sign; a
  remedy that keeps the direction of travel may cross a kink of a non-smooth
  residual where the sign changes legitimately (the stiff chain at kt = 1e4 and
  the fold scene at mu = 1e6 stopped early when every flipped point was rejected).
* :func:`lost_way_message`: what a failed branch did before it gave up.
* :func:`stall_message`: a branch that keeps finding points without advancing in
  ``lam`` (optional ``lam_stall`` of the stepper).  The EPMC backbone of the coupled
  lap joint with pressure-dependent stiffness (96 Gauss points, ``joint.kt_pressure``
  and ``kn_pressure``) does that at the macroslip onset, log10 a = -2.433874: there
  the two beams' static relative position is held only by the suspension springs,
  and the branch turns to run along that nearly free drift.  The dense direct path
  then took 120 points that advanced log10 a by 1.7e-5 in all (the contact
  coordinates doubling), heading for ``max_points``; the Krylov path shrank its step
  below ``step_min`` at the same log10 a.
"""
from __future__ import annotations

import numpy as np

from .arclength import orientation

#: A failed branch reports its reversals among its last ``REVERSAL_WINDOW`` points.
REVERSAL_WINDOW = 100
#: ``sign det [J; t]`` is checked (a dense determinant) only when ``ORIENTATION`` and
#: up to ``ORIENTATION_MAX_UNKNOWNS`` unknowns.
ORIENTATION = True
ORIENTATION_MAX_UNKNOWNS = 2000


def runs_back(d0, d1) -> bool:
    """Whether step ``d1`` runs against step ``d0`` (``d0 . d1 < 0``), both scaled,
    shape (n + 1,)."""
    return float(np.dot(d0, d1)) < 0.0


def orientation_sign(J, t) -> int:
    """``sign det [J; t]`` of the scaled Jacobian ``J``, shape (n, n + 1), and tangent
    ``t``, shape (n + 1,); 0 when not checked (``ORIENTATION`` off, more than
    ``ORIENTATION_MAX_UNKNOWNS`` unknowns, or non-finite values)."""
    if not ORIENTATION or J.shape[0] > ORIENTATION_MAX_UNKNOWNS:
        return 0
    return orientation(J, t)


def lost_way_message(reversals, n_points: int, retraced: int) -> str:
    """What a failed branch did before it gave up, when it lost its way.

    Parameters
    ----------
    reversals : sequence of (int, float)
        ``(index, lam)`` of the accepted points whose secant runs back.
    n_points : int
        Points of the branch.
    retraced : int
        Corrector tries of the failed step that landed back on the traced branch.

    Returns
    -------
    str
        ``"; ..."`` to append to the failure message, empty when neither happened.
    """
    rev = [lam for i, lam in reversals if n_points - i <= REVERSAL_WINDOW]
    out = []
    if retraced:
        out.append(f"{retraced} of its last corrector tries landed back on the branch "
                   f"already traced (the branch was running back along itself)")
    if rev:
        where = ", ".join(f"{v:.8g}" for v in rev[-6:])
        out.append(f"in its last {REVERSAL_WINDOW} points it reversed direction "
                   f"{len(rev)} times (at lam = {where}): it zig-zags between nearby "
                   f"pieces of the branch, a fold or corner it did not resolve")
    return "; " + "; ".join(out) if out else ""


def stall_message(lams, n: int, share: float, span: float) -> str | None:
    """Why a branch stalls in ``lam``, or None.

    Parameters
    ----------
    lams : sequence of float
        ``lam`` of the accepted points, in order.
    n : int
        Points looked back over.
    share : float
        The branch stalls when its last ``n`` points advanced ``lam`` by less than
        ``share * span`` in all.
    span : float
        The range of ``lam`` (> 0).
    """
    if n < 1 or len(lams) <= n:
        return None
    moved = abs(float(lams[-1]) - float(lams[-1 - n]))
    if moved >= share * span:
        return None
    return (f"the branch stalls at lam = {float(lams[-1]):.8g}: its last {n} points "
            f"advanced lam by {moved:.3g} in all, less than {share:g} of the range "
            f"({span:.3g}); it runs along a direction in which lam hardly changes")
