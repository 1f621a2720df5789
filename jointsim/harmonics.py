"""The harmonic coefficient order, in one place.

A periodic signal ``x(t)`` of base angular frequency ``omega`` is kept as its
coefficients over a set of harmonics ``h`` (each at most once, in the order
given), in the order ``[0, 1c, 1s, 2c, 2s, ...]``::

    x(t) = X_0 + sum_{h > 0} (X_hc cos(h omega t) + X_hs sin(h omega t)).

Harmonic 0 has one coefficient, every other harmonic two (cosine, then
sine).  Everything that needs to know where a coefficient sits (the row of
``X_hc``, the number of rows, the harmonic of a row, the DFT of samples, the
amplitude of a harmonic, the AFT basis) asks this module.
"""
from __future__ import annotations

import numpy as np

from . import _harmonic_kernels as HK


# --------------------------------------------------------------------------
# The order
# --------------------------------------------------------------------------
def coefficient_harmonics(harmonics) -> np.ndarray:
    """Harmonic number of each coefficient in the order ``[0, 1c, 1s, ...]``.

    Parameters
    ----------
    harmonics : sequence of int
        Harmonics kept, e.g. ``(0, 1, 3)``.

    Returns
    -------
    ndarray of int, shape (n_coeff,)
        ``(0, 1, 1, 3, 3)`` for the example.
    """
    return np.array([h for h in harmonics for _ in range(1 if h == 0 else 2)], dtype=np.int64)


def coefficient_kinds(harmonics) -> np.ndarray:
    """1 for the sine coefficients, 0 for the cosine and constant ones.

    Parameters
    ----------
    harmonics : sequence of int

    Returns
    -------
    ndarray of int, shape (n_coeff,)
        ``(0, 0, 1, 0, 1)`` for ``(0, 1, 3)``.
    """
    return np.array([k for h in harmonics for k in ((0,) if h == 0 else (0, 1))],
                    dtype=np.int64)


def n_coefficients(harmonics) -> int:
    """Number of coefficients ``n_coeff`` of a harmonic set (1 for h = 0, 2 for others)."""
    return sum(1 if int(h) == 0 else 2 for h in harmonics)


def rows(harmonics) -> dict:
    """Row slice of every harmonic, ``{h: slice}`` (length 1 for h = 0, else 2).

    Parameters
    ----------
    harmonics : sequence of int

    Returns
    -------
    dict of int -> slice
        ``{0: slice(0, 1), 1: slice(1, 3), 3: slice(3, 5)}`` for ``(0, 1, 3)``.
    """
    out, r = {}, 0
    for h in harmonics:
        n = 1 if h == 0 else 2
        out[int(h)] = slice(r, r + n)
        r += n
    return out


def coefficient_index(harmonics, h: int) -> tuple[int, int]:
    """Rows ``(ic, is)`` of the cosine and sine coefficients of harmonic ``h``.

    Parameters
    ----------
    harmonics : sequence of int
    h : int
        A kept harmonic.

    Returns
    -------
    ic, is : int
        Row of ``X_hc`` (of ``X_0`` for h = 0) and of ``X_hs`` (-1 for h = 0).

    Raises
    ------
    KeyError
        When ``h`` is not kept.
    """
    sl = rows(harmonics)[int(h)]
    return (sl.start, -1) if h == 0 else (sl.start, sl.start + 1)


def basis_functions(harmonics, theta) -> np.ndarray:
    """Values of the basis functions ``1, cos(h theta), sin(h theta)`` in coefficient order.

    Parameters
    ----------
    harmonics : sequence of int
    theta : float or ndarray, shape (n_t,)
        Phase ``omega t`` [rad].

    Returns
    -------
    ndarray, shape (n_coeff,) or (n_t, n_coeff)
        ``x(theta) = basis_functions(...) @ X``.
    """
    return basis_values(coefficient_harmonics(harmonics), coefficient_kinds(harmonics), theta)


def basis_values(hk, sk, theta) -> np.ndarray:
    """:func:`basis_functions` from precomputed :func:`coefficient_harmonics` ``hk`` and
    :func:`coefficient_kinds` ``sk`` (for evaluations in a loop)."""
    arg = np.multiply.outer(np.asarray(theta, dtype=float), hk)
    return np.where(sk == 1, np.sin(arg), np.cos(arg))


def harmonic_amplitude(harmonics, X, h: int = 1):
    """Amplitude ``sqrt(X_hc^2 + X_hs^2)`` of harmonic ``h`` (``|X_0|`` for h = 0).

    Parameters
    ----------
    harmonics : sequence of int or HarmonicBasis
        The kept harmonics (a basis stands for its ``harmonics``).
    X : ndarray, shape (n_coeff, ...)
        Coefficients.
    h : int

    Returns
    -------
    ndarray, shape ``X.shape[1:]``
    """
    ic, is_ = coefficient_index(getattr(harmonics, "harmonics", harmonics), h)
    X = np.asarray(X)
    if h == 0:
        return np.abs(X[ic])
    return np.hypot(X[ic], X[is_])


# --------------------------------------------------------------------------
# Signals given by harmonics
# --------------------------------------------------------------------------
def harmonic_coefficients(signal, harmonics) -> np.ndarray:
    """Coefficients of a signal in the order ``[0, 1c, 1s, ...]`` of ``harmonics``.

    Only for signals given by harmonics (not files, not clipped).

    Parameters
    ----------
    signal : jointsim.scene.Signal
    harmonics : sequence of int
        Harmonics kept, e.g. ``(0, 1, 3)``.

    Returns
    -------
    ndarray, shape (n_coeff,)
        One entry for harmonic 0, two (cos, sin) for every other.
    """
    if signal.file is not None or signal.clip_at_zero:
        raise NotImplementedError("harmonic coefficients of a file or clipped signal: "
                                  "sample it and take its DFT instead")
    coeff = []
    for h in harmonics:
        if h == 0:
            coeff.append(signal.constant)
        else:
            c = sum(x.cos for x in signal.harmonics if x.h == h)
            s = sum(x.sin for x in signal.harmonics if x.h == h)
            coeff.extend([c, s])
    missing = {x.h for x in signal.harmonics} - set(harmonics)
    if missing:
        raise ValueError(f"signal has harmonics {sorted(missing)} outside the kept set")
    return np.asarray(coeff, dtype=float)


# --------------------------------------------------------------------------
# Samples <-> coefficients
# --------------------------------------------------------------------------
def dft_matrix(harmonics, n: int, omega: float, t0: float = 0.0) -> np.ndarray:
    """Matrix taking ``n`` equispaced samples of a period to harmonic coefficients.

    Parameters
    ----------
    harmonics : sequence of int
        Harmonics kept (each < n/2).
    n : int
        Samples per period, at ``t0 + k T / n``.
    omega : float
        Angular frequency [rad/s].
    t0 : float
        Time of the first sample (a multiple of the period keeps the phase of
        the forcing) [s].

    Returns
    -------
    ndarray, shape (n_coeff, n)
        Rows in the order ``[0, 1c, 1s, 2c, 2s, ...]``.
    """
    hs = coefficient_harmonics(harmonics)
    if np.any(2 * hs >= n):
        raise ValueError(f"harmonics up to {hs.max()} need more than {2 * hs.max()} samples "
                         f"per period, got {n}")
    t = t0 + np.arange(n) * (2.0 * np.pi / omega) / n
    E = np.empty((hs.size, n))
    for h, sl in rows(harmonics).items():
        if h == 0:
            E[sl.start] = 1.0 / n
        else:
            E[sl.start] = (2.0 / n) * np.cos(h * omega * t)
            E[sl.start + 1] = (2.0 / n) * np.sin(h * omega * t)
    return E


class HarmonicBasis:
    """Sampling and DFT matrices of a harmonic set (the AFT basis).

    Parameters
    ----------
    harmonics : sequence of int
        Harmonics kept, each at most once.
    n_samples : int
        AFT samples per period, ``>= 2 max(h) + 1``.

    Attributes
    ----------
    hk : ndarray of int, shape (n_c,)
        Harmonic of each coefficient (order ``[0, 1c, 1s, ...]``).
    sk : ndarray of int, shape (n_c,)
        1 for sine coefficients.
    Gam : ndarray, shape (n_t, n_c)
        Samples from coefficients, ``x(t_j) = Gam[j] @ X``.
    P : ndarray, shape (n_c, n_t)
        Coefficients from samples (exact for the kept harmonics).
    CP : ndarray, shape (n_c, n_t + 1)
        Prefix sums of the columns of ``P``.
    cosm, sinm : ndarray, shape (n_t, 2 max(h) + 1)
        ``cos(m theta_j)``, ``sin(m theta_j)``.
    index : dict of int -> (int, int)
        :func:`coefficient_index` of every kept harmonic.
    """

    def __init__(self, harmonics, n_samples: int):
        harmonics = tuple(int(h) for h in harmonics)
        if len(set(harmonics)) != len(harmonics) or min(harmonics) < 0:
            raise ValueError(f"harmonics must be distinct and >= 0, got {harmonics}")
        hmax = max(harmonics)
        if n_samples < 2 * hmax + 1:
            raise ValueError(f"n_samples must be >= 2*max(h)+1 = {2 * hmax + 1}")
        self.harmonics = harmonics
        self.n_samples = int(n_samples)
        self.hk = coefficient_harmonics(harmonics)
        self.sk = coefficient_kinds(harmonics)
        self.n_coeff = self.hk.size
        theta = 2.0 * np.pi * np.arange(n_samples) / n_samples
        self.theta = theta
        self.Gam = basis_functions(harmonics, theta)
        self.wk = np.where(self.hk == 0, 1.0 / n_samples, 2.0 / n_samples)
        self.P = np.ascontiguousarray((self.Gam * self.wk[None, :]).T)
        self.CP = np.zeros((self.n_coeff, n_samples + 1))
        np.cumsum(self.P, axis=1, out=self.CP[:, 1:])
        m = np.arange(2 * hmax + 1)
        self.cosm = np.cos(np.outer(theta, m))
        self.sinm = np.sin(np.outer(theta, m))
        self.index = {h: coefficient_index(harmonics, h) for h in harmonics}
        H = np.asarray(harmonics)
        #: row of each kept harmonic's cosine coefficient (of the constant for h = 0)
        self.rows_cos = np.array([self.index[h][0] for h in harmonics], dtype=np.int64)
        #: which kept harmonics have a sine coefficient (h > 0)
        self.has_sine = H > 0
        #: row of the sine coefficient of each harmonic with one
        self.rows_sin = np.array([self.index[h][1] for h in H[self.has_sine]], dtype=np.int64)

    def to_complex(self, X):
        """Complex amplitudes ``X_hc - i X_hs`` of every kept harmonic (``X_0`` for h = 0).

        Parameters
        ----------
        X : ndarray, shape (n_c, ...)
            Coefficient rows.

        Returns
        -------
        ndarray, shape (n_h, ...), complex
        """
        out = X[self.rows_cos].astype(complex)
        out[self.has_sine] -= 1j * X[self.rows_sin]
        return out

    def from_complex(self, Y, out) -> None:
        """Write the coefficient rows of amplitudes ``Y`` (n_h, ...) into ``out`` (n_c, ...)
        (the inverse of :meth:`to_complex`; the imaginary part of h = 0 is dropped)."""
        out[self.rows_cos] = Y.real
        out[self.rows_sin] = -Y.imag[self.has_sine]

    def samples(self, X):
        """Samples over one period of coefficient arrays ``X`` (n_c, ...) -> (n_t, ...)."""
        return np.tensordot(self.Gam, X, axes=(1, 0))

    def diag_product(self, alpha, parallel: bool = True):
        """``P diag(alpha_e) Gam`` for every row of ``alpha`` (n_e, n_t) -> (n_e, n_c, n_c).

        ``parallel=False`` keeps the kernel on the calling thread."""
        J = np.zeros((alpha.shape[0], self.n_coeff, self.n_coeff))
        self.add_diag_product(J, alpha, parallel)
        return J

    def add_diag_product(self, J, alpha, parallel: bool = True):
        """Add ``P diag(alpha_e) Gam`` to ``J[e]`` for every row of ``alpha`` (n_e, n_t).

        ``parallel=False`` keeps the kernel on the calling thread."""
        alpha = np.ascontiguousarray(alpha)
        HK.add_diag_products(J, alpha @ self.cosm, alpha @ self.sinm, self.hk, self.sk, self.wk,
                             parallel)
