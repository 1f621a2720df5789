"""The EPMC solved at fixed modal amplitudes once its branch is done (issue 9, round 21).

:func:`exact_amplitudes` lists the amplitudes (``analysis.epmc.amplitudes`` and the
``loop_amplitudes`` inside the branch's range); :func:`solve_at_amplitudes` corrects
the mode there by Newton at fixed amplitude, from the branch points around each, and
writes ``/epmc/at_amplitudes/*`` with, at the loop amplitudes, the element loops and
Masing checks that the study reads (:func:`jointsim.post.study.study_group`).
Called by :mod:`jointsim.analyses.epmc`.
"""
from __future__ import annotations

import logging

import numpy as np

from ..io.hdf5 import unit
from ..io.loops import write_loops
from ..masing import check_loops
from ..solvers.jacobian import drop_last_column, scale_columns, solve

log = logging.getLogger(__name__)


def exact_amplitudes(a) -> tuple[float, ...]:
    """Modal amplitudes at which the mode is solved exactly once the branch is done.

    ``analysis.epmc.amplitudes`` and the ``loop_amplitudes`` inside the branch's
    range, sorted: values at a given amplitude that do not depend on where the
    branch placed its points (interpolating between them moved the damping of
    the lap joint by up to 4 %), for ``jointsim converge`` and the presets.

    Parameters
    ----------
    a : jointsim.analysis_sections.EPMCAnalysis

    Returns
    -------
    tuple of float
        Modal amplitudes [m kg^0.5].
    """
    lo, hi = sorted((a.log10_amplitude_start, a.log10_amplitude_end))
    loops = (x for x in a.loop_amplitudes if lo <= np.log10(x) <= hi)
    return tuple(sorted(set(a.amplitudes) | set(loops)))


#: The solves at fixed amplitude (:func:`solve_at_amplitudes`) converge to this share of
#: ``analysis.epmc.tol``: values that do not depend on the branch points they start
#: from.  At ``tol`` itself, on the coupled lap joint (96 points), the damping at
#: a = 3e-4 was 1.0158e-3 after one Newton step from one branch (residual 5.3e-9) and
#: 1.01567e-3 from another, and two elements' Eq. 4 / Eq. 6 verdicts differed.
EXACT_TOL_FACTOR = 1e-2


def solve_at_amplitudes(writer, a, system, ep, F, scale, rscale, amplitudes=None,
                        loops=None) -> dict:
    """Solve the nonlinear mode exactly at given modal amplitudes (default ``a.amplitudes``).

    For each amplitude the stored branch (``/epmc/y``) is interpolated linearly
    in ``log10 a`` between the two points around it, and Newton corrects
    ``(zh, omega, xi)`` at that fixed amplitude (scaled as the continuation;
    tolerance :data:`EXACT_TOL_FACTOR` ``a.tol`` on ``max|R| / rscale``).  An
    amplitude the branch did not reach is reported as not converged.  Writes ``/epmc/at_amplitudes/*``.

    Parameters
    ----------
    writer : jointsim.io.hdf5.ResultWriter
    a : jointsim.scene.EPMCAnalysis
    system : jointsim.solvers.hbm.HBMSystem
    ep : jointsim.solvers.epmc.EPMCSystem
    F : ndarray, shape (n_c, n_dof)
        Static force coefficients.
    scale : ndarray, shape (n_z + 3,)
        Variable scales of the continuation.
    rscale : float
        Residual scale.
    amplitudes : sequence of float, optional
        Modal amplitudes [m kg^0.5] (:func:`exact_amplitudes`).
    loops : tuple (law, tol), optional
        Also keep the element loops and Masing checks (contact law, tolerance of
        ``analysis.masing``) of the solutions at the ``a.loop_amplitudes``, in
        ``/epmc/at_amplitudes/loops`` and ``/masing`` (``point``: the index of the
        amplitude): loop sets at the loop amplitudes themselves, whose shares do not
        depend on where the branch placed its points (the branch's own sets are at
        the first point at or past each).

    Returns
    -------
    dict
        The arrays written (``amplitude``, ``omega``, ``xi``, ``damping_ratio``,
        ``X`` [n_amp, n_coeff, n_dof], ``converged``, ``iterations``, ``residual``).
    """
    from ..solvers.newton import NewtonOptions, newton

    nz = system.n_z
    Y = writer.h5["epmc/y"][()] if "epmc/y" in writer.h5 else np.zeros((0, nz + 3))
    lam = Y[:, -1]
    amplitudes = tuple(a.amplitudes if amplitudes is None else amplitudes)
    n_amp = len(amplitudes)
    n_dof = system.model.n_dof
    out = dict(amplitude=np.array(amplitudes, dtype=float), omega=np.full(n_amp, np.nan),
               xi=np.full(n_amp, np.nan), X=np.full((n_amp, system.n_c, n_dof), np.nan),
               converged=np.zeros(n_amp, dtype=bool), iterations=np.zeros(n_amp, np.int64),
               residual=np.full(n_amp, np.nan))
    sz = scale[:nz + 2]
    sets = []                    # (index, y) of the converged loop amplitudes
    for k, amp in enumerate(amplitudes):
        lt = float(np.log10(amp))
        seg = np.flatnonzero((lam[:-1] - lt) * (lam[1:] - lt) <= 0.0)
        if seg.size == 0:
            log.warning("epmc: modal amplitude %g was not reached by the branch", amp)
            continue
        i = int(seg[0])
        w = 0.0 if lam[i + 1] == lam[i] else (lt - lam[i]) / (lam[i + 1] - lam[i])
        guess = (1.0 - w) * Y[i] + w * Y[i + 1]

        def fun(zs, lt=lt):
            R, J, ev = ep.fun(np.append(zs * sz, lt))
            # dense, or structured on the Krylov path (linear_solver = "auto" from
            # 1200 unknowns on, e.g. the coupled lap joint at H = 0..15)
            return R / rscale, scale_columns(drop_last_column(J), sz / rscale), ev

        res = newton(fun, guess[:nz + 2] / sz,
                     NewtonOptions(EXACT_TOL_FACTOR * a.tol, max(a.max_iter, 30),
                                   check_start=True), solve=solve)
        y = np.append(res.x * sz, lt)
        out["iterations"][k] = res.iterations
        out["residual"][k] = float(np.abs(res.R).max(initial=0.0))
        if not res.success:
            log.warning("epmc: Newton at modal amplitude %g did not converge: %s", amp,
                        res.message)
            continue
        omega, xi = float(y[nz]), float(y[nz + 1])
        out["omega"][k], out["xi"][k], out["converged"][k] = omega, xi, True
        out["X"][k] = system.reconstruct(ep.z0 + amp * y[:nz], omega, F, xi=xi)
        if loops is not None and amp in a.loop_amplitudes:
            sets.append((k, y))
    out["damping_ratio"] = out["xi"] / (2.0 * out["omega"])
    _write_exact(writer, system.model.units, out)
    _write_exact_loops(writer, system, ep, F, out, sets, loops)
    log.info("epmc: solved at %d of %d given modal amplitudes", int(out["converged"].sum()),
             n_amp)
    return out


def _write_exact(writer, units: str, out: dict) -> None:
    """``/epmc/at_amplitudes/*`` of :func:`solve_at_amplitudes`'s ``out``."""
    amp_unit = "m kg^0.5" if units == "SI" else "length mass^0.5"
    # read as a whole: all of it or the previous run's (its loops are rewritten next)
    with writer.whole_group("epmc/at_amplitudes") as g:
        writer.write(f"{g}/amplitude", out["amplitude"], amp_unit,
                     "modal amplitude asked for (analysis.epmc.amplitudes and "
                     "loop_amplitudes)")
        writer.write(f"{g}/omega", out["omega"], unit("angular_frequency", units),
                     "angular frequency (NaN: not converged)")
        writer.write(f"{g}/frequency_hz", out["omega"] / (2 * np.pi), unit("frequency", units),
                     "frequency of the nonlinear mode")
        writer.write(f"{g}/damping_ratio", out["damping_ratio"], "1", "xi / (2 omega)")
        writer.write(f"{g}/xi", out["xi"], unit("angular_frequency", units),
                     "self-excitation (negative mass-proportional damping)")
        writer.write(f"{g}/X", out["X"], unit("displacement", units),
                     "harmonic coefficients [n_amp, n_coeff, n_dof]")
        writer.write(f"{g}/converged", out["converged"], "1", "Newton converged at the amplitude")
        writer.write(f"{g}/iterations", out["iterations"], "1", "Newton iterations")
        writer.write(f"{g}/residual", out["residual"], "1", "max |R| / residual scale")


def _write_exact_loops(writer, system, ep, F, out, sets, loops) -> None:
    """The element loops and Masing checks of the exact solutions ``sets``
    (``(index, y)``) in ``/epmc/at_amplitudes/{loops,masing}`` (see
    :func:`solve_at_amplitudes`); rewritten whole on every run (resume)."""
    g = "epmc/at_amplitudes"
    for name in ("loops", "masing", "control"):
        if f"{g}/{name}" in writer.h5:
            del writer.h5[f"{g}/{name}"]
    if loops is None or not sets or not system.n_z:
        return
    law, tol = loops
    nz = system.n_z
    for k, y in sets:
        amp = float(out["amplitude"][k])
        ev = system.evaluate(ep.z0 + amp * y[:nz], float(out["omega"][k]), F,
                             xi=float(out["xi"][k]), jacobian=False, wrt=())
        if ev.aft is None:
            continue
        u = system.slips(out["X"][k])
        report = check_loops(u, ev.aft.f, ev.aft.N, law, tol)
        write_loops(writer, k, u, ev.aft.f, ev.aft.N, report, system.model.units, prefix=g)
