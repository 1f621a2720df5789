"""A-posteriori error indicators of a harmonic-balance (HBM or EPMC) point.

A converged point of the condensed AFT harmonic balance (:mod:`.hbm`) keeps
the harmonics ``H`` (e.g. ``0..7``) and samples the contact laws at ``N_t``
points per period.  Two discretisation errors remain:

* **truncation** -- the contact forces have harmonics above ``H`` (the AFT
  samples them anyway); were they kept, the structure would respond at those
  harmonics, and through the contact tangent that response would change the
  retained harmonics;
* **aliasing** -- the laws are marched on ``N_t`` samples, and the force
  spectrum above ``N_t / 2`` folds back onto the retained harmonics.

Both are estimated at the converged point, without a nonlinear solve (HBM;
EPMC continues it to a short Newton solve, below), by one
linearised step of an *extended* harmonic balance: the harmonics
``H_x = H + {h <= h_ext not in H}`` (``h_ext = min(ext_factor * max(H) + 1,
N_x / 2 - 1)``) on ``N_x = sample_factor * N_t`` samples (4 N_t by default), evaluated at the
point (missing harmonics zero).  Its residual has two parts:

* rows of the missing harmonics: their contact forces ``phi_M`` (the force
  tail), which the truncated solution leaves unbalanced;
* rows of the retained harmonics: ``phi_R(N_x) - phi_R(N_t)``, the change of
  the retained contact forces when the laws are sampled finer (plus the
  Newton residual of the point, below tolerance).

With ``J_x`` the Jacobian of the extended system (dynamic stiffness of every
harmonic + the AFT contact tangent: the machinery of :class:`.hbm.HBMSystem`),
one factorisation gives the two corrections ``dz_t = -J_x^-1 [0; phi_M]`` and
``dz_a = -J_x^-1 [r_R; 0]``; mapped to the full coordinates, their retained
rows are the estimated errors.  For EPMC the extended system is bordered by
the amplitude and phase conditions (amplitude fixed), so the step also gives
the changes of frequency and damping.

**EPMC: the extended system is solved, not stepped once.**  On the FE lap
joint the linear step overshoots: the Newton iteration of the extended EPMC
system from the point does not start in its region of quadratic convergence
(the step changes which samples of which elements stick, slip or separate, a
kink the contact tangent does not see), and its steps alternate in sign.
Measured on the coupled-N joint (coarse mesh, a = 10^-3.5, H = 0..7,
N_t = 128): the first step changes the frequency by +4.3e-3 and the
self-excitation by -31 %, the next ones by -2.6e-3, -3.9e-4, +3.3e-5, ...
(+33 %, -7.4 %, +2.2 %, ...), and the extended solution is 1.4e-3 and -3.7 %
away, against a true error (H = 0..31, N_t = 2048) of 2.0e-3 and 1.7 %.
:meth:`ErrorEstimator.epmc` therefore continues the Newton iteration of the
extended system (full steps, at most :data:`EPMC_MAX_ITER`) until its last
step is below :data:`EPMC_CHANGE_TOL` of the total change of frequency,
self-excitation and state (one or two digits of the estimate; typically 4 to 6
steps); the changes are the estimates, the state's split into truncation and
aliasing keeps the proportion of the first step.  When the iteration does not
settle (it oscillates, e.g. the coupled joint at H = 0..5 and 0..11 at that
amplitude, or its residual stops falling, :data:`EPMC_STALL`) the first step is
reported, as before.  On the SDOF Jenkins
oscillator the first step is already in the quadratic region: frequency and
damping estimates are unchanged to four digits, and the state estimate is the
norm of the whole change rather than the sum of the norms of its two parts
(smaller by up to 2.5x where they partly cancel).

**What does not make them cheaper (measured, round 8).**  Solves of the extended
system that neglect a part of it break the validation: one block Gauss-Seidel
sweep for the truncation step (missing harmonics alone with their ``S_h`` plus the
harmonic projection of the contact tangent, then ``J_RR`` with the coupling) moved
the truncation indicator of the coarse FE joint by factors 0.18 to 12 against the
full solve (fixed and coupled N, H = 0..3, 0..5, 0..7); with the exact missing
block 0.07 to 2.2, and four sweeps still 0.25 to 1.8: the slipping elements'
tangent couples the missing harmonics back to the kept ones strongly.  The
block-Jacobi aliasing step (``J_RR`` alone) moved the aliasing indicator by 0.41 to
1.35.  A chord or Broyden iteration of the extended EPMC solve (the first step's
Jacobian kept) diverges on the coupled joint, and a warm start from the previous
point's extended solution (log10 a 0.05 apart) needed as many Newton steps (5
evaluations) as the start from the first step.  What remains cheaper without
changing a digit: the kept harmonics of the corrections are rebuilt by the main
system (they depend on the kept rows only), half the extended reconstruction.

**Linear points cost no extended solve.**  Where every element sticks and stays
closed (or open) over the whole period, the contact forces are affine in the
coefficients: they have no harmonics above ``H``, and ``4 N_t`` samples give the
same retained ones as ``N_t``.  The right-hand side of the extended step is then
the point's Newton residual alone, and the discretisation errors are zero.  The
estimator compares the forces of the two discretisations (one AFT of each system,
no residual or Jacobian: the contact forces alone decide) and reports
0 when they differ by at most :data:`LINEAR_FORCE_TOL` (measured on the coarse FE
joint: 6e-13..3e-12 coupled, 1e-15 fixed N).  What the extended solve gave there
is the Newton residual's correction: 2e-15..2e-13 at points converged to 1e-10,
up to 1.3e-8 on the default scene's FRC (Newton tolerance 1e-8); every other point
is unchanged to the bit.  On an FRC branch below the slip limit (force x 0.02) that
is most points (69 of 78 on the default scene, the FRC 22.4 -> 17.9 s), which cost
two extended GMRES solves each before.

**FRC points: the error across the branch.**  The error at a fixed frequency
mixes the discretisation error of the curve with its steepness: where the FRC is
steep (the flanks of a sharp peak, a fold) a curve right to 1e-3 is far off at the
same frequency (round 22: estimates of 35 and 1.4 on the 120-point lap joint, where
the curve is 0.46 % and 0.18 % off).  Where the fixed-frequency estimate exceeds
``curve_above`` (the runs: ``analysis.hbm.error_tol``), :meth:`ErrorEstimator.hbm`
also measures it across the branch, against the linearised extended branch's point
nearest to the point (:meth:`ErrorEstimator._across`; the direction of that branch
is a third column of the same solve): ``curve`` (with its truncation and aliasing
parts) and the relative frequency shift ``curve_frequency``.  Validated on the fold
chain against the refined branch's point on the hyperplane normal to the branch
(``tests/solvers/test_indicators.py``; README, "The FRC's error across the branch").

The aliasing step measures the change ``N_t -> 4 N_t``, taken as the error of
``N_t`` itself: the convergence in ``N_t`` of a stick-slip march (a slip
onset falls between samples) is erratic, and the error of ``4 N_t`` is
mostly far smaller (on the lumped cases the change is within 0.7..1.7 of
the true error; ``ALIAS_RICHARDSON`` scales it).

True error (what the indicators estimate, and what the tests check them
against): with ``X`` the full harmonic coefficients of the point and
``X_ref`` those of a converged refined solve of the same point (same
frequency for HBM, same modal amplitude for EPMC; ``H = 0..31`` or more and
``N_t = 2048`` or more), restricted to the harmonics kept,

    e = || X_R - X_ref,R ||_F / || X_ref,R (h >= 1) ||_F ,

i.e. the error of the retained harmonic coefficients relative to the
vibration (the static, harmonic-0 part is in the difference but not in the
reference norm, so a large preload offset does not hide the error).
``error_truncation`` estimates ``e`` for ``N_t -> infinity``,
``error_aliasing`` the part due to ``N_t``, ``error_estimate`` is their sum.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .epmc import EPMCSystem
from .hbm import HBMSystem
from .jacobian import drop_last_column, solve

log = logging.getLogger(__name__)

#: factor from the change N_t -> sample_factor N_t to the error of N_t
ALIAS_RICHARDSON = 1.0
#: Newton steps at most of the extended EPMC solve (:meth:`ErrorEstimator.epmc`)
EPMC_MAX_ITER = 8
#: the extended EPMC solve has settled when its last step is at most this share of
#: the total change of frequency, self-excitation and state
EPMC_CHANGE_TOL = 0.05
#: ... and has failed when the largest structural residual has not fallen by 10 % below
#: its best in this many steps (it grows where the iteration diverges or wanders: at two
#: points of the 480-Gauss-point EPMC it grew at nearly every one of the eight steps,
#: 103 and 31 s for the first step that is then reported; 39.8 and 21.4 s with the test,
#: the same indicators; round 45, docs/hbm.md)
EPMC_STALL = 2
#: GMRES tolerance (relative residual) of the extended solves on the Krylov path.  An
#: estimate needs a digit or two (the EPMC's extended Newton stops at EPMC_CHANGE_TOL):
#: 1e-3 instead of 1e-6 (round 12) changed the indicators of the 96-Gauss-point FRC's
#: gross-slip branch by at most 0.55 % (median 5e-4) and cut their GMRES iterations
#: 3,153 -> 2,031 and their time 0.72x; the EPMC's, by at most 4.6 % (one frequency
#: estimate; median 6e-7).
INDICATOR_RTOL = 1e-3
#: Whether a point's extended solve may reuse the preconditioner built for the last
#: point's (the chord policy of :class:`~.preconditioner_cache.PreconditionerCache`).  Off:
#: a fresh one solves to ``INDICATOR_RTOL`` in one GMRES iteration, the last point's
#: needed 7 to 20 (the points of a branch are a step apart and their slip patterns
#: differ), which cost more than the build they saved.  Measured on the 120-Gauss-point
#: lap joint's stored points, one thread, alternating (load 1.9 to 2.5): the force-20
#: FRC branch's indicators 35.2 / 33.9 s -> 27.5 / 26.9 s (19 -> 39 builds, 922 -> 117
#: GMRES iterations), force 2 30.5 / 28.5 s -> 28.6 / 29.0 s, the EPMC's 27.3 / 27.5 s
#: -> 23.2 / 22.5 s (the extended Newton's steps of one point still share one); the
#: estimates move by at most 0.3 % (HBM) and 0.15 % (EPMC frequency), one EPMC
#: damping estimate by 4.8 % (the GMRES tolerance's effect, ``INDICATOR_RTOL``).
REUSE_ACROSS_POINTS = False
#: Relative frequency step of the central difference of the reconstruction in
#: :meth:`ErrorEstimator._across` (``X`` is smooth in ``omega``: the difference's
#: truncation error is of order ``h^2`` and its round-off of order ``1e-16 / h``, both
#: far below the digit or two an estimate needs).
ACROSS_DOMEGA = 1e-6
#: A point whose contact forces the extended discretisation changes (force harmonics
#: above ``H``, and the retained ones on ``sample_factor N_t`` samples) by at most
#: this share of its retained vibrating force harmonics is linear to round-off
#: (:meth:`ErrorEstimator._linear`): its indicators are 0 without the extended solve.
LINEAR_FORCE_TOL = 1e-9


@dataclass
class ErrorIndicators:
    """Error indicators of one point (all relative, dimensionless).

    Attributes
    ----------
    truncation : float
        Estimated error of the retained coefficients from the harmonics above H.
    aliasing : float
        Estimated error of the retained coefficients from the AFT samples N_t.
    estimate : float
        ``truncation + aliasing``: the estimate of the true error ``e``.
    force_tail : float
        ``||phi_M|| / ||phi_R (h >= 1)||``: contact-force harmonics above H
        against the retained ones (Frobenius norms over elements).
    frequency, damping : float
        EPMC only (NaN for HBM): estimated relative error of the frequency and
        of the damping ratio (truncation and aliasing together).
    curve, curve_truncation, curve_aliasing : float
        HBM only (NaN for EPMC): the error measured across the branch instead of at
        the point's frequency (:meth:`ErrorEstimator.hbm`), its sum and parts; equal
        to ``estimate`` and its parts where that is at most the estimator's
        ``curve_above``.
    curve_frequency : float
        HBM only: ``|d omega| / omega`` of the extended branch's point across the
        branch from this one (0 where ``curve`` is not solved).
    """

    truncation: float
    aliasing: float
    estimate: float
    force_tail: float
    frequency: float = float("nan")
    damping: float = float("nan")
    curve: float = float("nan")
    curve_truncation: float = float("nan")
    curve_aliasing: float = float("nan")
    curve_frequency: float = float("nan")

    def across(self) -> tuple[float, float, float]:
        """``(estimate, truncation, aliasing)`` across the branch where it was
        computed (HBM), else at the point's own parameter (EPMC)."""
        if np.isfinite(self.curve):
            return self.curve, self.curve_truncation, self.curve_aliasing
        return self.estimate, self.truncation, self.aliasing


class ErrorEstimator:
    """Indicators of the points of one :class:`~.hbm.HBMSystem` (see the module doc).

    Parameters
    ----------
    system : HBMSystem
        The system of the points (its harmonics ``H`` and samples ``N_t``).
    ext_factor : int
        Extended harmonics up to ``ext_factor * max(H) + 1``.
    sample_factor : int
        The extended system samples ``sample_factor * N_t`` points per period.
    parallel : bool
        Numba threads for the extended AFT (False in worker processes).
    curve_above : float
        :meth:`hbm` measures the error across the branch (``curve``) at the points
        whose fixed-frequency ``estimate`` exceeds this (0: every point that slips;
        ``inf``: none).  When finite, the branch's direction is a third column of
        every slipping point's extended solve (about 15 % of its time).  The runs
        pass ``analysis.hbm.error_tol``: only a point it would mark needs it.
    """

    def __init__(self, system: HBMSystem, ext_factor: int = 2, sample_factor: int = 4,
                 parallel: bool = True, curve_above: float = 0.0):
        self.system = system
        self.curve_above = float(curve_above)
        H = tuple(system.basis.harmonics)
        nx = int(sample_factor) * system.basis.n_samples
        h_ext = min(int(ext_factor) * max(H) + 1, (nx - 1) // 2)
        extra = tuple(h for h in range(h_ext + 1) if h not in H)
        self.harmonics = H + extra
        self.n_samples = nx
        self.sample_factor = int(sample_factor)
        aft = system.aft
        # without contact unknowns the joint is linear: every indicator is 0, no extension
        self.ext = HBMSystem(system.model, self.harmonics, nx, aft.min_periods,
                             aft.max_periods, parallel=parallel,
                             linear_solver="krylov" if system.krylov else "direct",
                             lin=system.lin) \
            if system.n_z else None
        if self.ext is not None:
            # an estimate needs a few digits, not 1e-11: GMRES stops at INDICATOR_RTOL
            # (changes the indicators by about that, relative); each point builds its
            # own preconditioner (REUSE_ACROSS_POINTS), an EPMC point's Newton steps
            # share it
            self.ext.krylov_rtol = INDICATOR_RTOL
        self._kept = system.basis.hk > 0

    def prepare_forks(self, omega_max: float, xi: float = 0.0) -> None:
        """Make the extended system's one-time pieces before indicator workers fork
        (:meth:`.hbm.HBMSystem.prepare_forks` for its harmonics, up to ``2 h_max + 1``),
        so that the workers share them instead of each making them on its first point
        (1.3 s in each at 480 Gauss points: the flexibility's series, its HODLR and the
        interface operator's split).  Made first, they serve the point system too (its
        harmonics are lower), as they do in a serial run.

        Parameters
        ----------
        omega_max : float
            The highest fundamental frequency of the points [rad/s].
        xi : float
            Self-excitation [1/s] (EPMC).
        """
        if self.ext is not None:
            self.ext.prepare_forks(omega_max, xi)

    # -- helpers ----------------------------------------------------------------
    def _embed(self, A):
        """Rows of the retained harmonics into the extended order (zeros elsewhere)."""
        A = np.asarray(A, dtype=float)
        out = np.zeros((self.ext.n_c,) + A.shape[1:])
        out[:A.shape[0]] = A
        return out

    def _forces(self, aft) -> np.ndarray:
        """Contact-force coefficients of an AFT, tangential and normal rows stacked
        (n_elem rows, n_c of its system) [N]."""
        parts = [aft.Ft] if self.system.friction else []
        if self.system.coupled:
            parts.append(aft.Nc)
        return np.concatenate(parts, axis=0)

    def _force_tail(self, aft) -> float:
        """``||phi_M|| / ||phi_R (h >= 1)||`` of the extended system's AFT (0 without one)."""
        nc = self.system.n_c
        if aft is None:
            return 0.0
        Fc = self._forces(aft)                   # (n_elem rows, n_c_ext)
        kept = np.linalg.norm(Fc[:, :nc][:, self._kept])
        tail = np.linalg.norm(Fc[:, nc:])
        return float(tail / kept) if kept > 0 else (0.0 if tail == 0 else float("inf"))

    def _linear(self, z):
        """Whether the extended discretisation leaves the contact forces unchanged.

        Linear when the extended system's AFT at the contact coefficients ``z``
        (shape (n_z,) of the point's own system, [m]) has no force harmonics above
        ``H`` and the same retained ones as the point's own ``N_t`` samples, both
        to :data:`LINEAR_FORCE_TOL` of the retained vibrating forces: every element
        sticks and stays closed (or open) over the whole period, so the forces are
        affine in the coefficients.  The right-hand side of the extended step is
        then the point's Newton residual alone, and the discretisation errors the
        indicators estimate are zero.

        Returns
        -------
        linear : bool
        aft : AFTResult or None
            The extended system's AFT (its force tail is reported either way; None
            without contact elements).
        """
        s = self.system
        nc = s.n_c
        if not s.n_e:
            return False, None
        z = np.asarray(z, dtype=float)
        aft = self.ext.contact_forces(self._embed(z.reshape(nc, s.n_r)).ravel())
        Fx = self._forces(aft)
        Fk = self._forces(s.contact_forces(z))
        ref = float(np.linalg.norm(Fk[:, self._kept]))
        change = float(np.linalg.norm(Fx[:, nc:]) + np.linalg.norm(Fx[:, :nc] - Fk))
        return ref > 0.0 and change <= LINEAR_FORCE_TOL * ref, aft

    def _split_solve(self, A, r, n_rows, dr_domega=None):
        """``-A^-1`` of the residual ``r`` split into (alias: rows < n_rows, tail: the rest),
        and ``w = -A^-1 dr_domega`` when that is given (else None).

        One solve with the right-hand sides as columns: the dense LU once, or the
        Krylov path's GMRES on the columns in lockstep (each product and preconditioner
        application reads the blocks once for all; :func:`~.gmres.gmres_columns`).
        """
        ra = np.zeros_like(r)
        rt = np.zeros_like(r)
        ra[:n_rows] = r[:n_rows]
        rt[n_rows:] = r[n_rows:]
        cols = [ra, rt] if dr_domega is None else [ra, rt, dr_domega]
        d = solve(A, -np.column_stack(cols))
        return d[:, 0], d[:, 1], (None if dr_domega is None else d[:, 2])

    def _rel(self, dX, X):
        ref = np.linalg.norm(np.asarray(X)[self._kept])
        n = self.system.n_c
        return float(np.linalg.norm(dX[:n]) / ref) if ref > 0 else float("nan")

    # -- HBM ----------------------------------------------------------------------
    def hbm(self, z, omega: float, F, X=None, xi: float = 0.0) -> ErrorIndicators:
        """Indicators of a forced-response point.

        Parameters
        ----------
        z : ndarray, shape (n_z,)
            Contact coefficients of the converged point [m].
        omega : float
            Angular frequency [rad/s].
        F : ndarray, shape (n_c, n_dof)
            Force coefficients of the point [N].
        X : ndarray, shape (n_c, n_dof), optional
            Full coefficients (computed when not given) [m].
        xi : float
            Self-excitation [1/s] (0 for a forced response; the error across the
            branch is measured for a forced response only).

        Returns
        -------
        ErrorIndicators
            With the error across the branch (``curve``, ``curve_frequency``;
            :meth:`_across`) where ``estimate`` exceeds ``curve_above``, else
            ``curve`` equal to ``estimate``.
        """
        s, ext = self.system, self.ext
        if X is None:
            X = s.reconstruct(z, omega, F, xi)
        if not s.n_z:
            return ErrorIndicators(0.0, 0.0, 0.0, 0.0, curve=0.0, curve_truncation=0.0,
                                   curve_aliasing=0.0, curve_frequency=0.0)
        linear, aft = self._linear(z)        # the contact forces alone decide
        if linear:
            return ErrorIndicators(0.0, 0.0, 0.0, force_tail=self._force_tail(aft),
                                   curve=0.0, curve_truncation=0.0, curve_aliasing=0.0,
                                   curve_frequency=0.0)
        if not REUSE_ACROSS_POINTS:
            ext.preconditioner.forget(stage=True)
        # one solve (three columns) per preconditioner: a large low-rank stage is split
        # (no LU) and solved through its capacitance system
        # (preconditioner.LOOSE_SPLIT_MIN)
        ext.preconditioner.single_solve = not REUSE_ACROSS_POINTS
        ext.preconditioner.share_within_point = False
        ze = self._embed(np.asarray(z, dtype=float).reshape(s.n_c, s.n_r)).ravel()
        across = np.isfinite(self.curve_above) and xi == 0.0
        ev = ext.evaluate(ze, omega, self._embed(F), xi=xi,
                          wrt=("omega",) if across else ())
        n_rows = s.n_c * s.n_r
        da, dt, w = self._split_solve(ev.J, ev.R, n_rows,
                                      ev.dR["omega"] if across else None)
        # the kept rows of X depend on the kept rows of z only: the main system
        # rebuilds them (half the harmonics of the extended reconstruction)
        zero = np.zeros_like(F)
        dXa = s.reconstruct(da[:n_rows], omega, zero, xi)
        dXt = s.reconstruct(dt[:n_rows], omega, zero, xi)
        ea = ALIAS_RICHARDSON * self._rel(dXa, X)
        et = self._rel(dXt, X)
        ct, ca, cw = et, ea, 0.0
        if across and et + ea > self.curve_above:
            ct, ca, cw = self._across(z, omega, F, X, w, ((dt, dXt), (da, dXa)))
        return ErrorIndicators(truncation=et, aliasing=ea, estimate=et + ea,
                               force_tail=self._force_tail(ev.aft), curve=ct + ca,
                               curve_truncation=ct, curve_aliasing=ca, curve_frequency=cw)

    def _across(self, z, omega: float, F, X, w, steps):
        """The error across the branch: ``(truncation, aliasing, |d omega| / omega)``.

        At a fixed frequency the error of a point where the response is steep in
        frequency is mostly the shift of the curve along it (near a resonance peak
        or a fold of the FRC the fixed-frequency estimate can be hundreds of times
        the distance between the curves).  The linearised extended branch through
        the fixed-frequency step ``d`` is ``(z + d + w t, omega_0 + t)``, with
        ``w = dz/domega = -J_x^-1 dR/domega`` its direction.  Its point nearest to
        this one, in the retained coefficients relative to their vibration and the
        frequency relative to ``omega_0``, minimises
        ``||X(t) - X_0||^2 / ||X_0,vib||^2 + (t / omega_0)^2`` with ``X(t)`` linearised
        in ``t`` (``X`` is linear in ``z``; its own dependence on ``omega`` by a central
        difference): ``t = -(D . V) / (V . V + ||X_0,vib||^2 / omega_0^2)``, ``D`` the
        change of ``X`` by the step, ``V = dX/dt``.  The change of the retained
        coefficients at that point, reconstructed at ``omega_0 + t``, is the error.
        It is computed for the truncation and the aliasing steps as in :meth:`hbm`;
        ``t = 0`` gives back the fixed-frequency estimate, so the minimum is about at
        most that.  Where ``J_x`` is singular (a fold) ``d`` and ``w`` grow together
        and ``d + w t`` stays finite.

        Parameters
        ----------
        z : ndarray, shape (n_z,)
            Contact coefficients of the point [m].
        omega : float
            Its angular frequency [rad/s].
        F : ndarray, shape (n_c, n_dof)
            Its force coefficients [N].
        X : ndarray, shape (n_c, n_dof)
            Its full coefficients [m].
        w : ndarray, shape (n_z_ext,)
            ``-J_x^-1 dR/domega`` at the point [m s/rad] (solved with the steps).
        steps : tuple of (ndarray, ndarray)
            The fixed-frequency steps (truncation, aliasing): each ``d``, shape
            (n_z_ext,), and the change of ``X`` it makes, shape (n_c, n_dof) [m]
            (:meth:`hbm` has both).

        Returns
        -------
        truncation, aliasing : float
            Relative errors of the retained coefficients across the branch.
        frequency : float
            ``|d omega| / omega`` to the extended branch's nearest point.
        """
        s = self.system
        n_rows = s.n_c * s.n_r
        z = np.asarray(z, dtype=float)
        X0 = np.asarray(X, dtype=float)
        ref2 = float(np.sum(X0[self._kept] ** 2))
        h = ACROSS_DOMEGA * omega
        wk = w[:n_rows]
        V = (s.reconstruct(z + h * wk, omega + h, F)
             - s.reconstruct(z - h * wk, omega - h, F))[:s.n_c] / (2.0 * h)
        out, shift = [], 0.0
        for d, D in steps:
            t = -float(np.sum(D * V)) / (float(np.sum(V * V)) + ref2 / omega ** 2)
            Xt = s.reconstruct(z + d[:n_rows] + t * wk, omega + t, F)
            out.append(self._rel(Xt - X0, X0))
            shift += t
        return out[0], ALIAS_RICHARDSON * out[1], abs(shift) / omega

    # -- EPMC ---------------------------------------------------------------------
    def epmc(self, ep: EPMCSystem, y, max_iter: int | None = None) -> ErrorIndicators:
        """Indicators of a nonlinear-mode point ``y = (zh, omega, xi, log10 a)``.

        The extended EPMC system (same mode, same amplitude) is solved by Newton
        with the amplitude fixed, from the point (missing harmonics zero), to
        :data:`EPMC_CHANGE_TOL` of the changes of frequency, self-excitation and
        state: the changes are the estimated errors.  The first Newton step
        alone (the linear estimate, as for HBM) overshoots on the FE joint,
        where the step changes the stick/slip pattern of the elements (module
        doc, "EPMC"); it is kept for the split of the state error into its
        truncation and aliasing parts, and as the estimate when the Newton
        iteration does not settle in ``max_iter`` steps.

        Parameters
        ----------
        ep : EPMCSystem
            The EPMC system of the point (built on ``self.system``).
        y : ndarray, shape (n_z + 3,)
        max_iter : int, optional
            Newton steps at most (1: the linear estimate only); default
            :data:`EPMC_MAX_ITER`.

        Returns
        -------
        ErrorIndicators
        """
        s, ext = self.system, self.ext
        nz = s.n_z
        y = np.asarray(y, dtype=float)
        omega, xi, lam = float(y[nz]), float(y[nz + 1]), float(y[nz + 2])
        if not nz:
            return ErrorIndicators(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        linear, aft = self._linear(ep.z0 + 10.0 ** lam * y[:nz])
        if linear:
            return ErrorIndicators(0.0, 0.0, 0.0, self._force_tail(aft), 0.0, 0.0)
        X = ep.coefficients(y)
        epx = EPMCSystem(ext, ep.phi, self._embed(ep.F))
        zh = self._embed(y[:nz].reshape(s.n_c, s.n_r)).ravel()
        yx = np.concatenate([zh, [omega, xi, lam]])
        cache = ext.preconditioner
        if not REUSE_ACROSS_POINTS:
            cache.forget(stage=True)
        # the extended Newton's steps share it (a truncated or large low-rank stage is
        # split instead, preconditioner.LOOSE_SPLIT_MIN and LOOSE_SPLIT_SHARED_MIN: its
        # step's alone), and the
        # first build's harmonic stage in any case (their frequencies differ by the
        # estimated errors): their builds are low-rank stages (docs/hbm.md, "Round 44")
        cache.single_solve = False
        cache.share_within_point = True
        R, J, ev = epx.fun(yx)
        n_rows = s.n_c * s.n_r
        nzx = ext.n_z
        # rows: retained harmonics, missing harmonics, amplitude and phase (the last two
        # satisfied at the point; they go with the retained part)
        r_alias = np.zeros_like(R)
        r_alias[:n_rows] = R[:n_rows]
        r_alias[nzx:] = R[nzx:]
        r_tail = np.zeros_like(R)
        r_tail[n_rows:nzx] = R[n_rows:nzx]
        A = drop_last_column(J)          # log10 a fixed
        d = solve(A, -np.column_stack([r_alias, r_tail]))   # both columns in one solve
        da, dt = d[:, 0], d[:, 1]
        # X is affine in zh, but omega and xi move the condensed part too: take the
        # difference of the reconstructions (of the kept harmonics: they depend on the
        # kept rows of zh only, so the main system rebuilds them)
        def kept_X(x):
            return ep.coefficients(np.concatenate([x[:n_rows], x[nzx:nzx + 2], [lam]]))
        X0 = kept_X(yx)
        out = []
        for d in (da, dt):
            yd = np.concatenate([zh + d[:nzx], [omega + d[nzx], xi + d[nzx + 1]]])
            out.append((kept_X(yd) - X0, d[nzx], d[nzx + 1]))
        (dXa, dwa, dxa), (dXt, dwt, dxt) = out
        ea = ALIAS_RICHARDSON * self._rel(dXa, X)
        et = self._rel(dXt, X)
        zeta = xi / (2 * omega)

        def dzeta(dw, dx):
            return (xi + dx) / (2 * (omega + dw)) - zeta
        # the linear step: the two changes add with their signs
        fw = abs(ALIAS_RICHARDSON * dwa + dwt) / abs(omega)
        fz = abs(ALIAS_RICHARDSON * dzeta(dwa, dxa) + dzeta(dwt, dxt)) / abs(zeta) \
            if zeta != 0 else float("nan")
        max_iter = EPMC_MAX_ITER if max_iter is None else int(max_iter)
        x1 = yx[:-1] + ALIAS_RICHARDSON * da + dt
        try:
            sol = self._epmc_newton(epx, yx[:-1], x1, lam, max_iter,
                                    float(np.abs(R[:nzx]).max(initial=0.0)))
        except (np.linalg.LinAlgError, RuntimeError, FloatingPointError) as exc:
            log.debug("extended EPMC solve failed (%s: %s); first step reported",
                      type(exc).__name__, exc)
            sol = None
        if sol is not None:
            # the nonlinear changes; the state's split into truncation and aliasing
            # in the proportion of the linear step
            e = self._rel(kept_X(sol) - X0, X)
            share = et / (et + ea) if et + ea > 0 else 1.0
            et, ea = share * e, (1.0 - share) * e
            fw = abs(sol[nzx] - omega) / abs(omega)
            fz = abs(dzeta(sol[nzx] - omega, sol[nzx + 1] - xi)) / abs(zeta) \
                if zeta != 0 else float("nan")
        return ErrorIndicators(truncation=et, aliasing=ea, estimate=et + ea,
                               force_tail=self._force_tail(ev.aft) if ev is not None else
                               float("nan"), frequency=float(fw), damping=float(fz))

    @staticmethod
    def _epmc_newton(epx: EPMCSystem, x0, x1, lam: float, max_iter: int, r0: float):
        """Newton on the extended EPMC system at fixed ``log10 a = lam`` from the first
        step's result ``x1`` (``x0``: the point, ``r0``: max |R| of its structural
        rows), or None when it does not settle.

        Settled: the last step changes frequency, self-excitation and the state
        by at most :data:`EPMC_CHANGE_TOL` of their total change from ``x0`` (an
        estimate needs a digit or two, not a converged solve).  Failed: the largest
        structural residual has not fallen by 10 % below its best (from ``x1`` on) in
        :data:`EPMC_STALL` steps, or ``max_iter`` steps are made.  When the first
        step has already cut the structural residual to :data:`EPMC_CHANGE_TOL`
        of ``r0`` (the quadratic region: the lumped cases), ``x1`` is returned
        after that one residual evaluation (no Jacobian, no solve); the
        amplitude and phase rows are linear and hold after any step.
        """
        nzx = epx.s.n_z
        x = np.array(x1, dtype=float)
        if max_iter < 2:
            return None
        r1 = epx.residual(np.append(x, lam))
        if np.all(np.isfinite(r1)) and np.abs(r1).max(initial=0.0) <= EPMC_CHANGE_TOL * r0:
            return x
        R, J, _ = epx.fun(np.append(x, lam))
        best, since = np.inf, 0
        for _ in range(max_iter - 1):
            if not np.all(np.isfinite(R)):
                return None
            r = float(np.abs(R[:nzx]).max(initial=0.0))
            best, since = (r, 0) if r < 0.9 * best else (best, since + 1)
            if since >= EPMC_STALL:
                return None
            d = -solve(drop_last_column(J), R)
            x = x + d
            total = np.abs(x - x0)
            small = [np.abs(d[nzx]) <= EPMC_CHANGE_TOL * total[nzx],
                     np.abs(d[nzx + 1]) <= EPMC_CHANGE_TOL * total[nzx + 1],
                     np.linalg.norm(d[:nzx]) <= EPMC_CHANGE_TOL * np.linalg.norm(total[:nzx])]
            if all(small):
                return x if np.all(np.isfinite(x)) else None
            R, J, _ = epx.fun(np.append(x, lam))
        return None


class ToleranceWatch:
    """Warns once per branch when a point's estimated error exceeds the tolerance.

    The estimate is the error across the branch where it was solved (FRC points,
    :meth:`ErrorIndicators.across`), else ``error_estimate``.

    Parameters
    ----------
    tol : float
        The scene's tolerance (``analysis.hbm.error_tol`` / ``analysis.epmc.error_tol``);
        0 never warns.
    what : str
        Name of the analysis in the message (``"hbm"``, ``"epmc"``).
    """

    def __init__(self, tol: float, what: str):
        self.tol = float(tol)
        self.what = what
        self.warned: set = set()

    def check(self, branch, ind: ErrorIndicators | None, point: int, where: str) -> bool:
        """True when ``ind`` is above the tolerance (the first time per branch: a warning).

        Parameters
        ----------
        branch : hashable
            Branch of the point.
        ind : ErrorIndicators or None
        point : int
            Row of the point in the file.
        where : str
            Where the point is (e.g. ``"omega = 960"``), for the message.
        """
        if ind is None or not self.tol > 0:
            return False
        estimate, truncation, aliasing = ind.across()
        if not estimate > self.tol:
            return False
        if branch not in self.warned:
            self.warned.add(branch)
            log.warning(
                "%s branch %s: estimated discretisation error %.2g%s at point %d (%s) "
                "exceeds %s.error_tol = %.2g (truncation %.2g: raise the harmonics; aliasing "
                "%.2g: raise n_samples); further points of the branch are marked in "
                "/%s/error_* and on the figure, not warned again", self.what, branch,
                estimate, " across the branch" if np.isfinite(ind.curve) else "", point,
                where, f"analysis.{self.what}", self.tol, truncation, aliasing, self.what)
        return True


def safe_indicators(fn, *args) -> ErrorIndicators | None:
    """``fn(*args)``, or None (with a debug message) when the extended solve fails."""
    try:
        return fn(*args)
    except (np.linalg.LinAlgError, RuntimeError, ValueError, FloatingPointError) as exc:
        log.debug("error indicators not computed: %s: %s", type(exc).__name__, exc)
        return None
