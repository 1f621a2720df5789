"""Tangential contact laws: one class per law family, one protocol for all.

A law holds per-element parameter arrays (plain NumPy) and knows its kernels.
Every solver talks to a law only through the methods of
:class:`TangentialLaw`, so a new law is its class, its kernels, one row of
the selection table (:mod:`jointsim.contact.select`) and its scene
parameters; nothing in ``solvers/`` changes.

Every law is a *slider bank* (see :mod:`jointsim.contact._kernels`): slider
``i`` of element ``e`` has stiffness ``k[e, i]`` [N/m] and slip force
``g[e, i] N`` [N].  The families:

* :class:`AnchoredBank` -- physical elastic dry friction (Jenkins, Iwan);
* :class:`ScaledBank` -- the seed's Eq. 7 reversal law;
* :class:`ManifoldBank` -- Eq. 7's scaling with Masing's memory rule (on the
  Masing manifold wherever the manifold stays inside the friction limit);
* :class:`LinearSpring` -- a tangential spring that never slips (``stuck``);
* :class:`NoFriction` -- no tangential force (``effects.friction = false``).
"""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from . import _aft_kernels as AK
from . import _aft_manifold as AM
from . import _kernels as K


def iwan4_sliders(KT: float, Fs: float, chi: float, beta: float, n: int,
                  spacing: str = "uniform", lowest: float = 1e-3):
    """Discretise Segalman's 4-parameter Iwan element into ``n`` Jenkins sliders.

    The power-law part of the slider density, ``R phi^chi`` on
    ``[0, phi_max]``, is split into ``n - 1`` bins; each bin becomes one slider
    with the bin's exact stiffness and a slip displacement at the bin's
    centroid, so that the total stiffness ``KT`` and the total slip force
    ``Fs`` are exact.  The spike ``S delta(phi - phi_max)`` is the last slider.
    Bins of equal width (``spacing = "uniform"``) resolve deep microslip
    badly (no slider slips below ``phi_max / (n - 1)``); geometric bins
    (``[0, lowest phi_max]`` then a geometric sequence up to ``phi_max``) keep
    the relative dissipation error about constant down to small amplitudes
    (:func:`iwan4_dissipation_error`, :func:`iwan4_design`).

    Parameters
    ----------
    KT : float
        Total tangential stiffness [N/m].
    Fs : float
        Macroslip force [N].
    chi : float
        Exponent of the power-law density (> -1).
    beta : float
        Ratio of the spike to the power-law part (>= 0).
    n : int
        Number of sliders (>= 2).
    spacing : {"uniform", "geometric"}
        Bin edges.
    lowest : float
        Geometric spacing: the first bin edge above 0, relative to ``phi_max``.

    Returns
    -------
    k : ndarray, shape (n,)
        Slider stiffnesses [N/m]; their sum is ``KT``.
    fs : ndarray, shape (n,)
        Slider slip forces [N]; their sum is ``Fs``.
    """
    if n < 2:
        raise ValueError("an Iwan element needs at least 2 sliders")
    _c, phimax, R, S = iwan4_constants(KT, Fs, chi, beta)
    edges = phimax * _iwan4_edges(n, spacing, lowest)
    k = np.empty(n)
    fs = np.empty(n)
    k[:-1] = R * np.diff(edges ** (chi + 1.0)) / (chi + 1.0)
    fs[:-1] = R * np.diff(edges ** (chi + 2.0)) / (chi + 2.0)
    k[-1] = S  # beta = 0 leaves a slider of zero stiffness and strength
    fs[-1] = S * phimax
    return k, fs


def _iwan4_edges(n: int, spacing: str, lowest: float) -> np.ndarray:
    """Bin edges of the power-law part relative to ``phi_max``, shape (n,)."""
    if spacing == "uniform" or n == 2:
        return np.linspace(0.0, 1.0, n)
    if spacing == "geometric":
        return np.concatenate([[0.0], np.geomspace(lowest, 1.0, n - 1)])
    raise ValueError(f"unknown slider spacing {spacing!r}")


def iwan4_dissipation_error(chi: float, n: int, spacing: str = "geometric",
                            lowest: float = 1e-3, a_min: float = 0.01,
                            n_check: int = 200) -> float:
    """Largest relative error of the discretised Iwan element's dissipation per cycle.

    Against Segalman's closed form ``D = 4 R A^(chi+3) / ((chi+2)(chi+3))``
    (DESIGN §5) at amplitudes ``A`` from ``a_min phi_max`` to ``phi_max``
    (log-spaced), under constant normal load: there each slider is a Jenkins
    element, whose dissipation is ``4 fs (A - fs/k)`` once it slips.  The
    error does not depend on ``KT``, ``Fs`` or ``beta``.  In macroslip the
    relative error only falls (the spike's dissipation is exact).

    Returns
    -------
    float
        ``max |D_discrete / D - 1|`` [-].
    """
    KT, Fs, beta = 1.0, 1.0, 0.0
    _c, phimax, R, _S = iwan4_constants(KT, Fs, chi, beta)
    k, fs = iwan4_sliders(KT, Fs, chi, beta, n, spacing, lowest)
    k, fs = k[:-1], fs[:-1]
    phi = fs / k
    A = np.geomspace(a_min, 1.0, n_check)[:, None] * phimax
    D = 4.0 * np.sum(np.where(A > phi, fs * (A - phi), 0.0), axis=1)
    exact = 4.0 * R * A[:, 0] ** (chi + 3.0) / ((chi + 2.0) * (chi + 3.0))
    return float(np.max(np.abs(D / exact - 1.0)))


#: First geometric bin edges tried by :func:`iwan4_design` (relative to phi_max).
IWAN_LOWEST = (1e-4, 3e-4, 1e-3, 3e-3, 1e-2)


@functools.lru_cache(maxsize=64)
def iwan4_design(chi: float, rtol: float, a_min: float = 0.01, n: int | None = None):
    """The Iwan discretisation that meets a dissipation accuracy.

    Parameters
    ----------
    chi : float
        Exponent of the slider density.
    rtol : float
        Largest relative dissipation error wanted from ``a_min phi_max`` to
        macroslip (:func:`iwan4_dissipation_error`).
    a_min : float
        Smallest amplitude of interest, relative to ``phi_max``.
    n : int, optional
        A given slider count: then only the spacing is chosen.

    Returns
    -------
    n : int
        The fewest sliders (geometric spacing) that meet ``rtol`` (at most 2000).
    lowest : float
        The first geometric bin edge, relative to ``phi_max``.
    error : float
        The error reached.
    """
    counts = [n] if n is not None else list(range(4, 41)) + list(range(44, 2001, 4))
    best = None
    for m in counts:
        for lo in IWAN_LOWEST:
            err = iwan4_dissipation_error(chi, m, "geometric", lo, a_min)
            if best is None or err < best[2]:
                best = (m, lo, err)
        if best[2] <= rtol and best[0] == m:
            return best
    return best


def iwan4_constants(KT: float, Fs: float, chi: float, beta: float):
    """Segalman's derived constants ``(c, phi_max, R, S)`` (DESIGN §5)."""
    c = beta + (chi + 1.0) / (chi + 2.0)
    phimax = Fs * (1.0 + beta) / (KT * c)
    R = Fs * (chi + 1.0) / (phimax ** (chi + 2.0) * c)
    S = KT * beta / (1.0 + beta)
    return c, phimax, R, S


#: Codes of the tangential laws in the fused time-marching kernel
#: (:func:`jointsim.solvers._transient_kernels.march_dense`).
FUSED_NONE, FUSED_LINEAR, FUSED_ANCHOR = 0, 1, 2


@dataclass(frozen=True)
class TangentialLaw:
    """Tangential contact law of ``n_e`` elements (the protocol of every law).

    Attributes
    ----------
    k : ndarray, shape (n_e, n_s)
        Slider stiffnesses [N/m] (``LinearSpring``: one column, the spring).
    g : ndarray, shape (n_e, n_s)
        Slip force per unit normal load of each slider [-] (0 for laws that
        cannot slip).
    mu : ndarray, shape (n_e,)
        Friction coefficient; the macroslip force is ``mu N``.

    Class attributes
    ----------------
    name : str
        The kernel's name, for logs and result files (never switched on).
    has_force : bool
        False when the tangential force is identically zero.
    can_slip : bool
        True for friction laws (the element may slip; its state is history).
    fused_code : int or None
        Code of the law in the fused time-marching kernel; None when the
        fused kernel does not support it (the Python stepper is used).
    has_aft : bool
        False when the law has no AFT kernel with an exact Jacobian (scenes
        with harmonic balance are refused, see :mod:`jointsim.contact.select`).
    path_continuous : bool
        False when the force is not a continuous function of the path under
        a varying normal load (the scaled reversal laws): continuation may
        then meet a residual that jumps, see :func:`continuation_advice`.
    uses_gap : bool
        True when ``aft`` takes the gap samples (keyword ``gap``) to place the
        anchor of a contact that closes between two samples at its closing
        instant and to integrate the interval in which it opens up to its opening
        instant (keyword ``dF``, the correction of the coefficients;
        :class:`jointsim.solvers.aft.AFT`, ``closing``).
    """

    name: ClassVar[str] = ""
    has_force: ClassVar[bool] = True
    can_slip: ClassVar[bool] = True
    fused_code: ClassVar[int | None] = None
    has_aft: ClassVar[bool] = True
    path_continuous: ClassVar[bool] = True
    uses_gap: ClassVar[bool] = False

    k: np.ndarray
    g: np.ndarray
    mu: np.ndarray

    def __post_init__(self):
        for name in ("k", "g"):
            a = np.ascontiguousarray(getattr(self, name), dtype=float)
            if a.ndim != 2:
                raise ValueError(f"{name} must have shape (n_e, n_s)")
            object.__setattr__(self, name, a)
        object.__setattr__(self, "mu", np.ascontiguousarray(self.mu, dtype=float))

    @property
    def n_elements(self) -> int:
        return self.k.shape[0]

    @property
    def n_sliders(self) -> int:
        return self.k.shape[1]

    @property
    def kt(self) -> np.ndarray:
        """Initial (stuck) tangential stiffness of each element [N/m], shape (n_e,)."""
        return self.k.sum(axis=1)

    # -- state ----------------------------------------------------------------
    def state_size(self) -> int:
        """Number of state entries per element."""
        return 0

    def rest_state(self, N0) -> np.ndarray:
        """State of elements at rest at ``u = 0`` under normal load ``N0``.

        Parameters
        ----------
        N0 : array_like, shape (n_e,)
            Normal load at the start [N].

        Returns
        -------
        ndarray, shape (n_e, state_size)
        """
        return np.zeros((self.n_elements, self.state_size()))

    def state_at(self, u0, N0) -> np.ndarray:
        """State of unloaded elements resting at slip ``u0`` under load ``N0``.

        Parameters
        ----------
        u0, N0 : array_like, shape (n_e,)
            Slip [m] and normal load [N].

        Returns
        -------
        ndarray, shape (n_e, state_size)
        """
        return self.rest_state(N0)

    # -- marching -------------------------------------------------------------
    def march(self, u, N, state):
        """March all elements over the samples of ``u`` and ``N``.

        Parameters
        ----------
        u, N : ndarray, shape (n_e, n_t)
            Tangential displacement [m] and normal load [N].
        state : ndarray, shape (n_e, state_size)

        Returns
        -------
        f, dfdu, dfdN : ndarray, shape (n_e, n_t)
            Force [N], tangent stiffness [N/m] and derivative by N [-].
        state : ndarray
            State after the last sample (a new array).
        """
        raise NotImplementedError(f"{type(self).__name__} has no march kernel")

    def aft(self, u, N, dNdg, basis, min_periods: int, max_periods: int, tol: float,
            coupled: bool, parallel: bool = True):
        """Periodic march over one period of samples, with history derivatives.

        Parameters
        ----------
        u, N, dNdg : ndarray, shape (n_e, n_t)
            Slip [m], normal load [N] and ``dN/dg`` [N/m] at the samples.
        basis : jointsim.harmonics.HarmonicBasis
            Supplies ``Gam`` (n_t, n_c), ``P`` (n_c, n_t) and ``CP`` (prefix sums of
            ``P``'s columns, n_c x (n_t + 1)).
        min_periods, max_periods : int
            Periods marched at least / at most until the state repeats.
        tol : float
            Periodicity tolerance.
        coupled : bool
            Derivatives with respect to the gap coefficients are wanted.
        parallel : bool
            Allow the kernel numba threads (False: the calling thread only).

        Returns
        -------
        f, au, ag : ndarray, shape (n_e, n_t) (``au``/``ag`` may be None)
            Force [N] over the last period and its instantaneous tangents
            ``df/du`` and ``df/dN dN/dg`` [N/m] (None where identically zero).
        Juu, Jug : ndarray, shape (n_e, n_c, n_c), or None
            History part of ``dF/dU`` and ``dF/dG`` (None when the law has no
            history).
        periods : ndarray of int, shape (n_e,)
        change : ndarray, shape (n_e,)
            Relative state change over the last period.
        """
        raise NotImplementedError(f"{type(self).__name__} has no AFT kernel")

    # -- closed forms ---------------------------------------------------------
    def backbone(self, x, N):
        """Initial loading curve from rest at constant normal load.

        Parameters
        ----------
        x : ndarray, shape (n_e, ...) or broadcastable
            Displacement from rest, >= 0 [m].
        N : ndarray, broadcastable to ``x``
            Normal load [N].

        Returns
        -------
        ndarray
            ``f_bb(x; N) = sum_i min(k_i x, g_i N)`` for friction laws (0 for
            ``N <= 0``); ``k x`` for the linear law [N].
        """
        x = np.asarray(x, dtype=float)
        N = np.asarray(N, dtype=float)
        extra = (1,) * (max(x.ndim, N.ndim) - 1)
        out = np.zeros(np.broadcast(x, N).shape)
        Np = np.maximum(N, 0.0)
        for i in range(self.n_sliders):
            ki = self.k[:, i].reshape((-1,) + extra)
            gi = self.g[:, i].reshape((-1,) + extra)
            out += np.minimum(ki * x, gi * Np)
        return out

    def slip_force(self, N):
        """Macroslip force ``mu N`` [N] (0 where ``N <= 0``), broadcast per element."""
        N = np.asarray(N, dtype=float)
        mu = self.mu.reshape((-1,) + (1,) * (N.ndim - 1))
        return mu * np.maximum(N, 0.0)

    def subset(self, index) -> "TangentialLaw":
        """The law restricted to elements ``index``."""
        return dataclasses.replace(self, k=self.k[index], g=self.g[index], mu=self.mu[index])


def continuation_advice(law: TangentialLaw, coupled: bool) -> str:
    """Why a continuation with ``law`` may give up, and what to do; ``""`` when it should not.

    A scaled reversal law (seed Eq. 7, ``joint.reversal = "scaled"``, and
    ``"manifold"``) is not path-continuous once the normal load varies: its
    reference term ``f_r N / N_r`` jumps between 0 (a reversal taken while
    separated, ``N_r = 0``) and ``+-mu N`` (``N_r -> 0+`` with
    ``f_r = +-mu N_r``), and a micro-reversal re-scales the reference force
    (``kt (u - u_r) (N / N_r - 1)`` later).  The harmonic-balance residual is
    then discontinuous in the unknowns, and neither Newton nor a smaller step
    can cross the jump.

    Parameters
    ----------
    law : TangentialLaw
    coupled : bool
        The normal load is computed from the gap (``effects.normal = "coupled"``).
    """
    if law.path_continuous or not coupled:
        return ""
    return (f"the tangential law {law.name!r} is not path-continuous under a varying normal "
            "load (its reference force f_r N/N_r jumps between 0 and +-mu N when a reversal "
            "crosses a separation instant, a micro-reversal re-scales it, and with the "
            "manifold law the branch an inner loop closes onto scales by another N_r), so the "
            "residual can jump and continuation cannot pass such a point; use "
            "joint.reversal = 'anchor' for continuation and replay the loops with the scaled "
            "or manifold law in prescribed motion (README: Reversal laws and the manifold)")


def _no_history(u):
    ne = u.shape[0]
    return np.ones(ne, dtype=np.int64), np.zeros(ne)


@dataclass(frozen=True)
class SliderBank(TangentialLaw):
    """A friction law marched by :func:`jointsim.contact._kernels.march_bank`.

    Class attributes: ``bank_code``, the law's code in that kernel.
    """

    bank_code: ClassVar[int] = -1

    def march(self, u, N, state):
        return K.march_bank(self.bank_code, np.ascontiguousarray(u, dtype=float),
                            np.ascontiguousarray(N, dtype=float), self.k, self.g,
                            np.ascontiguousarray(state))


@dataclass(frozen=True)
class AnchoredBank(SliderBank):
    """Physical elastic dry friction (seed Eq. 1/3): anchored Jenkins sliders.

    State per element: the anchor ``w`` of every slider [m].
    """

    name: ClassVar[str] = "bank_anchor"
    bank_code: ClassVar[int] = K.BANK_ANCHOR
    fused_code: ClassVar[int | None] = FUSED_ANCHOR

    def state_size(self) -> int:
        return self.n_sliders

    def state_at(self, u0, N0) -> np.ndarray:
        s = self.rest_state(N0)
        s[:] = np.asarray(u0, dtype=float)[:, None]
        return s

    uses_gap: ClassVar[bool] = True

    def aft(self, u, N, dNdg, basis, min_periods, max_periods, tol, coupled, parallel=True,
            gap=None, dF=None):
        return AK.anchor_aft(u, N, dNdg, self.k, self.g, basis.CP, basis.Gam, min_periods,
                             max_periods, tol, coupled, parallel, gap=gap, dF=dF)


@dataclass(frozen=True)
class ScaledBank(SliderBank):
    """The seed's Eq. 7 reversal law: reversal force scaled by ``N / N_r``.

    State per element: the shared reversal memory (``SC_SHARED`` entries) and,
    per slider, the previous force and the force at the last reversal.
    """

    name: ClassVar[str] = "bank_scaled"
    bank_code: ClassVar[int] = K.BANK_SCALED
    path_continuous: ClassVar[bool] = False

    def state_size(self) -> int:
        return K.SC_SHARED + 2 * self.n_sliders

    def rest_state(self, N0) -> np.ndarray:
        ne = self.n_elements
        s = np.zeros((ne, self.state_size()))
        N0 = np.broadcast_to(np.asarray(N0, dtype=float), (ne,))
        s[:, K.SC_N_PREV] = N0
        s[:, K.SC_N_R] = N0
        return s

    def state_at(self, u0, N0) -> np.ndarray:
        s = self.rest_state(N0)
        s[:, K.SC_U_PREV] = u0
        s[:, K.SC_U_R] = u0
        return s

    def aft(self, u, N, dNdg, basis, min_periods, max_periods, tol, coupled, parallel=True):
        return AK.scaled_aft(u, N, dNdg, self.k, self.g, np.ascontiguousarray(N[:, 0]),
                             basis.P, basis.Gam, min_periods, max_periods, tol, coupled,
                             parallel)


@dataclass(frozen=True)
class ManifoldBank(SliderBank):
    """Seed Eq. 7's scaled reversal force with the Masing manifold's own memory.

    After a reversal ``(u_r, N_r, f_r)`` the force is the manifold's,
    ``f = f_r N / N_r + 2 sgn(u - u_r) f_bb(|u - u_r| / 2; N)`` (DESIGN §2),
    with ``f_bb`` the backbone of the slider bank ``(k, g)``; before the first
    reversal it is the backbone ``sgn(u - u_0) f_bb(|u - u_0|; N)``.  The
    governing reversal comes from a stack that is popped when an inner loop
    closes, exactly the memory rule of :func:`jointsim.masing.check_loops`, so
    the law is on its manifold to round-off wherever the manifold lies inside
    the friction limit; where it does not (``|f_manifold| > mu N``, possible
    when N falls after a reversal whose force was inside the limit) the
    force is clipped to ``+-mu N``, and the Masing check's deviation equals
    exactly the manifold's excess over the limit.

    Differences with :class:`ScaledBank` (Eq. 7): Eq. 7 keeps only the last
    reversal, so after an inner loop closes it does not return to the older
    branch; and it scales and clips each slider separately.  Both agree for
    two-reversal loops whose reversals are reached in slip.

    State per element: ``MF_SHARED`` entries and a stack of ``MF_DEPTH`` open
    reversals (see :func:`jointsim.contact._kernels.march_bank`).  On
    overflow the oldest open reversal is forgotten.  Like Eq. 7 the law is not
    path-continuous (a micro-reversal re-scales the reference force, and where an
    inner loop closes under varying N the older branch's ``f_r N / N_r`` differs
    from the inner branch's: the force jumps).  Its AFT
    kernel (:func:`jointsim.contact._aft_manifold.manifold_aft`) marches the
    same memory rule and force with exact derivatives through the stack, so
    harmonic balance and EPMC accept it.
    """

    name: ClassVar[str] = "bank_manifold"
    bank_code: ClassVar[int] = K.BANK_MANIFOLD
    path_continuous: ClassVar[bool] = False

    def state_size(self) -> int:
        return K.MF_SHARED + 3 * K.MF_DEPTH

    def rest_state(self, N0) -> np.ndarray:
        ne = self.n_elements
        s = np.zeros((ne, self.state_size()))
        s[:, K.MF_N_PREV] = np.broadcast_to(np.asarray(N0, dtype=float), (ne,))
        return s

    def state_at(self, u0, N0) -> np.ndarray:
        s = self.rest_state(N0)
        s[:, K.MF_U_PREV] = u0
        s[:, K.MF_U0] = u0
        return s

    def aft(self, u, N, dNdg, basis, min_periods, max_periods, tol, coupled,
            parallel=True):
        return AM.manifold_aft(u, N, dNdg, self.k, self.g, basis.P, basis.Gam, min_periods,
                               max_periods, tol, coupled, parallel)


@dataclass(frozen=True)
class LinearSpring(TangentialLaw):
    """A tangential spring that never slips (the ``stuck`` law): ``f = k u``."""

    name: ClassVar[str] = "linear"
    can_slip: ClassVar[bool] = False
    fused_code: ClassVar[int | None] = FUSED_LINEAR

    def march(self, u, N, state):
        f, dfdu = K.linear_spring(np.ascontiguousarray(u, dtype=float),
                                  np.ascontiguousarray(self.k[:, 0]))
        return f, dfdu, np.zeros_like(f), state

    def aft(self, u, N, dNdg, basis, min_periods, max_periods, tol, coupled, parallel=True):
        k = self.k[:, 0]
        periods, change = _no_history(u)
        return (k[:, None] * u, np.broadcast_to(k[:, None], u.shape), None, None, None,
                periods, change)

    def backbone(self, x, N):
        x = np.asarray(x, dtype=float)
        N = np.asarray(N, dtype=float)
        k = self.k[:, 0].reshape((-1,) + (1,) * (max(x.ndim, N.ndim) - 1))
        return k * x + 0.0 * N


@dataclass(frozen=True)
class NoFriction(TangentialLaw):
    """No tangential force (``effects.friction = false``)."""

    name: ClassVar[str] = "none"
    has_force: ClassVar[bool] = False
    can_slip: ClassVar[bool] = False
    fused_code: ClassVar[int | None] = FUSED_NONE

    def march(self, u, N, state):
        z = np.zeros(np.shape(u))
        return z, z.copy(), z.copy(), state

    def aft(self, u, N, dNdg, basis, min_periods, max_periods, tol, coupled, parallel=True):
        periods, change = _no_history(u)
        return np.zeros_like(u), None, None, None, None, periods, change

    def backbone(self, x, N):
        return np.zeros(np.broadcast(np.asarray(x, dtype=float),
                                     np.asarray(N, dtype=float)).shape)


def jenkins_parameters(joint, KT, mu):
    """Slider arrays of a Jenkins element: one slider ``(kt A, mu)`` per element."""
    return KT[:, None], mu[:, None]


def iwan4_parameters(joint, KT, mu):
    """Slider arrays of the discretised 4-parameter Iwan element.

    The slider stiffnesses do not depend on N; the slip forces scale with it,
    so the element is discretised at N = 1 (slip forces per unit normal load).
    With ``joint.iwan_spacing = "geometric"`` (default) the slider count, when
    not given, is the fewest that meets ``joint.iwan_rtol`` (:func:`iwan4_design`).
    """
    ne = KT.size
    n, lowest = joint.n_sliders or 40, 1e-3
    if joint.iwan_spacing == "geometric":
        n, lowest, _err = iwan4_design(joint.chi, joint.iwan_rtol, n=joint.n_sliders)
    k = np.empty((ne, n))
    g = np.empty((ne, n))
    for e in range(ne):
        k[e], g[e] = iwan4_sliders(KT[e], joint.mu, joint.chi, joint.beta, n,
                                   joint.iwan_spacing, lowest)
    return k, g


def spring_parameters(joint, KT, mu):
    """The spring of a law that never slips: stiffness ``kt A``, no slip force."""
    return KT[:, None], np.zeros((KT.size, 1))


def no_parameters(joint, KT, mu):
    """No slider (a frictionless element)."""
    return np.zeros((KT.size, 1)), np.zeros((KT.size, 1))
