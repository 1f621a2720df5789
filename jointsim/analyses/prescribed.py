"""Runner of prescribed-motion scenes: march the element, check its loop, write it."""
from __future__ import annotations

import logging

import numpy as np

from ..io.hdf5 import ResultWriter, unit
from ..io.loops import write_loops
from ..masing import check_loops

log = logging.getLogger(__name__)


def run_prescribed_scene(scene, writer: ResultWriter) -> None:
    """Prescribed-motion model: march, check the loop, write ``/prescribed``.

    Parameters
    ----------
    scene : jointsim.scene.Scene
        A scene with ``model.kind = "prescribed"``.
    writer : jointsim.io.hdf5.ResultWriter

    Raises
    ------
    RuntimeError
        After writing, when the loop is not periodic.
    """
    from ..solvers.prescribed import run_prescribed

    from .modes import separation_warning

    m = scene.model
    sep_warning = separation_warning(scene)
    kernels = scene.kernels()
    law = kernels.tangential_law(scene.joint, [m.area])
    res = run_prescribed(scene, law)
    units = m.units
    d, F = unit("displacement", units), unit("force", units)
    writer.group("prescribed", omega=m.omega, n_samples=m.n_samples,
                 n_periods=m.n_periods, law=kernels.law, reversal=scene.joint.reversal,
                 kernel=kernels.tangential, separation_warning=sep_warning,
                 **res.convergence.as_attrs())
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
