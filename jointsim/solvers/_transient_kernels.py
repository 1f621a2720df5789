"""Numba helpers of the time-marching solver.

The contact march kernels are compiled with ``parallel=True`` for harmonic
balance, where one call covers many samples and elements.  Time marching
calls them with one sample per Newton iteration, tens of thousands of times;
there, waking the thread pool costs far more than the work, and on a shared
machine a parallel launch can wait milliseconds for a descheduled worker.
:func:`single_threaded` runs such calls on the calling thread only.
"""
from __future__ import annotations

import contextlib

import numba


@contextlib.contextmanager
def single_threaded():
    """Run numba parallel kernels on one thread inside the block (thread-local)."""
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)
