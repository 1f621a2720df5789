"""Periodic signals from a time march: period change, energy balance, extrema.

Pure functions of marched samples, used by the drivers of
:mod:`jointsim.solvers.transient`:

* :func:`period_change` and :func:`geometric_error` measure how far a forced
  march is from its steady state (the change between consecutive periods,
  and the distance left estimated from its geometric decrease);
* :func:`energy_balance` closes the work budget of one marched period
  (:class:`EnergyBalance`) over its samples (:class:`PeriodData`);
* :func:`hermite_extremum`, :class:`ExtremumTracker` and
  :func:`decay_estimates` turn the extrema of a ring-down into amplitude,
  frequency and damping estimates.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._transient_kernels import gap_correction


# --------------------------------------------------------------------------
# Data
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class EnergyBalance:
    """Work done over one period, from the marched samples.

    The sums use the trapezoidal rule on the step grid: forces averaged over
    each step times the displacement increment, and ``h vbar^T C vbar`` with
    the mean velocity of the step.  With ``rho_inf = 1`` (the trapezoidal
    rule) the discrete balance is exact up to the Newton tolerance; with
    ``rho_inf < 1`` the imbalance is the numerical dissipation of the scheme.

    Attributes
    ----------
    input : float
        Work of the external force [J].
    viscous : float
        Dissipated by the damping matrix [J].
    friction : float
        Work of the tangential contact forces on the slips (the loop areas) [J].
    normal : float
        Work of the normal contact forces (zero over a period for the
        elastic penalty) [J].
    stored : float
        Change of kinetic plus linear elastic energy over the period [J].
    imbalance : float
        ``input - viscous - friction - normal - stored`` [J].
    relative : float
        ``|imbalance| / max(|input|, viscous + |friction|)`` [-].
    """

    input: float
    viscous: float
    friction: float
    normal: float
    stored: float
    imbalance: float
    relative: float

    def as_attrs(self) -> dict:
        return {f"energy_{k}": float(getattr(self, k)) for k in
                ("input", "viscous", "friction", "normal", "stored", "imbalance", "relative")}


@dataclass(frozen=True)
class PeriodData:
    """The marched samples of one period (``n + 1`` samples, both ends included).

    Attributes
    ----------
    index : int
        Period number (0 is the first).
    t : ndarray, shape (n + 1,)
        Times [s].
    x, v : ndarray, shape (n + 1, n_dof)
        Displacements [m] and velocities [m/s].
    u, f, N : ndarray, shape (n_e, n + 1)
        Tangential slip [m], tangential force [N] and normal load [N].
    g : ndarray, shape (n_e, n + 1)
        Gap changes ``Tn x`` [m] (zeros with a fixed normal load).
    """

    index: int
    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    u: np.ndarray
    f: np.ndarray
    N: np.ndarray
    g: np.ndarray



# --------------------------------------------------------------------------
# Period analysis (pure functions)
# --------------------------------------------------------------------------
def period_change(x_new, x_old) -> float:
    """Largest change between two periods relative to the vibration amplitude.

    Parameters
    ----------
    x_new, x_old : ndarray, shape (n, n_dof)
        Displacements at the same phases of consecutive periods [m].

    Returns
    -------
    float
        ``max |x_new - x_old| / max_j (max_t x_j - min_t x_j) / 2`` [-].
    """
    amp = 0.5 * float(np.max(np.ptp(x_new, axis=0)))
    diff = float(np.max(np.abs(x_new - x_old)))
    if amp == 0.0:
        return 0.0 if diff == 0.0 else np.inf
    return diff / amp


def energy_balance(p: PeriodData, force, M, C, K, unilateral=None) -> EnergyBalance:
    """Energy balance of one marched period (see :class:`EnergyBalance`).

    Parameters
    ----------
    p : PeriodData
    force : callable
        ``force(t) -> ndarray (n_dof,)`` [N].
    M, C, K : matrix, shape (n_dof, n_dof)
    unilateral : tuple, optional
        ``(gap0, kn)`` of unilateral penalty contacts: the normal work then uses
        the same energy-consistent average as the scheme
        (:func:`~jointsim.solvers._transient_kernels.gap_correction`), i.e. the
        change of the penalty energy.
    """
    F = np.array([force(t) for t in p.t])
    dx = np.diff(p.x, axis=0)
    w_in = float(np.sum(0.5 * (F[1:] + F[:-1]) * dx))
    h = np.diff(p.t)
    vbar = 0.5 * (p.v[1:] + p.v[:-1])
    w_c = float(np.sum(h * np.einsum("ij,ij->i", vbar, (C @ vbar.T).T)))
    w_f = float(np.sum(0.5 * (p.f[:, 1:] + p.f[:, :-1]) * np.diff(p.u, axis=1)))
    Nbar = 0.5 * (p.N[:, 1:] + p.N[:, :-1])
    if unilateral is not None and p.N.shape[0]:
        gap0, kn = unilateral
        gaps = gap0[:, None] + p.g
        c, dc = np.empty(gap0.size), np.empty(gap0.size)
        for j in range(p.t.size - 1):
            gap_correction(gaps[:, j], p.N[:, j], gaps[:, j + 1], p.N[:, j + 1], kn, c, dc)
            Nbar[:, j] += c
    w_n = float(np.sum(-Nbar * np.diff(p.g, axis=1)))

    def stored(x, v):
        return 0.5 * float(v @ (M @ v)) + 0.5 * float(x @ (K @ x))

    w_s = stored(p.x[-1], p.v[-1]) - stored(p.x[0], p.v[0])
    imb = w_in - w_c - w_f - w_n - w_s
    ref = max(abs(w_in), w_c + abs(w_f))
    return EnergyBalance(w_in, w_c, w_f, w_n, w_s, imb, abs(imb) / ref if ref > 0 else 0.0)


def geometric_error(changes) -> float:
    """Distance to the limit estimated from a geometrically decreasing sequence.

    With the last two changes ``c1 < c0``, ``rho = c1 / c0`` and the remaining
    distance is ``c1 rho / (1 - rho)``; ``inf`` when the sequence does not
    decrease, ``0`` when the last change is 0.
    """
    c = [v for v in changes if np.isfinite(v)]
    if not c:
        return np.inf
    if c[-1] == 0.0:
        return 0.0
    if len(c) < 2 or not c[-1] < c[-2]:
        return np.inf
    rho = c[-1] / c[-2]
    return c[-1] * rho / (1.0 - rho)


def hermite_extremum(t0, t1, q0, q1, d0, d1):
    """Extremum of the cubic Hermite interpolant of ``q`` on ``[t0, t1]``.

    ``d0`` and ``d1`` (the derivatives at the ends) must differ in sign or
    one of them be 0.

    Returns
    -------
    t, q : float
        Time and value of the extremum.
    """
    dt = t1 - t0
    a = 6.0 * q0 + 3.0 * dt * d0 - 6.0 * q1 + 3.0 * dt * d1
    b = -6.0 * q0 - 4.0 * dt * d0 + 6.0 * q1 - 2.0 * dt * d1
    c = dt * d0
    tau = None
    if abs(a) > 1e-14 * (abs(b) + abs(c)):
        disc = b * b - 4.0 * a * c
        if disc >= 0.0:
            sq = np.sqrt(disc)
            # numerically stable roots of a t^2 + b t + c
            qq = -0.5 * (b + np.copysign(sq, b))
            roots = [qq / a] + ([c / qq] if qq != 0.0 else [])
            inside = [r for r in roots if -1e-12 <= r <= 1.0 + 1e-12]
            if inside:
                tau = min(max(inside[0], 0.0), 1.0)
    elif b != 0.0:
        tau = min(max(-c / b, 0.0), 1.0)
    if tau is None:  # degenerate: linear interpolation of the derivative
        tau = d0 / (d0 - d1) if d0 != d1 else 0.5
    h00 = 2 * tau ** 3 - 3 * tau ** 2 + 1
    h10 = tau ** 3 - 2 * tau ** 2 + tau
    h01 = -2 * tau ** 3 + 3 * tau ** 2
    h11 = tau ** 3 - tau ** 2
    return t0 + tau * dt, h00 * q0 + h10 * dt * d0 + h01 * q1 + h11 * dt * d1


class ExtremumTracker:
    """Alternating extrema of a sampled signal ``q(t)`` with known derivative.

    Feed samples in time order with :meth:`add`; an extremum is found where
    ``dq/dt`` changes sign, and located by cubic Hermite interpolation.
    Consecutive extrema alternate (maximum, minimum, ...): a repeated kind
    (round-off near rest) keeps the more extreme value.
    """

    def __init__(self):
        self.t: list[float] = []
        self.q: list[float] = []
        self.kind: list[int] = []
        self._prev = None

    def add(self, t, q, d) -> None:
        if self._prev is not None:
            t0, q0, d0 = self._prev
            kind = 0
            if d0 > 0.0 and d <= 0.0:
                kind = 1
            elif d0 < 0.0 and d >= 0.0:
                kind = -1
            if kind:
                te, qe = hermite_extremum(t0, t, q0, q, d0, d)
                if self.kind and self.kind[-1] == kind:
                    if kind * qe > kind * self.q[-1]:
                        self.t[-1], self.q[-1] = te, qe
                else:
                    self.t.append(te)
                    self.q.append(qe)
                    self.kind.append(kind)
        self._prev = (t, q, d)


def decay_estimates(t_ext, q_ext):
    """Frequency, damping and amplitude of a ring-down from its extrema.

    With alternating extrema ``(t_j, q_j)`` and half swings
    ``H_j = |q_{j+1} - q_j| / 2``, every three consecutive swings give one
    estimate centred on swing ``j + 1``:

    * amplitude ``A = H_{j+1}``;
    * period ``T = (t_{j+2} - t_j + t_{j+3} - t_{j+1}) / 2``;
    * logarithmic decrement ``delta = ln(H_j / H_{j+2})`` over one cycle and
      ``zeta = delta / sqrt(4 pi^2 + delta^2)``.

    Swings are offset-free: a constant shift of the signal (a slider that
    stays displaced) does not bias them.  For a linear viscously damped
    oscillator the frequency (the damped one) and damping ratio are exact.
    For a nonlinear ring-down each estimate is an average over about 1.5
    cycles, and the amplitude is the peak value, not the first-harmonic
    amplitude of EPMC; both biases grow with the decay per cycle and the
    waveform distortion (see ``docs/transient.md``).

    Parameters
    ----------
    t_ext, q_ext : array_like, shape (n,)
        Times [s] and values of alternating extrema.

    Returns
    -------
    time, amplitude, frequency_hz, damping_ratio : ndarray, shape (max(n - 3, 0),)
    """
    t = np.asarray(t_ext, dtype=float)
    q = np.asarray(q_ext, dtype=float)
    if t.size < 4:
        e = np.zeros(0)
        return e, e, e, e
    H = 0.5 * np.abs(np.diff(q))
    j = np.arange(t.size - 3)
    period = 0.5 * ((t[j + 2] - t[j]) + (t[j + 3] - t[j + 1]))
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where((H[j] > 0) & (H[j + 2] > 0), np.log(H[j] / H[j + 2]), np.nan)
    zeta = delta / np.sqrt(4.0 * np.pi ** 2 + delta ** 2)
    return 0.5 * (t[j + 1] + t[j + 2]), H[j + 1], 1.0 / period, zeta
