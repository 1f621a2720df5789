"""Accuracy of a march: its time-step error, the scheme's range, undamped modes.

* :func:`step_error` estimates the time-step error of a steady period (one
  linear solve with the harmonic-balance Jacobian: the marched period put into
  the continuous equations, its leftover solved once);
* :func:`scheme_frequency_error` is the generalized-alpha scheme's exact period
  error for a linear oscillator, and :func:`step_range_warnings` says when a
  step is outside the scheme's range;
* :func:`undamped_modes` / :func:`with_mode_damping` find and damp the modes a
  scene leaves undamped (without which a refined march of a Craig-Bampton model
  is never periodic).

Used by :func:`jointsim.solvers.transient.march_steady` and the ``transient``
analysis; the theory is in ``docs/transient.md`` ("Accuracy of a march").
"""
from __future__ import annotations

import logging
import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from ..harmonics import coefficient_index, dft_matrix
from .contact_map import ContactMap
from .periodic import PeriodData
from .static import static_start


log = logging.getLogger(__name__)


# --------------------------------------------------------------------------
# Step-size error indicator and range of the scheme
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class StepError:
    """Estimated time-step (discretisation) error of a forced steady state.

    The marched period satisfies the *discrete* equations exactly; put into
    the continuous equation of motion, harmonic by harmonic, it leaves the
    defect

        r_k = (K - (k w)^2 M + i k w C) X_k + Phi_k - F_k,

    with ``X_k`` and ``Phi_k`` (the contact forces ``Tt^T f - Tn^T N``) the
    DFT of the marched samples (harmonic 0 has no defect: the scheme is exact
    for a constant state).  The marched period is thus the exact steady state
    under the force ``F + r``; the continuous steady state under ``F`` differs
    from it by ``dX = -J^-1 r`` to first order, with ``J`` the harmonic-balance
    Jacobian (:class:`jointsim.solvers.hbm.HBMSystem`, the same harmonics and
    ``steps_per_period`` AFT samples, condensed on the contact coordinates and
    evaluated at the marched solution, friction history terms included).
    Harmonic truncation is common to both sides, so ``dX`` estimates the
    step-size error alone, at the cost of one linear solve.

    Attributes
    ----------
    harmonics : tuple of int
    dX : ndarray, shape (n_coeff, n_dof)
        Estimated ``X_continuous - X_marched`` [m].
    rel_harmonics : ndarray, shape (n_h,)
        ``||dX_h|| / ||X_1 + dX_1||`` per harmonic [-].
    value : float
        ``||dX_1|| / ||X_1 + dX_1||``, the first-harmonic error relative to the
        estimated continuous solution (the cross-check's measure) [-].
    defect : float
        ``||r|| / ||F||`` over harmonics >= 1 [-].
    wall_time : float
        [s]
    """

    harmonics: tuple
    dX: np.ndarray
    rel_harmonics: np.ndarray
    value: float
    defect: float
    wall_time: float


def step_error(model, period: PeriodData, omega: float, force_scale: float, harmonics,
               n: int) -> StepError:
    """Time-step error indicator of a marched steady period (see :class:`StepError`).

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    period : PeriodData
        The steady period (``n + 1`` samples; the first ``n`` are used).
    omega : float
        Forcing frequency [rad/s].
    force_scale : float
        Multiplier of the harmonic loads.
    harmonics : sequence of int
        Harmonics of the estimate (must include 1; each < n/2).
    n : int
        Steps per period.

    Returns
    -------
    StepError
    """
    import scipy.sparse as sp

    from .hbm import HBMSystem
    t0 = time.perf_counter()
    hs = tuple(int(h) for h in harmonics)
    E = dft_matrix(hs, n, omega, period.t[0])
    X = E @ period.x[:n]
    c = model.contacts
    ne = c.n_elements
    fc = np.zeros((n, model.n_dof))
    if ne:
        Tt = sp.csr_matrix(c.Tt)
        if c.law.has_force:
            fc += np.asarray((Tt.T @ period.f[:, :n]).T)
        if c.coupled:
            fc -= np.asarray((sp.csr_matrix(c.Tn).T @ period.N[:, :n]).T)
    Phi = E @ fc
    F = model.force_coefficients(hs, force_scale)
    M, K = sp.csr_matrix(model.M), sp.csr_matrix(model.K)
    C = sp.csr_matrix(model.C)
    R = np.zeros_like(X)
    for h in hs:
        if h == 0:
            continue
        ic, is_ = coefficient_index(hs, h)
        nu = h * omega
        Xh = X[ic] - 1j * X[is_]
        rh = (K @ Xh - nu * nu * (M @ Xh) + 1j * nu * (C @ Xh)
              + (Phi[ic] - 1j * Phi[is_]) - (F[ic] - 1j * F[is_]))
        R[ic], R[is_] = rh.real, -rh.imag
    system = HBMSystem(model, hs, n, parallel=False, linear_solver="direct")
    zero = np.zeros_like(F)
    if system.n_z:
        z = system.contact_coordinates(X)
        ev = system.evaluate(z, omega, F, jacobian=True, wrt=())
        dR = ev.R - system.evaluate(z, omega, F + R, jacobian=False, wrt=()).R
        dz = -np.linalg.solve(ev.J, dR)
        dX = system.reconstruct(dz, omega, zero) - system.reconstruct(
            np.zeros(system.n_z), omega, R)
    else:
        dX = system.reconstruct(np.zeros(0), omega, -R)
    rows = {h: list(coefficient_index(hs, h)) for h in hs}
    ref = np.linalg.norm((X + dX)[rows[1]])   # the estimated continuous solution
    ref = ref if ref > 0 else 1.0
    rel = np.array([np.linalg.norm(dX[rows[h][:1] if h == 0 else rows[h]]) / ref
                    for h in hs])
    nF = np.linalg.norm(F[1:]) if F.shape[0] > 1 else 0.0
    defect = float(np.linalg.norm(R) / nF) if nF > 0 else float("nan")
    return StepError(hs, dX, rel, float(rel[hs.index(1)]), defect,
                     time.perf_counter() - t0)


def scheme_frequency_error(omega_h: float, rho_inf: float) -> float:
    """Relative frequency error of generalized-alpha on an undamped oscillator.

    The amplification matrix of the scheme for ``x'' + w^2 x = 0`` with the
    step ``h`` has the principal eigenvalues ``exp(+-i Omega_d)``; the
    relative period error is ``w h / arg(lambda) - 1`` (positive: the
    numerical oscillation is slower).

    Parameters
    ----------
    omega_h : float
        ``w h`` [rad] (``2 pi / steps_per_period`` at the forcing frequency).
    rho_inf : float

    Returns
    -------
    float
        ``w h / Omega_d - 1``, the relative period elongation [-]; inf when
        the eigenvalues are real.
    """
    from .generalized_alpha import alpha_parameters
    am, af, g, b = alpha_parameters(rho_inf)
    W2 = omega_h * omega_h
    # state (x, h v, h^2 a); the balance (1-am) a1 + am a0 + W2 [(1-af) x1 + af x0] = 0
    # with x1 = x0 + h v0 + h^2 ((1/2 - b) a0 + b a1), h v1 = h v0 + h^2 ((1-g) a0 + g a1)
    A = np.zeros((3, 3))
    lhs = (1.0 - am) + W2 * (1.0 - af) * b
    # a1 (scaled by h^2) in terms of (x0, hv0, h^2 a0)
    row = -np.array([W2 * ((1.0 - af) + af),
                     W2 * (1.0 - af),
                     am + W2 * (1.0 - af) * (0.5 - b)]) / lhs
    A[2] = row
    A[0] = np.array([1.0, 1.0, 0.5 - b]) + b * row
    A[1] = np.array([0.0, 1.0, 1.0 - g]) + g * row
    lam = np.linalg.eigvals(A)
    osc = lam[np.abs(lam.imag) > 1e-12 * np.abs(lam)]   # the principal (complex) pair
    if osc.size == 0:
        return float("inf")
    return float(omega_h / np.abs(np.angle(osc)).max() - 1.0)


#: Relative frequency error of the scheme at the first harmonic above which a
#: march is outside its accurate range (about 57 steps per period).
FREQUENCY_ERROR_WARN = 1e-3

#: Relative round-off of the acceleration ``eps / (w h)^2`` above which the
#: steps are too small for double precision (about 6e5 steps per period).
ROUNDOFF_WARN = 1e-6


def step_range_warnings(omega_h: float, rho_inf: float, h_max: int = 1,
                        what: str = "the forcing frequency") -> list:
    """Why a step ``h`` is outside the accurate range of generalized-alpha.

    Parameters
    ----------
    omega_h : float
        ``w h`` at the first harmonic (``2 pi / steps_per_period``) [rad].
    rho_inf : float
    h_max : int
        Highest harmonic extracted (its frequency error is reported too).
    what : str
        What ``w`` is, for the message.

    Returns
    -------
    list of str
        Empty when the step is inside the range: the frequency error of the
        scheme (:func:`scheme_frequency_error`) at the first harmonic is at
        most :data:`FREQUENCY_ERROR_WARN`, and the round-off of the
        acceleration at most :data:`ROUNDOFF_WARN`.
    """
    out = []
    n = 2.0 * np.pi / omega_h
    e1 = scheme_frequency_error(omega_h, rho_inf)
    if e1 > FREQUENCY_ERROR_WARN:
        eh = scheme_frequency_error(h_max * omega_h, rho_inf) if h_max > 1 else e1
        need = int(np.ceil(2.0 * np.pi / np.sqrt(12.0 * FREQUENCY_ERROR_WARN)))
        out.append(f"{n:.0f} steps per period of {what} are outside the accurate range of "
                   f"the scheme: it oscillates {100 * e1:.2g}% slower than the structure at "
                   f"harmonic 1" + (f" and {100 * eh:.2g}% at harmonic {h_max}"
                                    if h_max > 1 else "")
                   + f"; use at least {need} steps per period "
                   "(analysis.transient.steps_per_period)")
    if np.finfo(float).eps / omega_h ** 2 > ROUNDOFF_WARN:
        out.append(f"{n:.0f} steps per period of {what} are so many that round-off in the "
                   f"accelerations reaches {np.finfo(float).eps / omega_h ** 2:.1e} of their "
                   "size; fewer steps are as accurate and faster")
    return out


# --------------------------------------------------------------------------
# Modes left undamped by the scene
# --------------------------------------------------------------------------
#: A mode whose viscous damping ratio is below this counts as undamped.
UNDAMPED_ZETA = 1e-6


@dataclass(frozen=True)
class UndampedModes:
    """Modes of the stuck structure that the damping matrix leaves undamped.

    A forced march of a structure with such modes is not periodic in the
    continuous limit: their free vibration, started by the switch-on and fed
    by every slip event, only decays by the scheme's numerical dissipation,
    which vanishes like ``(w_j h)^3`` as the step is refined (on the lap joint
    at 512 steps per period the period-to-period change then falls by only
    0.3 % a period).  Harmonic balance never sees them (it keeps the periodic
    solution only).

    Attributes
    ----------
    frequency_hz : ndarray, shape (n,)
        Their frequencies with the joint stuck [Hz].
    shapes : ndarray, shape (n_dof, n)
        Mass-normalised shapes.
    omega : ndarray, shape (n,)
        [rad/s]
    """

    frequency_hz: np.ndarray
    shapes: np.ndarray
    omega: np.ndarray

    @property
    def n(self) -> int:
        return int(self.omega.size)


def undamped_modes(model, max_dof: int = 3000) -> UndampedModes | None:
    """Elastic modes of the stuck linearisation whose damping ratio
    ``phi^T C phi / (2 w)`` is below :data:`UNDAMPED_ZETA`.

    The stiffness is ``K`` plus the contact tangent at the static state
    (:func:`static_start`, sliders stuck).  Modes at zero frequency are left
    out.  None for models above ``max_dof`` DOFs (dense eigenproblem).

    Returns
    -------
    UndampedModes or None
    """
    import scipy.linalg as sla
    import scipy.sparse as sp
    n = model.n_dof
    if n > max_dof:
        return None
    K = sp.csr_matrix(model.K).toarray()
    cmap = ContactMap(model.contacts)
    if cmap.active:
        st = static_start(model)
        Bd = cmap.B.toarray() if sp.issparse(cmap.B) else np.asarray(cmap.B)
        K = K + Bd.T @ cmap.D_matrix(st.contact) @ Bd
    M = sp.csr_matrix(model.M).toarray()
    C = sp.csr_matrix(model.C).toarray()
    w2, phi = sla.eigh(0.5 * (K + K.T), M)
    w = np.sqrt(np.maximum(w2, 0.0))
    cdiag = np.einsum("ij,ik,kj->j", phi, C, phi)
    elastic = w > 1e-6 * max(w.max(), 1e-300)
    zeta = np.where(elastic, cdiag / (2.0 * np.where(elastic, w, 1.0)), np.inf)
    sel = elastic & (zeta < UNDAMPED_ZETA)
    return UndampedModes(w[sel] / (2.0 * np.pi), phi[:, sel], w[sel])


def with_mode_damping(model, modes: UndampedModes, zeta: float):
    """The model with viscous damping ratio ``zeta`` on the given modes.

    ``C + sum_j 2 zeta w_j (M phi_j)(M phi_j)^T``; the other modes keep their
    damping (the modes are M-orthogonal).

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    modes : UndampedModes
    zeta : float
        Damping ratio [-].

    Returns
    -------
    jointsim.model.StructuralModel
    """
    import scipy.sparse as sp
    if modes is None or modes.n == 0 or zeta <= 0.0:
        return model
    Mphi = np.asarray(sp.csr_matrix(model.M) @ modes.shapes)
    C = sp.csr_matrix(model.C) + sp.csr_matrix((Mphi * (2.0 * zeta * modes.omega)) @ Mphi.T)
    return dataclasses.replace(model, C=sp.csr_matrix(C))
