"""The generalized-alpha integrator (:mod:`jointsim.solvers.generalized_alpha`).

Its order on a linear oscillator, the step tangent, step cutting and the
agreement of its marching paths are tested in ``test_transient.py`` and
``test_transient_paths.py``; here: a step depends on its start state only.
"""
from __future__ import annotations

import numpy as np
import pytest

from jointsim.loads import LoadFunction
from jointsim.model import build_model
from jointsim.solvers.generalized_alpha import GeneralizedAlpha
from jointsim.solvers.static import static_start

from .._transient_scenes import sdof_jenkins


@pytest.mark.parametrize("fused", [False, True])
def test_step_newton_tolerance_does_not_depend_on_earlier_steps(fused):
    """Steps from the same state give the same result whatever was marched before.

    A loose Newton tolerance makes the tolerance's displacement scale matter
    (the predictor is accepted when it is within tolerance).  One stepper
    first rings down from a deflection 20 times the later swing; a fresh
    stepper without that history must march the next steps alike (to the
    round-off of its own factorisation of the step matrix; a tolerance
    scaled by the history moves the results by about ``newton_tol``).
    """
    w = 1.0
    model = build_model(sdof_jenkins({"omega": w}, F=0.05))
    force = LoadFunction(model, w)
    st = static_start(model)
    h = 2.0 * np.pi / w / 64

    def stepper():
        return GeneralizedAlpha(model, force, rho_inf=0.85, newton_tol=1e-5, fused=fused)

    ga = stepper()
    assert ga.fused == fused
    s = ga.start(0.0, np.array([20.0]), np.zeros(1), st.contact.state)
    s, x_hist, *_ = ga.march_block(s, np.arange(401) * h)
    t = (400 + np.arange(65)) * h
    _, *after_history = ga.march_block(s, t)
    _, *fresh = stepper().march_block(s, t)
    assert np.abs(after_history[0]).max() < 0.2 * np.abs(x_hist).max()
    for a, b in zip(after_history, fresh):
        assert np.abs(a - b).max() <= 1e-12 * max(np.abs(b).max(), 1e-300)
