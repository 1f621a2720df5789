"""Error indicators of solution points computed on forked worker processes (issue 10).

The indicators of a point (:mod:`jointsim.solvers.indicators`) depend on that
point only, and they cost several times the point itself (EPMC on the 121-pair lap
joint: 212 of 245 s).  :class:`IndicatorPool` computes them beside the
continuation: the runner writes each point with its ``error_*`` rows NaN ("not
computed yet"), hands ``(row, y)`` to the pool, and writes each result into its row
as it comes back (:func:`jointsim.io.hbm_points.set_error_indicators`).

* The workers are forked once, when the pool is made, after everything they need
  exists (the system, the estimator built with ``parallel=False``: a forked process
  never starts numba threads); they build nothing, receive ``(row, args)`` and send
  back ``(row, fn(*args))``.
* Each worker has its own task queue and its own result pipe (no lock is shared
  between workers, so a worker killed at any moment blocks no other).  At most
  :data:`DEPTH` rows are assigned to a worker at once, first in first out: the oldest
  is the one being computed.
* Once the continuation is done, the parent computes the rows no worker has started
  (:meth:`IndicatorPool.drain`): a row queued behind a busy worker's is taken back
  off that worker's queue.  Before (round 59), the last rows of a branch, the
  dearest, could wait behind each other on one worker while the other core was free.
* A worker that dies loses the row it was computing (its row stays NaN; the runner
  warns, and ``--resume`` computes it); the rows queued behind it go to the others.
  When no worker is left the parent computes the remaining rows itself once the
  continuation is done (:meth:`IndicatorPool.drain`): nothing but the rows being
  computed when the workers died is lost.
* Workers die with the parent (:func:`jointsim.analyses.forking.die_with_parent`).

Same numbers as serial, on the direct and the Krylov path: a point's extended solve
builds its own preconditioner (:data:`~jointsim.solvers.indicators.REUSE_ACROSS_POINTS`),
so neither the worker nor the points before it change its indicators (before round 25
a worker's solves reused preconditioners over a different sequence of points, and the
indicators differed by about ``INDICATOR_RTOL``, relative).  Only the AFT kernels on
numba threads (serial runs) and on one (workers) may differ in the last digits.
Measured side by side (2 cores, load 0.6 to 1.9; README, "How accurate is
a point?"): the EPMC of the 121-pair joint 191.8 -> 104.0 s, one FRC branch of it
103.8 -> 62.8 s, the main job 53.8 -> 41.0 s.
"""
from __future__ import annotations

import logging
import multiprocessing.connection as mpc
import os
import queue
from collections import deque

import numpy as np

from ..results import interrupt_cause

log = logging.getLogger(__name__)

#: Below this many unknowns of a point's system (``n_z``; the lumped scenes have 15 to
#: 30, the coarse FE lap joint 510) ``workers = 0`` computes the indicators in the
#: calling process: a point's take milliseconds there, and the pool's forks, pipes and
#: dispatch cost as much.  Measured on the one-DOF scene of ``tests/test_converge.py``
#: (EPMC and FRC, three runs each, alternating): the run 3.27 -> 2.99 s, the process's
#: CPU 5.4 -> 4.3 s without the pools (round 27).
POOL_MIN_UNKNOWNS = 200
#: Rows assigned to one worker at once (one computed, one waiting: no idle gap while
#: the parent is busy with the continuation and does not dispatch).
DEPTH = 2
#: While draining with a row queued behind a busy worker's, results are waited for at
#: most this long [s] before the queue is tried again (its row may still have been in
#: the feeder thread's buffer).
UNSTARTED_POLL = 0.05


def pool_workers(setting: int, n_rows_hint: int | None = None,
                 n_unknowns: int | None = None) -> int:
    """Number of indicator workers for a ``workers`` setting (0: one per core, or 1 for
    a system of fewer than :data:`POOL_MIN_UNKNOWNS` unknowns).

    1 (serial, in the calling process) when the platform cannot fork or the caller
    is itself a daemonic worker (dask, multiprocessing), exactly as the FRC branches
    (:func:`jointsim.analyses.forking._can_fork`, :func:`~jointsim.analyses.forking._in_daemon`).

    Parameters
    ----------
    setting : int
        The scene's ``workers`` key (``analysis.epmc.workers``).
    n_rows_hint : int, optional
        Rows known to be computed (a bound on useful workers).
    n_unknowns : int, optional
        Unknowns of the points' system (``n_z``); an explicit ``setting`` is kept
        whatever it is.
    """
    from .forking import _can_fork, _in_daemon

    if not int(setting) and n_unknowns is not None and n_unknowns < POOL_MIN_UNKNOWNS:
        return 1
    n = int(setting) or (os.cpu_count() or 1)
    if n_rows_hint is not None:
        n = min(n, max(int(n_rows_hint), 1))
    if n > 1 and _can_fork() and not _in_daemon():
        return n
    return 1


def _worker(tasks, conn, fn, parent_pid) -> None:
    """Body of a worker: ``(row, args)`` from ``tasks`` -> ``(row, fn(*args))`` on ``conn``."""
    from .forking import die_with_parent

    die_with_parent(parent_pid)
    while True:
        msg = tasks.get()
        if msg is None:
            break
        conn.send(_compute(fn, *msg))
    conn.close()


def _compute(fn, row: int, args: tuple) -> tuple:
    """``("ok", row, fn(*args))``, or ``("error", row, message)`` when ``fn`` raises (its
    own failures are its business: reported, and the next row goes on).  An interrupt
    handled inside a numba call (a ``SystemError`` caused by ``KeyboardInterrupt``,
    :func:`jointsim.results.interrupt_cause`) is not a failure of ``fn``: it goes on up
    (in the parent, which computes the rows no worker is left for)."""
    try:
        return "ok", row, fn(*args)
    except Exception as exc:
        if interrupt_cause(exc) is not None:
            raise
        return "error", row, f"{type(exc).__name__}: {exc}"


class IndicatorPool:
    """Forked workers that compute ``fn(*args)`` for rows and hand the results back.

    Parameters
    ----------
    fn : callable
        ``fn(*args) -> result`` (picklable result), run in the workers.  Everything it
        uses must exist before the pool is made (the workers are forked then).
    n_workers : int
        Worker processes (>= 1).
    what : str
        Name for messages (``"epmc"``).

    Attributes
    ----------
    lost : list of int
        Rows whose worker died while computing them (their results never come).
    """

    def __init__(self, fn, n_workers: int, what: str = "epmc"):
        import multiprocessing as mp

        ctx = mp.get_context("fork")
        self.fn = fn
        self.what = what
        self.lost: list[int] = []
        self._lost_out: list[tuple[int, None]] = []
        self.errors: list[tuple[int, str]] = []
        self.backlog: deque = deque()
        self.workers: list[dict] = []
        parent = os.getpid()
        for _ in range(int(n_workers)):
            tasks = ctx.Queue()
            recv, send = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_worker, args=(tasks, send, fn, parent), daemon=True)
            proc.start()
            send.close()
            self.workers.append(dict(proc=proc, tasks=tasks, conn=recv, rows=deque(),
                                     alive=True))
        log.info("%s: error indicators on %d worker processes", what, len(self.workers))

    # -- state ---------------------------------------------------------------------
    @property
    def n_workers(self) -> int:
        return len(self.workers)

    @property
    def pending(self) -> int:
        """Rows submitted whose result has not come back (and is not lost)."""
        return len(self.backlog) + len(self._lost_out) + sum(
            len(w["rows"]) for w in self.workers if w["alive"])

    # -- use ---------------------------------------------------------------------------
    def submit(self, row: int, *args) -> None:
        """Queue ``fn(*args)`` for ``row`` (never blocks)."""
        # copies: the queue pickles later, on its feeder thread
        args = tuple(np.array(v) if isinstance(v, np.ndarray) else v for v in args)
        self.backlog.append((int(row), args))
        self._dispatch()

    def _dispatch(self) -> None:
        live = [w for w in self.workers if w["alive"]]
        if not live:       # the rows wait for the drain: this process computes them
            return
        while self.backlog:
            w = min(live, key=lambda w: len(w["rows"]))
            if len(w["rows"]) >= DEPTH:
                return
            row, args = self.backlog.popleft()
            w["rows"].append((row, args))
            w["tasks"].put((row, args))

    def _lose(self, row: int, why: str) -> None:
        self.lost.append(row)
        self._lost_out.append((row, None))
        log.warning("%s: the error indicators of point %d were not computed (%s); they stay "
                    "NaN, --resume computes them", self.what, row, why)

    def poll(self, timeout: float | None = 0.0) -> list[tuple[int, object]]:
        """Results that have come back, as ``(row, result)``; waits up to ``timeout`` [s]
        for the first one (None: until one comes or a worker dies).

        A result of ``fn`` that raised, and a lost row (:attr:`lost`), are reported
        as ``(row, None)`` (logged).
        """
        live = [w for w in self.workers if w["alive"]]
        if live and not self._lost_out:
            mpc.wait([w["conn"] for w in live] + [w["proc"].sentinel for w in live], timeout)
        out = []
        for w in live:
            # checked before reading: a worker that has ended sent its last results before
            dead = not w["proc"].is_alive()
            while True:
                try:
                    if not w["conn"].poll():
                        break
                    kind, row, res = w["conn"].recv()
                except (EOFError, OSError):
                    break
                done = [i for i, (r, _) in enumerate(w["rows"]) if r == row]
                if done:
                    del w["rows"][done[0]]
                out.append(self._result(kind, row, res, "in a worker"))
            if dead:
                self._died(w)
        self._dispatch()
        out += self._lost_out
        self._lost_out = []
        return out

    def _result(self, kind: str, row: int, res, where: str) -> tuple[int, object]:
        """``(row, result)`` of a :func:`_compute` message; a failure is logged, kept in
        :attr:`errors` and reported as ``(row, None)``."""
        if kind == "error":
            log.warning("%s: error indicators of point %d failed %s: %s", self.what, row,
                        where, res)
            self.errors.append((row, res))
            return row, None
        return row, res

    def _died(self, w) -> None:
        """A worker has ended: its first row (being computed) is lost, the rest re-queued."""
        w["alive"] = False
        w["tasks"].cancel_join_thread()
        rows = list(w["rows"])
        w["rows"].clear()
        if rows:
            self._lose(rows[0][0], f"its worker process ended, exit code {w['proc'].exitcode}")
            self.backlog.extendleft(reversed(rows[1:]))

    def drain(self, on_result, desc: str = "indicators") -> None:
        """Wait for every pending row; ``on_result(row, result)`` for each (progress bar).

        Once the backlog has gone to the workers, this process, idle otherwise, computes
        the rows no worker has started: those queued behind the row a worker is
        computing, taken back off its task queue (:meth:`_unstarted`).  Without it the
        last rows of a branch, the dearest, wait behind each other on one worker while a
        core is free.  (The backlog itself goes to the workers as they free up: taken
        here, a row would hold back their next ones while it is computed.)  When no
        worker is left, every remaining row is computed here.  A row that raises is
        reported as ``(row, None)``, as from a worker.
        """
        from tqdm import tqdm

        if not self.pending:
            return
        here, warned = 0, False
        with tqdm(total=self.pending, desc=f"{desc} ({self.n_workers} workers)", unit="pt",
                  disable=None, leave=False) as bar:
            while self.pending:
                alive = any(w["alive"] for w in self.workers)
                if self.backlog and not alive and not warned:
                    warned = True
                    log.warning("%s: no indicator worker is left; this process computes "
                                "the %d remaining point(s)", self.what, len(self.backlog))
                job = (None if alive else self.backlog.popleft()) if self.backlog \
                    else self._unstarted()
                if job is not None:
                    here += 1
                    on_result(*self._result(*_compute(self.fn, *job), "here"))
                    bar.update(1)
                got = self.poll(timeout=0.0 if job is not None or not alive else
                                UNSTARTED_POLL if self._queued() else 1.0)
                for row, res in got:
                    on_result(row, res)
                    bar.update(1)
        if here:
            log.info("%s: %d point(s)' error indicators computed here while draining",
                     self.what, here)

    def _queued(self) -> bool:
        """Whether a live worker has a row assigned behind the one it computes."""
        return any(w["alive"] and len(w["rows"]) > 1 for w in self.workers)

    def _unstarted(self) -> tuple | None:
        """``(row, args)`` of a row assigned to a live worker that it has not started,
        taken back off its task queue (it is then no longer the worker's), or None.

        The queue's read lock makes the take exclusive: the worker gets the row or
        this process does, never both.  A worker blocked waiting on its queue holds
        that lock, and its queue is then empty anyway; a row still in the feeder
        thread's buffer is not taken (the next call may)."""
        for w in self.workers:
            if not (w["alive"] and len(w["rows"]) > 1):
                continue
            try:
                row, args = w["tasks"].get_nowait()
            except (queue.Empty, OSError, EOFError):
                continue
            done = [i for i, (r, _) in enumerate(w["rows"]) if r == row]
            if done:
                del w["rows"][done[0]]
            return row, args
        return None

    def close(self) -> None:
        """Stop the workers (rows still pending are abandoned: they stay NaN)."""
        for w in self.workers:
            if w["alive"] and w["proc"].is_alive():
                try:
                    w["tasks"].put(None)
                except (OSError, ValueError):
                    pass
        for w in self.workers:
            w["proc"].join(timeout=0.5 if not w["rows"] else 0.0)
            if w["proc"].is_alive():
                w["proc"].terminate()
                # a forked worker shares the result file's descriptor until it is gone
                w["proc"].join(timeout=10)
            w["tasks"].cancel_join_thread()
            w["tasks"].close()
            w["conn"].close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class InOrder:
    """Releases results in the order their rows were registered (for a warning that
    names the first point in branch order, whatever order the workers finish in)."""

    def __init__(self):
        self.order: deque = deque()
        self.done: dict = {}

    def expect(self, row: int) -> None:
        """Register a row (in branch order)."""
        self.order.append(int(row))

    def add(self, row: int, value) -> list[tuple[int, object]]:
        """Record ``value`` for ``row``; the ``(row, value)`` now releasable, in order."""
        self.done[int(row)] = value
        out = []
        while self.order and self.order[0] in self.done:
            r = self.order.popleft()
            out.append((r, self.done.pop(r)))
        return out


class PointIndicators:
    """The error indicators of a runner's points: computed at once (serial) or on an
    :class:`IndicatorPool`, written into the points' rows, checked in row order.

    Serial (``n_workers == 1``): the runner calls :meth:`compute` before it writes
    the point and writes the result with it, as without a pool.  Pooled: the runner
    writes the point with NaN indicators and calls :meth:`submit` after its commit;
    :meth:`collect` writes the results that have come back (each in its own commit)
    and :meth:`finish` waits for the rest.  The tolerance watch sees the points in
    row order either way.

    Parameters
    ----------
    writer : jointsim.io.hdf5.ResultWriter
    prefix : {'hbm', 'epmc'}
    fn : callable
        ``fn(*args) -> ErrorIndicators or None`` (None: not computed).
    watch : jointsim.solvers.indicators.ToleranceWatch
    n_workers : int
        1: serial; more: forked workers (:func:`pool_workers`).
    """

    def __init__(self, writer, prefix: str, fn, watch, n_workers: int):
        self.writer, self.prefix, self.fn, self.watch = writer, prefix, fn, watch
        self.pool = IndicatorPool(fn, n_workers, prefix) if n_workers > 1 else None
        self.order = InOrder()
        self.where: dict[int, tuple] = {}

    @property
    def serial(self) -> bool:
        return self.pool is None

    def compute(self, *args):
        """``fn(*args)`` here and now (the serial path)."""
        return self.fn(*args)

    def submit(self, row: int, args: tuple, where: str, branch=0) -> None:
        """Row ``row`` (already written, indicators NaN) goes to the pool; serially it is
        computed and written at once."""
        self.order.expect(row)
        self.where[int(row)] = (branch, where)
        if self.pool is None:
            self._write(row, self.fn(*args))
        else:
            self.pool.submit(row, *args)
            self.collect()

    def collect(self) -> None:
        """Write the results that have come back (does not wait)."""
        if self.pool is not None:
            for row, res in self.pool.poll(0.0):
                self._write(row, res)

    def finish(self) -> None:
        """Wait for every submitted row and write it (computing them here when no worker
        is left); warn about rows lost with a worker."""
        if self.pool is None:
            return
        self.pool.drain(self._write, desc=f"{self.prefix} error indicators")
        if self.pool.lost:
            log.warning("%s: the error indicators of %d point(s) were not computed (a worker "
                        "process died): rows %s stay NaN; run again with --resume to compute "
                        "them", self.prefix, len(self.pool.lost), sorted(self.pool.lost))

    def _write(self, row: int, ind) -> None:
        from ..io.hbm_points import set_error_indicators

        with self.writer.commit():
            set_error_indicators(self.writer, self.prefix, row, ind)
        for r, v in self.order.add(row, ind):
            branch, where = self.where.pop(r)
            self.watch.check(branch, v, r, where)

    def close(self) -> None:
        if self.pool is not None:
            self.pool.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
