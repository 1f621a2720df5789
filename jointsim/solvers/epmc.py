"""Nonlinear modes by the extended periodic motion concept (EPMC, Krack 2015).

The autonomous system with an artificial negative damping term,

    M x'' + (C - xi M) x' + K x + f_c(x) = f_static,

has periodic solutions along a nonlinear mode; ``xi`` [1/s] is the
self-excitation that exactly balances the dissipation, so that the mode's
damping ratio is ``zeta = xi / (2 omega)``.  It is solved by the same
condensed AFT harmonic balance as the FRC (:mod:`jointsim.solvers.hbm`), with
two extra unknowns (``omega``, ``xi``) and two extra equations that fix the
amplitude and the phase:

* **amplitude** -- the modal amplitude of the fundamental harmonic,
  ``a = phi^T M (X_1c - i X_1s)``, with ``phi`` the mass-normalised linear mode
  of the structure linearised at its static state ``x0`` with the joint stuck
  (:func:`jointsim.solvers.static.stuck_linearisation`; for the lap joint:
  the preloaded joint, the modes of ``[analysis.modes]``); the phase is fixed
  by making it real: ``Re = a``, ``Im = 0``.  For a single DOF with ``m = 1``
  this is the amplitude of the cosine of ``x``.  ``mode`` counts elastic
  modes only (:func:`jointsim.solvers.modes.elastic_mode`).
* **scaling** -- the unknowns are the contact coefficients measured from the
  static state and divided by ``a``, ``z = z0 + a zh`` with ``z0`` the
  contact coordinates of ``x0`` (harmonic 0), so that a branch over several
  decades of amplitude stays well scaled and starts at the static state; the
  residual is divided by ``a`` too.  The continuation parameter is
  ``log10(a)``.

At small amplitude the mode starts from the linear one (``omega`` = its
frequency, ``xi = phi^T C phi``, ``zh`` = the contact coordinates of
``phi`` in the cosine of harmonic 1).
"""
from __future__ import annotations

import logging

import numpy as np

from .hbm import HBMSystem, _dense
from .modes import elastic_mode

log = logging.getLogger(__name__)

LN10 = np.log(10.0)


class EPMCSystem:
    """EPMC equations in amplitude-normalised unknowns.

    Unknowns ``y = (zh, omega, xi, lam)`` with ``z = z0 + 10^lam zh`` the
    contact coefficients (``z0``: the static state, harmonic 0); equations
    ``R(z, omega, xi) / a`` and the amplitude and phase conditions.

    Parameters
    ----------
    system : HBMSystem
    phi : ndarray, shape (n_dof,)
        Mass-normalised reference mode.
    F : ndarray, shape (n_c, n_dof)
        Static force coefficients (no harmonic excitation).
    """

    def __init__(self, system: HBMSystem, phi, F):
        if 1 not in system.basis.harmonics:
            raise ValueError("EPMC needs harmonic 1")
        self.s = system
        self.z0 = system.static_coordinates()
        self.phi = np.asarray(phi, dtype=float)
        self.F = F
        lin = system.lin
        Mphi = _dense(system.model.M) @ self.phi
        self.m_q = lin.Psi.T @ Mphi
        self.m_y = lin.Z.T @ Mphi

    def _modal(self, Q, omega, xi, derivs: bool):
        """``q1 = phi^T M X_1`` (complex), its gradient in the harmonic-1 rows, and
        its derivatives by omega and xi."""
        s, lin = self.s, self.s.lin
        qh = s._complex(Q, 1)
        A, B, Bp, E = lin.blocks(omega, xi)
        Ef = lin.factor_E(E) if lin.n_y else E
        Fy = lin.Z.T @ s._complex(self.F, 1)
        y = lin.solve_E(Ef, Fy - Bp @ qh) if lin.n_y else np.zeros(0, complex)
        q1 = self.m_q @ qh + self.m_y @ y
        if not derivs:
            return q1, None, None
        ell = self.m_q - (Bp.T @ lin.solve_E(Ef, self.m_y.astype(complex), trans=True)
                          if lin.n_y else 0.0)
        d = {}
        for p in ("omega", "xi"):
            if lin.n_y:
                _dA, _dB, dBp, dE = lin.dblocks(omega, xi, p, 1)
                d[p] = self.m_y @ (-lin.solve_E(Ef, dBp @ qh + lin.apply_dE(dE, y)))
            else:
                d[p] = 0.0 + 0.0j
        return q1, ell, d

    def fun(self, y):
        """Residual (n_z + 2,) and Jacobian (n_z + 2, n_z + 3) at ``y``, plus the evaluation."""
        s = self.s
        nz = s.n_z
        zh, omega, xi, lam = y[:nz], y[nz], y[nz + 1], y[nz + 2]
        if not -300.0 < lam < 300.0 or not np.all(np.isfinite(y)):
            # a diverged Newton iterate: report it as non-finite, not as a warning
            return np.full(nz + 2, np.nan), np.full((nz + 2, nz + 3), np.nan), None
        a = 10.0 ** lam
        J = np.zeros((nz + 2, nz + 3))
        ev = s.evaluate(self.z0 + a * zh, omega, self.F, xi=xi, wrt=("omega", "xi"),
                        J_out=J[:nz, :nz])
        Rt = ev.R / a
        Q = zh.reshape(s.n_c, s.n_r)
        q1, ell, d = self._modal(Q, omega, xi, True)
        R = np.concatenate([Rt, [q1.real - 1.0, q1.imag]])
        J[:nz, nz] = ev.dR["omega"] / a
        J[:nz, nz + 1] = ev.dR["xi"] / a
        J[:nz, nz + 2] = LN10 * (ev.J @ zh - Rt)
        ic, is_ = s.basis.index[1]
        nr = s.n_r
        cols_c = ic * nr + np.arange(nr)
        cols_s = is_ * nr + np.arange(nr)
        # q1 = ell . (qc - i qs)
        J[nz, cols_c] = ell.real
        J[nz, cols_s] = ell.imag
        J[nz + 1, cols_c] = ell.imag
        J[nz + 1, cols_s] = -ell.real
        J[nz, nz] = d["omega"].real
        J[nz + 1, nz] = d["omega"].imag
        J[nz, nz + 1] = d["xi"].real
        J[nz + 1, nz + 1] = d["xi"].imag
        return R, J, ev


class _LoopSelection:
    """Which EPMC points keep their element loops.

    With target amplitudes, the first point at or past each target (in the
    direction of the continuation); otherwise the indices of
    ``analysis.masing.points`` (every point when empty).  On resume, targets
    already passed by the stored points are done.
    """

    def __init__(self, amplitudes, points, lam0, lam1, stored):
        self.up = lam1 >= lam0
        targets = sorted(amplitudes, reverse=not self.up)
        if stored.size:
            reached = stored.max() if self.up else stored.min()
            targets = [t for t in targets if (t > reached if self.up else t < reached)]
        self.targets = targets
        self.by_amplitude = bool(amplitudes)
        self.points = set(points)

    def __call__(self, p: int, amp: float) -> bool:
        if not self.by_amplitude:
            return not self.points or p in self.points
        hit = False
        while self.targets and (amp >= self.targets[0] if self.up else amp <= self.targets[0]):
            self.targets.pop(0)
            hit = True
        return hit


def run_epmc_analysis(scene, model, writer) -> None:
    """Runner of ``[analysis.epmc]``: the backbone of one mode, written point by point.

    Datasets (per point): ``/epmc/amplitude`` (modal amplitude ``a``),
    ``/epmc/frequency_hz``, ``/epmc/omega``, ``/epmc/damping_ratio``
    (``xi / (2 omega)``), ``/epmc/xi``, ``/epmc/X`` [n_points, n_coeff, n_dof]
    (coefficients of ``x``, not normalised), ``/epmc/iterations``,
    ``/epmc/residual``, ``/epmc/step``, ``/epmc/y`` and ``/epmc/tangent``
    (for ``--resume``); once: ``/epmc/harmonics``, ``/epmc/mode_shape``.
    Loops and Masing checks go to ``/loops`` and ``/masing`` unless the scene
    also runs an FRC (which then owns them).
    """
    from ..io.hdf5 import unit, write_loops
    from ..masing import check_loops
    from .continuation import continue_branch

    import time
    t_start = time.perf_counter()
    a = scene.analysis.epmc
    units = model.units
    system = HBMSystem(model, a.harmonics, a.n_samples, a.min_periods, a.max_periods)
    em = elastic_mode(model, a.mode, a.rigid_cutoff_hz)
    phi, w0 = em.phi, em.omega
    F = system.force_coefficients(0.0)
    ep = EPMCSystem(system, phi, F)
    C = _dense(model.C)
    xi0 = float(phi @ C @ phi)
    nz = system.n_z
    amp_unit = "m kg^0.5" if units == "SI" else "length mass^0.5"
    g = writer.group("epmc", mode=a.mode, linear_frequency_hz=w0 / (2 * np.pi),
                     linear_damping_ratio=xi0 / (2 * w0), n_samples=a.n_samples,
                     mode_index=em.index, n_rigid_below=em.n_rigid,
                     amplitude_definition="modal amplitude of the fundamental harmonic, "
                     "|phi^T M (X_1c - i X_1s)|, phi the mass-normalised mode of the "
                     "structure linearised at its static state with the joint stuck")
    if "epmc/harmonics" not in writer.h5:
        writer.write("epmc/harmonics", np.array(a.harmonics, dtype=np.int64), "1",
                     "harmonics kept; coefficient order [0, 1c, 1s, ...]")
        writer.write("epmc/mode_shape", phi, "1/sqrt(kg)" if units == "SI" else "1",
                     "mass-normalised stuck mode at the static state (phi^T M phi = 1)")
    if "contacts/area" not in writer.h5 and model.contacts.n_elements:
        writer.write("contacts/area", model.contacts.area, "m^2" if units == "SI" else "length^2",
                     "contact area of each element")
    if g.attrs.get("branch_status", "") in ("complete", "gave up"):
        log.info("epmc already %s; skipped", g.attrs["branch_status"])
        return
    lam0, lam1 = a.log10_amplitude_start, a.log10_amplitude_end
    if writer.rows("epmc/y"):
        y0 = writer.h5["epmc/y"][-1]
        t0 = writer.h5["epmc/tangent"][-1]
        h0 = float(writer.h5["epmc/step"][-1]) or a.step
        solve_first, max_pts = False, a.max_points - writer.rows("epmc/y") + 1
    else:
        Q = np.zeros((system.n_c, system.n_r))
        ic, _ = system.basis.index[1]
        Q[ic] = system.T @ phi
        y0 = np.concatenate([Q.ravel(), [w0, xi0, lam0]])
        t0, h0, solve_first, max_pts = None, a.step, True, a.max_points
    zscale = max(float(np.abs(y0[:nz]).max(initial=0.0)), 1e-300) if nz else 1.0
    scale = np.concatenate([np.full(nz, zscale), [w0, w0, 1.0]])
    R0, J0, _ = ep.fun(y0)
    rscale = max(float(np.abs(J0[:nz, :nz]).max(initial=0.0)) * zscale, 1e-300) if nz else 1.0
    masing = scene.analysis.masing
    keep = _LoopSelection(a.loop_amplitudes, masing.points, lam0, lam1,
                          writer.h5["epmc/amplitude"][()] if "epmc/amplitude" in writer.h5
                          else np.zeros(0))
    d_u = unit("displacement", units)
    law = model.contacts.law

    def on_point(i, y, info):
        if not solve_first and i == 0:
            return
        omega, xi, lam = float(y[nz]), float(y[nz + 1]), float(y[nz + 2])
        amp = 10.0 ** lam
        X = system.reconstruct(ep.z0 + amp * y[:nz], omega, F, xi=xi)
        p = writer.rows("epmc/omega")
        writer.append("epmc/amplitude", amp, amp_unit, "modal amplitude of the fundamental")
        writer.append("epmc/omega", omega, unit("angular_frequency", units), "angular frequency")
        writer.append("epmc/frequency_hz", omega / (2 * np.pi), unit("frequency", units),
                      "frequency of the nonlinear mode")
        writer.append("epmc/damping_ratio", xi / (2 * omega), "1", "xi / (2 omega)")
        writer.append("epmc/xi", xi, unit("angular_frequency", units),
                      "self-excitation (negative mass-proportional damping)")
        writer.append("epmc/X", X, d_u, "harmonic coefficients [n_coeff, n_dof]")
        writer.append("epmc/iterations", np.int64(info.iterations), "1", "Newton iterations")
        writer.append("epmc/residual", info.residual, "1", "max |R| / residual scale")
        writer.append("epmc/step", info.step, "1", "scaled arclength step")
        writer.append("epmc/y", y, "1", "unknowns (shape, omega, xi, log10 a), for --resume")
        writer.append("epmc/tangent", info.tangent, "1", "unit tangent (scaled)")
        ev = info.extra
        if ev is not None and ev.aft is not None and keep(p, amp):
            u = system.slips(X)
            report = check_loops(u, ev.aft.f, ev.aft.N, law, masing.tol)
            write_loops(writer, p, u, ev.aft.f, ev.aft.N, report, units, prefix="epmc")
            writer.h5["epmc/loops"].attrs["analysis"] = "epmc"

    br = continue_branch(ep.fun, y0, lam1, scale=scale, rscale=rscale, step=h0,
                         step_min=a.step_min, step_max=a.step_max, max_points=max_pts,
                         tol=a.tol, max_iter=a.max_iter, solve_first=solve_first,
                         tangent0=t0, on_point=on_point, desc=f"epmc mode {a.mode}")
    conv = br.convergence
    g.attrs["time_s"] = g.attrs.get("time_s", 0.0) + time.perf_counter() - t_start
    g.attrs["n_points"] = writer.rows("epmc/omega")
    g.attrs["branch_status"] = "complete" if conv.success else "gave up"
    for k, v in conv.as_attrs().items():
        g.attrs[k] = v
    log.info("epmc mode %d: %s", a.mode, conv.message)
    if not conv.success:
        raise RuntimeError(f"epmc: {conv.message}")


def _register():
    from ..run import ANALYSES
    ANALYSES["epmc"] = run_epmc_analysis


_register()
