"""The ``/crosscheck`` group: a steady time-marching result against harmonic balance.

The comparison itself is :mod:`jointsim.solvers.crosscheck`; the transient
runner calls :func:`write_cross_check` with the HBM runner's result in memory.
:func:`cross_check_file` does the same against the ``/hbm`` group of a file
(read by :func:`jointsim.io.hbm_points.read_hbm_solutions`).
"""
from __future__ import annotations

import logging

import numpy as np

from ..io.hbm_points import read_hbm_solutions
from ..io.hdf5 import unit
from ..solvers.crosscheck import CrossCheck, HBMSolutions, cross_check, hbm_reference

log = logging.getLogger(__name__)


def write_cross_check(writer, scene, model, result, hbm: HBMSolutions,
                      tol: float = 1e-3) -> CrossCheck | None:
    """Cross-check a steady time-marching result against harmonic balance at its frequency.

    The HBM solution is solved at exactly the frequency and force scale of
    the march, with the harmonics and samples of the FRC ``hbm`` (the HBM
    runner's result, in memory; :func:`~jointsim.solvers.crosscheck.hbm_reference`).
    Writes ``/crosscheck/*``: ``harmonics``,
    ``rel_diff``, ``rel_own``, ``amplitude_transient``, ``amplitude_hbm``,
    ``X_transient``, ``X_hbm``, ``df``, ``dN``, ``memory`` and attributes
    ``omega``, ``force_scale``, ``dc_diff``, ``dc_history``, ``agree``,
    ``tol``, ``verdict``, ``hbm_source``, ``hbm_points``, ``hbm_success``,
    ``hbm_message``, ``hbm_n_samples``, ``hbm_time_s``.

    Parameters
    ----------
    writer : jointsim.io.hdf5.ResultWriter
    scene : jointsim.scene.Scene
    model : jointsim.model.StructuralModel
    result : jointsim.solvers.transient.SteadyResult
    hbm : jointsim.solvers.crosscheck.HBMSolutions
        The solution points of the scene's FRC.
    tol : float
        Agreement tolerance on ``rel_diff``.

    Returns
    -------
    CrossCheck or None
        None (and a warning, and ``verdict`` saying why) when the HBM solve
        at the frequency did not converge.
    """
    ht = result.harmonics
    ref = hbm_reference(hbm, scene, model, result.omega, result.force_scale, result.X, ht)
    common = dict(omega=result.omega, force_scale=result.force_scale, tol=float(tol),
                  hbm_source=ref.source, hbm_points=np.asarray(ref.points, dtype=np.int64),
                  hbm_success=bool(ref.convergence.success),
                  hbm_message=ref.convergence.message, hbm_n_samples=ref.n_samples,
                  hbm_time_s=ref.wall_time)
    if not ref.convergence.success:
        msg = f"no HBM solution at omega = {result.omega:g}: {ref.convergence.message}"
        log.warning("cross-check: %s; nothing compared", msg)
        writer.group("crosscheck", agree=False, verdict=msg, **common)
        return None
    n = result.last.f.shape[1] - 1
    loops = (result.last.f[:, :n], result.last.N[:, :n])
    se = getattr(result, "step_error", None)
    if se is not None and tuple(se.harmonics) != tuple(ht):
        se = None
    cc = cross_check(result.X, ht, ref.X, ref.harmonics, model=model, loops=loops, tol=tol,
                     step_error=se)
    verdict = cc.verdict
    if not result.convergence.success:
        verdict += (f" (the march is not steady: {result.convergence.message})")
    writer.group("crosscheck", dc_diff=cc.dc_diff, dc_history=cc.dc_history, agree=cc.agree,
                 verdict=verdict, transient_steady=bool(result.convergence.success),
                 error_estimate=float(result.error_estimate), **common)
    units = model.units
    one = unit("dimensionless", units)
    writer.write("crosscheck/harmonics", np.asarray(cc.harmonics, dtype=np.int64), "1",
                 "harmonics compared")
    if cc.rel_diff_corrected is not None:
        writer.write("crosscheck/rel_diff_step_corrected", cc.rel_diff_corrected, one,
                     "rel_diff of the march corrected by its estimated time-step error "
                     "(transient/error_step_dX)", step_error=cc.step_error)
    writer.write("crosscheck/rel_diff", cc.rel_diff, one,
                 "||X_tm,h - X_hbm,h|| / ||X_hbm,1|| per harmonic")
    writer.write("crosscheck/rel_own", cc.rel_own, one,
                 "||X_tm,h - X_hbm,h|| / ||X_hbm,h|| per harmonic")
    d = unit("displacement", units)
    writer.write("crosscheck/amplitude_transient", cc.amplitude_a, d,
                 "first-harmonic amplitude per DOF, time marching")
    writer.write("crosscheck/amplitude_hbm", cc.amplitude_b, d,
                 "first-harmonic amplitude per DOF, harmonic balance")
    writer.write("crosscheck/X_transient", result.X, d, "coefficients of the time-marching "
                 "period [0, 1c, 1s, ...] of its harmonics", harmonics=np.asarray(ht))
    writer.write("crosscheck/X_hbm", ref.X, d, "coefficients of the HBM solution at the "
                 "same frequency", harmonics=np.asarray(ref.harmonics))
    F = unit("force", units)
    writer.write("crosscheck/df", cc.df, F, "mean tangential force differences that hold "
                 "the DC difference")
    writer.write("crosscheck/dN", cc.dN, F, "mean normal load differences")
    writer.write("crosscheck/memory", cc.memory, "1",
                 "elements that stick all period (keep their history)")
    (log.info if cc.agree else log.warning)("cross-check at omega = %g (HBM %s): %s",
                                            result.omega, ref.source, verdict)
    return cc


def cross_check_file(writer, scene, model, result, tol: float = 1e-3) -> CrossCheck | None:
    """:func:`write_cross_check` against the ``/hbm`` points stored in the writer's file.

    Parameters
    ----------
    writer : jointsim.io.hdf5.ResultWriter
        A file whose ``/hbm`` holds solution points.
    scene, model, result, tol
        As in :func:`write_cross_check`.
    """
    return write_cross_check(writer, scene, model, result, read_hbm_solutions(writer.h5),
                             tol=tol)
