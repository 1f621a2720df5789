"""Runner of ``[analysis.qsma]``: the QSMA backbone of one mode, written to ``/qsma``.

The quantities are described in :mod:`jointsim.solvers.qsma`.
"""
from __future__ import annotations

import logging

import numpy as np

from ..io.hdf5 import unit
from ..solvers.modes import stuck_modes
from ..solvers.qsma import QSMAResult, qsma

log = logging.getLogger(__name__)


def run_qsma_analysis(scene, model, writer, results=None) -> QSMAResult:
    """``[analysis.qsma]``: the QSMA backbone of one mode, written to ``/qsma``.

    The runner contract (arguments, ``results``) is in :mod:`jointsim.analyses`.

    Returns
    -------
    jointsim.solvers.qsma.QSMAResult

    Raises
    ------
    RuntimeError
        After writing what was computed, when a load increment failed.
    """
    a = scene.analysis.qsma
    x0 = model.linearisation.x0
    modes = stuck_modes(model, a.mode + 10, suspension_hz=a.rigid_cutoff_hz)
    elastic = np.nonzero(modes.elastic)[0]
    if a.mode > elastic.size:
        raise ValueError(f"analysis.qsma.mode = {a.mode} but only {elastic.size} elastic "
                         "modes were found")
    k = elastic[a.mode - 1]
    phi = modes.shapes[k]
    phi = phi * np.sign(phi[np.argmax(np.abs(phi))])
    w0 = 2 * np.pi * modes.frequency_hz[k]
    amps = np.logspace(a.log10_amplitude_start, a.log10_amplitude_end, a.n_steps)
    res = qsma(model, phi, x0, w0 ** 2 * amps, tol=a.tol, progress=True)
    units = model.units
    g = writer.group("qsma", mode=a.mode, linear_frequency_hz=res.linear_hz,
                     zeta_linear=res.zeta_linear, **res.convergence.as_attrs())
    del g
    writer.write("qsma/amplitude", res.amplitude, unit("modal_amplitude", units),
                 "modal amplitude q = phi^T M (x - x0), phi mass-normalised")
    writer.write("qsma/frequency_hz", res.frequency_hz, unit("frequency", units),
                 "secant frequency sqrt(alpha / q) / (2 pi)")
    writer.write("qsma/damping_ratio", res.damping_ratio, "1",
                 "Masing damping D / (2 pi q alpha) plus the linear viscous damping of the "
                 "mode (attribute zeta_linear of /qsma)")
    writer.write("qsma/damping_ratio_friction", res.damping_ratio_friction, "1",
                 "friction (Masing) part D / (2 pi q alpha)")
    writer.write("qsma/dissipation", res.dissipation, unit("energy", units),
                 "Masing dissipation per cycle 8 int alpha dq - 4 q alpha")
    writer.write("qsma/alpha", res.alpha, unit("modal_load", units),
                 "modal load factor: the load is f_static + alpha M phi")
    writer.write("qsma/mode_shape", phi, unit("mode_shape", units), "mass-normalised stuck mode")
    writer.write("qsma/x", res.x, unit("displacement", units), "displacements along the loading")
    writer.write("qsma/element_u", res.u_t, unit("displacement", units),
                 "element slips along the loading (per-element backbones)")
    writer.write("qsma/element_f", res.f_t, unit("force", units),
                 "element tangential forces along the loading")
    writer.write("qsma/element_N", res.N, unit("force", units),
                 "element normal loads along the loading")
    log.info("qsma mode %d: %s; linear %.4f Hz", a.mode, res.convergence.message, res.linear_hz)
    if not res.convergence.success:
        raise RuntimeError(f"qsma: {res.convergence.message}")
    return res
