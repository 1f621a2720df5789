"""The single-writer lock of a result file: an exclusive ``flock`` on a side file.

A second writer is refused before it opens the result file, so it changes
nothing; the kernel drops the lock when the writer dies, however it dies.
:class:`jointsim.io.hdf5.ResultWriter` takes it.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import os
from pathlib import Path


class FileLockedError(OSError):
    """Another process is writing the result file."""


def lock_path(path) -> Path:
    """The side file whose ``flock`` makes a process the writer of ``path``."""
    path = Path(path)
    return path.with_name(path.name + ".lock")


def acquire_lock(path) -> int:
    """Become the only writer of ``path``: an exclusive, non-blocking ``flock``.

    The lock is on the side file :func:`lock_path` (the result file itself
    is not opened, so a refused writer changes nothing).  The kernel drops
    the lock when the process dies, however it dies.

    Returns
    -------
    int
        The file descriptor holding the lock (give it to :func:`release_lock`).

    Raises
    ------
    FileLockedError
        When another process holds the lock.
    """
    lp = lock_path(path)
    while True:
        fd = os.open(lp, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise FileLockedError(f"{path}: another jointsim process is writing this "
                                      f"file (lock {lp.name} is held); nothing was changed")
                raise
            raise
        # the holder before us may have removed the side file after we opened it:
        # then our lock is on a dead inode, and we try again on the new one
        try:
            same = os.stat(lp).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
            return fd
        os.close(fd)


def release_lock(path, fd: int) -> None:
    """Remove the side file and drop the lock taken by :func:`acquire_lock`."""
    with contextlib.suppress(FileNotFoundError):
        os.unlink(lock_path(path))
    os.close(fd)
