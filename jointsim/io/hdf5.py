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
point are extendable along their first axis and the file is flushed after
every append, so an interrupted run leaves a valid, readable file whose
``status`` says how far it got.
"""
from __future__ import annotations

import datetime
import logging
from pathlib import Path

import h5py
import numpy as np

from .. import __version__

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1

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
    """Incremental writer of a result file.

    Use as a context manager; an exception inside marks the file ``failed``
    (``interrupted`` for Ctrl-C) with the reason, and re-raises.

    Parameters
    ----------
    path : str or Path
        Output file; its folder is created.
    scene : jointsim.scene.Scene
        The resolved scene, stored as text.
    resume : bool
        Open an existing file to continue it; its stored scene must match.
    """

    def __init__(self, path, scene, resume: bool = False):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if resume:
            if not self.path.exists():
                raise FileNotFoundError(f"{self.path}: cannot resume, the file does not exist")
            self.h5 = h5py.File(self.path, "a")
            stored = self.h5.attrs.get("scene", "")
            if stored != scene.text:
                self.h5.close()
                raise ValueError(f"{self.path}: cannot resume, it was written for a different "
                                 "scene (the resolved scene text differs)")
        else:
            self.h5 = h5py.File(self.path, "w")
            a = self.h5.attrs
            a["schema_version"] = SCHEMA_VERSION
            a["jointsim_version"] = __version__
            a["scene"] = scene.text
            a["scene_path"] = str(scene.path)
            a["model_kind"] = scene.model.kind
            a["units"] = getattr(scene.model, "units", "SI")
            a["created"] = datetime.datetime.now(datetime.timezone.utc).isoformat()
        self.h5.attrs["status"] = "running"
        self.h5.attrs["message"] = ""
        self.h5.flush()

    # -- context management -------------------------------------------------
    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if not self.h5.id.valid:  # already finished
            return False
        if exc_type is None:
            if self.h5.attrs.get("status") == "running":
                self.finish("complete", "")
        elif issubclass(exc_type, KeyboardInterrupt):
            self.finish("interrupted", "stopped by the user; the file holds what was computed")
        else:
            self.finish("failed", f"{exc_type.__name__}: {exc}")
        return False

    def finish(self, status: str, message: str) -> None:
        """Set the final status and close the file."""
        if not self.h5.id.valid:
            return
        self.h5.attrs["status"] = status
        self.h5.attrs["message"] = message
        self.h5.attrs["finished"] = datetime.datetime.now(datetime.timezone.utc).isoformat()
        self.h5.flush()
        self.h5.close()

    # -- writing --------------------------------------------------------------
    def group(self, name: str, **attrs) -> h5py.Group:
        """Get or create a group and set attributes on it."""
        g = self.h5.require_group(name)
        for k, v in attrs.items():
            g.attrs[k] = v
        return g

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
        if name not in self.h5:
            ds = self.h5.create_dataset(name, shape=(0,) + shape, dtype=dtype,
                                        maxshape=(None,) + shape, chunks=chunks)
            ds.attrs["unit"] = unit
            if doc:
                ds.attrs["doc"] = doc
        ds = self.h5[name]
        if ds.shape[1:] != shape:
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
        n = ds.shape[0]
        ds.resize(n + 1, axis=0)
        ds[n] = row
        self.h5.flush()
        return n + 1

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
        n = ds.shape[0]
        if rows.shape[0]:
            ds.resize(n + rows.shape[0], axis=0)
            ds[n:] = rows
            self.h5.flush()
        return n + rows.shape[0]

    def rows(self, name: str) -> int:
        """Rows stored in an extendable dataset (0 if absent)."""
        return self.h5[name].shape[0] if name in self.h5 else 0


def write_loops(writer: ResultWriter, point: int, u, f, N, report, units: str,
                prefix: str) -> None:
    """Append one solution point's element loops and their Masing check.

    Every analysis keeps its loops under its own group (``/<prefix>/loops``,
    ``/<prefix>/masing``).  The root ``/loops`` and ``/masing`` of the public
    contract are soft links to the first analysis that wrote loops in the
    file, so a file with one loop-producing analysis reads as before.

    Parameters
    ----------
    writer : ResultWriter
    point : int
        Index of the solution point the loops belong to.
    u, f, N : ndarray, shape (n_e, n_samples)
        Steady period of each element.
    report : jointsim.masing.MasingReport
    units : str
        Unit system of the model.
    prefix : str
        The analysis group (``prescribed``, ``hbm``, ``epmc``, ``transient``).
    """
    d, F = unit("displacement", units), unit("force", units)
    p = prefix.strip("/") + "/" if prefix.strip("/") else ""
    writer.append(f"{p}loops/point", np.int64(point), "1", "solution point of each loop set")
    writer.append(f"{p}loops/u", u, d, "tangential displacement over one steady period")
    writer.append(f"{p}loops/f", f, F, "tangential force over one steady period")
    writer.append(f"{p}loops/N", N, F, "normal load over one steady period")
    one = "1"
    writer.append(f"{p}masing/dev_manifold", report.dev_manifold, one,
                  "max |f - f_manifold| / max(mu N)")
    writer.append(f"{p}masing/dev_masing", report.dev_masing, one,
                  "max |f - f_masing| / max(mu N), classical Masing at the mean N")
    writer.append(f"{p}masing/on_manifold", report.on_manifold, one, "dev_manifold <= tol")
    writer.append(f"{p}masing/on_masing", report.on_masing, one, "dev_masing <= tol")
    writer.append(f"{p}masing/eq4_ok", report.eq4_ok, one, "seed Eq. 4: d(mu N)/ds >= -kt "
                  "while the force opposes the motion after a reversal")
    writer.append(f"{p}masing/eq6_ok", report.eq6_ok, one, "seed Eq. 6: d(mu N)/ds <= kt "
                  "while slipping")
    writer.append(f"{p}masing/eq4_margin", report.eq4_margin, one, "held: min(1 + d(mu N)/ds / kt); violated: -integrated violation / (kt ptp(u))")
    writer.append(f"{p}masing/eq6_margin", report.eq6_margin, one, "held: min(1 - d(mu N)/ds / kt); violated: -integrated violation / (kt ptp(u))")
    writer.append(f"{p}masing/n_reversals", report.n_reversals, one, "reversals of u per period")
    writer.append(f"{p}masing/f_manifold", report.f_manifold, F, "manifold prediction")
    writer.append(f"{p}masing/f_masing", report.f_masing, F, "classical Masing prediction")
    writer.h5[f"{p}masing"].attrs["tol"] = report.tol
    if p and "loops" not in writer.h5:
        writer.h5["loops"] = h5py.SoftLink(f"/{p}loops")
        writer.h5["masing"] = h5py.SoftLink(f"/{p}masing")
        writer.h5.attrs["loops_of"] = prefix.strip("/")


def read_attrs(path) -> dict:
    """Root attributes of a result file, as plain Python values."""
    with h5py.File(path, "r") as h5:
        return {k: (v.item() if hasattr(v, "item") else v) for k, v in h5.attrs.items()}
