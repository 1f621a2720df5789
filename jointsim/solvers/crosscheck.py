"""Cross-check of a time-marching steady state against a harmonic-balance solution.

Both methods describe the same periodic response by coefficients in the order
``[0, 1c, 1s, 2c, 2s, ...]`` (``/transient/harmonics`` and ``/hbm/X``).  The
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

log = logging.getLogger(__name__)

#: Relative closeness to the slip force that counts as macroslip.
SLIP_RTOL = 1e-6


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
        ``||X_a,h - X_b,h|| / ||X_b,h||`` (``nan`` where ``X_b,h`` is 0) [-].
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


def _rows(harmonics):
    """Row slices of every harmonic in the coefficient order ``[0, 1c, 1s, ...]``."""
    out, r = {}, 0
    for h in harmonics:
        n = 1 if h == 0 else 2
        out[int(h)] = slice(r, r + n)
        r += n
    return out


def first_harmonic_amplitude(X, harmonics) -> np.ndarray:
    """``sqrt(X_1c^2 + X_1s^2)`` per DOF, shape (n_dof,)."""
    rows = _rows(harmonics)
    if 1 not in rows:
        raise ValueError("harmonic 1 is not among the harmonics")
    c, s = np.asarray(X)[rows[1]]
    return np.hypot(c, s)


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
    if law.kind not in ("bank_anchor", "bank_scaled"):
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
    if c.kernels.coupled:
        cols.append(-sp.csr_matrix(c.Tn).T.toarray())
    A = np.hstack(cols)
    sol, *_ = np.linalg.lstsq(A, rhs, rcond=None)
    nrm = np.linalg.norm(rhs)
    res = np.linalg.norm(A @ sol - rhs) / nrm if nrm > 0 else 0.0
    df = sol[:ne]
    dN = sol[ne:] if c.kernels.coupled else np.zeros(ne)
    return df, dN, float(res)


def cross_check(Xa, harmonics_a, Xb, harmonics_b, *, model=None, loops=None,
                tol: float = 1e-3) -> CrossCheck:
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
        own.append(d / nb if nb > 0 else np.nan)
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
    verdict = ("agree: " if agree else "DISAGREE: ") + "; ".join(parts)
    return CrossCheck(common, rel, own, first_harmonic_amplitude(Xa, harmonics_a),
                      first_harmonic_amplitude(Xb, harmonics_b), dc_diff, dc_history,
                      df, dN, memory, agree, float(tol), verdict)


# --------------------------------------------------------------------------
# Against the /hbm group of a result file
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class HBMPoint:
    """An HBM solution at a requested frequency, read from a result file.

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
        points (no HBM point sits at the frequency); the interpolation error
        is not controlled.
    """

    X: np.ndarray
    harmonics: tuple
    omega: float
    points: tuple
    interpolated: bool


def hbm_solution_at(h5, omega: float, force_scale: float | None = None, X_near=None,
                    rtol: float = 1e-9) -> HBMPoint | None:
    """The HBM solution at ``omega`` from ``/hbm`` (DESIGN §4 paths).

    Uses ``/hbm/omega`` [n_points], ``/hbm/X`` [n_points, n_coeff, n_dof] and
    ``/hbm/harmonics``; with ``/hbm/branch`` [n_points] (the branch of each
    point) brackets never span two branches, and with ``/hbm/force_scale``
    (one entry per branch, indexed by ``/hbm/branch``) only branches of the
    requested force scale are used.  Where a branch passes ``omega`` several
    times (turning points), the solution nearest ``X_near`` is taken.

    Returns
    -------
    HBMPoint or None
        None when no stored branch reaches ``omega``.
    """
    if "hbm/omega" not in h5 or "hbm/X" not in h5:
        return None
    w = h5["hbm/omega"][()]
    X = h5["hbm/X"]
    hs = tuple(int(h) for h in h5["hbm/harmonics"][()])
    n = w.size
    ok = np.ones(n, dtype=bool)
    branch = h5["hbm/branch"][()] if "hbm/branch" in h5 else np.zeros(n, dtype=int)
    if force_scale is not None and "hbm/force_scale" in h5:
        scales = np.atleast_1d(h5["hbm/force_scale"][()])
        ok &= np.isclose(scales[branch], force_scale, rtol=1e-12)
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


def cross_check_file(writer, scene, model, result, tol: float = 1e-3) -> CrossCheck | None:
    """Cross-check a steady time-marching result against ``/hbm`` of the same file.

    Writes ``/crosscheck/*``: ``harmonics``, ``rel_diff``, ``rel_own``,
    ``amplitude_transient``, ``amplitude_hbm``, ``df``, ``dN``, ``memory`` and
    attributes ``omega``, ``dc_diff``, ``dc_history``, ``agree``, ``tol``,
    ``verdict``, ``hbm_points``, ``interpolated``.

    Parameters
    ----------
    writer : jointsim.io.hdf5.ResultWriter
    scene : jointsim.scene.Scene
    model : jointsim.model.StructuralModel
    result : jointsim.solvers.transient.SteadyResult
    tol : float

    Returns
    -------
    CrossCheck or None
        None (and a warning) when no HBM solution reaches the frequency.
    """
    from ..io.hdf5 import unit
    ht = result.harmonics
    hb = _rows(tuple(int(h) for h in writer.h5["hbm/harmonics"][()])) \
        if "hbm/harmonics" in writer.h5 else {}
    Xnear = None
    if 1 in hb:
        Xnear = np.zeros((max(s.stop for s in hb.values()), model.n_dof))
        Xnear[hb[1]] = result.X[_rows(ht)[1]]
    pt = hbm_solution_at(writer.h5, result.omega, result.force_scale, Xnear)
    if pt is None:
        log.warning("cross-check: no HBM solution at omega = %g (force scale %g) in the "
                    "file; nothing compared", result.omega, result.force_scale)
        writer.group("crosscheck", omega=result.omega, agree=False,
                     verdict="no HBM solution at this frequency")
        return None
    n = result.last.f.shape[1] - 1
    loops = (result.last.f[:, :n], result.last.N[:, :n])
    cc = cross_check(result.X, ht, pt.X, pt.harmonics, model=model, loops=loops, tol=tol)
    if pt.interpolated:
        cc_verdict = cc.verdict + (f" (HBM interpolated between points {pt.points}; "
                                   "the interpolation error is not controlled)")
    else:
        cc_verdict = cc.verdict
    writer.group("crosscheck", omega=result.omega, force_scale=result.force_scale,
                     dc_diff=cc.dc_diff, dc_history=cc.dc_history, agree=cc.agree,
                     tol=cc.tol, verdict=cc_verdict, hbm_points=np.asarray(pt.points),
                     interpolated=pt.interpolated)
    units = model.units
    one = unit("dimensionless", units)
    writer.write("crosscheck/harmonics", np.asarray(cc.harmonics, dtype=np.int64), "1",
                 "harmonics compared")
    writer.write("crosscheck/rel_diff", cc.rel_diff, one,
                 "||X_tm,h - X_hbm,h|| / ||X_hbm,1|| per harmonic")
    writer.write("crosscheck/rel_own", cc.rel_own, one,
                 "||X_tm,h - X_hbm,h|| / ||X_hbm,h|| per harmonic")
    d = unit("displacement", units)
    writer.write("crosscheck/amplitude_transient", cc.amplitude_a, d,
                 "first-harmonic amplitude per DOF, time marching")
    writer.write("crosscheck/amplitude_hbm", cc.amplitude_b, d,
                 "first-harmonic amplitude per DOF, harmonic balance")
    F = unit("force", units)
    writer.write("crosscheck/df", cc.df, F, "mean tangential force differences that hold "
                 "the DC difference")
    writer.write("crosscheck/dN", cc.dN, F, "mean normal load differences")
    writer.write("crosscheck/memory", cc.memory, "1",
                 "elements that stick all period (keep their history)")
    (log.info if cc.agree else log.warning)("cross-check at omega = %g: %s", result.omega,
                                            cc_verdict)
    return cc
