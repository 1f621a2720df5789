"""The reuse of the harmonic preconditioner across Jacobians (the chord policy).

:class:`PreconditionerCache` keeps the :class:`~.preconditioner.HarmonicPreconditioner`
in use and offers it to the next Jacobians (Newton iterations, continuation steps, the
tangent) while it pays, and when it has to build one for a Jacobian at (nearly) the
same frequency it keeps the harmonic stage and builds only the low-rank one
(``SHARE_HARMONIC_STAGE``).  The scheme is explained in :mod:`jointsim.solvers.jacobian`.
"""
from __future__ import annotations

import logging

from . import preconditioner
from .preconditioner import SINGLE_LU_RTOL, HarmonicPreconditioner

log = logging.getLogger(__name__)

#: GMRES iterations above which a reused preconditioner is always allowed to be
#: rebuilt (the least threshold of :meth:`PreconditionerCache.threshold`).
REFRESH_ITERATIONS = 10
#: Chord policy: a reused preconditioner is kept while the GMRES iterations it costs
#: beyond those it needed when fresh are cheaper than a new build.  The cost model
#: is in floating-point operations (:attr:`HarmonicPreconditioner.build_flops`,
#: :attr:`HarmonicPreconditioner.iteration_flops`); an iteration's flops are
#: memory-bound products and count ``ITERATION_WEIGHT`` times (measured at 121
#: contact pairs, FRC at force scale 20, one BLAS thread: a build cost 42 GMRES
#: iterations, 1.4 s against 33 ms at load 17, where the flop model says 107).  Only a preconditioner that was (nearly) exact when fresh, at
#: most ``REFRESH_ITERATIONS`` iterations, is kept beyond ``REFRESH_ITERATIONS``:
#: reusing a truncated one (50 iterations fresh in gross slip) was measured 2.2x
#: more GMRES iterations and slower overall.  Off by default: measured side by
#: side at 121 pairs and load 1, the first 15 EPMC points took 19.1 s with it
#: against 12.8 s with the fixed threshold ``REFRESH_ITERATIONS`` (1,705 vs 547
#: GMRES iterations, 3 vs 16 builds); the FRC at force scale 2 lost too.
COST_REUSE = False
ITERATION_WEIGHT = 2.5
#: ... but from this many rows ``n_r`` the cost model is used by a cache whose
#: Jacobians are solved tightly (a branch's continuation, not the error indicators'
#: loose extended systems): a build's ``n_r^3`` then outweighs the iterations' ``n_r^2``.
#: Measured side by side (round 50, EPMC, first 25 points): 480 Gauss points (960 rows)
#: 98.4 -> 64.4 s with the indicators off (builds 28 -> 4, GMRES iterations 908 ->
#: 1,662, X equal to 1.5e-9) and 142.7 -> 125.7 s with them; 240 points 40.4 -> 40.8 s;
#: on every cache down to 48 points it lost 5 to 20 % (docs/hbm.md, "Round 50").
COST_REUSE_MIN_ROWS = 800
#: Largest threshold of the chord policy (GMRES iterations; below the restart length).
REFRESH_MAX = 60

#: A truncated preconditioner (gross slip: 25 to 50 GMRES iterations even fresh, so
#: it serves its own Jacobian only and every Newton iteration builds one) would be
#: offered to the next Jacobians while a solve with it needs at most this many times
#: the iterations it needed fresh (0: never).  Off: measured side by side at 121
#: pairs, force scale 20, first 12 points, load 10 (``benchmarks/profile_case.py hbm
#: --force 20 --points 12``), at 2.0 the builds went 46 -> 22 but the GMRES
#: iterations 1,976 -> 3,489 and the time 61.9 -> 74.1 s (a reused truncated
#: preconditioner needs about twice its fresh iterations; they cost more than the
#: builds saved).
TRUNCATED_REUSE = 0.0
#: A preconditioner built for a Jacobian at a frequency within this fraction of the
#: last full build's (``|d omega| + |d xi| <= SHARE_HARMONIC_STAGE omega``) keeps that
#: build's harmonic stage (``S_h`` and the ``H + 1`` inverses, at the old frequency
#: and with the old harmonic projection of the tangent) and builds only its low-rank
#: stage, which then corrects for the whole change of the tangent (``partial``).
#: 0: every build is full.  A shifted stage (the EPMC's bordered solves) is shared by
#: builds shifted on the same harmonic, with its own shift (round 44).  Not for
#: Jacobians solved to a loose tolerance (``SINGLE_LU_RTOL``: the error indicators'
#: extended systems) unless the cache says so (:attr:`PreconditionerCache.
#: share_within_point`): for an FRC point's extended solve the low-rank LU dominates
#: the build, and the old projection adds the elements that stuck in one state and
#: slipped in the other to it.  Measured on 120 Gauss points, force-20 branch, one
#: thread: a main system's build 133 ms full, 42 ms partial; an extended system's
#: 0.41 s full, 0.47 s partial.
#: The branch (error indicators off) on 240 Gauss points: 145.6 s without sharing,
#: 117.8 s at 1e-3, 112.2 s at 5e-3 (Newton iterations and points unchanged, GMRES
#: iterations 2,949 / 3,105 / 3,257, X equal to 2.4e-12).  The shifted stages of the
#: EPMC on 480 Gauss points (error indicators off, round 44): 272.1 -> 212.2 s, the same
#: 34 points, GMRES iterations 2,904 -> 3,101.  A stage from the stuck flexibility is
#: shared only when shifted (round 56: the EPMC's tight bordered solves from
#: ``preconditioner.SHIFTED_SPLIT_MIN_ROWS`` rows, whose shifted block is inverted; error
#: indicators off, 240 points 8.16 -> 7.51 s, 480 points 26.32 -> 22.73 s; at 2e-2
#: instead of 5e-3 9.02 and 26.20 s).
SHARE_HARMONIC_STAGE = 5e-3

#: A truncated low-rank stage that fails: after ``RAISE_AFTER`` solves in which a
#: fresh, truncated preconditioner needed more than ``RAISE_ITERATIONS`` GMRES
#: iterations in one run, the cache raises its low-rank limit from
#: ``preconditioner.LOWRANK_MAX`` to ``LOWRANK_MAX_RAISED`` coordinates for the rest of
#: its life (:attr:`PreconditionerCache.lowrank_max`; the correction is then exact up to
#: that size and truncated to it beyond).  Measured (round 37) on the force-20 FRC
#: branch: at 480 Gauss points its stage wants 6,300 to 6,700 coordinates, kept 4,590,
#: and a fresh one needed 80 to 400 iterations in a run (1,600 to 2,850 a point, 6 to 9
#: builds, about 60 s a point); raised after two builds: 41 to 80 a point, 1 to 3
#: builds, about 6 s a point.  At 240 points, where a fresh truncated stage needs at
#: most 20 iterations but once (225), a limit of 8000 throughout made the whole FRC
#: slower (80.7 against 75.3 s, round 36): the limit is raised only where truncation is
#: seen to fail, and at 240 points never.  A partial preconditioner (on a shared
#: harmonic stage) counts as a full one: at 480 points the branch's stage first wants
#: 4,650 coordinates, and after its first full truncated build (148 iterations) 8
#: partial ones needed 79 to 229 each; a second full one raised the limit at the 16th
#: truncated build.  Counting the partial ones, it is raised at the second, and the
#: branch (error indicators off) took 178.3 s instead of 251.3 s (round 46).  The
#: EPMC at 480 points in gross slip wants 6,000 to 7,700 coordinates, and its fresh
#: truncated stages needed 70 to 98 iterations in a run, three builds a point: at 60
#: instead of 100 its limit is raised there (round 47; error indicators off: 236.6 ->
#: 220.3 s, GMRES iterations 3,055 -> 1,337, builds 59 -> 48, the same 34 points; the
#: FRC at 480 points and the EPMC at 240 do not change).
RAISE_ITERATIONS = 60
RAISE_AFTER = 2
LOWRANK_MAX_RAISED = 8000


class PreconditionerCache:
    """The harmonic preconditioner in use, shared by successive Jacobians (chord reuse).

    A preconditioner built from one Jacobian is reused for the next ones (Newton
    iterations, continuation steps, the tangent and the error indicators of a
    point) as long as it pays: it is dropped when a solve needs more GMRES
    iterations than :meth:`threshold`, i.e. when the iterations it costs beyond
    those it needed on its own Jacobian would have paid for a new build
    (``COST_REUSE``; at least ``REFRESH_ITERATIONS``, at most ``REFRESH_MAX``).

    Parameters
    ----------
    refresh_iterations : int
        Least threshold (GMRES iterations).
    reuse : bool
        False: build a new preconditioner for every Jacobian.
    cost_reuse : bool, optional
        Use the cost model (default ``COST_REUSE``); False: the fixed threshold
        ``refresh_iterations``.
    """

    def __init__(self, refresh_iterations: int = REFRESH_ITERATIONS, reuse: bool = True,
                 cost_reuse: bool | None = None):
        self.refresh_iterations = int(refresh_iterations)
        self.reuse = bool(reuse)
        self.cost_reuse = COST_REUSE if cost_reuse is None else bool(cost_reuse)
        self.current = None
        self.owner = None
        #: GMRES iterations the current preconditioner needed on its own Jacobian
        self.fresh_iterations = 0
        #: the current one is kept for its own Jacobian only (weak even when fresh)
        self.exclusive = False
        #: the last preconditioner whose harmonic stage was built (shared by the
        #: partial ones after it, ``SHARE_HARMONIC_STAGE``), and the GMRES iterations
        #: its first solve needed
        self.stage = None
        self.stage_iterations = None
        #: each preconditioner serves one solve (the FRC points' extended solves of the
        #: error indicators): a loose one may split its low-rank stage (element blocks
        #: of ``I + L_r G``) and be solved through its capacitance system (``LOOSE_SPLIT_MIN``; a split
        #: one is kept for its own Jacobian only); set by the caller
        self.single_solve = False
        #: the builds share the kept harmonic stage whatever their frequency and
        #: tolerance (an EPMC point's extended Newton steps, whose frequencies differ
        #: by the estimated errors; the caller drops the stage at each point,
        #: :meth:`forget`): set by the caller
        self.share_within_point = False
        #: the harmonic stage's inverses may be in single precision
        #: (``preconditioner.SINGLE_INVERSE_MIN``): an FRC branch's continuation sets it
        #: (:func:`jointsim.analyses.hbm._run_branch`), where it pays; off elsewhere
        self.single_inverses = False
        #: fresh truncated preconditioners (full or partial) that needed more than
        #: ``RAISE_ITERATIONS`` GMRES iterations (``RAISE_AFTER`` raise the limit)
        self.failed_truncations = 0

    @property
    def lowrank_max(self) -> int:
        """Largest low-rank correction (coordinates) of the preconditioners built here:
        ``preconditioner.LOWRANK_MAX``, or ``LOWRANK_MAX_RAISED`` once truncated ones
        failed (``RAISE_AFTER``)."""
        return max(LOWRANK_MAX_RAISED, preconditioner.LOWRANK_MAX) \
            if self.failed_truncations >= RAISE_AFTER else preconditioner.LOWRANK_MAX

    def get(self, jac, shift=None) -> tuple["HarmonicPreconditioner", bool]:
        """A preconditioner for ``jac`` and whether it was built from ``jac`` itself
        (``shift``: see :class:`HarmonicPreconditioner`; used when one is built)."""
        if self.current is not None and (self.owns(jac) or (self.reuse and not self.exclusive)):
            return self.current, self.owns(jac)
        return self.refresh(jac, shift), True

    def owns(self, jac) -> bool:
        """Whether the current preconditioner was built from ``jac``'s pieces (``jac``
        itself or a column-scaled copy of it)."""
        o = self.owner
        return o is not None and (o is jac or (o.freq is jac.freq and o.Juu is jac.Juu
                                               and o.Jug is jac.Jug and o.JNN is jac.JNN))

    def refresh(self, jac, shift=None, full: bool = False) -> "HarmonicPreconditioner":
        """Build the preconditioner of ``jac`` (with ``shift``) and keep it.

        Its harmonic stage is the last one's (only the low-rank stage is built,
        ``partial``) while the frequency is within ``SHARE_HARMONIC_STAGE`` of that
        stage's and neither is shifted, unless ``full``.
        """
        base = None if full else self._stage_for(jac, shift)
        self.current = HarmonicPreconditioner(jac, shift, base)
        if base is None:
            self.stage = self.current
            self.stage_iterations = None
        self.owner = jac
        self.fresh_iterations = 0
        self.exclusive = False
        if jac.stats is not None:
            jac.stats.factorizations += 1
        return self.current

    def _stage_for(self, jac, shift) -> "HarmonicPreconditioner | None":
        """The kept harmonic stage when ``jac`` may share it, else None."""
        P = self.stage
        if P is None or not P.shares_shift(shift):
            return None
        o = P.jac
        if o.basis is not jac.basis or o.lin is not jac.lin \
                or any((a is None) != (b is None) for a, b in
                       ((o.Juu, jac.Juu), (o.Jug, jac.Jug), (o.JNN, jac.JNN))):
            return None
        if self.share_within_point:
            return P
        # loose: see the constant; a modal stage is cheap to make, but a shifted one
        # (its shifted block's n_r^3 inverse: the EPMC's bordered solves, round 56)
        if not (self.reuse and SHARE_HARMONIC_STAGE > 0) or jac.rtol >= SINGLE_LU_RTOL \
                or (P.modal and P.C2 is None):
            return None
        change = abs(jac.freq.omega - P.omega) + abs(jac.freq.xi - P.xi)
        return P if change <= SHARE_HARMONIC_STAGE * abs(P.omega) else None

    def partial_budget(self) -> int:
        """GMRES iterations a partial preconditioner (a shared harmonic stage) gets
        before a full one is built: twice what the stage needed fresh, at least
        ``2 REFRESH_ITERATIONS``."""
        return max(2 * self.refresh_iterations, 2 * (self.stage_iterations or 0))

    def _truncated(self) -> bool:
        """Whether the current preconditioner is a truncated one kept for reuse
        (``TRUNCATED_REUSE``)."""
        return TRUNCATED_REUSE > 0 and self.current is not None \
            and bool(getattr(self.current, "truncated", False))

    def _by_cost(self) -> bool:
        """Whether the current preconditioner is kept by the cost model (``COST_REUSE``,
        or ``COST_REUSE_MIN_ROWS`` for a tightly solved one)."""
        P = self.current
        return P is not None and (self.cost_reuse or (P.jac.n_r >= COST_REUSE_MIN_ROWS
                                                      and P.jac.rtol < SINGLE_LU_RTOL))

    def budget(self) -> int:
        """GMRES iterations a reused preconditioner gets before it is rebuilt."""
        if self._by_cost() or self._truncated():
            return self.threshold()
        return 2 * self.threshold()

    def threshold(self) -> int:
        """GMRES iterations above which the preconditioner is dropped.

        With the cost model: the iterations it needed when fresh plus the number of
        iterations a build costs (``build_flops / iteration_flops``).  A truncated one
        (``TRUNCATED_REUSE``): that factor times the iterations it needed fresh.
        """
        if self._truncated():
            return max(self.refresh_iterations,
                       int(TRUNCATED_REUSE * max(self.fresh_iterations, 1)))
        if not self._by_cost() or self.fresh_iterations > self.refresh_iterations:
            return self.refresh_iterations
        P = self.current
        extra = P.build_flops / max(ITERATION_WEIGHT * P.iteration_flops, 1.0)
        return int(min(max(self.fresh_iterations + extra, self.refresh_iterations),
                       REFRESH_MAX))

    def after_solve(self, iterations: int, fresh: bool) -> None:
        """Keep or drop the current preconditioner after a solve with it.

        One built from the Jacobian just solved stays for that Jacobian's further
        solves (bordered, tangent, the indicators' two) even when it needed more
        than :meth:`threshold` iterations; it is then not offered to other
        Jacobians.  A reused one that needed more is dropped.
        """
        if fresh:
            self.fresh_iterations = max(self.fresh_iterations, int(iterations))
            P = self.current
            if iterations > RAISE_ITERATIONS and getattr(P, "truncated", False) \
                    and self.failed_truncations < RAISE_AFTER:
                self.failed_truncations += 1
                if self.failed_truncations == RAISE_AFTER:
                    log.info("a truncated preconditioner needed %d GMRES iterations: "
                             "low-rank corrections exact up to %d coordinates from here",
                             iterations, self.lowrank_max)
            if self.current is self.stage and self.stage_iterations is None:
                self.stage_iterations = int(iterations)
            # a split low-rank stage (its capacitance solves) is weak on another Jacobian
            if iterations > self.threshold() or getattr(P, "capacitance_solves", False):
                self.exclusive = True
        elif iterations > self.threshold():
            self.forget()

    def forget(self, stage: bool = False) -> None:
        """Drop the current preconditioner: the next Jacobian builds its own (the error
        indicators do this at every point, ``indicators.REUSE_ACROSS_POINTS``), and with
        ``stage`` the kept harmonic stage too (the next build is full)."""
        self.current = None
        self.owner = None
        self.exclusive = False
        if stage:
            self.stage = None
            self.stage_iterations = None
