"""Right-preconditioned restarted GMRES, for one right-hand side or several at once.

:func:`gmres` solves ``A x = b``; :func:`gmres_columns` solves ``A X = B`` for the
columns of ``B`` with one Krylov space per column, advanced in lockstep so that the
operator and the preconditioner are applied to all active columns in one call.  On
the structured HBM Jacobian (:mod:`jointsim.solvers.jacobian`) a product with two
columns reads the per-harmonic blocks once, as one does: the error indicators'
two extended solves per point (:mod:`jointsim.solvers.indicators`) cost about one.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.linalg as sla

#: Relative residual ``|b - A x| / |b|`` at which GMRES stops.
KRYLOV_RTOL = 1e-11
#: GMRES restart length and iteration limit.
KRYLOV_RESTART = 80
KRYLOV_MAXITER = 400
#: GMRES stops (stagnation) after a restart cycle that reduced the true residual by
#: less than this factor.
STAGNATION = 0.5


class GMRESResult(NamedTuple):
    """What :func:`gmres` returns."""

    x: np.ndarray
    iterations: int
    relres: float
    at_floor: bool


def gmres(matvec, b, psolve, rtol: float = KRYLOV_RTOL, restart: int = KRYLOV_RESTART,
          maxiter: int = KRYLOV_MAXITER, x0=None):
    """Right-preconditioned restarted GMRES for ``A x = b`` (real).

    Minimises ``|b - A P^-1 u|`` over the Krylov space of ``A P^-1``, with
    ``x = P^-1 u`` (so the residual it monitors is the true one, up to
    round-off; it is recomputed at every restart and at the end).

    Parameters
    ----------
    matvec : callable
        ``v -> A v``.
    b : ndarray, shape (n,)
    psolve : callable
        ``v -> P^-1 v``.
    rtol : float
        Stop at ``|b - A x| <= rtol |b|``.
    restart, maxiter : int
    x0 : ndarray, shape (n,), optional
        Start (default zero), e.g. the result of an attempt that ran out of
        iterations.

    Returns
    -------
    GMRESResult
        ``(x, iterations, relres, at_floor)``: the solution, shape (n,), the
        iterations, ``|b - A x| / |b|``, and whether GMRES stopped at the
        round-off floor (below).

    Notes
    -----
    Besides ``rtol`` and ``maxiter`` it stops when a restart cycle reduced the
    true residual by less than ``1 / STAGNATION``; ``relres`` then tells the
    caller how far it got.  ``at_floor``: the last cycle's own (Arnoldi)
    residual reached ``rtol`` but the recomputed true one did not: the
    residual floor of an ill-conditioned system (near a lightly damped
    resonance, 1e-11 to 2e-10 at 96 contact points), which no better
    preconditioner lowers (:func:`krylov_solve`).
    """
    # one column of gmres_columns (the same iteration, one code path)
    b = np.asarray(b, dtype=float)
    X0 = None if x0 is None else np.asarray(x0, dtype=float)[:, None]
    return gmres_columns(lambda V: matvec(V[:, 0])[:, None], b[:, None],
                         lambda V: psolve(V[:, 0])[:, None], rtol=rtol, restart=restart,
                         maxiter=maxiter, X0=X0)[0]


def gmres_columns(matvec, B, psolve, rtol: float = KRYLOV_RTOL,
                  restart: int = KRYLOV_RESTART, maxiter: int = KRYLOV_MAXITER, X0=None):
    """:func:`gmres` for every column of ``B`` at once (``A X = B``).

    Each column has its own Krylov space, residual and stopping tests (those of
    :func:`gmres`, which is this function on one column); the columns are advanced in
    lockstep, and ``matvec`` and
    ``psolve`` are called on the ``(n, k)`` block of the columns still iterating.

    Parameters
    ----------
    matvec, psolve : callable
        ``V -> A V`` and ``V -> P^-1 V`` for ``V`` of shape (n, k') (``k' <= k``).
    B : ndarray, shape (n, k)
    rtol, restart, maxiter
        As in :func:`gmres`, per column.
    X0 : ndarray, shape (n, k), optional
        Start per column (used where it is better than zero).

    Returns
    -------
    list of GMRESResult
        One per column (``x`` of shape (n,)).
    """
    n, k = B.shape
    bn = np.linalg.norm(B, axis=0)
    X = np.zeros((n, k))
    R = B.copy()
    beta = bn.copy()
    if X0 is not None and np.all(np.isfinite(X0)):
        R0 = B - matvec(X0)
        better = np.linalg.norm(R0, axis=0) < bn
        X[:, better], R[:, better] = X0[:, better], R0[:, better]
        beta[better] = np.linalg.norm(R0[:, better], axis=0)
    total = np.zeros(k, dtype=int)
    done = [None] * k
    for c in range(k):
        if bn[c] == 0.0 or n == 0:
            done[c] = GMRESResult(np.zeros(n), 0, 0.0, False)
    while True:
        for c in range(k):
            if done[c] is None and (beta[c] <= rtol * bn[c] or total[c] >= maxiter):
                done[c] = GMRESResult(X[:, c].copy(), int(total[c]), beta[c] / bn[c], False)
        active = [c for c in range(k) if done[c] is None]
        if not active:
            return done
        m = min(restart, maxiter - int(min(total[active])))
        ka = len(active)
        V = np.zeros((ka, m + 1, n))
        Zp = np.zeros((ka, m, n))
        H = np.zeros((ka, m + 1, m))
        cs, sn = np.zeros((ka, m)), np.zeros((ka, m))
        g = np.zeros((ka, m + 1))
        for a, c in enumerate(active):
            g[a, 0] = beta[c]
            V[a, 0] = R[:, c] / beta[c]
        j_end = np.zeros(ka, dtype=int)
        going = [a for a in range(ka) if total[active[a]] < maxiter]
        converged = np.zeros(ka, dtype=bool)
        hn = np.zeros(ka)
        for j in range(m):
            if not going:
                break
            Zj = psolve(np.stack([V[a, j] for a in going], axis=1))
            W = matvec(Zj)
            still = []
            for i_, a in enumerate(going):
                c = active[a]
                Zp[a, j] = Zj[:, i_]
                w = W[:, i_].copy()
                for _ in range(2):                  # classical Gram-Schmidt, twice
                    hj = V[a, :j + 1] @ w
                    w -= hj @ V[a, :j + 1]
                    H[a, :j + 1, j] += hj
                hn[a] = float(np.linalg.norm(w))
                H[a, j + 1, j] = hn[a]
                if hn[a] > 0.0:
                    V[a, j + 1] = w / hn[a]
                Ha = H[a]
                for i in range(j):                  # earlier rotations
                    t = cs[a, i] * Ha[i, j] + sn[a, i] * Ha[i + 1, j]
                    Ha[i + 1, j] = -sn[a, i] * Ha[i, j] + cs[a, i] * Ha[i + 1, j]
                    Ha[i, j] = t
                d = np.hypot(Ha[j, j], Ha[j + 1, j])
                cs[a, j], sn[a, j] = (1.0, 0.0) if d == 0.0 else (Ha[j, j] / d, Ha[j + 1, j] / d)
                Ha[j, j] = d
                Ha[j + 1, j] = 0.0
                g[a, j + 1] = -sn[a, j] * g[a, j]
                g[a, j] = cs[a, j] * g[a, j]
                total[c] += 1
                j_end[a] = j + 1
                converged[a] = abs(g[a, j + 1]) <= 0.5 * rtol * bn[c]
                if not (converged[a] or hn[a] == 0.0 or total[c] >= maxiter):
                    still.append(a)
            going = still
        for a, c in enumerate(active):
            je = j_end[a]
            y = sla.solve_triangular(H[a, :je, :je], g[a, :je], check_finite=False)
            X[:, c] = X[:, c] + y @ Zp[a, :je]
        R[:, active] = B[:, active] - matvec(X[:, active])
        for a, c in enumerate(active):
            beta_start, beta[c] = beta[c], float(np.linalg.norm(R[:, c]))
            if beta[c] <= rtol * bn[c]:
                continue
            if j_end[a] < m and hn[a] == 0.0:       # breakdown without convergence
                done[c] = GMRESResult(X[:, c].copy(), int(total[c]), beta[c] / bn[c], False)
            elif beta[c] > STAGNATION * beta_start:
                done[c] = GMRESResult(X[:, c].copy(), int(total[c]), beta[c] / bn[c],
                                      bool(converged[a]))
