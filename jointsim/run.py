"""Run a scene: build what it declares, solve, and write the result file.

``run_scene`` is the one place that connects the pieces.  Model kinds with a
structure are built by :func:`jointsim.model.build_model`; each analysis
present in ``[analysis]`` is run by the runner registered for it in
:data:`ANALYSES`, in the order of that table, and writes its own groups of
the result file as it goes.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Callable

import numpy as np

from .io.hdf5 import ResultWriter, unit, write_loops
from .masing import check_loops

log = logging.getLogger(__name__)


def run_prescribed_scene(scene, writer: ResultWriter) -> None:
    """Prescribed-motion model: march, check the loop, write it."""
    from .solvers.prescribed import run_prescribed

    m = scene.model
    kernels = scene.kernels()
    law = kernels.tangential_law(scene.joint, [m.area])
    res = run_prescribed(scene, law)
    units = m.units
    d, F = unit("displacement", units), unit("force", units)
    writer.group("prescribed", omega=m.omega, n_samples=m.n_samples,
                 n_periods=m.n_periods, law=kernels.law, reversal=scene.joint.reversal,
                 kernel=kernels.tangential, **res.convergence.as_attrs())
    writer.write("prescribed/t", res.t, unit("time", units), "time of every sample")
    writer.write("prescribed/u_t", res.u, d, "prescribed tangential displacement")
    writer.write("prescribed/N", res.N, F, "prescribed normal load")
    writer.write("prescribed/f", res.f, F, "tangential force")
    writer.write("prescribed/periodicity", res.periodicity, "1",
                 "force change between the last two periods / slip force")
    writer.write("prescribed/backbone_x", _backbone_grid(res.u), d,
                 "displacement grid of the backbone")
    x = writer.h5["prescribed/backbone_x"][()]
    Nbar = res.N[:, -m.n_samples:].mean(axis=1)
    writer.write("prescribed/backbone_f", law.backbone(x[None, :], Nbar[:, None]), F,
                 "initial loading curve f_bb(x; mean N)")
    u, f, N = res.last_period()
    report = check_loops(u, f, N, law, scene.analysis.masing.tol)
    write_loops(writer, 0, u, f, N, report, units, prefix="prescribed")
    writer.h5["prescribed/loops"].attrs["omega"] = m.omega
    log.info("prescribed: dev_manifold = %.3e, dev_masing = %.3e (%s)",
             report.dev_manifold.max(), report.dev_masing.max(), res.convergence.message)
    if not res.convergence.success:
        raise RuntimeError(res.convergence.message)


def _backbone_grid(u) -> np.ndarray:
    amp = float(np.max(np.abs(u))) or 1.0
    return np.linspace(0.0, amp, 201)


#: analysis name -> runner(scene, model, writer), run in this order when the
#: scene declares the analysis.  Solvers register themselves here.
ANALYSES: dict[str, Callable] = {}

#: the order in which analyses run when present
ORDER = ("modes", "qsma", "epmc", "hbm", "transient")


def run_scene(scene, out_path, resume: bool = False) -> Path:
    """Run every analysis of a scene and write the result file.

    Parameters
    ----------
    scene : jointsim.scene.Scene
    out_path : str or Path
        HDF5 result file.
    resume : bool
        Continue an interrupted file written for the same scene.

    Returns
    -------
    Path
        The result file.
    """
    out_path = Path(out_path)
    t0 = time.perf_counter()
    with ResultWriter(out_path, scene, resume=resume) as writer:
        if scene.model.kind == "prescribed":
            run_prescribed_scene(scene, writer)
        else:
            from .model import build_model
            _register_solvers()
            model = build_model(scene)
            from .solvers.modes import write_model_tables
            write_model_tables(scene, model, writer)  # /static, /contacts, /model, /mesh
            todo = [a for a in ORDER if getattr(scene.analysis, a) is not None]
            if not todo:
                log.warning("%s declares no analysis; only the model is built", scene.path)
            for name in todo:
                if name not in ANALYSES:
                    raise NotImplementedError(f"analysis {name!r} is not implemented yet")
                log.info("analysis %s", name)
                ANALYSES[name](scene, model, writer)
        writer.h5.attrs["wall_time_s"] = time.perf_counter() - t0
    log.info("wrote %s in %.2f s", out_path, time.perf_counter() - t0)
    return out_path


def _register_solvers() -> None:
    """Import the solver modules so that they register their analyses."""
    from ._plugins import import_available
    import_available(("jointsim.solvers.modes", "jointsim.solvers.hbm",
                      "jointsim.solvers.epmc", "jointsim.solvers.transient",
                      "jointsim.solvers.qsma"))
