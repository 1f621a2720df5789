"""Does a reduced basis of the contact coordinates serve the harmonic balance? (issue 10)

Issue 10 item 2 names three ways to make a fine interface affordable; the third is an
*interface reduction*: the contact coordinates (slip and gap of every contact element)
restricted to ``k`` shapes, so that the harmonic balance solves for ``n_c k`` unknowns
instead of ``n_c n_r``, its error on the peak reported.  This script measures that
error on points of a computed FRC before anyone builds it into the solvers.

Method.  With ``z_0`` the preload's contact coordinates (harmonic 0), the unknowns are
``z = z_0 + (I_{n_c} (x) V) w`` with ``V`` (n_r x k) orthonormal, and the residual is
projected, ``(I (x) V)^T R(z) = 0`` (Galerkin; the contact forces are evaluated on every
element by the same AFT).  Newton on the dense reduced Jacobian ``V^T J V`` starts from
the projection of the full solution (the most favourable start) at the point's own
frequency and force.  Errors against the full point (an exact solution of the same
harmonic balance):

* ``X``: ``||X_red - X|| / ||X (h >= 1)||`` over every DOF and kept coefficient;
* ``amp``: relative error of the fundamental amplitude at the response DOF;
* ``estimate``: what a run without the reference could report, the change of ``X``
  by one Newton step of the full system from the reduced solution.

Bases (``--basis``):

* ``pod``: the leading left singular vectors of every stored point's vibration
  ``z - z_0`` (each point scaled to unit norm; all branches, the tested point
  included): a basis that already holds the answer, the best case any reduction
  can reach;
* ``pod-other``: the same from the *other* branches (force levels) only: can shapes
  from one amplitude serve another?
* ``pod-epmc``: the same from the points of the file's EPMC backbone (``/epmc``, same
  harmonics): shapes a scene computes anyway, before its FRC;
* ``pod-epmc-stuck``: the EPMC points and the stuck joint's forced responses at
  ``N_STUCK`` frequencies of the FRC range (one linear solve each, from the preload);
* ``legendre``: Legendre polynomials of the element position along the interface,
  tangential and normal rows separately (``k / 2`` each);
* ``stiffness``: the lowest eigenvectors of the stuck static stiffness on the contact
  coordinates (harmonic-0 block of the Jacobian at the preload).

Usage (any result file with ``/hbm`` of an FE scene; the scene, with its overrides, is
read back from the file)::

    jointsim run models/lap_joint.toml -o frc.h5 --set "model.mesh=''" \\
        --set model.dx_lap=0.0025 --set model.dx_full=0.005 --set model.ny_half=8 \\
        --set model.bolt_washer_radius=0.01 --set model.contact_points=gauss \\
        --set joint.kt_pressure=1.1811e7 --set joint.kn_pressure=1.1811e7 \\
        --set analysis.epmc.log10_amplitude_end=-2.45 --set analysis.hbm.step_max=0.17
    python benchmarks/interface_reduction.py frc.h5 --k 48 64 96 --basis pod pod-epmc
    python benchmarks/interface_reduction.py frc.h5 --branch 20 --basis pod-epmc-stuck --k 96

Measured (round 11, that file: 96
Gauss points with both pressure keys, ``n_r`` = 192 contact coordinates, 2,880
unknowns; H = 0..7, Nt = 128; the table is in docs/hbm.md "Round 11: interface
reduction"): shapes that do not come from solutions (``legendre``, ``stiffness``) do
not serve (1e-2 and worse at k = 96, Newton often fails); shapes from the run's own
EPMC backbone (``pod-epmc``) reproduce every tested FRC point to 1.5e-4 in X at k = 96
(half the coordinates), gross slip included, at 0.13-0.15 s per Newton iteration
against 0.42-0.58 s on the full Krylov path in gross slip; one full Newton step from
a reduced solution estimates its error within about a factor 1.5.  Over the whole
force-20 branch (``--branch``, the EPMC shapes plus 9 stuck forced responses) the
reduced continuation is 1.51x faster (46.0 s against 69.6 s; largest one-step estimate
6.7e-4): its dense bordered LUs of 1,441 unknowns take most of the gain back.
"""
from __future__ import annotations

import argparse
import logging
import os
import time
from pathlib import Path

import h5py
import numpy as np
from numpy.polynomial import legendre

from jointsim.harmonics import harmonic_amplitude

BASES = ("pod", "pod-other", "pod-epmc", "pod-epmc-stuck", "legendre", "stiffness")
#: frequencies of the stuck forced responses of ``pod-epmc-stuck``
N_STUCK = 9
MAX_ITER = 30
TOL = 1e-10


def project_jacobian(J, V) -> np.ndarray:
    """``(I (x) V)^T J (I (x) V)`` of a structured Jacobian without forming ``J``.

    Parameters
    ----------
    J : jointsim.solvers.jacobian.HBMJacobian
        Unscaled (``col`` = 1).
    V : ndarray, shape (n_r, k)

    Returns
    -------
    ndarray, shape (n_c k, n_c k)
        Harmonic-major like ``J``: ``V^T S_h V`` per harmonic (``n_r^2 k`` each) plus
        each element's AFT block times the outer product of its rows of ``V``
        (``n_e n_c^2 k^2``).
    """
    nc, k = J.n_c, V.shape[1]
    Jr = np.zeros((nc, k, nc, k))
    for i, h in enumerate(J.basis.harmonics):
        Sr = V.T @ J.schur(i) @ V
        c, s_ = J._ic[i], J._is[i]
        Jr[c, :, c, :] = Sr.real
        if h:
            Jr[c, :, s_, :] = Sr.imag
            Jr[s_, :, c, :] = -Sr.imag
            Jr[s_, :, s_, :] = Sr.real
    Vt = V[J.t_row] if J.Juu is not None else None
    Vn = V[J.n_row] if J.JNN is not None or J.Jug is not None else None
    if J.Juu is not None:
        Jr += np.einsum("eab,ei,ej->aibj", J.Juu, Vt, Vt, optimize=True)
    if J.Jug is not None:
        Jr += np.einsum("eab,ei,ej->aibj", J.Jug, Vt, Vn, optimize=True)
    if J.JNN is not None:
        Jr -= np.einsum("eab,ei,ej->aibj", J.JNN, Vn, Vn, optimize=True)
    return Jr.reshape(nc * k, nc * k)


def full_newton_step(system, z, omega, F):
    """One Newton step of the full system at ``z``: residual, Jacobian and one linear
    solve with a new preconditioner (in gross slip every Newton iteration builds one;
    GMRES on the Krylov path).

    Returns
    -------
    d : ndarray, shape (n_z,)
        The step [m]: at a reduced solution, the estimate of its reduction error.
    seconds : float
        Its wall time [s].
    """
    from jointsim.solvers.jacobian import solve
    from jointsim.solvers.preconditioner_cache import PreconditionerCache
    t0 = time.perf_counter()
    system.preconditioner = PreconditionerCache()
    ev = system.evaluate(z, omega, F, wrt=())
    d = solve(ev.J, -ev.R)
    return d, time.perf_counter() - t0


def error_estimate(system, z, omega, F) -> float:
    """What a run without a reference could report of a reduced point ``z``: the change
    of its coefficients X by one full Newton step (:func:`full_newton_step`), relative
    to its vibration ``||X (h >= 1)||``; NaN when the full solve fails."""
    X = system.reconstruct(z, omega, F)
    try:
        d, _ = full_newton_step(system, z, omega, F)
    except (RuntimeError, np.linalg.LinAlgError):
        return float("nan")
    ref = float(np.linalg.norm(X[system.basis.hk > 0]))
    return float(np.linalg.norm(system.reconstruct(z + d, omega, F) - X)) / ref


def reduced_solve(system, V, z0, z_start, omega, F):
    """Galerkin Newton of ``z = z0 + (I (x) V) w`` at a fixed frequency.

    Parameters
    ----------
    system : jointsim.solvers.hbm.HBMSystem
        On the Krylov path its structured Jacobians are projected
        (:func:`project_jacobian`); on the direct path the dense ones.
    V : ndarray, shape (n_r, k)
        Orthonormal basis of the contact coordinates.
    z0, z_start : ndarray, shape (n_z,)
        The affine offset (preload) and the full point to project as the start [m].
    omega : float
        Angular frequency [rad/s].
    F : ndarray, shape (n_c, n_dof)
        Force coefficients [N].

    Returns
    -------
    z : ndarray, shape (n_z,)
        The reduced solution in full coordinates [m].
    iterations : int
    converged : bool
        The last Newton step was below ``TOL`` of the coefficients.
    seconds : float
        Wall time of the Newton iterations [s].
    """
    nc, nr = system.n_c, system.n_r
    k = V.shape[1]
    Z0 = z0.reshape(nc, nr)
    W = (z_start.reshape(nc, nr) - Z0) @ V
    t0 = time.perf_counter()

    def out(it, ok):
        return (Z0 + W @ V.T).ravel(), it, ok, time.perf_counter() - t0
    for it in range(1, MAX_ITER + 1):
        ev = system.evaluate((Z0 + W @ V.T).ravel(), omega, F, wrt=())
        R = (ev.R.reshape(nc, nr) @ V).ravel()
        if system.krylov:
            J = project_jacobian(ev.J, V)
        else:
            J = np.einsum("ri,arbs,sj->aibj", V, ev.J.reshape(nc, nr, nc, nr), V,
                          optimize=True).reshape(nc * k, nc * k)
        try:
            d = np.linalg.solve(J, -R).reshape(nc, k)
        except np.linalg.LinAlgError:
            return out(it, False)
        W = W + d
        if not np.all(np.isfinite(W)):
            return out(it, False)
        if np.abs(d).max() <= TOL * max(np.abs(W).max(), 1e-300):
            return out(it, True)
    return out(MAX_ITER, False)


def follow_branch(system, F, y0, a, scale, rscale, V=None, z0=None):
    """One FRC branch by arclength continuation, full or on the basis ``V``.

    Parameters
    ----------
    system : jointsim.solvers.hbm.HBMSystem
        Krylov path (structured Jacobians).
    F : ndarray, shape (n_c, n_dof)
        Force coefficients [N].
    y0 : ndarray, shape (n_z + 1,)
        First point ``(z, omega)`` (solved again on the reduced system).
    a : jointsim.analysis_sections.HBMSection
        The scene's ``[analysis.hbm]`` (steps, tolerances, frequency range).
    scale, rscale
        :func:`jointsim.solvers.frc.frc_scales` of the full system (the reduced
        coordinates, orthonormal shapes in metres, take its ``z`` scale).
    V : ndarray, shape (n_r, k), optional
        Shapes; None: the full system, as :mod:`jointsim.analyses.hbm` solves it
        (without the error indicators).
    z0 : ndarray, shape (n_z,)
        Preload contact coordinates (the affine offset of the reduced unknowns) [m].

    Returns
    -------
    points : list of ndarray
        The branch's points in full coordinates ``(z, omega)``.
    branch : jointsim.solvers.continuation.Branch
    seconds : float
    """
    from jointsim.solvers.continuation import continue_branch
    from jointsim.solvers.jacobian import BorderedJacobian
    nc, nr = system.n_c, system.n_r

    if V is None:
        def fun(y):
            ev = system.evaluate(y[:-1], y[-1], F)
            return ev.R, BorderedJacobian(ev.J, ev.dR["omega"]), ev
        start, sc, origin = y0, scale, z0

        def full(y):
            return y
    else:
        Z0 = z0.reshape(nc, nr)

        def full(y):
            return np.append((Z0 + y[:-1].reshape(nc, -1) @ V.T).ravel(), y[-1])

        def fun(y):
            ev = system.evaluate(full(y)[:-1], y[-1], F)
            J = np.column_stack([project_jacobian(ev.J, V),
                                 (ev.dR["omega"].reshape(nc, nr) @ V).ravel()])
            return (ev.R.reshape(nc, nr) @ V).ravel(), J, ev
        w0 = ((y0[:-1].reshape(nc, nr) - Z0) @ V).ravel()
        start = np.append(w0, y0[-1])
        sc = np.append(np.full(w0.size, scale[0]), scale[-1])
        origin = np.zeros(w0.size)
    t0 = time.perf_counter()
    br = continue_branch(fun, start, a.omega_end, scale=sc, rscale=rscale, step=a.step,
                         step_min=a.step_min, step_max=a.step_max, max_points=a.max_points,
                         tol=a.tol, max_iter=a.max_iter, solve_first=True, progress=False,
                         lam_start=a.omega_start, adapt_scale=True, z_origin=origin,
                         desc="reduced branch" if V is not None else "full branch")
    seconds = time.perf_counter() - t0
    return [full(np.asarray(y)) for y in br.y], br, seconds


def compare_branches(system, F, y0, a, V, z0, dof):
    """The full and the reduced branch side by side (see :func:`follow_branch`); prints
    their points, Newton iterations, times, largest amplitudes, and the largest
    one-step error estimate over the reduced points."""
    from jointsim.solvers.frc import frc_scales
    scale, rscale = frc_scales(system, F, a.omega_start, a.omega_end)
    runs = {}
    for name, basis in (("full", None), (f"reduced (k = {V.shape[1]})", V)):
        pts, br, sec = follow_branch(system, F, y0, a, scale, rscale, basis, z0)
        amps = [float(harmonic_amplitude(system.basis,
                                         system.reconstruct(y[:-1], y[-1], F)[:, dof]))
                for y in pts]
        i = int(np.argmax(amps))
        runs[name] = dict(points=pts, n=len(pts), iterations=int(np.sum(br.iterations)),
                          seconds=sec, amplitude=amps[i], omega=float(pts[i][-1]),
                          message=br.convergence.message)
    full, red = runs.values()
    w_red = [float(y[-1]) for y in red["points"]]
    est = [error_estimate(system, y[:-1], float(y[-1]), F) for y in red["points"]]
    j = int(np.nanargmax(est))
    print("one-step error estimates of the reduced points, omega [rad/s]: estimate")
    print(", ".join(f"{w:.1f}: {e:.1e}" for w, e in zip(w_red, est)))
    print("| branch | points | Newton it. | s | s / point | largest amplitude [m] | at omega "
          "[rad/s] | end |")
    print("|---|---|---|---|---|---|---|---|")
    for name, r in runs.items():
        print(f"| {name} | {r['n']} | {r['iterations']} | {r['seconds']:.1f} | "
              f"{r['seconds'] / r['n']:.3f} | {r['amplitude']:.6e} | {r['omega']:.3f} | "
              f"{r['message']} |")
    print(f"largest amplitude: relative difference "
          f"{abs(red['amplitude'] - full['amplitude']) / full['amplitude']:.2e}, its frequency "
          f"{abs(red['omega'] - full['omega']) / full['omega']:.2e} (both unrefined: branch "
          f"points); time ratio full / reduced {full['seconds'] / red['seconds']:.2f}; "
          f"largest one-step error estimate over the reduced points {est[j]:.2e} "
          f"(omega = {w_red[j]:.2f})")


class Bases:
    """The candidate bases of one system (see the module doc)."""

    def __init__(self, system, z0, Z_points, branch, Z_epmc=None, omega_range=None):
        self.s = system
        self.omega_range = omega_range
        self.z0 = z0
        self.Z = Z_points                  # (n_points, n_z)
        self.branch = branch
        self.Z_epmc = Z_epmc               # (n_epmc_points, n_z) or None
        x = system.contacts.position[:, 0]
        span = float(x.max() - x.min()) or 1.0
        self.xi = 2.0 * (x - x.min()) / span - 1.0
        self._stiff = None

    def _pod(self, Z, k):
        nc, nr = self.s.n_c, self.s.n_r
        D = Z - self.z0
        # each point's vibration at unit norm: the small force levels count as much
        # as the large ones
        D = D / np.maximum(np.linalg.norm(D, axis=1, keepdims=True), 1e-300)
        snaps = D.reshape(-1, nc, nr).reshape(-1, nr).T
        u, _, _ = np.linalg.svd(snaps, full_matrices=False)
        return u[:, :k]

    def _stuck(self):
        """``z`` of the stuck joint's forced responses (one Newton step from the preload)
        at ``N_STUCK`` frequencies of ``omega_range`` (n, n_z)."""
        from jointsim.solvers.jacobian import solve
        s = self.s
        F = s.force_coefficients(1.0)
        out = []
        for w in np.linspace(*self.omega_range, N_STUCK):
            ev = s.evaluate(self.z0, float(w), F, wrt=())
            out.append(self.z0 + solve(ev.J, -ev.R))
        return np.array(out)

    def get(self, kind, k, branch):
        """``V`` (n_r, k) of basis ``kind`` (``pod-other`` leaves out ``branch``)."""
        s = self.s
        if kind == "pod":
            return self._pod(self.Z, k)
        if kind == "pod-other":
            rows = np.flatnonzero(self.branch != branch)
            return self._pod(self.Z[rows], k) if rows.size else None
        if kind == "pod-epmc":
            return None if self.Z_epmc is None else self._pod(self.Z_epmc, k)
        if kind == "pod-epmc-stuck":
            if self.Z_epmc is None or self.omega_range is None:
                return None
            return self._pod(np.vstack([self.Z_epmc, self._stuck()]), k)
        if kind == "legendre":
            m = max(k // (2 if s.coupled and s.friction else 1), 1)
            P = legendre.legvander(self.xi, m - 1)
            V = np.zeros((s.n_r, 0))
            for rows in (s.t_row, s.n_row):
                if rows[0] >= 0:
                    block = np.zeros((s.n_r, m))
                    block[rows] = P
                    V = np.hstack([V, block])
            return np.linalg.qr(V)[0][:, :k]
        if kind == "stiffness":
            if self._stiff is None:
                ev = s.evaluate(self.z0, 1.0, np.zeros((s.n_c, s.model.n_dof)), wrt=())
                i0 = s.basis.index[0][0] * s.n_r + np.arange(s.n_r)
                Jd = ev.J.to_dense() if hasattr(ev.J, "to_dense") else ev.J
                K = Jd[np.ix_(i0, i0)]
                self._stiff = np.linalg.eigh(0.5 * (K + K.T))[1]
            return self._stiff[:, :k]
        raise ValueError(f"unknown basis {kind!r}; one of {BASES}")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("result", help="result file with /hbm (an FE scene)")
    p.add_argument("--k", type=int, nargs="+", default=[8, 16, 32, 48],
                   help="basis sizes (shapes per coefficient)")
    p.add_argument("--basis", nargs="+", default=list(BASES), choices=BASES)
    p.add_argument("--branch", type=float, default=None, metavar="FORCE_SCALE",
                   help="instead of the point table: follow that force level's FRC branch "
                        "in full (Krylov path, no error indicators) and on the first "
                        "--basis with the first --k shapes, side by side")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    from jointsim.model import build_model
    from jointsim.post.common import scene_from_file
    from jointsim.solvers.hbm import HBMSystem

    path = Path(a.result)
    with h5py.File(path, "r") as f:
        if "hbm" not in f:
            raise SystemExit(f"{path}: no /hbm group (run a scene with [analysis.hbm])")
        scene = scene_from_file(f)
        g = f["hbm"]
        br, om, amp = g["branch"][()], g["omega"][()], g["amplitude"][()]
        X = g["X"][()]
        dof = int(g.attrs["response_dof"])
        scales = g["force_scale"][()]
        X_epmc = None
        if "epmc/X" in f and np.array_equal(f["epmc/harmonics"][()], g["harmonics"][()]):
            X_epmc = f["epmc/X"][()]
            X_epmc = X_epmc[np.all(np.isfinite(X_epmc), axis=(1, 2))]
    hb = scene.analysis.hbm
    if 0 not in tuple(hb.harmonics) and "stiffness" in a.basis:
        a.basis.remove("stiffness")             # no harmonic-0 block
    model = build_model(scene)
    s = HBMSystem(model, hb.harmonics, hb.n_samples, hb.min_periods, hb.max_periods,
                  linear_solver="krylov")
    z0 = s.static_coordinates()
    Z = np.array([s.contact_coordinates(x) for x in X])
    Z_epmc = None if X_epmc is None or not len(X_epmc) else \
        np.array([s.contact_coordinates(x) for x in X_epmc])
    bases = Bases(s, z0, Z, br, Z_epmc, (hb.omega_start, hb.omega_end))
    kept = s.basis.hk > 0

    def fundamental(x):
        return float(harmonic_amplitude(s.basis, x[:, dof]))
    print(f"{path}: {s.n_e} contact elements, {s.n_r} contact coordinates x {s.n_c} "
          f"coefficients = {s.n_z} unknowns; load {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if a.branch is not None:
        ib = int(np.argmin(np.abs(scales - a.branch)))
        first = int(np.flatnonzero(br == ib)[0])
        V = bases.get(a.basis[0], min(a.k[0], s.n_r), ib)
        if V is None:
            raise SystemExit(f"basis {a.basis[0]} has no snapshots in {path}")
        print(f"force scale {scales[ib]:g}, basis {a.basis[0]}, k = {V.shape[1]} "
              f"({s.n_c * V.shape[1]:,} unknowns)")
        compare_branches(s, s.force_coefficients(float(scales[ib])),
                         np.append(Z[first], om[first]), hb, V, z0, dof)
        return
    print("| force scale | omega [rad/s] | basis | k | unknowns | Newton it. | converged "
          "| s / iteration (full) | rel. error X | its estimate | rel. error amplitude |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    t0 = time.perf_counter()
    for b in np.unique(br):
        rows = np.flatnonzero(br == b)
        F = s.force_coefficients(float(scales[b]))
        for p_ in (rows[np.argmax(amp[rows])], rows[len(rows) // 4]):
            ref = float(np.linalg.norm(X[p_][kept]))
            a_ref = fundamental(X[p_])
            full = np.mean([full_newton_step(s, Z[p_], float(om[p_]), F)[1]
                            for _ in range(2)])
            for kind in a.basis:
                for k in a.k:
                    V = bases.get(kind, min(k, s.n_r), b)
                    if V is None:
                        continue
                    z, its, ok, sec = reduced_solve(s, V, z0, Z[p_], float(om[p_]), F)
                    Xr = s.reconstruct(z, float(om[p_]), F)
                    eX = float(np.linalg.norm(Xr - X[p_]) / ref)
                    ea = abs(fundamental(Xr) - a_ref) / a_ref
                    est = error_estimate(s, z, float(om[p_]), F)
                    print(f"| {scales[b]:g} | {om[p_]:.3f} | {kind} | {V.shape[1]} | "
                          f"{s.n_c * V.shape[1]:,} | {its} | {'yes' if ok else 'no'} | "
                          f"{sec / its:.3f} ({full:.3f}) | {eX:.2e} | {est:.2e} | {ea:.2e} |",
                          flush=True)
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
