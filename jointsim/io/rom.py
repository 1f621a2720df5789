"""Reduced-model files: .npz, .mat (MATLAB, scipy.io) and HDF5.

A ROM file holds flat, named arrays (the same names in every format; in HDF5
they are datasets at the root or in a group ``/rom``):

=====================  ================  =====================================
name                   shape             meaning
=====================  ================  =====================================
``M``, ``K``           (n, n)            mass [kg], stiffness [N/m] (bolt
                                         springs included); dense or sparse
``C``                  (n, n)            optional damping [N s/m]
``f_static``           (n,)              optional constant load other than the
                                         bolt clamping [N]
``lower_dofs``         (n_e, d)          DOFs of each pair's lower node, one
                                         per direction (-1: none)
``upper_dofs``         (n_e, d)          DOFs of each pair's upper node
``area``               (n_e,)            tributary area [m^2]
``frame``              (n_e, 2, d)       optional; row 0 unit tangent, row 1
                                         unit normal (lower -> upper); default
                                         tangent x, normal y (d = 2)
``position``           (n_e, 2)          optional pair position [m]
``bolt_lower_dofs``,   (n_b, d)          optional bolt table: DOFs of the two
``bolt_upper_dofs``                      bolt ends
``bolt_axis``          (n_b, d)          unit bolt axis (lower -> upper end)
``bolt_stiffness``     (n_b,)            axial bolt spring [N/m]
``bolt_preload``       (n_b,)            clamping force [N]
``point_<name>``       scalar int        a named DOF (e.g. ``point_response``)
``dof_labels``         (n,) strings      optional DOF names
``index_base``         scalar int        0 (default) or 1 for 1-based DOF
                                         indices (MATLAB)
=====================  ================  =====================================

Point names may contain a dot in jointsim (``excitation.y``); in files the
dot is written ``__`` (``point_excitation__y``) because MATLAB names cannot
hold dots.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from ..fem.interface import Interface
from ..fem.reduced import BoltTable, ReducedModel

log = logging.getLogger(__name__)

FORMATS = (".npz", ".mat", ".h5", ".hdf5")


def _to_arrays(rom: ReducedModel) -> dict:
    it = rom.interface
    out = {"M": rom.M, "K": rom.K, "f_static": rom.f_static,
           "lower_dofs": it.lower_dofs, "upper_dofs": it.upper_dofs, "area": it.area,
           "frame": it.frame, "position": it.position, "index_base": np.int64(0),
           "dof_labels": np.array(rom.dof_labels, dtype=str)}
    if rom.C is not None:
        out["C"] = rom.C
    if rom.bolts is not None:
        b = rom.bolts
        out.update(bolt_lower_dofs=b.lower_dofs, bolt_upper_dofs=b.upper_dofs,
                   bolt_axis=b.axis, bolt_stiffness=b.stiffness, bolt_preload=b.preload,
                   bolt_names=np.array(b.names, dtype=str))
    for name, dof in rom.points.items():
        out["point_" + name.replace(".", "__")] = np.int64(dof)
    return out


def save_rom(path, rom: ReducedModel) -> Path:
    """Write a reduced model.

    Parameters
    ----------
    path : str or Path
        ``.npz``, ``.mat`` or ``.h5``/``.hdf5``.
    rom : jointsim.fem.reduced.ReducedModel

    Returns
    -------
    Path
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in FORMATS:
        raise ValueError(f"{path}: ROM files must end in one of {FORMATS}")
    path.parent.mkdir(parents=True, exist_ok=True)
    data = _to_arrays(rom)
    if ext == ".npz":
        np.savez_compressed(path, **data)
    elif ext == ".mat":
        import scipy.io
        scipy.io.savemat(path, data, do_compression=True, oned_as="column")
    else:
        import h5py
        with h5py.File(path, "w") as h5:
            g = h5.create_group("rom")
            for k, v in data.items():
                v = np.asarray(v)
                if v.dtype.kind == "U":
                    v = v.astype(h5py.string_dtype())
                g.create_dataset(k, data=v)
            g.attrs["format"] = "jointsim reduced model"
    log.info("wrote ROM %s (%d DOFs, %d contact pairs)", path, rom.n_dof,
             rom.interface.n_elements)
    return path


def _read_raw(path: Path) -> dict:
    ext = path.suffix.lower()
    if ext == ".npz":
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    if ext == ".mat":
        import scipy.io
        raw = scipy.io.loadmat(path, squeeze_me=False, chars_as_strings=True)
        return {k: v for k, v in raw.items() if not k.startswith("__")}
    if ext in (".h5", ".hdf5"):
        import h5py
        with h5py.File(path, "r") as h5:
            g = h5["rom"] if "rom" in h5 else h5
            out = {}
            for k, ds in g.items():
                if isinstance(ds, h5py.Dataset):
                    v = ds[()]
                    if ds.dtype.kind in ("O", "S"):
                        v = np.array([s.decode() if isinstance(s, bytes) else str(s)
                                      for s in np.atleast_1d(v)])
                    out[k] = v
            return out
    raise ValueError(f"unknown ROM format {ext!r}; use one of {FORMATS}")


def _matrix(v, name):
    if sp.issparse(v):
        v = v.toarray()
    v = np.asarray(v, dtype=float)
    if v.ndim != 2 or v.shape[0] != v.shape[1]:
        raise ValueError(f"{name} must be a square matrix, got shape {v.shape}")
    return v


def _int_table(v, ne, name):
    v = np.asarray(v)
    if v.ndim == 1:
        v = v.reshape(ne, -1)
    return v.astype(np.int64)


def _strings(v) -> tuple:
    v = np.asarray(v).ravel()
    out = []
    for s in v:
        if isinstance(s, np.ndarray):  # MATLAB cell entries
            s = s.ravel()[0] if s.size else ""
        out.append(str(s).strip())
    return tuple(out)


def load_rom(path) -> ReducedModel:
    """Read a reduced model file (format by extension; see the module docstring).

    Raises
    ------
    KeyError
        A required array is missing.
    ValueError
        Shapes or indices are inconsistent.
    """
    path = Path(path)
    raw = _read_raw(path)
    for key in ("M", "K", "lower_dofs", "upper_dofs", "area"):
        if key not in raw:
            raise KeyError(f"ROM file lacks the required array {key!r}")
    base = int(np.asarray(raw.get("index_base", 0)).ravel()[0])
    if base not in (0, 1):
        raise ValueError(f"index_base must be 0 or 1, got {base}")
    M, K = _matrix(raw["M"], "M"), _matrix(raw["K"], "K")
    n = M.shape[0]
    area = np.asarray(raw["area"], dtype=float).ravel()
    ne = area.size
    lo = _int_table(raw["lower_dofs"], ne, "lower_dofs")
    up = _int_table(raw["upper_dofs"], ne, "upper_dofs")

    def shift(a):
        return np.where(a >= base, a - base, -1) if base else a

    lo, up = shift(lo), shift(up)
    d = lo.shape[1]
    if "frame" in raw:
        frame = np.asarray(raw["frame"], dtype=float).reshape(ne, 2, d)
    elif d == 2:
        frame = np.tile(np.array([[1.0, 0.0], [0.0, 1.0]]), (ne, 1, 1))
    else:
        raise KeyError("ROM file lacks 'frame' (required unless DOFs are 2D x/y pairs)")
    norms = np.linalg.norm(frame, axis=2)
    if not np.allclose(norms, 1.0, atol=1e-8):
        raise ValueError("frame rows must be unit vectors")
    position = (np.asarray(raw["position"], dtype=float).reshape(ne, -1)
                if "position" in raw else np.column_stack([np.arange(ne, dtype=float),
                                                           np.zeros(ne)]))
    iface = Interface(lo, up, frame, area, position)
    bolts = None
    if "bolt_stiffness" in raw:
        k = np.asarray(raw["bolt_stiffness"], dtype=float).ravel()
        nb = k.size
        bl = shift(_int_table(raw["bolt_lower_dofs"], nb, "bolt_lower_dofs"))
        bu = shift(_int_table(raw["bolt_upper_dofs"], nb, "bolt_upper_dofs"))
        names = _strings(raw["bolt_names"]) if "bolt_names" in raw else \
            tuple(f"bolt{i + 1}" for i in range(nb))
        bolts = BoltTable(lower_dofs=bl, upper_dofs=bu,
                          axis=np.asarray(raw["bolt_axis"], dtype=float).reshape(nb, -1),
                          stiffness=k,
                          preload=np.asarray(raw["bolt_preload"], dtype=float).ravel(),
                          names=names)
    points = {}
    for key, v in raw.items():
        if key.startswith("point_"):
            points[key[len("point_"):].replace("__", ".")] = \
                int(np.asarray(v).ravel()[0]) - base
    labels = _strings(raw["dof_labels"]) if "dof_labels" in raw else ()
    if labels and len(labels) != n:
        raise ValueError(f"dof_labels has {len(labels)} entries for {n} DOFs")
    C = _matrix(raw["C"], "C") if "C" in raw else None
    f_static = np.asarray(raw["f_static"], dtype=float).ravel() if "f_static" in raw else None
    rom = ReducedModel(M=M, K=K, interface=iface, C=C, f_static=f_static, bolts=bolts,
                       points=points, dof_labels=labels)
    log.info("read ROM %s: %d DOFs, %d contact pairs, %d bolts", path, n, ne,
             0 if bolts is None else bolts.n_bolts)
    return rom
