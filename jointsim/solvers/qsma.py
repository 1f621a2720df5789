"""Quasi-static modal analysis (QSMA, Lacayo and Allen).

From the preloaded state ``x0`` with its stuck tangent ``K0`` and the
mass-normalised mode ``phi`` of ``(K0, M)``, the structure is loaded
statically with ``f_static + alpha M phi`` for increasing ``alpha``.  Each load
increment is a nonlinear static solve (:func:`jointsim.solvers.static.solve_static`
with ``tangential = "law"``) whose contact state starts from the previous
increment's, so the friction history is carried along the loading curve.
Along it:

* modal amplitude ``q = phi^T M (x - x0)`` [sqrt(kg) m];
* secant frequency ``w^2 = alpha / q``;
* Masing dissipation ``D = 8 int_0^q alpha dq - 4 q alpha`` [J] (trapezoidal
  integral along the computed curve, which starts at the origin);
* damping ratio ``zeta = D / (2 pi q alpha) + zeta_0``: the friction (Masing)
  part plus the linear viscous damping of the mode, ``zeta_0 = phi^T C phi /
  (2 w_0)``, so that it compares with EPMC and with measurements (the
  friction part alone is stored too).

The Masing construction assumes the whole structure obeys Masing's rules
along this one load path; :func:`qsma_cycle` marches the full static loop
(up, down and up again) with the same solver, so the assumption can be
checked: with fixed normal loads its area equals ``D``.

Result-file groups (analysis ``[analysis.qsma]``, written by
:func:`jointsim.analyses.qsma.run_qsma_analysis`): ``/qsma/amplitude``
[n_steps], ``/qsma/frequency_hz``, ``/qsma/damping_ratio``, ``/qsma/alpha``,
``/qsma/dissipation``, the loading curve ``/qsma/x`` [n_steps, n_dof] and the
per-element backbones ``/qsma/element_u``, ``/qsma/element_f``,
``/qsma/element_N`` [n_steps, n_elements]; attributes hold the mode, its
linear frequency and the convergence report.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ..results import NOT_CONVERGED, SUCCESS, Convergence
from .static import solve_static

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class QSMAResult:
    """A QSMA loading curve.

    Attributes
    ----------
    alpha : ndarray, shape (n,)
        Modal load factor [sqrt(kg) m/s^2]: the load is ``f_static + alpha M phi``.
    amplitude : ndarray, shape (n,)
        Modal amplitude ``q`` [sqrt(kg) m].
    frequency_hz : ndarray, shape (n,)
        Secant frequency [Hz].
    dissipation : ndarray, shape (n,)
        Masing dissipation per cycle [J].
    damping_ratio : ndarray, shape (n,)
        ``damping_ratio_friction + zeta_linear`` [-].
    damping_ratio_friction : ndarray, shape (n,)
        ``D / (2 pi q alpha)`` [-].
    zeta_linear : float
        Viscous damping ratio of the mode, ``phi^T C phi / (2 w_0)`` [-].
    x : ndarray, shape (n, n_dof)
        Displacements along the loading curve [m].
    u_t, f_t, N : ndarray, shape (n, n_e)
        Element slips [m], tangential forces [N] and normal loads [N]: the
        per-element backbones.
    linear_hz : float
        Frequency of the mode at vanishing amplitude [Hz].
    convergence : Convergence
        ``iterations``: load increments completed.
    """

    alpha: np.ndarray
    amplitude: np.ndarray
    frequency_hz: np.ndarray
    dissipation: np.ndarray
    damping_ratio: np.ndarray
    damping_ratio_friction: np.ndarray
    zeta_linear: float
    x: np.ndarray
    u_t: np.ndarray
    f_t: np.ndarray
    N: np.ndarray
    linear_hz: float
    convergence: Convergence = field(repr=False)


def masing_dissipation(alpha, q):
    """Masing dissipation per cycle from a loading curve starting at the origin.

    Parameters
    ----------
    alpha, q : ndarray, shape (n,)
        Load factor and modal amplitude along the initial loading, increasing.

    Returns
    -------
    ndarray, shape (n,)
        ``8 int_0^q alpha dq - 4 q alpha`` at every point [J].
    """
    a = np.concatenate([[0.0], alpha])
    x = np.concatenate([[0.0], q])
    area = np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]) * np.diff(x))])[1:]
    return 8.0 * area - 4.0 * q * alpha


def qsma(model, phi, x0, alphas, state0=None, tol: float = 1e-10,
         progress: bool = False) -> QSMAResult:
    """Load a structure statically along a mode and build its QSMA backbone.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    phi : ndarray, shape (n_dof,)
        Mass-normalised mode of the stuck, preloaded structure [1/sqrt(kg)].
    x0 : ndarray, shape (n_dof,)
        Preload state [m]; it must solve ``K x + f_c(x) = f_static`` with
        the contacts at rest.
    alphas : ndarray, shape (n,)
        Increasing load factors.
    state0 : ndarray, optional
        Contact-law state at ``x0`` (default: the law's rest state at N0).
    tol : float
        Relative residual tolerance of each static solve.

    Returns
    -------
    QSMAResult
        Stops at the first increment that fails (the result keeps what was
        computed and says why).
    """
    from tqdm import tqdm

    alphas = np.asarray(alphas, dtype=float)
    if np.any(np.diff(alphas) <= 0) or alphas[0] <= 0:
        raise ValueError("QSMA load factors must be positive and increasing")
    c = model.contacts
    M = model.M
    Mphi = M @ phi
    f_static = np.asarray(model.f_static, dtype=float)
    state = c.law.rest_state(c.N0) if state0 is None else np.array(state0, copy=True)
    x_prev, f_prev = np.asarray(x0, dtype=float), f_static
    rows = []
    conv = None
    for i, a in enumerate(tqdm(alphas, desc="qsma", unit="step",
                               disable=None if progress else True)):
        f_new = f_static + a * Mphi
        res = solve_static(model.K, f_new, c, tangential="law", state=state, x_start=x_prev,
                           f_start=f_prev, tol=tol, n_increments=1)
        if not res.convergence.success:
            conv = Convergence(False, res.convergence.status or NOT_CONVERGED,
                               f"QSMA stopped at alpha = {a:.4g} (step {i}): "
                               f"{res.convergence.message}", i)
            log.warning(conv.message)
            break
        state, x_prev, f_prev = res.state, res.x, f_new
        rows.append((a, res.x, res.u_t, res.f_t, res.N))
    if conv is None:
        conv = Convergence(True, SUCCESS, f"{len(rows)} load increments", len(rows))
    if not rows:
        empty = np.zeros((0,))
        return QSMAResult(empty, empty, empty, empty, empty, empty, float("nan"),
                          np.zeros((0, model.n_dof)),
                          np.zeros((0, c.n_elements)), np.zeros((0, c.n_elements)),
                          np.zeros((0, c.n_elements)), float("nan"), conv)
    alpha = np.array([r[0] for r in rows])
    x = np.array([r[1] for r in rows])
    q = (x - x0) @ Mphi
    w2 = alpha / q
    D = masing_dissipation(alpha, q)
    zeta = D / (2.0 * np.pi * q * alpha)
    w_lin = np.sqrt(float(phi @ (_stuck_K(model, x0) @ phi)))
    zeta0 = float(phi @ (model.C @ phi)) / (2.0 * w_lin)
    return QSMAResult(alpha=alpha, amplitude=q, frequency_hz=np.sqrt(w2) / (2 * np.pi),
                      dissipation=D, damping_ratio=zeta + zeta0, damping_ratio_friction=zeta,
                      zeta_linear=zeta0, x=x,
                      u_t=np.array([r[2] for r in rows]), f_t=np.array([r[3] for r in rows]),
                      N=np.array([r[4] for r in rows]), linear_hz=w_lin / (2 * np.pi),
                      convergence=conv)


def _stuck_K(model, x0):
    """Stuck tangent at ``x0``: the model's linearisation when ``x0`` is its state."""
    lin = model.linearisation
    if np.array_equal(x0, lin.x0):
        return lin.K
    from .static import tangent_stiffness
    return tangent_stiffness(model.K, model.contacts, x0)


def qsma_cycle(model, phi, x0, alpha_max: float, n_per_branch: int = 40, state0=None,
               tol: float = 1e-10):
    """March the full static loop ``0 -> alpha_max -> -alpha_max -> alpha_max``.

    Parameters
    ----------
    model, phi, x0, state0, tol
        As in :func:`qsma`.
    alpha_max : float
        Load-factor amplitude.
    n_per_branch : int
        Increments per half cycle.

    Returns
    -------
    alpha, q : ndarray, shape (n,)
        The closed cycle from ``+alpha_max`` down to ``-alpha_max`` and back.
    dissipation : float
        Work of the load over the closed loop, ``oint alpha dq`` [J].
    """
    c = model.contacts
    Mphi = model.M @ phi
    f_static = np.asarray(model.f_static, dtype=float)
    up = np.linspace(0.0, alpha_max, n_per_branch + 1)[1:]
    down = np.linspace(alpha_max, -alpha_max, 2 * n_per_branch + 1)[1:]
    up2 = np.linspace(-alpha_max, alpha_max, 2 * n_per_branch + 1)[1:]
    path = np.concatenate([up, down, up2])
    state = c.law.rest_state(c.N0) if state0 is None else np.array(state0, copy=True)
    x_prev, f_prev = np.asarray(x0, dtype=float), f_static
    qs = []
    for a in path:
        f_new = f_static + a * Mphi
        res = solve_static(model.K, f_new, c, tangential="law", state=state, x_start=x_prev,
                           f_start=f_prev, tol=tol, n_increments=1)
        if not res.convergence.success:
            raise RuntimeError(f"static cycle failed at alpha = {a:.4g}: "
                               f"{res.convergence.message}")
        state, x_prev, f_prev = res.state, res.x, f_new
        qs.append(float((res.x - x0) @ Mphi))
    n_cycle = down.size + up2.size
    alpha = np.concatenate([[alpha_max], path[-n_cycle:]])
    q = np.concatenate([[qs[up.size - 1]], qs[-n_cycle:]])
    area = float(np.sum(0.5 * (alpha[1:] + alpha[:-1]) * np.diff(q)))
    return alpha, q, area
