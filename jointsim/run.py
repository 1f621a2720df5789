"""Run a scene: build what it declares, solve, and write the result file.

``run_scene`` is the one place that connects the pieces.  Model kinds with a
structure are built by :func:`jointsim.model.build_model`; each analysis
present in ``[analysis]`` is run by its runner in
:data:`jointsim.analyses.ANALYSES`, in the order of that table; each writes
its own groups of the result file as it goes and returns its result, which
the later runners receive in memory.  An analysis that fails (its runner
raises ``RuntimeError`` after writing its points) does not stop the ones after
it: none needs another's result (the transient cross-check against harmonic
balance is skipped when the HBM analysis failed); the run then raises one
``RuntimeError`` naming every failed analysis, and the file is marked failed.
"""
from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from pathlib import Path

from .io.hdf5 import ResultWriter
from .results import interrupt_cause

log = logging.getLogger(__name__)


@contextlib.contextmanager
def _signals_interrupt():
    """SIGINT, SIGTERM and SIGHUP raise :class:`KeyboardInterrupt` while inside (never mid-commit).

    The writer then marks the file ``interrupted`` with its committed point
    counts.  Only in the main thread (signal handlers live there).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    from .io.hdf5 import interrupt_handler
    old = {s: signal.signal(s, interrupt_handler)
           for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def run_scene(scene, out_path, resume: bool = False, overwrite: bool = False) -> Path:
    """Run every analysis of a scene and write the result file.

    Sets the BLAS threads first (:func:`jointsim.blas.limit_blas_threads`).

    Parameters
    ----------
    scene : jointsim.scene.Scene
    out_path : str or Path
        HDF5 result file.
    resume : bool
        Continue an interrupted file written for the same scene.
    overwrite : bool
        Replace an existing file (otherwise an existing file is refused unless
        resuming).  The model is built before the file is opened, so an
        error found while building it writes nothing.

    Returns
    -------
    Path
        The result file.
    """
    from .analyses import ANALYSES, run_prescribed_scene, write_model_tables
    from .blas import limit_blas_threads
    limit_blas_threads()
    out_path = Path(out_path)
    t0 = time.perf_counter()
    model = None
    if scene.model.kind != "prescribed":
        from .model import build_model
        model = build_model(scene)  # errors found here write nothing
    with _signals_interrupt(), \
            ResultWriter(out_path, scene, resume=resume, overwrite=overwrite) as writer:
        failed: list[str] = []
        if scene.model.kind == "prescribed":
            run_prescribed_scene(scene, writer)
        else:
            write_model_tables(scene, model, writer)  # /static, /contacts, /model, /mesh
            todo = [a for a in ANALYSES if getattr(scene.analysis, a) is not None]
            if not todo:
                log.warning("%s declares no analysis; only the model is built", scene.path)
            results: dict[str, object] = {}
            for name in todo:
                log.info("analysis %s", name)
                try:
                    results[name] = ANALYSES[name](scene, model, writer, results)
                except (SystemError, ImportError) as exc:
                    # a signal handled while a numba kernel was being called (or a
                    # module imported) comes out as an error caused by the interrupt
                    cause = interrupt_cause(exc)
                    if cause is None:
                        raise
                    raise KeyboardInterrupt(str(cause)) from None
                except RuntimeError as exc:
                    # the runner wrote what it computed; no later analysis needs it
                    # (the transient cross-check is skipped without an HBM result)
                    log.error("analysis %s failed (%s); the next analyses still run",
                              name, exc)
                    failed.append(str(exc))
        writer.h5.attrs["wall_time_s"] = time.perf_counter() - t0
        if failed:  # the file is marked failed; the CLI exits with status 1
            raise RuntimeError("; ".join(failed))
    log.info("wrote %s in %.2f s", out_path, time.perf_counter() - t0)
    return out_path
