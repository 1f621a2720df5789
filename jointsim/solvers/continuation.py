"""Pseudo-arclength continuation of ``R(z, lam) = 0``.

The unknowns ``y = (z, lam)`` (``n + 1`` values, ``lam`` last) are scaled,
``y = scale * yh``, and so is the residual, ``Rh = R / rscale``; steps and
tolerances refer to the scaled quantities.

* Predictor: the unit tangent ``t`` of the branch, from ``[J; t_prev^T] t =
  [0; 1]`` (``J`` the scaled Jacobian ``n x (n+1)``), oriented like the
  previous one; ``yh_pred = yh + h t``.
* Corrector: Newton on ``[Rh(yh); t . (yh - yh_k) - h] = 0`` (the point
  stays on the hyperplane normal to the tangent, so turning points pass).
  Converged when ``max|Rh| <= tol`` after at least one iteration.  A step
  that increases the residual is halved (up to ``backtrack - 1`` times): the
  AFT residual is only piecewise smooth, and plain Newton can cycle across a
  kink.
* Step control: after a success the step grows or shrinks towards
  ``target_iter`` iterations.  A failed corrector (no convergence, a stall,
  non-finite values, or a jump farther than ``max_jump * h`` from the
  predictor) first tries, once per point, a 4 times longer step (a kink of
  the residual, where Newton cycles, is often passed by landing beyond it),
  then the corner rules below, then halves the step and retries;
  below ``step_min`` the branch gives up and returns what it has with the
  reason.
* Monitored change (optional ``monitor(y) -> array``, values already divided
  by their largest allowed change per step): a corrected point whose
  monitored values changed by more than 1 is rejected and the step shrunk in
  proportion (down to ``2 step_min``), and the next step is kept below that
  limit too.  EPMC monitors the damping ratio and the log of the frequency,
  so the corner of the backbone at the slip onset is resolved without a
  small step everywhere.
* Corners (when the step is already small): a point beyond a corner of up to 80
  degrees far from the predictor (``CORNER_JUMP``); failing that, the tangent of the
  piece beyond in both orientations (given up on a stall); failing that, a
  corrector at fixed ``lam`` a little ahead (a corner sharper than 90 degrees).
* Orientation: the new tangent is oriented like the secant of the last step,
  or, after a step shorter than a quarter of the one before that lands
  straight behind the last point, like the chord over the last two steps (a tiny step from a poor tangent must not turn the
  branch round); a new tangent nearly perpendicular to that reference
  (``AMBIGUOUS_COS``) is oriented like the previous tangent instead, when that
  one is clearly on one side (the sign of so small a product is a coin flip).
* Orientation kept (``keep_orientation``): a remedy point that runs back and
  flips ``sign det [J; t]`` is rejected and the step shrunk; a branch that gives
  up says when it reversed and ran back along itself (:mod:`.branch_watch`).
* No retracing: a corrected point that lies back on the last
  ``RETRACE_POINTS`` points of the branch (closer to one of their segments
  than half its distance from the current point) is rejected; at a sharp
  corner of a piecewise-smooth branch, the forward hyperplane can otherwise
  cut the incoming piece and send the branch back the way it came.
* Scale-invariant steps (optional ``adapt_scale``): the ``z`` scales grow
  with the solution (``max|z - z0|`` beyond ``SCALE_GROWTH`` scales), so a
  branch that outgrows the scale it was given steps relative to its size; a
  run of points growing ``UNBOUNDED_GROWTH`` times at nearly fixed ``lam``
  stops the branch as an unbounded response (an undamped resonance).
* End: when a point passes ``lam_end`` the branch is closed by a Newton
  solve at ``lam = lam_end`` exactly.  A branch that turns back out of the
  range through ``lam_start`` stops there.

The algorithm is the stepper :class:`Continuation` (after scipy's
``OdeSolver``: construct, then ``step()`` until ``status`` is no longer
``"running"``); :func:`continue_branch` drives it and hands every accepted
point to ``on_point`` at once, so a caller can write it to disk (an
interrupted run keeps the branch so far).
"""
from __future__ import annotations

import logging

import numpy as np

from ..results import (NON_FINITE, NOT_CONVERGED, STEP_TOO_SMALL, SUCCESS, Convergence)
from .jacobian import drop_last_column, scale_columns, solve
from .newton import NewtonOptions, newton
from .arclength import bordered, corner_step, fold_step, tangent
from .branch_record import Branch, PointInfo
from .branch_watch import lost_way_message, orientation_sign, runs_back, stall_message

log = logging.getLogger(__name__)

#: Try to pass corners of piecewise-smooth branches (a switch for debugging).
CORNERS = True
#: At a corner, a corrected point may lie this many steps from the predictor
#: (tan 80 deg: corners of up to 80 degrees).
CORNER_JUMP = 5.7
#: Newton iterations per corrector the step control aims at (default ``target_iter``).
TARGET_ITER = 4
#: A failed corrector is retried this many times longer, once per point (docs/hbm.md, round 19).
LONGER_STEP = 4.0
#: Near ``lam_end`` a step aims ``END_AIM`` past it; a point that lands short by at most
#: ``END_SHORT`` of its step's gain in ``lam`` is closed at ``lam_end`` (a bending branch
#: left 169.9992, 170 - 4e-8, 170 Hz; aiming 1.05 past a range ending at a kink, the
#: EPMC's stuck onset, gave a poor closing start: docs/hbm.md, "Round 16").
END_AIM = 1.001
END_SHORT = 0.1
#: Points of the traced branch a new point is checked against (no retracing).
RETRACE_POINTS = 500
#: Orientation: a short step whose secant makes an angle with the step before
#: whose cosine is below ``-BEHIND_COS`` (about 155 degrees or more) "landed
#: behind" the last point; the tangent is then oriented by the chord.
BEHIND_COS = 0.9
#: Orientation: a new tangent within ``acos(AMBIGUOUS_COS)`` (about 78 degrees or
#: more) of perpendicular to its orientation reference is ambiguously oriented by it;
#: it is then oriented like the previous tangent when that is the clearer reference.
AMBIGUOUS_COS = 0.2
#: ``adapt_scale``: rescale ``z`` when ``max|z - z0|`` exceeds this many ``z`` scales.
SCALE_GROWTH = 2.0
#: ``adapt_scale``: a run of points whose ``max|z - z0|`` never decreases, growing
#: ``UNBOUNDED_GROWTH`` times in all while ``lam`` stays within ``UNBOUNDED_LAM``
#: of the range, is an unbounded response (an undamped resonance).
UNBOUNDED_GROWTH = 100.0
UNBOUNDED_LAM = 1e-3


class Continuation:
    """Pseudo-arclength continuation of ``R(z, lam) = 0`` as a stepper object.

    After scipy's ``OdeSolver``: the constructor solves (or accepts) the first
    point, each :meth:`step` advances the branch by one accepted point
    (shrinking and retrying failed steps internally), and ``status`` tells
    whether stepping may go on.  The algorithm is in the module docstring.

    Parameters
    ----------
    fun : callable
        ``fun(y) -> (R, J, extra)`` with ``R`` of shape (n,) and ``J = dR/dy``
        of shape (n, n + 1) (the last column is ``dR/dlam``).
    y0 : ndarray, shape (n + 1,)
        Start (``lam`` last).  With ``solve_first`` it is corrected at fixed
        ``lam`` first; otherwise it must already be a solution.
    lam_end : float
        End of the range; the direction is from ``y0[-1]`` towards it.
    scale : ndarray, shape (n + 1,)
        Variable scales (``y = scale * yh``).
    rscale : float
        Residual scale.
    step, step_min, step_max : float
        Initial, smallest and largest scaled arclength steps.
    max_points : int
        Points at most (including the first).
    tol : float
        Tolerance on ``max|R| / rscale``.
    max_iter, target_iter : int
        Corrector iterations at most / aimed at by the step control.
    max_jump : float
        A corrector landing farther than ``max_jump * h`` from its predictor
        is rejected (guards against jumping to another branch).
    backtrack : int
        Halvings of a Newton step that increases the residual (1: none).
    stall : int
        A corrector whose best residual has not fallen by 10 % in this many
        iterations is given up (it cycles across a kink).
    solve_first : bool
        Correct ``y0`` at fixed ``lam`` before accepting it.
    tangent0 : ndarray, shape (n + 1,), optional
        Tangent guess at the start (scaled); default ``+-e_lam`` towards the end.
    desc : str
        Name of the branch in log messages.
    monitor : callable, optional
        ``monitor(y) -> ndarray`` of quantities (unscaled ``y``) divided by
        their largest allowed change per step (see the module docstring).
    lam_start : float, optional
        Where the branch began (default ``y0[-1]``); a branch resumed from a
        later point passes its true start, so that "turned back out of the
        range" means the same as uninterrupted.
    adapt_scale : bool
        Scale-invariant steps in ``z``: when ``max|z - z0|`` of an accepted
        point exceeds ``SCALE_GROWTH`` times the largest ``z`` scale, the ``z``
        scales are multiplied by ``max|z - z0| / max(scale_z)`` (never
        decreased).  A branch whose solution is much larger than the scale it
        was given (a stiff contact whose stuck response sets the scale, then
        slips) then takes steps relative to its size.  It also stops a branch
        that grows without bound (``max|z - z0|`` never decreasing over a run of
        points whose ``lam`` stays within ``UNBOUNDED_LAM`` of the range, and
        growing ``UNBOUNDED_GROWTH`` times over it), as at an undamped resonance.
    z_origin : ndarray, shape (n,), optional
        ``z0`` of ``adapt_scale`` (default ``y0[:-1]``; a resumed branch passes
        the start of the uninterrupted one).
    lam_stall : tuple (n, share), optional
        Stop the branch (not converged, saying why) when its last ``n`` points
        advanced ``lam`` by less than ``share`` of the range in all
        (:func:`.branch_watch.stall_message`).
    keep_orientation : bool
        Reject a point found by a remedy that flips ``sign det [J; t]``
        (:meth:`_flips`).  The FRC runner sets it where re-closing contacts take
        their anchor at a sample (:func:`jointsim.solvers.frc_diagnosis.
        sampled_reclosing`: the residual's small jumps leave nearby pieces of the
        branch); on the stiff chain (kt = 1e4, fixed N) it stopped a branch that
        completes without it.  The EPMC branch of the coupled
        lap joint at H = 0..15 gives up with it (at log10 a = -3.93), so EPMC
        keeps the previous behaviour.

    Attributes
    ----------
    status : str
        ``"running"`` (``step`` may be called), ``"finished"`` (the branch
        reached ``lam_end`` or turned back out of the range) or ``"failed"``
        (the first point did not converge, the step shrank below ``step_min``,
        or ``max_points`` were reached first).
    message : str or None
        Why the branch ended (None while running).
    convergence : jointsim.results.Convergence or None
        The end as a convergence report (None while running).
    y : ndarray, shape (n + 1,)
        The last accepted point (unscaled), ``lam = y[-1]``.
    h : float
        Scaled arclength step the next :meth:`step` tries first.
    points : list of ndarray, shape (n + 1,)
        Every accepted point (unscaled).
    infos : list of PointInfo
        Bookkeeping of every accepted point (``infos[-1].tangent``: the unit
        tangent at the last one, scaled variables).
    branch : Branch
        The points so far as a :class:`Branch`.
    n_points : int
        Accepted points.
    nfev : int
        Evaluations of ``fun``.
    n_failed : int
        Corrector attempts that were rejected (each followed by another try).
    """

    def __init__(self, fun, y0, lam_end: float, *, scale, rscale: float, step: float,
                 step_min: float, step_max: float, max_points: int, tol: float,
                 max_iter: int = 20, target_iter: int = TARGET_ITER, max_jump: float = 2.0,
                 backtrack: int = 4, stall: int = 5, solve_first: bool = True,
                 tangent0=None, desc: str = "continuation", monitor=None,
                 lam_start=None, adapt_scale: bool = False, z_origin=None,
                 keep_orientation: bool = False, lam_stall=None):
        y0 = np.asarray(y0, dtype=float).copy()
        self.keep_orientation = bool(keep_orientation)
        self.lam_stall = lam_stall
        self.adapt_scale = bool(adapt_scale)
        self._z0 = y0[:-1].copy() if z_origin is None else np.asarray(z_origin, dtype=float)
        self._growth = []     # (|z - z0|, lam) of the points of a geometric growth
        self.monitor = monitor
        self.fun = fun
        self.scale = np.array(scale, dtype=float)   # a copy: adapt_scale changes it
        self.rscale = float(rscale)
        self.n1 = y0.size
        self.lam0 = float(y0[-1])
        self.lam_end = float(lam_end)
        self.direction = 1.0 if lam_end >= self.lam0 else -1.0
        self.step_min, self.step_max = step_min, step_max
        self.max_points, self.tol, self.max_iter = max_points, tol, max_iter
        self.target_iter, self.max_jump = target_iter, max_jump
        self.backtrack, self.stall = backtrack, stall
        self.desc = desc
        self._col = self.scale / self.rscale
        # lam_start: where the branch began (a resumed branch starts later)
        self._lam_start_h = (self.lam0 if lam_start is None else float(lam_start)) \
            / self.scale[-1]
        self._lam_end_h = lam_end / self.scale[-1]
        self.status, self.message, self.convergence = "running", None, None
        self.points, self.infos = [], []
        self._turned = False
        self.nfev = self.n_failed = 0
        self.n_retraced = 0     # corrector tries rejected as landing on the traced branch
        self.n_flipped = 0      # ... as oriented against the branch (:meth:`_flips`)
        self._J = None          # scaled Jacobian at the last accepted point
        self._sign = None       # its sign det [J; t] once computed (:meth:`_flips`)
        self.reversals = []     # (index, lam) of accepted points whose secant reverses
        #                         the one before (:meth:`_lost_way`)
        self.h = float(step)
        self._start(y0, solve_first, tangent0)

    # -- state ------------------------------------------------------------------
    @property
    def n_points(self) -> int:
        """Accepted points."""
        return len(self.points)

    @property
    def y(self) -> np.ndarray:
        """The last accepted point (unscaled)."""
        return self.points[-1]

    @property
    def branch(self) -> Branch:
        """The points accepted so far (``convergence`` None while running)."""
        infos = self.infos
        return Branch(y=np.array(self.points).reshape(len(self.points), self.n1),
                      iterations=np.array([i.iterations for i in infos]),
                      residual=np.array([i.residual for i in infos]),
                      step=np.array([i.step for i in infos]), convergence=self.convergence,
                      tangents=[i.tangent for i in infos])

    # -- pieces -----------------------------------------------------------------
    def _F(self, yh):
        """Scaled residual and Jacobian at the scaled point ``yh``."""
        self.nfev += 1
        R, J, extra = self.fun(yh * self.scale)
        return R / self.rscale, scale_columns(J, self._col), extra

    def _accept(self, yh, info: PointInfo) -> None:
        if self.points and self._reverses(self.points[-1] / self.scale, yh):
            self.reversals.append((len(self.points), float(yh[-1] * self.scale[-1])))
        self.points.append(yh * self.scale)
        info.z_scale = float(self.scale[:-1].max(initial=0.0))
        self.infos.append(info)

    def _finish(self, status: int, message: str) -> str:
        self.convergence = Convergence(status == SUCCESS, status, message, len(self.points))
        self.status = "finished" if status == SUCCESS else "failed"
        self.message = message
        if status != SUCCESS:
            log.warning("%s: %s", self.desc, message)
        return message

    def _start(self, y0, solve_first, tangent0) -> None:
        """Solve (or take) the first point and its tangent."""
        yh = y0 / self.scale
        t_prev = np.zeros(self.n1)
        t_prev[-1] = self.direction
        if tangent0 is not None:
            t_prev = np.asarray(tangent0, dtype=float) / np.linalg.norm(tangent0)
        if solve_first:
            yh, R, J, extra, it, ok = self._corrector_fixed(yh, yh[-1])
            if not ok:
                self._finish(NOT_CONVERGED, f"the first point (lam = {self.lam0:g}) did not "
                                            f"converge in {self.max_iter} Newton iterations")
                return
        else:
            R, J, extra = self._F(yh)
            it = 0
        t = tangent(J, t_prev)
        self._accept(yh, PointInfo(it, float(np.abs(R).max(initial=0.0)), 0.0, t, extra))
        self._yh, self._t = yh, t
        self._J, self._sign = J, None
        if not solve_first:
            # a resumed branch whose last point already ended it
            if (yh[-1] - self._lam_end_h) * self.direction \
                    >= -1e-12 * max(1.0, abs(self._lam_end_h)):
                self._finish(SUCCESS, f"reached lam = {self.lam_end:g} (resumed at its end)")
                return
            if (yh[-1] - self._lam_start_h) * self.direction < 0:
                self._finish(SUCCESS, f"the branch turned back out of the range through "
                                      f"lam = {self._lam_start_h * self.scale[-1]:g} "
                                      "(resumed at its end)")
                return
        self._check_max_points()

    def _check_max_points(self) -> None:
        if self.status == "running" and len(self.points) >= self.max_points:
            self._finish(NOT_CONVERGED, f"stopped at max_points = {self.max_points} before "
                                        f"lam = {self.lam_end:g} (reached "
                                        f"{self.points[-1][-1]:.8g})")

    def _corrector_fixed(self, yh, lam_h, stall=None):
        """Newton in z at fixed lam (scaled); gives up on a stall when ``stall`` is set."""
        def fun(z):
            R, J, extra = self._F(np.concatenate([z, [lam_h]]))
            return R, drop_last_column(J), (J, extra)

        res = newton(fun, yh[:-1], NewtonOptions(self.tol, self.max_iter, line_search="none",
                                                 stall=stall), solve=solve)
        J, extra = res.extra
        return (np.concatenate([res.x, [lam_h]]), res.R, J, extra, res.iterations,
                res.success)

    def _retraces(self, yc, yk) -> bool:
        """Whether ``yc`` lies back on the branch already traced: closer to one of
        the last segments than half its distance from ``yk``."""
        d = np.linalg.norm(yc - yk)
        pts = [p / self.scale for p in self.points[-RETRACE_POINTS:]]
        for a, b in zip(pts[:-1], pts[1:]):
            ab = b - a
            s_ = float(np.clip((yc - a) @ ab / max(ab @ ab, 1e-300), 0.0, 1.0))
            if np.linalg.norm(yc - (a + s_ * ab)) < 0.5 * d:
                return True
        return False

    def _correct(self, yk, t, h, jump_limit=None):
        """Predictor ``yk + h t`` and Newton on the hyperplane ``t.(y - yk) = h``.

        Fails on non-finite values, on ``max_iter`` iterations, on stagnation
        (the best residual not improved by 10 % in ``stall`` iterations: Newton
        cycling across a kink), when it lands farther than ``jump_limit * h``
        (default ``max_jump * h``) from the predictor, and when it lands back on
        the branch already traced.  Returns ``(ok, y, R, J, extra, iterations)``.
        """
        jump_limit = self.max_jump if jump_limit is None else jump_limit
        desc = self.desc
        pred = yk + h * t
        # backtracking: on the piecewise-smooth residual a full step can cycle across a kink
        fun, jac, measure = bordered(self._F, t, yk, h)
        res = newton(fun, pred, NewtonOptions(self.tol, self.max_iter, line_search="decrease",
                                              max_tries=self.backtrack, stall=self.stall),
                     jacobian=jac, measure=measure)
        yc, (R, J, extra), ok, it = res.x, res.extra, res.success, res.iterations
        if not ok:
            log.debug("%s: corrector failed (h = %.3g): %s", desc, h, res.message)
        jumped = bool(ok and np.linalg.norm(yc - pred) > jump_limit * h)
        if jumped:
            ok = False
            log.debug("%s: corrector jumped %.3g from the predictor (h = %.3g); retrying",
                      desc, np.linalg.norm(yc - pred), h)
        if ok and self._retraces(yc, yk):
            ok = False
            self.n_retraced += 1
            log.debug("%s: corrector landed back on the traced branch (h = %.3g)", desc, h)
        if not ok:
            self.n_failed += 1
            self._failed = (h, jumped, (yc, R, J, extra, it))   # for _try_corner
        return ok, yc, R, J, extra, it

    def _orientation(self, yk, yc):
        """Unit direction the new tangent at ``yc`` is oriented like (scaled points).

        The last secant ``yc - yk``; after a step shorter than a quarter of the
        one before that lands straight behind ``yk`` (the secant runs against the
        step before to within ``acos(BEHIND_COS)``; a step across a fold turns
        less sharply and keeps its secant), the chord from the point before ``yk`` to ``yc``: after a tiny
        step from a point whose tangent was poor (a near-singular Jacobian, e.g.
        at an internal resonance of a nonlinear mode), the last secant can point
        back along the branch and would turn the branch round, which then
        retraces itself point by point.
        The chord keeps the direction of travel at folds (and at corners of up to
        90 degrees); after a normal step the secant does.
        """
        ref = yc - yk
        if len(self.points) > 1 and not self._turned:
            prev = yk - self.points[-2] / self.scale
            n_ref, n_prev = np.linalg.norm(ref), np.linalg.norm(prev)
            if (n_ref < 0.25 * n_prev
                    and float(ref @ prev) < -BEHIND_COS * n_ref * n_prev):
                ref = ref + prev
        n = np.linalg.norm(ref)
        if not np.isfinite(n) or n == 0.0:
            ref, n = yc - yk, max(np.linalg.norm(yc - yk), 1e-300)
        return ref / n

    def _new_tangent(self, J, yk, yc, t):
        """Unit tangent at the corrected point ``yc`` (scaled), oriented.

        Like :meth:`_orientation`'s reference; but when the tangent is nearly
        perpendicular to that reference (``|cos| < AMBIGUOUS_COS``: the branch
        turns by about 90 degrees within the step, or the tangent is poorly
        determined, as next to an internal resonance where the Jacobian is
        nearly singular), the sign of so small a product is a coin flip, and a
        wrong one sends the branch back the way it came.  The tangent is then
        oriented like the previous tangent ``t`` if it is clearly not
        perpendicular to that (the smaller of the two turns).  A turn at a
        non-smooth fold keeps the secant.
        """
        ref = self._orientation(yk, yc)
        t_new = tangent(J, ref)
        c_ref, c_prev = float(t_new @ ref), float(t_new @ t)
        if (not self._turned and abs(c_ref) < AMBIGUOUS_COS
                and abs(c_prev) >= AMBIGUOUS_COS and c_prev < 0.0):
            log.debug("%s: tangent at lam = %.8g nearly perpendicular to the secant "
                      "(cos %.3f); oriented like the previous tangent (cos %.3f)", self.desc,
                      yc[-1] * self.scale[-1], c_ref, c_prev)
            t_new = -t_new
        return t_new

    def _monitor_change(self, yk, yc) -> float:
        """Largest change of the monitored quantities from ``yk`` to ``yc`` (scaled
        points; 0 without a monitor)."""
        if self.monitor is None:
            return 0.0
        d = np.asarray(self.monitor(yc * self.scale)) - np.asarray(self.monitor(yk * self.scale))
        c = float(np.abs(d).max(initial=0.0))
        return c if np.isfinite(c) else 0.0

    def _try_longer(self, yk, t, h):
        """A longer step (``LONGER_STEP`` times, at most ``step_max``) over a kink.

        A kink of the piecewise-smooth residual (a stick/slip or contact switch
        crossing a sample) can make Newton cycle near it while a longer step
        lands beyond it.  Returns ``(ok, h, y, R, J, extra, iterations)``.
        """
        hj = min(LONGER_STEP * h, self.step_max)
        ok, yc, R, J, extra, it = self._correct(yk, t, hj)
        if ok:
            log.debug("%s: stepped over a kink at lam = %.8g (h %.3g -> %.3g)",
                      self.desc, yk[-1] * self.scale[-1], h, hj)
            return True, hj, yc, R, J, extra, it
        return False, h, yc, R, J, extra, it

    def _try_corner(self, yk, t, h):
        """Pass a corner of the piecewise-smooth branch.

        First accept a point beyond a corner of up to 80 degrees (the hyperplane still
        cuts the branch there, far from the predictor; not when this step just failed
        otherwise, which would recur), then the tangent of the piece beyond it in both
        orientations (a stalled direction is given up), last a corrector at fixed
        ``lam`` a little ahead (:meth:`_natural_step`; no hyperplane normal to the
        incoming tangent cuts the new piece of a corner sharper than 90 degrees near
        it: issue 13 case 14; tried first, it sent the rough branches of sampled
        closing in ``tests/hard`` zig-zagging, round 50).  Returns ``(ok, h, y, R, J,
        extra, iterations)``.
        """
        hc = max(h, 1e3 * self.step_min)
        ok, (yc, R, J, extra, it) = False, self._failed[2]
        if self._failed[:2] != (hc, False):     # a stall or retrace would recur
            ok, yc, R, J, extra, it = self._correct(yk, t, hc, jump_limit=CORNER_JUMP)
        if ok:
            h = hc
            log.debug("%s: passed a corner of the branch at lam = %.8g", self.desc,
                      yk[-1] * self.scale[-1])
        got = None if ok else corner_step(self._F, yk, t, hc, self.tol, self.max_iter,
                                          self.max_jump, self.stall)
        if got is not None and self._retraces(got[0], yk):
            got = None
        if got is not None:
            yc, R, J, extra, it = got
            ok = True
            log.debug("%s: passed a corner of the branch at lam = %.8g", self.desc,
                      yk[-1] * self.scale[-1])
        got = None if ok else self._natural_step(yk, hc)
        if got is not None:
            yc, R, J, extra, it = got
            ok, h = True, float(np.linalg.norm(yc - yk))
        if not ok:
            # a non-smooth fold (kink whose pieces are not coherently oriented):
            # the point beyond it lies on the other piece, so it is not a retrace
            got = fold_step(self._F, yk, t, h, self.tol, self.max_iter)
            if got is not None:
                yc, R, J, extra, it = got
                ok, self._turned = True, True
                log.debug("%s: turned at a non-smooth fold at lam = %.8g", self.desc,
                          yk[-1] * self.scale[-1])
        return ok, h, yc, R, J, extra, it

    def _natural_step(self, yk, h):
        """Newton at fixed ``lam = lam_k + h`` (scaled, towards the end) from ``yk``.

        Accepted when it converges within ``CORNER_JUMP * h`` of ``yk`` and does
        not lie back on the traced branch.  Returns ``(y, R, J, extra,
        iterations)`` or None.
        """
        lam_h = yk[-1] + self.direction * h
        yc, R, J, extra, it, ok = self._corrector_fixed(yk, lam_h, self.stall)
        if not ok or not np.all(np.isfinite(yc)):
            return None
        if np.linalg.norm(yc - yk) > CORNER_JUMP * h or self._retraces(yc, yk):
            return None
        log.debug("%s: passed a corner of the branch at lam = %.8g at fixed lam", self.desc,
                  yk[-1] * self.scale[-1])
        return yc, R, J, extra, it

    def _close_at_end(self, yk, t, yc, R, extra, it, h, t_new) -> str | None:
        """Close the branch at ``lam_end`` from the secant ``yk -> yc`` (``yc`` past it or
        just short); when that fails ``yc`` is kept, and short of the end the branch goes
        on from it (None returned)."""
        lam_end_h = self._lam_end_h
        lam_new = yc[-1]
        a = (lam_end_h - yk[-1]) / (lam_new - yk[-1]) if lam_new != yk[-1] else 1.0
        guess = yk + a * (yc - yk)
        yf, Rf, Jf, ef, itf, okf = self._corrector_fixed(guess, lam_end_h)
        if okf:
            self._accept(yf, PointInfo(itf, float(np.abs(Rf).max(initial=0.0)),
                                       float(np.linalg.norm(yf - yk)), tangent(Jf, t), ef))
        else:
            self._accept(yc, PointInfo(it, float(np.abs(R).max(initial=0.0)), h, t_new, extra))
            if (lam_new - lam_end_h) * self.direction < 0:
                return None
        return self._finish(SUCCESS, f"reached lam = {self.lam_end:g} with "
                                     f"{len(self.points)} points")

    # -- the step -------------------------------------------------------------------
    def step(self) -> str | None:
        """Advance the branch by one accepted point.

        Failed correctors are retried with longer steps (once per point), at
        corners, and with halved steps; the branch fails when the step falls
        below ``step_min``.

        Returns
        -------
        message : str or None
            Why the branch ended, when this step ended it (``status`` is then
            ``"finished"`` or ``"failed"``); None when it goes on.
        """
        if self.status != "running":
            raise RuntimeError("attempt to step a finished or failed continuation")
        yk, t, scale = self._yh, self._t, self.scale
        self._turned = False   # set by a turn at a non-smooth fold (:func:`fold_step`)
        direction, step_min, step_max = self.direction, self.step_min, self.step_max
        corner_tries = jump_tries = 0
        retraced0 = self.n_retraced
        while True:
            h = self.h
            remedy = False
            # do not aim (much) past the end of the range
            near_end = False
            if t[-1] * direction > 0:
                to_end = (self._lam_end_h - yk[-1]) / t[-1]
                if 0 < to_end < h:
                    h = max(min(to_end * END_AIM, h), step_min)
                    near_end = True
            ok, yc, R, J, extra, it = self._correct(yk, t, h)
            if not ok and jump_tries == 0 and h < step_max:
                jump_tries += 1
                ok, h, yc, R, J, extra, it = self._try_longer(yk, t, h)
                remedy = ok
            if not ok and CORNERS and corner_tries < 2 and h < 0.05 * step_max:
                corner_tries += 1
                ok, h, yc, R, J, extra, it = self._try_corner(yk, t, h)
                remedy = ok
            change = self._monitor_change(yk, yc) if ok else 0.0
            if ok and change > 1.0 and h > 2.0 * step_min:
                # too large a change of a monitored quantity (e.g. damping at the
                # slip onset): shrink in proportion and retry
                self.n_failed += 1
                self.h = max(h * max(0.9 / change, 0.05), 2.0 * step_min)
                corner_tries, jump_tries = 2, 1  # no longer steps or corner tricks now
                continue
            if ok:
                t_new = self._new_tangent(J, yk, yc, t)
                if not remedy or h <= 2.0 * step_min or not self._reverses(yk, yc) \
                        or not self._flips(J, t_new):
                    break
                # a regular point whose tangent, oriented by the direction of travel,
                # gives the branch the other orientation: the corrector landed on a
                # piece running the other way (or the stepper turned round)
                ok = False
                self.n_failed += 1
                self.n_flipped += 1
                log.debug("%s: corrected point at lam = %.8g is oriented against the "
                          "branch (h = %.3g); retrying", self.desc, yc[-1] * scale[-1], h)
            self.h = h * 0.5
            if self.h < step_min:
                status = NON_FINITE if not np.isfinite(np.abs(R).max(initial=0.0)) \
                    else STEP_TOO_SMALL
                return self._finish(status, f"corrector failed with the step shrunk below "
                                            f"step_min = {step_min:g} at lam = "
                                            f"{yk[-1] * scale[-1]:.8g} after "
                                            f"{len(self.points)} points"
                                            + self._lost_way(self.n_retraced - retraced0))
        lam_new = yc[-1]
        short = (self._lam_end_h - lam_new) * direction
        if short <= 0 or (near_end and short <= END_SHORT * (lam_new - yk[-1]) * direction):
            why = self._close_at_end(yk, t, yc, R, extra, it, h, t_new)
            if why is not None:      # else short of the end, yc kept: the branch goes on
                return why
        else:
            info = PointInfo(it, float(np.abs(R).max(initial=0.0)), h, t_new, extra)
            if (lam_new - self._lam_start_h) * direction < 0 and len(self.points) > 1:
                self._accept(yc, info)
                return self._finish(SUCCESS, f"the branch turned back out of the range "
                                             f"through lam = {self.lam0:g} after "
                                             f"{len(self.points)} points")
            self._accept(yc, info)
        self._yh, self._t = yc, t_new
        self._J, self._sign = J, None
        self.h = next_step(h, it, self.target_iter, step_min, step_max, change)
        if self.adapt_scale:
            self._rescale()
            if self.status != "running":
                return self.message
        if self.lam_stall is not None:
            why = stall_message([p[-1] for p in self.points], *self.lam_stall,
                                abs(self.lam_end - self._lam_start_h * self.scale[-1]))
            if why:
                return self._finish(NOT_CONVERGED, why)
        self._check_max_points()
        return self.message

    def _flips(self, J, t_new) -> bool:
        """Whether the corrected point's tangent ``t_new`` (oriented by the direction of
        travel) flips ``sign det [J; t]`` against the last point (:mod:`.branch_watch`);
        False without ``keep_orientation``, after a turn at a non-smooth fold, or when
        either sign is unknown."""
        if not self.keep_orientation or self._turned or self._J is None:
            return False
        if self._sign is None:
            self._sign = orientation_sign(self._J, self._t)
        if not self._sign:
            return False
        s = orientation_sign(J, t_new)
        return s != 0 and s != self._sign

    def _reverses(self, yk, yc) -> bool:
        """Whether the step ``yk -> yc`` (scaled) runs back against the last accepted
        step (:func:`.branch_watch.runs_back`)."""
        if len(self.points) < 2:
            return False
        return runs_back(yk - self.points[-2] / self.scale, yc - yk)

    def _lost_way(self, retraced: int) -> str:
        """:func:`.branch_watch.lost_way_message` of this branch."""
        return lost_way_message(self.reversals, len(self.points), retraced)

    def _rescale(self) -> None:
        """``adapt_scale``: grow the ``z`` scales with the solution; stop an unbounded one."""
        y = self.points[-1]
        d = float(np.abs(y[:-1] - self._z0).max(initial=0.0))
        g = self._growth
        if g and d >= g[-1][0]:
            g.append((d, float(y[-1])))
        else:
            g[:] = [(d, float(y[-1]))]
        span = abs(self._lam_end_h - self._lam_start_h) * self.scale[-1]
        while len(g) > 1 and abs(g[0][1] - g[-1][1]) > UNBOUNDED_LAM * span:
            g.pop(0)   # keep the run within a lam window
        if len(g) > 2:
            lams = [p[1] for p in g]
            growth = g[-1][0] / max(g[0][0], 1e-300)
            if growth >= UNBOUNDED_GROWTH and max(lams) - min(lams) <= UNBOUNDED_LAM * span:
                self._finish(NOT_CONVERGED,
                             f"the response grows without bound near lam = {y[-1]:.8g}: "
                             f"max|z - z0| grew {growth:.3g} times over the last {len(g)} "
                             f"points while lam changed by {max(lams) - min(lams):.3g}")
                return
        sz = float(self.scale[:-1].max(initial=0.0))
        if sz > 0.0 and d > SCALE_GROWTH * sz:
            old = self.scale.copy()
            self.scale[:-1] *= d / sz
            self._col = self.scale / self.rscale
            self._yh = y / self.scale
            t = self._t * old / self.scale
            self._t = t / np.linalg.norm(t)
            self.infos[-1].tangent = self._t
            self.infos[-1].z_scale = float(self.scale[:-1].max())
            log.debug("%s: z scales grown %.3g times at lam = %.8g", self.desc, d / sz, y[-1])


def next_step(step: float, iterations: int, target_iter: int, step_min: float,
              step_max: float, change: float = 0.0) -> float:
    """The step after a point reached with ``step`` in ``iterations`` Newton iterations.

    Grows or shrinks towards ``target_iter`` iterations (by at most 2), within
    ``[step_min, step_max]``, and so that the monitored ``change`` of the last
    step (relative to its allowed value, 0 without a monitor) stays below 0.9.
    A resumed branch starts with it, so that it takes the steps the
    uninterrupted branch would have taken.
    """
    fac = np.sqrt(target_iter / max(int(iterations), 1))
    if change > 0.0:
        fac = min(fac, 0.9 / change)
    return float(np.clip(step * np.clip(fac, 0.5, 2.0), step_min, step_max))


def continue_branch(fun, y0, lam_end: float, *, scale, rscale: float, step: float,
                    step_min: float, step_max: float, max_points: int, tol: float,
                    max_iter: int = 20, target_iter: int = TARGET_ITER, max_jump: float = 2.0,
                    backtrack: int = 4, stall: int = 5,
                    solve_first: bool = True, tangent0=None, on_point=None,
                    progress: bool = True, desc: str = "continuation",
                    monitor=None, lam_start=None, adapt_scale: bool = False,
                    z_origin=None, keep_orientation: bool = False,
                    lam_stall=None) -> Branch:
    """Follow the solution branch of ``R(z, lam) = 0`` from ``y0`` to ``lam = lam_end``.

    Drives a :class:`Continuation` (whose parameters it takes) to its end.

    Parameters
    ----------
    fun, y0, lam_end, scale, rscale, step, step_min, step_max, max_points, tol
        As for :class:`Continuation`.
    max_iter, target_iter, max_jump, backtrack, stall, solve_first, tangent0, desc, monitor
    adapt_scale, z_origin, keep_orientation, lam_stall
        As for :class:`Continuation`.
    lam_start : float, optional
        Where the branch began, when ``y0`` is a later point of it (resume).
    on_point : callable, optional
        ``on_point(index, y, info: PointInfo)`` for every accepted point, as
        soon as it is accepted.
    progress : bool
        Show a tqdm bar of the progress through the ``lam`` range.

    Returns
    -------
    Branch
        Every accepted point; ``convergence`` says how the branch ended.
    """
    if progress:
        from tqdm.auto import tqdm
    else:  # the bar is disabled: plain tqdm, without tqdm.auto's import of asyncio
        from tqdm import tqdm

    bar = tqdm(total=1000, desc=desc, disable=(not progress) or None, leave=False,
               bar_format="{l_bar}{bar}| {postfix}")
    try:
        cont = Continuation(fun, y0, lam_end, scale=scale, rscale=rscale, step=step,
                            step_min=step_min, step_max=step_max, max_points=max_points,
                            tol=tol, max_iter=max_iter, target_iter=target_iter,
                            max_jump=max_jump, backtrack=backtrack, stall=stall,
                            solve_first=solve_first, tangent0=tangent0, desc=desc,
                            monitor=monitor, lam_start=lam_start,
                            adapt_scale=adapt_scale, z_origin=z_origin,
                            keep_orientation=keep_orientation, lam_stall=lam_stall)
        span = abs(cont.lam_end - cont.lam0)
        done = 0
        while True:
            for i in range(done, cont.n_points):
                y, info = cont.points[i], cont.infos[i]
                if on_point is not None:
                    on_point(i, y, info)
                frac = 0.0 if span == 0 else \
                    min(max((y[-1] - cont.lam0) * cont.direction / span, 0.0), 1.0)
                bar.n = int(1000 * frac)
                bar.set_postfix_str(f"{i + 1} pts, lam={y[-1]:.6g}, h={info.step:.2g}")
                bar.refresh()
            done = cont.n_points
            if cont.status != "running":
                return cont.branch
            cont.step()
    finally:
        bar.close()
