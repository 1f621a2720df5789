"""Parameter sweeps: one scene, many overrides, run on dask.distributed.

A sweep is the Cartesian product of ``--vary key=v1,v2,...`` lists applied to
one scene.  Every variant is validated before anything is submitted (a bad
value names the key and writes nothing); each variant then runs as its own
``jointsim run`` on a dask worker and writes its own result file.  An index
file ``sweep.h5`` records, for every variant, its overrides, its result file
and how it ended (``running`` until then); it is written as variants finish,
each time whole and renamed into place, so an interrupted sweep shows what is
done and the index can be read at any time.  A rerun into the same folder
keeps complete variants and resumes killed ones.

Without a scheduler address a local cluster of processes is started on this
machine; with ``--scheduler tcp://host:8786`` the variants go to an existing
cluster that shares the file system.
"""
from __future__ import annotations

import itertools
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from .run import _signals_interrupt
from .scene import SceneError, load_scene

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Variant:
    """One point of a sweep: its overrides and its result file."""

    index: int
    overrides: tuple[str, ...]
    output: Path


def expand(vary: list[str], file: str) -> list[tuple[str, ...]]:
    """Cartesian product of ``key=v1,v2,...`` lists into override tuples.

    Values are split on commas outside brackets and braces, so
    ``model.n_samples=[1,2],[3]`` is not what you want but
    ``joint.mu=0.1,0.2`` and ``joint.law=jenkins,iwan4`` are.
    """
    axes = []
    for item in vary:
        if "=" not in item:
            raise SceneError(file, item, "sweep axis must look like key=v1,v2,... (from --vary)")
        key, values = item.split("=", 1)
        parts = _split_top_level(values)
        if not parts or any(p.strip() == "" for p in parts):
            raise SceneError(file, key, "sweep axis has an empty value (from --vary)")
        axes.append([f"{key.strip()}={p.strip()}" for p in parts])
    return [tuple(c) for c in itertools.product(*axes)] if axes else [()]


def _split_top_level(text: str) -> list[str]:
    out, depth, cur = [], 0, []
    for ch in text:
        if ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        if ch == "," and depth == 0:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur))
    return out


def plan(scene_path, vary: list[str], outdir, common: list[str] = ()) -> list[Variant]:
    """Validate every variant of a sweep and name its result file.

    Raises
    ------
    SceneError
        For the first invalid variant; nothing is written.
    """
    outdir = Path(outdir)
    stem = Path(scene_path).stem
    variants = []
    for i, combo in enumerate(expand(vary, str(scene_path))):
        overrides = tuple(common) + combo
        load_scene(scene_path, list(overrides))  # validates; raises SceneError
        variants.append(Variant(i, overrides, outdir / f"{stem}_{i:04d}.h5"))
    return variants


def _previous(scene, output: Path) -> str:
    """What to do with a variant's result file: ``"run"``, ``"keep"`` or ``"resume"``.

    A file of the same scene that is ``complete`` is kept; one that was
    ``running`` (its sweep was killed) or ``interrupted`` is resumed; any
    other file (failed, another scene, not a result) is replaced.
    """
    from .io.hdf5 import read_attrs
    if not output.exists():
        return "run"
    try:
        a = read_attrs(output)
    except (OSError, ValueError):
        return "run"
    if a.get("scene") != scene.text:
        return "run"
    if a.get("status") == "complete":
        return "keep"
    return "resume" if a.get("status") in ("running", "interrupted") else "run"


def run_variant(scene_path: str, variant: Variant) -> dict:
    """Run one variant (on a worker).  Never raises: failures are reported.

    A variant whose result file is complete is not run again; a killed one
    is resumed (:func:`_previous`).  Sets the worker's BLAS threads first
    (:func:`jointsim.blas.limit_blas_threads`).  Inside a dask worker (a
    daemonic process) harmonic balance runs its branches serially.
    """
    from .blas import limit_blas_threads
    from .run import run_scene
    limit_blas_threads()
    try:
        scene = load_scene(scene_path, list(variant.overrides))
        todo = _previous(scene, variant.output)
        if todo == "keep":
            return {"index": variant.index, "status": "complete",
                    "message": "kept: complete from an earlier sweep"}
        run_scene(scene, variant.output, resume=todo == "resume", overwrite=todo == "run")
        return {"index": variant.index, "status": "complete",
                "message": "resumed" if todo == "resume" else ""}
    except Exception as exc:  # reported in the index, the sweep goes on
        return {"index": variant.index, "status": "failed",
                "message": f"{type(exc).__name__}: {exc}"}


def _write_index(index: Path, head: dict, columns: dict[str, list[str]]) -> None:
    """Write the whole index afresh beside it, then rename it over the old one.

    A rename is atomic: a reader (or a sweep killed at any instant) sees the
    old index or the new one, whole, never one torn inside the HDF5 library,
    and the index is never held open between updates.

    Parameters
    ----------
    index : Path
        ``sweep.h5``.
    head : dict
        Root attributes (``scene_path``, ``axes``, ``common``).
    columns : dict of str to list of str
        ``overrides``, ``output``, ``status`` and ``message``, one entry per variant.
    """
    tmp = index.with_name(index.name + ".tmp")
    s = h5py.string_dtype()
    with h5py.File(tmp, "w", locking=False) as h5:
        for k, v in head.items():
            h5.attrs[k] = np.array(v, dtype=s) if isinstance(v, (list, tuple)) else v
        for name, col in columns.items():
            h5.create_dataset(name, data=np.array(col, dtype=s))
            h5[name].attrs["unit"] = "1"
    with open(tmp, "rb") as f:
        os.fsync(f.fileno())
    os.replace(tmp, index)


def _client(scheduler: str | None, n_workers: int, timeout_s: float = 10.0):
    """A dask client of ``scheduler`` (failing within ``timeout_s``) or of a local cluster."""
    from dask.distributed import Client, LocalCluster
    if scheduler:
        # connect in a daemon thread with a hard deadline: a server that accepts the
        # connection but does not speak dask's protocol would otherwise hang the handshake
        import threading
        box: dict = {}

        def connect():
            try:
                box["client"] = Client(scheduler, timeout=f"{timeout_s}s")
            except Exception as exc:  # OSError, TimeoutError, ValueError (bad address)
                box["error"] = exc

        th = threading.Thread(target=connect, daemon=True, name="dask-connect")
        th.start()
        th.join(timeout_s + 2.0)
        if "client" in box:
            return box["client"], None
        exc = box.get("error")
        why = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}" \
            if exc is not None else "no answer to the dask handshake"
        raise OSError(f"--scheduler {scheduler}: no dask scheduler answered within "
                      f"{timeout_s:g} s ({why})")
    cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                           dashboard_address=None)
    return Client(cluster), cluster


def run_sweep(scene_path, vary: list[str], outdir, scheduler: str | None = None,
              n_workers: int = 2, common: list[str] = ()) -> Path:
    """Run a sweep and write its index ``outdir/sweep.h5``.

    A rerun into the same folder keeps the variants that are complete and
    resumes the ones a killed sweep left (:func:`run_variant`).

    Parameters
    ----------
    scene_path : str or Path
        The scene file.
    vary : list of str
        Sweep axes ``key=v1,v2,...``.
    outdir : str or Path
        Folder of the result files and the index.
    scheduler : str, optional
        Address of a running dask scheduler; default: a local cluster.
    n_workers : int
        Worker processes of the local cluster (at least 1).
    common : list of str
        Overrides applied to every variant.

    Returns
    -------
    Path
        The index file.

    Raises
    ------
    RuntimeError
        After the index is written, when a variant failed.
    ValueError
        For ``n_workers < 1`` (nothing is written).
    OSError
        When ``scheduler`` does not answer (nothing is run).
    """
    if not scheduler and n_workers < 1:
        raise ValueError(f"--workers {n_workers}: a local cluster needs at least 1 worker")
    variants = plan(scene_path, vary, outdir, common)
    index, results = run_variants(scene_path, variants, outdir, scheduler, n_workers,
                                  attrs={"axes": list(vary), "common": list(common)})
    n_failed = sum(r["status"] != "complete" for r in results)
    log.info("sweep of %d runs done, %d failed; index %s", len(variants), n_failed, index)
    if n_failed:
        raise RuntimeError(f"{n_failed} of {len(variants)} sweep variants failed (messages in "
                           f"{index}); rerun the sweep to compute only those")
    return index


def run_variants(scene_path, variants: list[Variant], outdir, scheduler: str | None = None,
                 n_workers: int = 2, index_name: str = "sweep.h5",
                 attrs: dict | None = None, desc: str = "sweep",
                 client=None) -> tuple[Path, list[dict]]:
    """Run validated variants on dask workers and keep their index file.

    The pool of :func:`run_sweep`; ``jointsim converge`` submits its ladders
    here too.  A variant's failure is reported in its row, never raised.

    Parameters
    ----------
    scene_path : str or Path
    variants : list of Variant
        Validated (see :func:`plan`); ``index`` is the row in the index file.
    outdir : str or Path
    scheduler, n_workers
        As in :func:`run_sweep`.
    index_name : str
        File name of the index inside ``outdir``.
    attrs : dict, optional
        String lists stored as attributes of the index.
    desc : str
        Progress-bar label.
    client : dask.distributed.Client, optional
        A client to use (and leave open) instead of connecting to ``scheduler``
        or starting a local cluster.

    Returns
    -------
    index : Path
    results : list of dict
        Per variant, in the order of ``variants``: ``index``, ``status``
        (``complete`` or ``failed``), ``message``.
    """
    try:
        from dask.distributed import as_completed
    except ModuleNotFoundError:
        raise NotImplementedError("sweeps need dask.distributed: pip install 'jointsim[dask]'") \
            from None
    from tqdm import tqdm

    own = client is None
    if own and not scheduler and n_workers < 1:
        raise ValueError(f"--workers {n_workers}: a local cluster needs at least 1 worker")
    outdir = Path(outdir)
    index = outdir / index_name
    head = {"scene_path": str(scene_path), **(attrs or {})}
    cols = {"overrides": [" ".join(v.overrides) for v in variants],
            "output": [v.output.name for v in variants],
            "status": ["running"] * len(variants), "message": [""] * len(variants)}
    row = {v.index: k for k, v in enumerate(variants)}
    results: list[dict] = [{}] * len(variants)
    with _signals_interrupt():   # SIGINT, SIGTERM, SIGHUP: KeyboardInterrupt
        client, cluster = _client(scheduler, n_workers) if own else (client, None)
        try:
            outdir.mkdir(parents=True, exist_ok=True)
            _write_index(index, head, cols)
            futures = [client.submit(run_variant, str(scene_path), v, pure=False)
                       for v in variants]
            for fut in tqdm(as_completed(futures), total=len(futures), desc=desc,
                            unit="run"):
                r = fut.result()
                k = row[r["index"]]
                results[k] = r
                cols["status"][k], cols["message"][k] = r["status"], r["message"]
                _write_index(index, head, cols)
                if r["status"] != "complete":
                    log.warning("variant %s failed: %s", variants[k].output.name,
                                r["message"])
        except KeyboardInterrupt as exc:  # say so in the index, then stop
            if index.exists():
                why = str(exc) or "stopped by the user (Ctrl-C)"
                for k, st in enumerate(cols["status"]):
                    if st == "running":
                        cols["status"][k] = "interrupted"
                        cols["message"][k] = f"{why}; rerun to finish it"
                _write_index(index, head, cols)
            raise
        finally:
            if own:
                client.close()
                if cluster is not None:
                    cluster.close()
    return index, results
