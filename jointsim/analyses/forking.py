"""Forked worker processes of the runners: whether they may be used, and how a
worker ties its life to its parent (FRC branches, :mod:`.hbm`; error indicators,
:mod:`.indicator_pool`)."""
from __future__ import annotations

import logging
import os
import time

log = logging.getLogger(__name__)


def _in_daemon(what: str = "branches and error indicators") -> bool:
    """In a daemonic process (a dask or multiprocessing worker), which may not fork
    workers; ``what`` names the work that then runs serially (logged)."""
    import multiprocessing as mp
    if mp.current_process().daemon:
        log.info("in a daemonic worker process: %s run serially", what)
        return True
    return False


def _can_fork() -> bool:
    import multiprocessing as mp
    return "fork" in mp.get_all_start_methods()


def die_with_parent(parent_pid: int) -> None:
    """In a forked worker: be killed (SIGKILL) when the parent dies, however it dies.

    Linux: ``prctl(PR_SET_PDEATHSIG, SIGKILL)``; elsewhere a thread that
    polls the parent pid every 0.5 s.  Also closes the descriptors of the
    parent's result writers (:func:`jointsim.io.hdf5.release_inherited`), so a
    worker never holds the file lock, and leaves SIGINT to the parent (which
    stops the workers and marks the file).
    """
    import signal
    import sys
    import threading

    from ..io.hdf5 import release_inherited
    release_inherited()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    armed = False
    if sys.platform.startswith("linux"):
        import ctypes
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(1, int(signal.SIGKILL), 0, 0, 0) == 0  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os._exit(1)
    if not armed:
        def watch():
            while os.getppid() == parent_pid:
                time.sleep(0.5)
            os._exit(1)
        threading.Thread(target=watch, daemon=True).start()


#: Points whose error indicators the parent may hold from the branch workers at once
#: (being computed or waiting, :class:`Deferral`).
DEFER_BACKLOG = 2


class Deferral:
    """Which points' error indicators the FRC branch workers leave to the parent.

    Once a core is free (:meth:`start`: no branch is left to start), a worker leaves a
    point's indicators to the parent (:func:`jointsim.analyses.hbm._run_branches_forked`)
    while the parent holds fewer than :data:`DEFER_BACKLOG` of them, and computes them
    itself otherwise: the parent and the last worker share the last branch's
    indicators and finish together (before round 32 every point was left to the
    parent, whose backlog then outlasted the branch).  No lock: each worker counts the
    points it left in its own slot of a shared array, the parent the ones it has
    computed in a shared integer, and each count has one writer (a worker killed at
    any moment blocks nobody; two workers reading the same count may both leave a
    point, one more than the bound).

    Parameters
    ----------
    ctx : multiprocessing context
        The fork context of the workers.
    n_slots : int
        Workers' slots (one per branch index).
    """

    def __init__(self, ctx, n_slots: int):
        self._on = ctx.Event()
        self._left = ctx.Array("i", max(int(n_slots), 1), lock=False)
        self._computed = ctx.Value("i", 0, lock=False)

    def start(self) -> None:
        """A core is free: from now on the workers may leave indicators (parent)."""
        self._on.set()

    @property
    def started(self) -> bool:
        return self._on.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until :meth:`start` (True), or ``timeout`` seconds (False)."""
        return self._on.wait(timeout)

    def take(self, slot: int) -> bool:
        """Whether the worker of ``slot`` leaves its next point's indicators (worker)."""
        if not self._on.is_set() or \
                sum(self._left) - self._computed.value >= DEFER_BACKLOG:
            return False
        self._left[slot] += 1
        return True

    def computed(self) -> None:
        """The parent has computed a left point's indicators (parent)."""
        self._computed.value += 1
