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
