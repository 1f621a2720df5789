"""External and static loads of a structural model, for every solver.

A model carries a constant load ``f_static`` [N] (e.g. the bolt preload) and
load signals ``load_signals[i]`` acting on DOF ``load_dofs[i]``
(:class:`jointsim.scene.Signal`: a constant plus harmonics, or samples from
a file, optionally clipped at zero).  This module is the one place that
turns them into

* harmonic coefficients in the order of :mod:`jointsim.harmonics`
  (:func:`force_coefficients`, harmonic balance and EPMC),
* the constant load (:func:`static_load`, the static state), and
* a function of time (:class:`LoadFunction`, time marching; its
  :attr:`~LoadFunction.coefficients` and :attr:`~LoadFunction.harmonic_rows`
  are also what the fused numba march evaluates).

A ``scale`` multiplies the harmonic (not the constant) parts of the loads.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .harmonics import (basis_values, coefficient_harmonics, coefficient_index,
                        coefficient_kinds, harmonic_coefficients)


def _is_sampled(signal) -> bool:
    """Whether a signal must be sampled (a file or clipped) rather than expanded."""
    return signal.file is not None or signal.clip_at_zero


def force_coefficients(model, harmonics, scale: float = 1.0) -> np.ndarray:
    """External force of a model in harmonic coefficients.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    harmonics : sequence of int
        Harmonics kept; coefficient order ``[0, 1c, 1s, 2c, 2s, ...]``.
    scale : float
        Multiplier of the harmonic (not the static) loads.

    Returns
    -------
    ndarray, shape (n_coeff, n_dof)
        Coefficients [N].  Static parts (the loads' constants and
        ``f_static``) sit in the harmonic-0 row, unscaled, when 0 is kept.
    """
    static = coefficient_harmonics(harmonics) == 0
    F = np.zeros((static.size, model.n_dof))
    for dof, sig in zip(model.load_dofs, model.load_signals):
        c = harmonic_coefficients(sig, harmonics)
        F[:, dof] += np.where(static, c, scale * c)
    F[static] += model.f_static
    return F


def _constant_load(model, loads) -> np.ndarray:
    """``f_static`` plus the constants of ``loads`` (pairs ``(dof, signal)``) [N], (n_dof,)."""
    f = np.array(model.f_static, dtype=float)
    for dof, sig in loads:
        f[dof] += sig.constant
    return f


def static_load(model) -> np.ndarray:
    """Constant load on a model: ``f_static`` plus the constant parts of its loads.

    Parameters
    ----------
    model : jointsim.model.StructuralModel

    Returns
    -------
    ndarray, shape (n_dof,) [N]

    Raises
    ------
    NotImplementedError
        For a file or clipped load signal (its mean is not a scene value).
    """
    loads = list(zip(model.load_dofs, model.load_signals))
    for _dof, sig in loads:
        if _is_sampled(sig):
            harmonic_coefficients(sig, (0,))  # raises with the reason
    return _constant_load(model, loads)


@dataclass(frozen=True)
class LoadFunction:
    """External force ``f(t) = f_static + sum_loads`` as a callable.

    Harmonic load signals are kept as coefficients and evaluated as
    ``F0 + sum_h (Fc_h cos h w t + Fs_h sin h w t)``; file and clipped signals
    are sampled (and may not be scaled).

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    omega : float
        Base angular frequency [rad/s]; 0 keeps only the static parts.
    scale : float
        Multiplier of the harmonic parts of the loads.
    base_dir : Path, optional
        Folder of file signals.
    """

    model: object
    omega: float
    scale: float = 1.0
    base_dir: object = None
    _coef: np.ndarray = field(init=False, repr=False)
    _hs: tuple = field(init=False, repr=False)
    _h: np.ndarray = field(init=False, repr=False)
    _sk: np.ndarray = field(init=False, repr=False)
    _sampled: tuple = field(init=False, repr=False)

    def __post_init__(self):
        m = self.model
        harmonic, sampled = [], []
        for dof, sig in zip(m.load_dofs, m.load_signals):
            (sampled if _is_sampled(sig) else harmonic).append((int(dof), sig))
        hmax = max((s.max_harmonic for _d, s in harmonic), default=0)
        hs = tuple(range(hmax + 1)) if self.omega != 0.0 else (0,)
        coef = np.zeros((coefficient_harmonics(hs).size, m.n_dof))
        coef[0] = _constant_load(m, harmonic)
        for dof, sig in harmonic:
            for hh in sig.harmonics:
                if hh.h not in hs:
                    continue
                ic, is_ = coefficient_index(hs, hh.h)
                coef[ic, dof] += self.scale * hh.cos
                coef[is_, dof] += self.scale * hh.sin
        if sampled and self.scale != 1.0 and self.omega > 0.0:
            raise NotImplementedError("force_scale != 1 with a file or clipped load signal: "
                                      "scale the signal itself in the scene")
        if sampled and self.omega == 0.0:
            raise NotImplementedError("free decay with a file or clipped load signal: only "
                                      "constant loads can be held during a free decay")
        object.__setattr__(self, "_coef", coef)
        object.__setattr__(self, "_hs", hs)
        object.__setattr__(self, "_h", coefficient_harmonics(hs))
        object.__setattr__(self, "_sk", coefficient_kinds(hs))
        object.__setattr__(self, "_sampled", tuple(sampled))

    @property
    def harmonics(self) -> tuple:
        """Harmonics of :attr:`coefficients`: ``(0, 1, ..., max)`` (``(0,)`` for omega = 0)."""
        return self._hs

    @property
    def harmonic_rows(self) -> np.ndarray:
        """Harmonic number of each row of :attr:`coefficients`, shape (n_coeff,)."""
        return self._h

    @property
    def coefficients(self) -> np.ndarray:
        """Force coefficients ``[0, 1c, 1s, ...]`` [N], shape (n_coeff, n_dof)."""
        return self._coef

    @property
    def sampled(self) -> bool:
        """True when some load is a file or clipped signal (sampled, not harmonic)."""
        return bool(self._sampled)

    def static(self) -> np.ndarray:
        """The constant part ``f_static + load constants`` [N], shape (n_dof,)."""
        return self._coef[0].copy()

    def __call__(self, t: float) -> np.ndarray:
        """The force at time ``t`` [s], shape (n_dof,) [N]."""
        out = basis_values(self._h, self._sk, self.omega * t) @ self._coef
        if self._sampled:
            from .signals import sample
            for dof, sig in self._sampled:
                out[dof] += float(sample(sig, np.array([t]), self.omega, self.base_dir)[0])
        return out
