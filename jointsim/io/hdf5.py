"""The HDF5 result file (DESIGN §4), written as results are computed.

Public contract (schema version 1):

* root attributes ``schema_version``, ``jointsim_version``, ``scene`` (the
  resolved TOML), ``scene_path``, ``created``, ``status`` (``running``,
  ``complete``, ``failed`` or ``interrupted``) and ``message``;
* ``/loops/u``, ``/loops/f``, ``/loops/N`` [n_points, n_elements, n_samples]
  and ``/loops/point`` [n_points] (the solution point of each loop);
* ``/masing/dev_manifold``, ``/masing/dev_masing`` [n_points, n_elements],
  ``/masing/on_manifold``, ``/masing/on_masing`` (bool), the condition
  checks, and the per-sample predictions; attribute ``tol``;
* ``/hbm/*``, ``/transient/*``, ``/qsma/*``, ``/epmc/*``, ``/modes/*``,
  ``/static/*`` written by their analyses.

Every dataset carries a ``unit`` attribute.  Datasets that grow point by
point are extendable along their first axis.

Crash consistency (issue 11):

* **One writer per file.**  A writer takes an exclusive ``flock`` on the
  side file ``<name>.lock`` *before* the result file is opened; a second
  writer is refused (:class:`FileLockedError`) and nothing is touched.  An
  existing result file is opened for writing only to resume it or when
  overwriting is asked for explicitly.  Forked worker processes never hold
  the lock (:func:`release_inherited`).  A new file is created as
  ``<name>.new`` and renamed into place once its header is written, so the
  path never names a half-created file and a file being overwritten stays
  whole until then.
* **Committed points.**  The rows of one point (all its datasets, its loops
  and Masing rows) are appended inside :meth:`ResultWriter.commit`; then the
  file is flushed, the attribute ``committed_rows`` (:data:`COMMITTED`) of
  every dataset appended to is advanced, and the file is flushed again (a
  group whose datasets take one row per point, such as ``/hbm``, carries the
  same count: its committed points).  Rows beyond it belong to a point
  that was being written when the process died: readers
  (:func:`open_result`) and ``--resume`` ignore them, and a writer that
  closes normally or resumes trims them.  The writer holds the datasets it
  writes open between commits and keeps their counts
  (:mod:`.open_datasets`): a commit then costs a few link lookups, not a
  reading of every dataset of its groups.  Points that finish within
  :data:`COMMIT_INTERVAL_S` of the last commit are committed with the next
  ones (each dataset at the rows it had when its point was whole), so a kill
  loses at most that much computing; finishing commits them first.
* **Damaged files.**  A kill that lands inside the HDF5 library's own
  flush can leave metadata half written, which no ordering of jointsim's
  writes prevents.  Readers (:func:`open_result`) then raise
  :class:`DamagedFileError` (one line naming the file), and ``--resume``
  renames the file to ``<name>.damaged`` (:func:`set_aside`) and computes
  the run again from the start, so that the run still completes with the
  uninterrupted result.
* **Resumed files are rewritten.**  A kill inside that flush can also leave
  a file that reads whole but whose free-space bookkeeping (the end of the
  allocated space recorded in the superblock) lags behind blocks that its
  metadata already points to; appending to it in place would then overwrite
  them.  ``--resume`` therefore copies every object of the killed file into a
  new file (:func:`rewrite`) and renames it over the old one before it appends;
  the copy reads every block, data included, so a file with a block beyond its
  recorded end is found damaged and set aside like the others.
"""
from __future__ import annotations

import contextlib
import datetime
import fcntl
import io
import logging
import os
import signal
import time
from pathlib import Path

import h5py
import numpy as np

from .. import __version__
from .lock import FileLockedError, acquire_lock, lock_path, release_lock  # noqa: F401 (API)
from .open_datasets import OpenDatasets, append_rows as _append_rows

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1

#: Group attribute: rows of the group's extendable datasets that hold whole points.
COMMITTED = "committed_rows"
#: Seconds a whole point may wait for its commit (:meth:`ResultWriter.commit`): the points
#: of a fast run (a lumped model: a few ms each) are committed together, at most this
#: much computing is lost to a kill.  A commit costs two flushes and a count per dataset,
#: about 4 ms a point of the 2-DOF chain's FRC (1.0 of its 4.2 s).
COMMIT_INTERVAL_S = 0.25
#: Root attribute (1) of files whose groups carry :data:`COMMITTED`: a group
#: without it there has no committed point yet.
COMMITS = "commits_points"
#: Suffix of a group being written whole (:meth:`ResultWriter.whole_group`).
PARTIAL = ".partial"


class NotAResultError(ValueError):
    """An HDF5 file that jointsim did not write."""


class DamagedFileError(OSError):
    """An HDF5 file that the HDF5 library cannot read (torn by a crash inside it)."""


#: The first bytes of every HDF5 file (superblock at offset 0).
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def is_hdf5(path) -> bool:
    """Whether ``path`` starts with the HDF5 signature (however damaged the rest is)."""
    try:
        with open(path, "rb") as f:
            return f.read(len(HDF5_SIGNATURE)) == HDF5_SIGNATURE
    except OSError:
        return False


def _walk(h5) -> None:
    """Read the attributes of the root and of every object (all the metadata HDF5 decodes)."""
    dict(h5.attrs)
    h5.visititems(lambda name, obj: dict(obj.attrs) and None)


def _being_written(path) -> bool:
    """Whether a live process holds the writer's lock of ``path`` (:func:`acquire_lock`)."""
    try:
        fd = os.open(lock_path(path), os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)  # drops the shared lock if it was taken
    return False


def _damaged(path, exc) -> DamagedFileError:
    """The error of a reader of an unreadable file (one being written says so)."""
    why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    if _being_written(path):
        return DamagedFileError(f"{path}: cannot be read while it is being written ({why}); "
                                "read it again in a moment")
    return DamagedFileError(f"{path}: damaged, the HDF5 library cannot read it ({why}); "
                            "`jointsim run --resume` sets it aside as "
                            f"{Path(path).name}.damaged and computes the run again")


def set_aside(path) -> Path:
    """Rename a damaged file to ``<name>.damaged`` (``.damaged.1``, ... if taken)."""
    path = Path(path)
    dest = path.with_name(path.name + ".damaged")
    k = 0
    while dest.exists():
        k += 1
        dest = path.with_name(f"{path.name}.damaged.{k}")
    os.replace(path, dest)
    return dest


def rewrite(path) -> None:
    """Copy every object and attribute of ``path`` into a new file and rename it over ``path``.

    The copy allocates its space afresh, so nothing of the old file's
    free-space bookkeeping survives; a kill during the copy leaves ``path``
    as it was (the copy is written under ``<name>.new``).  Soft links stay
    soft links.
    """
    path = Path(path)
    fresh = path.with_name(path.name + ".new")
    try:
        with h5py.File(path, "r", locking=False) as src, \
                h5py.File(fresh, "w", locking=False) as dst:
            for key, value in src.attrs.items():
                dst.attrs[key] = value
            for name in src:
                link = src.get(name, getlink=True)
                if isinstance(link, h5py.SoftLink):
                    dst[name] = h5py.SoftLink(link.path)
                else:
                    src.copy(src[name], dst, name=name)
    except BaseException:
        fresh.unlink(missing_ok=True)
        raise
    os.replace(fresh, path)


#: Lock descriptors and HDF5 file descriptors of the writers of this process.
_OPEN_WRITERS: dict[int, "ResultWriter"] = {}


def release_inherited() -> None:
    """In a forked child: close the writers' descriptors it inherited.

    A forked worker shares its parent's open file descriptions, and with them
    the ``flock`` of the result file; closing its copies (without touching
    HDF5, which belongs to the parent) lets the lock go as soon as the parent
    is gone.
    """
    for w in list(_OPEN_WRITERS.values()):
        for fd in (w._lock_fd, w._h5_fd):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
    _OPEN_WRITERS.clear()


#: Depth of the critical sections of this process, and the signals held meanwhile.
_CRITICAL = {"depth": 0, "pending": []}


def interrupt_handler(signum, frame) -> None:
    """Signal handler: raise :class:`KeyboardInterrupt`, after the current commit.

    Installed by :func:`jointsim.run.run_scene` for SIGINT, SIGTERM and SIGHUP;
    a signal that arrives while a point is being committed (or the file
    finished) is held and raised when that is done, so a commit is never cut
    in half.
    """
    if _CRITICAL["depth"]:
        _CRITICAL["pending"].append(signum)
        return
    raise KeyboardInterrupt(f"stopped by {signal.Signals(signum).name}")


@contextlib.contextmanager
def _signals_deferred():
    """A critical section: :func:`interrupt_handler` holds signals until it ends."""
    _CRITICAL["depth"] += 1
    try:
        yield
    finally:
        _CRITICAL["depth"] -= 1
    if not _CRITICAL["depth"] and _CRITICAL["pending"]:
        signum = _CRITICAL["pending"][0]
        _CRITICAL["pending"].clear()
        raise KeyboardInterrupt(f"stopped by {signal.Signals(signum).name}")


def _extendable_datasets(h5) -> list:
    """The extendable datasets of an open file (soft links not followed)."""
    out = []

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset) and obj.maxshape and obj.maxshape[0] is None:
            out.append(obj)

    h5.visititems(visit)  # visititems does not follow soft links
    return out


def torn_groups(h5) -> dict[str, int]:
    """Datasets holding rows beyond their committed count: ``{dataset: committed rows}``.

    A dataset's committed count is its own :data:`COMMITTED`; in a group with a
    count (one row per point) it is the smallest of the group's and its
    committed datasets' counts (a dataset never committed counts 0 alone).
    In a file with :data:`COMMITS`, an extendable dataset without the
    :data:`COMMITTED` attribute has committed nothing.  A file of an older
    jointsim (without :data:`COMMITS`) is taken as it is.
    """
    if not h5.attrs.get(COMMITS, 0):
        return {}
    datasets = _extendable_datasets(h5)
    # one row per point (the group has a count): a kill inside the commit's final
    # flush can leave some of the group's and its datasets' counts on disk and not
    # others; the smallest keeps the rows aligned and drops the half-committed point
    point_rows: dict[str, int] = {}
    for d in datasets:
        g = d.parent
        if COMMITTED in g.attrs and COMMITTED in d.attrs:
            n = min(int(g.attrs[COMMITTED]), int(d.attrs[COMMITTED]))
            point_rows[g.name] = min(point_rows.get(g.name, n), n)
    out = {}
    for d in datasets:
        n = point_rows.get(d.parent.name, int(d.attrs.get(COMMITTED, 0)))
        if d.shape[0] > n:
            out[d.name] = n
    return out


def _trim(h5, torn: dict[str, int]) -> None:
    """Cut torn rows; the datasets (and their group, where its datasets agree) then
    record their committed count, also when it is 0 (a first point that was torn).  A
    dataset that the torn point created (never committed) is removed: a point's
    datasets are all there or none (a SIGINT between two of a first loop set's Masing
    datasets left ``eq4_ok`` without ``eq6_ok``, and ``jointsim info`` failed)."""
    groups = set()
    for name, n in torn.items():
        d = h5[name]
        if n == 0 and COMMITTED not in d.attrs:
            del h5[name]
            continue
        d.resize(n, axis=0)
        d.attrs[COMMITTED] = n
        groups.add(d.parent.name)
    for g in groups:
        rows = {d.shape[0] for d in h5[g].values()
                if isinstance(d, h5py.Dataset) and d.maxshape and d.maxshape[0] is None}
        if len(rows) == 1:
            h5[g].attrs[COMMITTED] = rows.pop()


def open_result(path):
    """Open a result file for reading, committed points only.

    A file whose writer was killed may hold a torn last point (rows beyond a
    group's committed count); then an in-memory copy with those rows removed
    is returned, and the file on disk is not changed.

    Returns
    -------
    h5py.File
        Read it inside ``with``.

    Raises
    ------
    NotAResultError
        When the file is HDF5 but was not written by jointsim.
    OSError
        When it cannot be opened as HDF5.
    """
    try:
        h5 = h5py.File(path, "r")
    except OSError as exc:
        if is_hdf5(path):
            raise _damaged(path, exc) from None
        raise
    try:
        _walk(h5)
    except (OSError, KeyError, RuntimeError, ValueError) as exc:
        h5.close()
        raise _damaged(path, exc) from None
    if "schema_version" not in h5.attrs or "status" not in h5.attrs:
        h5.close()
        raise NotAResultError(f"{path}: an HDF5 file that jointsim did not write (no "
                              "schema_version/status attributes); not a result file")
    torn = torn_groups(h5)
    if not torn:
        return h5
    h5.close()
    log.info("%s: ignoring the torn last point of %s", path, ", ".join(sorted(torn)))
    mem = h5py.File(io.BytesIO(Path(path).read_bytes()), "r+")
    _trim(mem, torn)
    return mem

#: Physical quantity -> unit, per unit system of the model.
_UNITS = {
    "displacement": ("m", "length"),
    "force": ("N", "force"),
    "angular_frequency": ("rad/s", "1/time"),
    "frequency": ("Hz", "1/time"),
    "time": ("s", "time"),
    "stiffness": ("N/m", "force/length"),
    "energy": ("J", "force*length"),
    "pressure": ("Pa", "force/length^2"),
    "dimensionless": ("1", "1"),
    "modal_amplitude": ("sqrt(kg) m", "sqrt(mass) length"),
    "modal_load": ("sqrt(kg) m/s^2", "sqrt(mass) length/time^2"),
    "mode_shape": ("1/sqrt(kg)", "1/sqrt(mass)"),
}


def unit(quantity: str, system: str = "SI") -> str:
    """Unit string of a physical quantity in a unit system.

    Parameters
    ----------
    quantity : str
        A key of the table: ``displacement``, ``force``, ``angular_frequency``,
        ``frequency``, ``time``, ``stiffness``, ``energy``, ``pressure``,
        ``dimensionless``, ``modal_amplitude`` (q = phi^T M x with phi
        mass-normalised), ``modal_load`` (alpha, the load being alpha M phi),
        ``mode_shape``.
    system : str
        ``"SI"`` or ``"nondimensional"`` (consistent units, named by dimension).
    """
    si, nd = _UNITS[quantity]
    return si if system == "SI" else nd


class ResultWriter:
    """Incremental, crash-consistent writer of a result file.

    Use as a context manager; an exception inside marks the file ``failed``
    (``interrupted`` for Ctrl-C, SIGTERM: any :class:`KeyboardInterrupt`) with
    the reason and the committed point counts, and re-raises.

    Parameters
    ----------
    path : str or Path
        Output file; its folder is created.
    scene : jointsim.scene.Scene
        The resolved scene, stored as text.
    resume : bool
        Open an existing file to continue it; its stored scene must match.
        Rows of a torn last point are removed first.
    overwrite : bool
        Replace an existing file.  Without ``resume`` or ``overwrite`` an
        existing file is refused (:class:`FileExistsError`) and not touched.

    Raises
    ------
    FileLockedError
        When another process writes the file (checked before it is opened).
    """

    def __init__(self, path, scene, resume: bool = False, overwrite: bool = False):
        self.path = Path(path)
        if self.path.is_dir():
            raise IsADirectoryError(f"{self.path}: the output is a directory, not a file")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._txn: set | None = None
        #: dataset -> (object address, rows) of whole points not committed yet
        self._pending: dict[str, tuple] = {}
        self._committed_at = -float("inf")
        self._h5_fd = None
        self._lock_fd = acquire_lock(self.path)
        try:
            # a signal while the file is opened waits until it is whole and registered,
            # and is then raised here: the file is marked interrupted, not left running
            with _signals_deferred():
                self._open(scene, resume, overwrite)
                with contextlib.suppress(Exception):
                    self._h5_fd = int(self.h5.id.get_vfd_handle())
                _OPEN_WRITERS[id(self)] = self
        except KeyboardInterrupt as exc:
            if _OPEN_WRITERS.get(id(self)) is self:
                self.__exit__(KeyboardInterrupt, exc, None)
            else:
                self._abandon()
            raise
        except BaseException:
            self._abandon()
            raise

    def _abandon(self) -> None:
        """Close what a failed open left open, and drop the lock."""
        if getattr(self, "h5", None) is not None and self.h5.id.valid:
            self.h5.close()
        release_lock(self.path, self._lock_fd)

    def _open(self, scene, resume, overwrite):
        self.h5 = None
        if resume and self.path.exists() and is_hdf5(self.path):
            try:
                with h5py.File(self.path, "r", locking=False) as h5:
                    _walk(h5)
                    ours = "schema_version" in h5.attrs and h5.attrs.get("scene", "") == scene.text
                if ours:
                    # never append to a killed file in place: the copy reads every block
                    # (data too) and allocates afresh (module doc, "Resumed files")
                    rewrite(self.path)
            except (OSError, KeyError, RuntimeError, ValueError) as exc:
                # torn inside the HDF5 library (a kill during its flush): what it
                # held cannot be trusted; keep it aside and compute the run again
                dest = set_aside(self.path)
                log.warning("%s: damaged, the HDF5 library cannot read it (%s); set aside "
                            "as %s, computing the run again", self.path,
                            str(exc).splitlines()[0] if str(exc) else type(exc).__name__,
                            dest.name)
                resume, overwrite = False, True
        if resume:
            if not self.path.exists():
                raise FileNotFoundError(f"{self.path}: cannot resume, the file does not exist")
            try:
                self.h5 = h5py.File(self.path, "a", locking=False)
            except OSError as exc:
                raise OSError(f"{self.path}: cannot resume, not a readable HDF5 file "
                              f"({exc})") from None
            if "schema_version" not in self.h5.attrs:
                raise NotAResultError(f"{self.path}: cannot resume, an HDF5 file that "
                                      "jointsim did not write")
            stored = self.h5.attrs.get("scene", "")
            if stored != scene.text:
                raise ValueError(f"{self.path}: cannot resume, it was written for a different "
                                 "scene (the resolved scene text differs)")
            torn = torn_groups(self.h5)
            if torn:
                log.info("%s: removing the torn last point of %s", self.path,
                         ", ".join(sorted(torn)))
                _trim(self.h5, torn)
            if not self.h5.attrs.get(COMMITS, 0):  # an older file: commit what it holds
                for d in _extendable_datasets(self.h5):
                    d.attrs[COMMITTED] = d.shape[0]
                self.h5.attrs[COMMITS] = 1
        else:
            if self.path.exists() and not overwrite:
                raise FileExistsError(f"{self.path}: exists; continue it with --resume or "
                                      "replace it with --overwrite (nothing was changed)")
            # created under a side name and renamed into place once its header is
            # written: the path never names a half-created file, and an existing
            # file that is overwritten stays whole until then
            fresh = self.path.with_name(self.path.name + ".new")
            self.h5 = h5py.File(fresh, "w", locking=False)
            a = self.h5.attrs
            a["schema_version"] = SCHEMA_VERSION
            a["jointsim_version"] = __version__
            a["scene"] = scene.text
            a["scene_path"] = str(scene.path)
            a["model_kind"] = scene.model.kind
            a["units"] = getattr(scene.model, "units", "SI")
            a["created"] = datetime.datetime.now(datetime.timezone.utc).isoformat()
            a[COMMITS] = 1
        self.h5.attrs["status"] = "running"
        self.h5.attrs["message"] = ""
        self.h5.attrs["pid"] = os.getpid()
        self.h5.flush()
        if not resume:
            os.replace(fresh, self.path)
        self._open_datasets = OpenDatasets(self.h5, COMMITTED)

    # -- context management -------------------------------------------------
    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if not self.h5.id.valid:  # already finished
            self._release()
            return False
        if exc_type is None:
            if self.h5.attrs.get("status") == "running":
                self.finish("complete", "")
        elif issubclass(exc_type, KeyboardInterrupt):
            why = str(exc) or "stopped by the user (Ctrl-C)"
            self.finish("interrupted", f"{why}; {self.committed_summary()}; "
                        "continue with --resume")
        else:
            self.finish("failed", f"{exc_type.__name__}: {exc}")
        return False

    def committed_summary(self) -> str:
        """``"committed points: hbm 37, hbm/loops 37"`` (groups with one committed count;
        the points held are committed first)."""
        self._commit_pending()
        parts = []
        self.h5.visititems(lambda n, o: parts.append(f"{n} {int(o.attrs[COMMITTED])}")
                           if isinstance(o, h5py.Group) and COMMITTED in o.attrs else None)
        return "committed points: " + (", ".join(parts) if parts else "none")

    def finish(self, status: str, message: str) -> None:
        """Remove torn rows, set the final status and close the file (and drop the lock)."""
        if not self.h5.id.valid:
            self._release()
            return
        with _signals_deferred():
            self._finish_now(status, message)

    def _finish_now(self, status: str, message: str) -> None:
        self._txn = None
        self._commit_pending()
        torn = torn_groups(self.h5)
        if torn:
            _trim(self.h5, torn)
        self.h5.attrs["status"] = status
        self.h5.attrs["message"] = message
        self.h5.attrs["finished"] = datetime.datetime.now(datetime.timezone.utc).isoformat()
        self.h5.flush()
        self.h5.close()
        self._release()

    def _release(self) -> None:
        if self._lock_fd is not None:
            release_lock(self.path, self._lock_fd)
            self._lock_fd = None
        _OPEN_WRITERS.pop(id(self), None)

    @contextlib.contextmanager
    def commit(self):
        """Write one point atomically: appends inside go to the file, then are committed.

        On leaving without an exception the point's rows are complete; they are
        committed (:meth:`_commit_pending`) at once, or with the next points when
        the last commit is less than :data:`COMMIT_INTERVAL_S` old.  A process killed
        before that leaves rows that readers and ``--resume`` ignore (at most that
        interval of computing is lost).  Nested use joins the outer commit.
        """
        if self._txn is not None:
            yield self
            return
        self._txn = set()
        try:
            yield self
            touched = self._txn
        finally:
            self._txn = None
        # a signal may not land between the records of one point's datasets: committed
        # with the points before it, part of a point would misalign its group
        with _signals_deferred():
            self._hold(touched)
            if time.monotonic() - self._committed_at >= COMMIT_INTERVAL_S:
                self._commit_pending()

    def _hold(self, names) -> None:
        """Record the rows the datasets ``names`` hold now as whole points to commit
        (with their object addresses: a dataset deleted or replaced since is not
        committed by the record)."""
        for name in names:
            self._pending[name] = self._open_datasets.rows(name)

    def _commit(self, names) -> None:
        """Commit the datasets ``names`` at their rows now, with the points held."""
        with _signals_deferred():
            self._hold(names)
            self._commit_pending()

    def _commit_pending(self) -> None:
        """Flush, then advance :data:`COMMITTED` of every dataset held to its recorded
        rows, flush again.

        A group whose extendable datasets all have the same committed rows
        (one row per point: ``/hbm``, ``/hbm/loops``, ...) gets that count too.
        SIGINT and SIGTERM wait until it is done.
        """
        if not self._pending:
            return
        with _signals_deferred():
            rows, self._pending = self._pending, {}
            self._commit_now(rows)
            self._committed_at = time.monotonic()

    def _commit_now(self, rows: dict) -> None:
        self.h5.flush()
        od = self._open_datasets
        groups = set()
        for name in sorted(rows):
            addr, n = rows[name]
            if od.advance(name, n, addr):   # not if deleted or replaced since it was held
                groups.add(name.rpartition("/")[0] or "/")
        for gname in sorted(groups):
            od.settle_group(gname)
        self.h5.flush()

    # -- writing --------------------------------------------------------------
    def group(self, name: str, **attrs) -> h5py.Group:
        """Get or create a group and set attributes on it.

        The points held for the next commit are committed first: an attribute set
        after a point (a branch's status) never reaches the file before it.
        """
        g = self.h5.require_group(name)
        if attrs:
            with _signals_deferred():
                self._commit_pending()
                for k, v in attrs.items():
                    g.attrs[k] = v
                self.h5.flush()
        return g

    @contextlib.contextmanager
    def whole_group(self, name: str, **attrs):
        """Write the group ``name`` whole or not at all; yields the path to write into.

        The datasets go to a side group ``<name>.partial``, which replaces ``name``
        in one link move (signals deferred) when the block ends without an exception.
        A signal or a SIGKILL in the block leaves ``name`` as it was (the side group
        is removed, or ignored and replaced by the next write): readers never see
        half of a group that is read as a whole (round 30: ``info`` failed on an
        ``/epmc/control`` cut between two of its datasets by SIGINT).
        """
        tmp = name + PARTIAL
        if tmp in self.h5:
            del self.h5[tmp]
        g = self.h5.create_group(tmp)
        for k, v in attrs.items():
            g.attrs[k] = v
        try:
            yield tmp
        except BaseException:
            with contextlib.suppress(Exception):
                del self.h5[tmp]
            raise
        with _signals_deferred():
            self._commit_pending()
            if name in self.h5:
                del self.h5[name]
            self.h5.move(tmp, name)
            self.h5.flush()

    def write(self, name: str, data, unit: str, doc: str = "", **attrs) -> None:
        """Write (or replace) a whole dataset with its unit."""
        if name in self.h5:
            del self.h5[name]
        ds = self.h5.create_dataset(name, data=np.asarray(data))
        ds.attrs["unit"] = unit
        if doc:
            ds.attrs["doc"] = doc
        for k, v in attrs.items():
            ds.attrs[k] = v
        self.h5.flush()

    def _extendable(self, name: str, shape: tuple, dtype, unit: str, doc: str, chunks):
        """The extendable dataset ``name`` for rows of ``shape`` (created on first use)."""
        ds = self._open_datasets.get(_absolute(name))
        if ds is None:
            ds = self.h5.create_dataset(name, shape=(0,) + shape, dtype=dtype,
                                        maxshape=(None,) + shape, chunks=chunks)
            ds.attrs["unit"] = unit
            if doc:
                ds.attrs["doc"] = doc
        if ds.id.shape[1:] != shape:
            raise ValueError(f"{name}: a row of shape {shape} does not fit {ds.shape[1:]}")
        return ds

    def append(self, name: str, row, unit: str, doc: str = "") -> int:
        """Append one row along the first axis of an extendable dataset.

        Parameters
        ----------
        name : str
            Dataset path, created on first use with shape ``(0, *row.shape)``.
        row : array_like
            One point's data.
        unit : str

        Returns
        -------
        int
            The number of rows now stored.
        """
        row = np.asarray(row)
        ds = self._extendable(name, row.shape, row.dtype, unit, doc,
                              (1,) + row.shape if row.size else True)
        n = _append_rows(ds, row[np.newaxis])
        self._appended(ds)
        return n

    def append_rows(self, name: str, rows, unit: str, doc: str = "") -> int:
        """Append a block of rows at once (one resize, one flush).

        Parameters
        ----------
        name : str
            Dataset path, created on first use with shape ``(0, *rows.shape[1:])``.
        rows : array_like, shape (n_rows, ...)
            Several points' data, stacked along the first axis.
        unit : str

        Returns
        -------
        int
            The number of rows now stored.
        """
        rows = np.asarray(rows)
        if rows.ndim == 0:
            raise ValueError(f"{name}: append_rows needs an array of rows, got a scalar")
        ds = self._extendable(name, rows.shape[1:], rows.dtype, unit, doc, True)
        if not rows.shape[0]:
            return ds.id.shape[0]
        n = _append_rows(ds, rows)
        self._appended(ds)
        return n

    def _appended(self, ds) -> None:
        """Record a group appended to; outside :meth:`commit` commit it at once."""
        if self._txn is not None:
            self._txn.add(ds.name)
        else:
            self._commit({ds.name})

    def set_row(self, name: str, row: int, value) -> None:
        """Overwrite row ``row`` of an existing extendable dataset (its rows unchanged).

        Inside :meth:`commit` the change is flushed with the point; outside, at once.
        """
        ds = self._open_datasets.get(_absolute(name))
        if ds is None:
            raise KeyError(f"{name}: no such dataset in {self.path}")
        if not 0 <= row < ds.shape[0]:
            raise IndexError(f"{name}: row {row} out of range (rows: {ds.shape[0]})")
        ds[row] = value
        self._appended(ds)

    def rows(self, name: str) -> int:
        """Rows stored in an extendable dataset (0 if absent; committed rows outside a commit)."""
        ds = self._open_datasets.get(_absolute(name))
        return 0 if ds is None else ds.shape[0]


def _absolute(name: str) -> str:
    """``name`` as a path from the file's root."""
    return name if name.startswith("/") else "/" + name


def read_attrs(path) -> dict:
    """Root attributes of a result file, as plain Python values."""
    with open_result(path) as h5:
        return {k: (v.item() if hasattr(v, "item") else v) for k, v in h5.attrs.items()}

