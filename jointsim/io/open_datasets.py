"""The result writer's open datasets and their committed counts.

Every commit of a point (:meth:`.hdf5.ResultWriter.commit`) advances the
committed count of the datasets it appended to, and sets a group's count when
all of the group's extendable datasets agree.  Reading that agreement from
the file opened every dataset of the group and its attribute through h5py's
objects (6 to 8 ms a group of 27 datasets), and every append looked its
dataset up twice by name (about 1 ms an append).  On the one-DOF Jenkins scene
of ``tests/test_converge.py`` (64 points) that was 4.0 of the run's 8.8 s
under cProfile; with this module, 1.4 s (the run 7.4 -> 5.7 s, the file equal
but for its times), and the default test suite 390 -> 292 s warm.

:class:`OpenDatasets` keeps each object the writer has asked for open, with
its object address and, for an extendable dataset, its committed count:

* A name is trusted while its hard link still points at the address of the
  object held open.  An object that is held open keeps its file space, so a
  dataset deleted and created again under the same name (by the writer or by
  any other code) has another address, and is read afresh.
* Once the writer has opened the file, only the writer sets the counts
  (:meth:`advance`), so a cached count stays true until it changes it.

Rows and counts are written with h5py's low-level calls: the same bytes as
``Dataset.resize`` and ``__setitem__``, without their selection machinery.
"""
from __future__ import annotations

from dataclasses import dataclass

import h5py
import numpy as np
from h5py import h5a, h5l, h5s

#: dtype kinds written with the low-level call (strings and objects go through h5py).
_NUMERIC = "biufc"


@dataclass
class _Seen:
    """An object held open: its h5py object, object address, committed count."""
    obj: h5py.HLObject
    addr: int
    count: int | None  # committed rows of an extendable dataset; None for anything else


class OpenDatasets:
    """Objects of an open result file, held open by path, with committed counts.

    Parameters
    ----------
    h5 : h5py.File
        The writer's file.
    attr : str
        The count attribute (``committed_rows``).
    """

    def __init__(self, h5: h5py.File, attr: str):
        self.h5 = h5
        self.attr = attr
        self._attr_b = attr.encode()
        self._seen: dict[str, _Seen] = {}
        self._root = _Seen(h5["/"], -1, None)

    def _entry(self, path: str) -> _Seen | None:
        """The object at ``path`` (absolute), held open; None if there is none."""
        if path == "/":  # the root group: no link names it
            return self._root
        try:
            info = self.h5.id.links.get_info(path.encode())
        except (KeyError, RuntimeError):
            return None
        if info.type != h5l.TYPE_HARD:  # a soft or external link: read afresh, not kept
            obj = self.h5.get(path)
            return None if obj is None else _Seen(obj, -1, self._stored_count(obj))
        seen = self._seen.get(path)
        if seen is None or seen.addr != info.u:
            obj = self.h5[path]
            seen = _Seen(obj, info.u, self._stored_count(obj))
            self._seen[path] = seen
        return seen

    def _stored_count(self, obj) -> int | None:
        """The count attribute of an extendable dataset (0 if unset); None otherwise."""
        if isinstance(obj, h5py.Dataset) and obj.maxshape and obj.maxshape[0] is None:
            return int(obj.attrs.get(self.attr, 0))
        return None

    def rows(self, path: str) -> tuple[int, int]:
        """``(object address, rows)`` of the extendable dataset ``path`` (absolute)."""
        seen = self._entry(path)
        return seen.addr, seen.obj.id.shape[0]

    def get(self, path: str):
        """The h5py object at ``path`` (absolute), or None."""
        seen = self._entry(path)
        return None if seen is None else seen.obj

    def advance(self, path: str, n: int | None = None, addr: int | None = None) -> bool:
        """Set the committed count of the extendable dataset ``path`` to ``n`` (default:
        its rows).  With ``addr``, only if ``path`` is still that object (not deleted or
        replaced since): whether the count was set."""
        seen = self._entry(path)
        if addr is not None and (seen is None or seen.addr != addr):
            return False
        if n is None:
            n = seen.obj.id.shape[0]
        self._write_attr(seen.obj, n)
        seen.count = n
        return True

    def settle_group(self, path: str) -> None:
        """Give group ``path`` the committed count its extendable datasets agree on, or
        remove its count when they differ."""
        g = self.get(path)
        prefix = "" if path == "/" else path
        counts = set()
        for name in g.id:
            seen = self._entry(f"{prefix}/{name.decode()}")
            if seen is not None and seen.count is not None:
                counts.add(seen.count)
        if len(counts) == 1:
            self._write_attr(g, counts.pop())
        elif h5a.exists(g.id, self._attr_b):
            del g.attrs[self.attr]

    def _write_attr(self, obj, n: int) -> None:
        """Write the count attribute in place (created through h5py the first time)."""
        if h5a.exists(obj.id, self._attr_b):
            aid = h5a.open(obj.id, self._attr_b)
            if aid.shape == () and aid.dtype.kind in "iu":
                aid.write(np.asarray(n, dtype=aid.dtype))
                return
        obj.attrs[self.attr] = n


def append_rows(ds: h5py.Dataset, rows: np.ndarray) -> int:
    """Extend ``ds`` along its first axis by ``rows`` (shape ``(k, *row_shape)``).

    Returns
    -------
    int
        The rows now stored.
    """
    n = ds.id.shape[0]
    k = rows.shape[0]
    if rows.dtype.kind not in _NUMERIC or ds.dtype.kind not in _NUMERIC or not rows.size:
        ds.resize(n + k, axis=0)
        ds[n:] = rows
        return n + k
    rows = np.ascontiguousarray(rows)
    ds.id.set_extent((n + k,) + rows.shape[1:])
    space = ds.id.get_space()
    space.select_hyperslab((n,) + (0,) * (rows.ndim - 1), rows.shape)
    ds.id.write(h5s.create_simple(rows.shape), space, rows)
    return n + k
