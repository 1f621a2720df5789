"""Cross-check of a time-marching steady state against a harmonic-balance solution.

Both methods describe the same periodic response by coefficients in the order
``[0, 1c, 1s, 2c, 2s, ...]`` (``/transient/harmonics`` and ``/hbm/X``).  The
comparison is pure; :mod:`jointsim.analyses.crosscheck` writes ``/crosscheck``.  The
check reports, for every harmonic both keep, the norm of the difference

* relative to the norm of the first harmonic (``rel_diff``: how much the
  harmonic matters for the response), and
* relative to the harmonic's own norm (``rel_own``: how well it is resolved).

The DC part needs care.  Averaging the equation of motion over a period gives
``K X0 + Tt^T mean(f_t) - Tn^T mean(N) = F0`` for *any* periodic solution,
so two solutions whose DC parts differ by ``d0`` differ in their mean contact
forces by ``K d0`` (nothing else can hold a static offset).  A slider that
sticks for the whole period keeps whatever force its history left in it:
that offset is legitimate, and the two methods may differ there (HBM picks
one of the admissible DC states, time marching the one its transient left).
A slider that slips within the period has its history wiped, so its mean
force is fixed by the motion.  The check therefore solves for the mean
force differences ``df`` (and ``dN``) that explain ``d0`` and calls the DC
difference *history* when they sit only on elements that never reach
macroslip during the period (and the normal loads agree); otherwise the DC
difference is a real disagreement.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..harmonics import harmonic_amplitude
from ..harmonics import rows as _rows

log = logging.getLogger(__name__)

#: Relative closeness to the slip force that counts as macroslip.
SLIP_RTOL = 1e-6

#: A harmonic smaller than this fraction of the first one is round-off: no
#: ``rel_own`` for it.
OWN_FLOOR = 1e-12


@dataclass(frozen=True)
class CrossCheck:
    """Harmonic-by-harmonic comparison of two periodic solutions.

    Attributes
    ----------
    harmonics : tuple of int
        Harmonics compared (kept by both).
    rel_diff : ndarray, shape (n_h,)
        ``||X_a,h - X_b,h|| / ||X_b,1||`` per harmonic (cos and sin rows and all
        DOFs together) [-].
    rel_own : ndarray, shape (n_h,)
        ``||X_a,h - X_b,h|| / ||X_b,h||`` (``nan`` where ``X_b,h`` is below
        ``OWN_FLOOR`` times ``||X_b,1||``, i.e. round-off) [-].
    amplitude_a, amplitude_b : ndarray, shape (n_dof,)
        First-harmonic amplitude ``sqrt(c^2 + s^2)`` of each DOF [m].
    dc_diff : float
        ``||X_a,0 - X_b,0|| / ||X_b,1||`` [-] (0 when harmonic 0 is not compared).
    dc_history : bool
        The DC difference exceeds ``tol`` and is explained by force offsets
        locked in elements that stick throughout the period.
    df : ndarray, shape (n_e,)
        Mean tangential force differences that explain the DC difference [N].
    dN : ndarray, shape (n_e,)
        Mean normal load differences (coupled normal load; zeros otherwise) [N].
    memory : ndarray of bool, shape (n_e,)
        Elements that never reach macroslip in solution ``a``'s period.
    agree : bool
        Every harmonic >= 1 within ``tol`` (``rel_diff``), and the DC part within
        ``tol`` or explained by history.
    tol : float
    verdict : str
        One line for the log and the report.
    step_error : float
        Time-step error indicator of solution ``a`` (first harmonic, relative;
        nan when not given).
    rel_diff_corrected : ndarray, shape (n_h,), or None
        ``rel_diff`` of ``Xa + dXa`` (the march corrected by its estimated
        step-size error) against ``Xb``.
    """

    harmonics: tuple
    rel_diff: np.ndarray
    rel_own: np.ndarray
    amplitude_a: np.ndarray
    amplitude_b: np.ndarray
    dc_diff: float
    dc_history: bool
    df: np.ndarray
    dN: np.ndarray
    memory: np.ndarray
    agree: bool
    tol: float
    verdict: str
    step_error: float = float("nan")
    rel_diff_corrected: np.ndarray | None = None


def first_harmonic_amplitude(X, harmonics) -> np.ndarray:
    """``sqrt(X_1c^2 + X_1s^2)`` per DOF, shape (n_dof,)."""
    if 1 not in _rows(harmonics):
        raise ValueError("harmonic 1 is not among the harmonics")
    return harmonic_amplitude(harmonics, X, 1)


def memory_elements(f, N, law) -> np.ndarray:
    """Elements that never reach macroslip over a period.

    Parameters
    ----------
    f, N : ndarray, shape (n_e, n)
        Tangential force [N] and normal load [N] over one period.
    law : jointsim.contact.TangentialLaw

    Returns
    -------
    ndarray of bool, shape (n_e,)
        True where ``|f| < mu N`` at every sample with ``N > 0`` (some slider
        keeps its history); False for elements that are separated for the
        whole period (no force, no memory) or have no friction.
    """
    f = np.atleast_2d(f)
    N = np.atleast_2d(N)
    if not law.can_slip:
        return np.zeros(f.shape[0], dtype=bool)
    slip = law.slip_force(N)
    loaded = N > 0.0
    at_limit = loaded & (np.abs(f) >= slip * (1.0 - SLIP_RTOL))
    return loaded.any(axis=1) & ~at_limit.any(axis=1)


def explain_dc(d0, model):
    """Mean contact-force differences that hold a DC displacement difference.

    Solves ``Tt^T df - Tn^T dN = -K d0`` (least squares; ``dN`` only with a
    coupled normal load).

    Parameters
    ----------
    d0 : ndarray, shape (n_dof,)
        DC difference [m].
    model : jointsim.model.StructuralModel

    Returns
    -------
    df, dN : ndarray, shape (n_e,)
        Tangential and normal mean force differences [N].
    residual : float
        ``||Tt^T df - Tn^T dN + K d0|| / ||K d0||`` (0 when ``d0`` is 0) [-].
    """
    c = model.contacts
    ne = c.n_elements
    rhs = -np.asarray(sp.csr_matrix(model.K) @ d0).ravel()
    if ne == 0:
        nrm = np.linalg.norm(rhs)
        return np.zeros(0), np.zeros(0), (1.0 if nrm > 0 else 0.0)
    cols = [sp.csr_matrix(c.Tt).T.toarray()]
    if c.coupled:
        cols.append(-sp.csr_matrix(c.Tn).T.toarray())
    A = np.hstack(cols)
    sol, *_ = np.linalg.lstsq(A, rhs, rcond=None)
    nrm = np.linalg.norm(rhs)
    res = np.linalg.norm(A @ sol - rhs) / nrm if nrm > 0 else 0.0
    df = sol[:ne]
    dN = sol[ne:] if c.coupled else np.zeros(ne)
    return df, dN, float(res)


def cross_check(Xa, harmonics_a, Xb, harmonics_b, *, model=None, loops=None,
                tol: float = 1e-3, step_error=None) -> CrossCheck:
    """Compare solution ``a`` (time marching) with solution ``b`` (harmonic balance).

    Parameters
    ----------
    Xa, Xb : ndarray, shape (n_coeff_a, n_dof), (n_coeff_b, n_dof)
        Coefficients in the order ``[0, 1c, 1s, ...]`` of their harmonics [m].
    harmonics_a, harmonics_b : sequence of int
    model : jointsim.model.StructuralModel, optional
        Needed to explain a DC difference by the slider history.
    loops : tuple of ndarray, optional
        ``(f, N)`` of solution ``a``'s elements over its period, shape
        (n_e, n) each, to tell which elements keep a history.
    tol : float
        Agreement tolerance on ``rel_diff``.
    step_error : jointsim.solvers.march_accuracy.StepError, optional
        The time-step error indicator of solution ``a`` (on ``harmonics_a``):
        the verdict then says whether the step size explains the difference
        (the march plus its estimated step error agrees with ``b``) or not.

    Returns
    -------
    CrossCheck
    """
    Xa, Xb = np.asarray(Xa, dtype=float), np.asarray(Xb, dtype=float)
    ra, rb = _rows(harmonics_a), _rows(harmonics_b)
    common = tuple(h for h in harmonics_a if h in rb)
    if 1 not in common:
        raise ValueError("both solutions must keep harmonic 1")
    ref = np.linalg.norm(Xb[rb[1]])
    ref = ref if ref > 0 else 1.0
    rel, own = [], []
    for h in common:
        d = np.linalg.norm(Xa[ra[h]] - Xb[rb[h]])
        nb = np.linalg.norm(Xb[rb[h]])
        rel.append(d / ref)
        own.append(d / nb if nb > OWN_FLOOR * ref else np.nan)
    rel, own = np.array(rel), np.array(own)
    ne = model.contacts.n_elements if model is not None else 0
    df, dN = np.zeros(ne), np.zeros(ne)
    memory = np.zeros(ne, dtype=bool)
    dc_diff, dc_history = 0.0, False
    if 0 in common:
        d0 = Xa[ra[0]][0] - Xb[rb[0]][0]
        dc_diff = float(np.linalg.norm(d0) / ref)
        if dc_diff > tol and model is not None and ne:
            df, dN, _res = explain_dc(d0, model)
            if loops is not None:
                f, N = loops
                memory = memory_elements(f, N, model.contacts.law)
                scale = np.maximum(model.contacts.law.slip_force(np.max(N, axis=1)),
                                   np.max(np.abs(f), axis=1))
                scale = np.where(scale > 0, scale, 1.0)
                big_t = np.abs(df) > tol * scale
                big_n = np.abs(dN) > tol * np.maximum(np.max(N, axis=1), 1e-300)
                dc_history = bool(memory.any() and not np.any(big_t & ~memory)
                                  and not np.any(big_n))
    higher = np.array([h != 0 for h in common])
    harmonics_ok = bool(np.all(rel[higher] <= tol))
    dc_ok = dc_diff <= tol or dc_history
    agree = harmonics_ok and dc_ok
    worst = int(np.argmax(np.where(higher, rel, -np.inf)))
    parts = [f"harmonic {common[worst]} differs by {rel[worst]:.2e} of the first harmonic"]
    if 0 in common:
        if dc_diff <= tol:
            parts.append(f"DC within tolerance ({dc_diff:.2e})")
        elif dc_history:
            parts.append(f"DC differs by {dc_diff:.2e}: explained by forces locked in "
                         f"{int(memory.sum())} element(s) that stick all period (slider "
                         "history, a legitimate difference)")
        else:
            parts.append(f"DC differs by {dc_diff:.2e} and the slider history does not "
                         "explain it")
    e_step, rel_c = float("nan"), None
    if step_error is not None:
        e_step = float(step_error.value)
        Xc = Xa + np.asarray(step_error.dX)
        rel_c = np.array([np.linalg.norm(Xc[ra[h]] - Xb[rb[h]]) / ref for h in common])
        worst_c = float(np.max(np.where(higher, rel_c, -np.inf)))
        if harmonics_ok:
            if e_step > tol:
                parts.append(f"but the march's time-step error indicator is {e_step:.2e} > "
                             f"tol: the agreement is partly luck; refine the step")
        elif worst_c <= tol:
            parts.append(f"explained by the time step: its error indicator is "
                         f"{e_step:.2e} and the march corrected by it differs by "
                         f"{worst_c:.2e} <= tol; raise analysis.transient.steps_per_period")
        elif worst_c < 0.5 * rel[worst]:
            parts.append(f"partly the time step (indicator {e_step:.2e}; corrected by it the "
                         f"march differs by {worst_c:.2e}): raise steps_per_period, and see "
                         "the remaining causes in docs/transient.md")
        else:
            parts.append(f"not the time step (indicator {e_step:.2e}; corrected by it the "
                         f"march still differs by {worst_c:.2e}): the march is not steady, "
                         "or HBM is not converged in its harmonics or samples (docs/transient.md)")
    verdict = ("agree: " if agree else "DISAGREE: ") + "; ".join(parts)
    return CrossCheck(common, rel, own, first_harmonic_amplitude(Xa, harmonics_a),
                      first_harmonic_amplitude(Xb, harmonics_b), dc_diff, dc_history,
                      df, dN, memory, agree, float(tol), verdict, e_step, rel_c)


# --------------------------------------------------------------------------
# Against harmonic-balance solution points (in memory)
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class HBMSolutions:
    """The solution points of a harmonic-balance FRC, as the cross-check uses them.

    The HBM runner returns this object (the points it wrote to ``/hbm``, in the
    same order), so later analyses compare with it in memory;
    :func:`jointsim.io.hbm_points.read_hbm_solutions` reads the same from a
    finished file.

    Attributes
    ----------
    omega : ndarray, shape (n_points,)
        Frequency of each point [rad/s].
    X : ndarray, shape (n_points, n_coeff, n_dof)
        Harmonic coefficients ``[0, 1c, 1s, ...]`` [m].
    harmonics : tuple of int
    n_samples : int or None
        AFT samples per period of the FRC (None: unknown).
    q : ndarray, shape (n_points, n_z), optional
        Contact-coordinate coefficients (the Newton unknowns) [m].
    branch : ndarray of int, shape (n_points,), optional
        Branch of each point (index into ``force_scale``).
    force_scale : ndarray, shape (n_branches,), optional
        Excitation multiplier of each branch.
    """

    omega: np.ndarray
    X: np.ndarray
    harmonics: tuple
    n_samples: int | None = None
    q: np.ndarray | None = None
    branch: np.ndarray | None = None
    force_scale: np.ndarray | None = None

    @property
    def n_points(self) -> int:
        return int(self.omega.size)


@dataclass(frozen=True)
class HBMPoint:
    """A stored HBM solution near a requested frequency.

    Attributes
    ----------
    X : ndarray, shape (n_coeff, n_dof)
    harmonics : tuple of int
    omega : float
        The frequency the solution belongs to [rad/s].
    points : tuple of int
        The stored HBM point(s) used.
    interpolated : bool
        True when ``X`` is interpolated linearly in omega between two stored
        points (no HBM point sits at the frequency); such an ``X`` is only a
        seed, not a solution.
    """

    X: np.ndarray
    harmonics: tuple
    omega: float
    points: tuple
    interpolated: bool


def hbm_solution_at(solutions: HBMSolutions | None, omega: float,
                    force_scale: float | None = None, X_near=None,
                    rtol: float = 1e-9) -> HBMPoint | None:
    """The HBM solution at (or around) ``omega`` among stored solution points.

    ``solutions`` is an :class:`HBMSolutions` (the HBM runner's result, or
    :func:`jointsim.io.hbm_points.read_hbm_solutions` of a file).  With
    ``branch`` (the branch of each point) brackets never span two branches,
    and with ``force_scale`` (one entry per branch) only branches of the
    requested force scale are used.  Where a branch passes ``omega`` several
    times (turning points), the solution nearest ``X_near`` is taken.  Between
    stored points the coefficients are interpolated linearly (flagged
    ``interpolated``): :func:`hbm_reference` uses that only to pick the seed
    of a Newton solve at exactly ``omega``.

    Returns
    -------
    HBMPoint or None
        None when no stored branch reaches ``omega``.
    """
    sols = solutions
    if sols is None:
        return None
    w = sols.omega
    X = sols.X
    hs = sols.harmonics
    n = w.size
    ok = _scale_mask(sols, force_scale)
    branch = sols.branch if sols.branch is not None else np.zeros(n, dtype=int)
    cands = []
    for i in np.flatnonzero(ok & np.isclose(w, omega, rtol=rtol, atol=0.0)):
        cands.append(HBMPoint(X[i], hs, float(w[i]), (int(i),), False))
    for i in range(n - 1):
        if not (ok[i] and ok[i + 1]) or branch[i] != branch[i + 1]:
            continue
        lo, hi = sorted((w[i], w[i + 1]))
        if lo < omega < hi:
            s = (omega - w[i]) / (w[i + 1] - w[i])
            Xi = (1.0 - s) * X[i] + s * X[i + 1]
            cands.append(HBMPoint(Xi, hs, float(omega), (i, i + 1), True))
    if not cands:
        return None
    exact = [c for c in cands if not c.interpolated]
    pool = exact or cands
    if X_near is None or len(pool) == 1:
        return pool[0]
    rows = _rows(hs)[1]
    return min(pool, key=lambda c: np.linalg.norm(c.X[rows] - np.asarray(X_near)[rows]))


def _scale_mask(sols: HBMSolutions, force_scale) -> np.ndarray:
    """Stored points that belong to a branch of ``force_scale`` (all when None)."""
    n = sols.n_points
    ok = np.ones(n, dtype=bool)
    if force_scale is not None and sols.force_scale is not None:
        branch = sols.branch if sols.branch is not None else np.zeros(n, dtype=int)
        scales = np.atleast_1d(sols.force_scale)
        ok &= np.isclose(scales[branch], force_scale, rtol=1e-12)
    return ok


@dataclass(frozen=True)
class HBMReference:
    """A harmonic-balance solution at exactly the frequency of a time-marching run.

    Attributes
    ----------
    X : ndarray, shape (n_coeff, n_dof)
        Coefficients ``[0, 1c, 1s, ...]`` [m].
    harmonics : tuple of int
    omega : float
        [rad/s]
    source : str
        Where it comes from: ``"stored point i"`` (a point of ``/hbm`` at the
        frequency), or ``"solved ..."`` with the seed of the Newton solve.
    points : tuple of int
        Stored HBM points used (as solution or seed).
    n_samples : int
        AFT samples of the solve.
    residual : float
        ``max |R|`` over the force scale [-] (nan for a stored point).
    wall_time : float
        [s]
    convergence : jointsim.results.Convergence
    """

    X: np.ndarray
    harmonics: tuple
    omega: float
    source: str
    points: tuple
    n_samples: int
    residual: float
    wall_time: float
    convergence: object


def hbm_reference(solutions, scene, model, omega: float, force_scale: float, X_near=None,
                  harmonics_near=None) -> HBMReference:
    """Solve the harmonic balance at exactly ``omega`` with the settings of an FRC.

    The harmonics and AFT samples are those the FRC used (``harmonics``,
    ``n_samples`` of ``solutions``); the AFT march limits and
    the tolerance come from ``scene.analysis.hbm`` when the scene has one.  A
    stored point at ``omega`` (same force scale) is taken as it is.
    Otherwise Newton (:func:`jointsim.solvers.hbm.solve_point`) is seeded, in
    turn, from

    1. the stored point of the same force scale nearest ``omega`` on a branch
       that passes ``omega`` (of several passes, the one nearest ``X_near``
       in the first harmonic), or else the stored point nearest in frequency;
    2. zero (whose first Newton step is the stuck linear response);
    3. ``X_near`` itself (the time-marching solution),

    until one converges.  The seed only picks which solution Newton finds
    where there are several; the solution is HBM's own.

    Parameters
    ----------
    solutions : HBMSolutions
        The FRC's solution points.
    scene : jointsim.scene.Scene
    model : jointsim.model.StructuralModel
    omega : float
        [rad/s]
    force_scale : float
        Multiplier of the harmonic loads.
    X_near : ndarray, shape (n_coeff_near, n_dof), optional
        The solution to compare with (selects among several HBM solutions).
    harmonics_near : sequence of int, optional
        Harmonics of the rows of ``X_near``.

    Returns
    -------
    HBMReference
        With ``convergence.success`` False when no seed converged (``X`` is
        then the last iterate).
    """
    import time

    from ..results import NOT_CONVERGED, SUCCESS, Convergence
    from .hbm import HBMSystem, solve_point
    t0 = time.perf_counter()
    sols = solutions
    hs = sols.harmonics
    near = _in_harmonics(X_near, harmonics_near, hs, model.n_dof)
    settings = scene.analysis.hbm if scene is not None else None
    n_samples = int(sols.n_samples if sols.n_samples is not None
                    else getattr(settings, "n_samples", 128))
    pt = hbm_solution_at(sols, omega, force_scale, near)
    if pt is not None and not pt.interpolated:
        i = pt.points[0]
        return HBMReference(pt.X, hs, pt.omega, f"stored point {i}", pt.points, n_samples,
                            np.nan, time.perf_counter() - t0,
                            Convergence(True, SUCCESS, f"stored HBM point {i} at omega", 0))
    system = HBMSystem(model, hs, n_samples, getattr(settings, "min_periods", 2),
                       getattr(settings, "max_periods", 50))
    F = system.force_coefficients(force_scale)
    tol = min(float(getattr(settings, "tol", 1e-10)), 1e-10)
    max_iter = max(int(getattr(settings, "max_iter", 20)), 30)
    seeds = _seeds(sols, system, pt, omega, force_scale, near)
    sol, used = None, seeds[-1]
    for seed in seeds:
        z0 = np.asarray(seed[2], dtype=float)
        if z0.shape != (system.n_z,):
            continue
        sol = solve_point(system, omega, F, z0=z0, tol=tol, max_iter=max_iter)
        used = seed
        if sol.convergence.success:
            break
    c = sol.convergence
    source = f"solved at omega by Newton from {used[0]}"
    conv = Convergence(c.success, SUCCESS if c.success else NOT_CONVERGED,
                       f"{source}: {c.message}", c.iterations)
    return HBMReference(sol.X, hs, float(omega), source, used[1], n_samples,
                        sol.residual / max(float(np.abs(F).max(initial=0.0)), 1e-300),
                        time.perf_counter() - t0, conv)


def _in_harmonics(X, harmonics_x, harmonics, n_dof: int):
    """``X`` (rows of ``harmonics_x``) on the rows of ``harmonics``, zero where it
    has no harmonic; None without ``X`` or ``harmonics_x``.

    Returns
    -------
    ndarray, shape (n_coeff, n_dof), or None
    """
    if X is None or harmonics_x is None:
        return None
    rows = _rows(harmonics)
    rn = _rows(tuple(harmonics_x))
    out = np.zeros((max(s.stop for s in rows.values()), n_dof))
    for h, sl in rows.items():
        if h in rn:
            out[sl] = np.asarray(X)[rn[h]]
    return out


def _seeds(sols: HBMSolutions, system, pt: HBMPoint | None, omega: float, force_scale,
           near) -> list:
    """Newton seeds of :func:`hbm_reference`, in the order they are tried.

    Returns
    -------
    list of tuple
        ``(description, stored points used, contact coordinates z0 (n_z,))``.
    """
    seeds = []
    w = sols.omega

    def stored_seed(i):
        z = sols.q[i] if sols.q is not None else system.contact_coordinates(sols.X[i])
        return (f"stored point {i} (omega = {w[i]:.8g})", (i,), z)

    if pt is not None:   # a branch passes omega: the nearer end of its bracket
        seeds.append(stored_seed(min(pt.points, key=lambda j: abs(w[j] - omega))))
    elif sols.n_points:
        ok = np.flatnonzero(_scale_mask(sols, force_scale))
        if ok.size:
            seeds.append(stored_seed(int(ok[np.argmin(np.abs(w[ok] - omega))])))
    seeds.append(("the stuck linear response", (), np.zeros(system.n_z)))
    if near is not None:
        seeds.append(("the time-marching solution", (), system.contact_coordinates(near)))
    return seeds
