"""Contact-law parameters, state, backbones, and the call into the kernels.

A :class:`TangentialLaw` holds per-element parameter arrays (plain NumPy) and
knows which kernel marches it.  It is built once, before any loop, from the
joint parameters and the element areas (see :mod:`jointsim.contact.select`).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from . import _kernels as K

TANGENTIAL_KINDS = ("bank_anchor", "bank_scaled", "linear", "none")
NORMAL_KINDS = ("given", "unilateral", "bilateral")


def iwan4_sliders(KT: float, Fs: float, chi: float, beta: float, n: int):
    """Discretise Segalman's 4-parameter Iwan element into ``n`` Jenkins sliders.

    The power-law part of the slider density, ``R phi^chi`` on
    ``[0, phi_max]``, is split into ``n - 1`` equal-width bins; each bin
    becomes one slider with the bin's exact stiffness and a slip displacement
    at the bin's centroid, so that the total stiffness ``KT`` and the total
    slip force ``Fs`` are exact.  The spike ``S delta(phi - phi_max)`` is the
    last slider.

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
    edges = np.linspace(0.0, phimax, n)
    p1 = edges ** (chi + 1.0)
    p2 = edges ** (chi + 2.0)
    k = np.empty(n)
    fs = np.empty(n)
    k[:-1] = R * np.diff(p1) / (chi + 1.0)
    fs[:-1] = R * np.diff(p2) / (chi + 2.0)
    k[-1] = S  # beta = 0 leaves a slider of zero stiffness and strength
    fs[-1] = S * phimax
    return k, fs


def iwan4_constants(KT: float, Fs: float, chi: float, beta: float):
    """Segalman's derived constants ``(c, phi_max, R, S)`` (DESIGN §5)."""
    c = beta + (chi + 1.0) / (chi + 2.0)
    phimax = Fs * (1.0 + beta) / (KT * c)
    R = Fs * (chi + 1.0) / (phimax ** (chi + 2.0) * c)
    S = KT * beta / (1.0 + beta)
    return c, phimax, R, S


@dataclass(frozen=True)
class TangentialLaw:
    """Tangential contact law of ``n_e`` elements.

    Attributes
    ----------
    kind : str
        Kernel: ``bank_anchor``, ``bank_scaled``, ``linear`` or ``none``.
    k : ndarray, shape (n_e, n_s)
        Slider stiffnesses [N/m] (``linear``: one column, the spring).
    g : ndarray, shape (n_e, n_s)
        Slip force per unit normal load of each slider [-] (0 for ``linear``).
    mu : ndarray, shape (n_e,)
        Friction coefficient; the macroslip force is ``mu N``.
    """

    kind: str
    k: np.ndarray
    g: np.ndarray
    mu: np.ndarray

    def __post_init__(self):
        if self.kind not in TANGENTIAL_KINDS:
            raise ValueError(f"unknown tangential kernel {self.kind!r}")
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

    def state_size(self) -> int:
        """Number of state entries per element."""
        if self.kind == "bank_anchor":
            return self.n_sliders
        if self.kind == "bank_scaled":
            return K.SC_SHARED + 2 * self.n_sliders
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
        ne = self.n_elements
        s = np.zeros((ne, self.state_size()))
        if self.kind == "bank_scaled":
            N0 = np.broadcast_to(np.asarray(N0, dtype=float), (ne,))
            s[:, K.SC_N_PREV] = N0
            s[:, K.SC_N_R] = N0
        return s

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
        u = np.ascontiguousarray(u, dtype=float)
        N = np.ascontiguousarray(N, dtype=float)
        if self.kind == "bank_anchor":
            return K.bank_anchor_march(u, N, self.k, self.g, np.ascontiguousarray(state))
        if self.kind == "bank_scaled":
            return K.bank_scaled_march(u, N, self.k, self.g, np.ascontiguousarray(state))
        if self.kind == "linear":
            f, dfdu = K.linear_spring(u, np.ascontiguousarray(self.k[:, 0]))
            return f, dfdu, np.zeros_like(f), state
        z = np.zeros_like(u)
        return z, z.copy(), z.copy(), state

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
        if self.kind == "none":
            return np.zeros(np.broadcast(x, N).shape)
        extra = (1,) * (max(x.ndim, N.ndim) - 1)
        if self.kind == "linear":
            k = self.k[:, 0].reshape((-1,) + extra)
            return k * x + 0.0 * N
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


def make_tangential_law(kind: str, law: str, joint, area) -> TangentialLaw:
    """Per-element parameter arrays of a tangential law.

    Parameters
    ----------
    kind : str
        Kernel kind (from the selection table).
    law : str
        ``jenkins``, ``iwan4`` or ``stuck``.
    joint : jointsim.scene.Joint
        Joint parameters (stiffness per unit area).
    area : array_like, shape (n_e,)
        Element areas [m^2].
    """
    area = np.atleast_1d(np.asarray(area, dtype=float))
    ne = area.size
    mu = np.full(ne, joint.mu)
    KT = joint.kt * area
    if kind == "none":
        return TangentialLaw("none", np.zeros((ne, 1)), np.zeros((ne, 1)), mu)
    if kind == "linear":
        return TangentialLaw("linear", KT[:, None], np.zeros((ne, 1)), mu)
    if law == "jenkins":
        return TangentialLaw(kind, KT[:, None], mu[:, None], mu)
    if law == "iwan4":
        # The slider stiffnesses do not depend on N; the slip forces scale with
        # it.  Discretise at N = 1 to get slip forces per unit normal load.
        k = np.empty((ne, joint.n_sliders))
        g = np.empty((ne, joint.n_sliders))
        for e in range(ne):
            k[e], g[e] = iwan4_sliders(KT[e], joint.mu, joint.chi, joint.beta,
                                       joint.n_sliders)
        return TangentialLaw(kind, k, g, mu)
    raise ValueError(f"no tangential law {law!r} for kernel {kind!r}")
