"""Prescribed motion: contact elements driven by given u_t(t) and N(t).

The elements start at rest (``u = 0``, anchors at 0) and are marched over
``n_periods`` periods of ``n_samples`` samples each.  Because every law is
rate independent, the force at a sample depends only on the sequence of
sampled inputs: the march is exact at the samples, and there is no time step
error.
"""
from __future__ import annotations

import logging

import numpy as np

from ..results import NOT_CONVERGED, SUCCESS, Convergence, PrescribedResult
from ..signals import sample

log = logging.getLogger(__name__)

#: Largest force change between the last two periods, relative to the slip
#: force, for the loop to count as periodic.
PERIODIC_TOL = 1e-10


def march_prescribed(u, N, law, n_samples: int, omega: float, t=None) -> PrescribedResult:
    """March elements from rest under prescribed inputs.

    Parameters
    ----------
    u, N : ndarray, shape (n_e, n_t)
        Tangential displacement [m] and normal load [N]; ``n_t`` is a whole
        number of periods of ``n_samples`` samples.
    law : jointsim.contact.TangentialLaw
    n_samples : int
        Samples per period.
    omega : float
        Base angular frequency [rad/s].
    t : ndarray, shape (n_t,), optional
        Sample times [s], stored in the result.

    Returns
    -------
    PrescribedResult
    """
    u = np.atleast_2d(np.asarray(u, dtype=float))
    N = np.atleast_2d(np.asarray(N, dtype=float))
    ne, nt = u.shape
    if nt % n_samples or nt // n_samples < 2:
        raise ValueError("the inputs must hold at least two whole periods")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(N))):
        raise ValueError("prescribed inputs contain non-finite values")
    if t is None:
        t = np.arange(nt) * (2.0 * np.pi / omega) / n_samples
    state = law.rest_state(N[:, 0])
    f, _dfdu, _dfdN, _state = law.march(u, N, state)
    last = f[:, -n_samples:]
    before = f[:, -2 * n_samples:-n_samples]
    scale = np.maximum(law.slip_force(N).max(axis=1), np.abs(f).max(axis=1))
    scale = np.where(scale > 0.0, scale, 1.0)
    periodicity = np.abs(last - before).max(axis=1) / scale
    n_periods = nt // n_samples
    if np.all(periodicity <= PERIODIC_TOL):
        conv = Convergence(True, SUCCESS, f"loop periodic after {n_periods} periods "
                                          f"(change {periodicity.max():.1e})", n_periods)
    else:
        conv = Convergence(False, NOT_CONVERGED,
                           f"loop not periodic after {n_periods} periods: the force still "
                           f"changes by {periodicity.max():.2e} of the slip force between "
                           "the last two periods; raise model.n_periods", n_periods)
        log.warning(conv.message)
    return PrescribedResult(t=np.asarray(t, dtype=float), u=u, N=N, f=f,
                            n_samples=n_samples, omega=omega, periodicity=periodicity,
                            convergence=conv)


def run_prescribed(scene, law) -> PrescribedResult:
    """Sample a prescribed-motion scene's inputs and march its element.

    Parameters
    ----------
    scene : jointsim.scene.Scene
        A scene with ``model.kind = "prescribed"``.
    law : jointsim.contact.TangentialLaw
        The one-element law built for the scene.
    """
    m = scene.model
    period = 2.0 * np.pi / m.omega
    t = np.arange(m.n_periods * m.n_samples) * period / m.n_samples
    u = sample(m.u_t, t, m.omega, scene.base_dir)[None, :]
    N = sample(m.N, t, m.omega, scene.base_dir)[None, :]
    if np.any(N < 0.0):
        log.warning("%s: N(t) is negative at some samples; the law treats N <= 0 as "
                    "separated (set clip_at_zero = true to make this explicit)", scene.path)
    return march_prescribed(u, N, law, m.n_samples, m.omega, t)
