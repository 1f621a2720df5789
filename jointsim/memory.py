"""Memory a scene plans to hold, checked before anything runs (bad input names its key).

:func:`memory_estimates` gives lower estimates of the largest arrays that a
scene's sample counts ask for, per key; :func:`jointsim.scene.load_scene`
refuses a scene whose estimate exceeds :func:`memory_limit`.
"""
from __future__ import annotations

import os


def memory_limit() -> float:
    """Bytes a run may plan to hold: half of the machine's physical memory (8 GB if unknown)."""
    try:
        return 0.5 * os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 8e9


def memory_estimates(scene) -> list[tuple[str, float]]:
    """Lower estimates of the largest arrays a scene's sample counts ask for.

    Parameters
    ----------
    scene : jointsim.scene.Scene

    Returns
    -------
    list of (key, bytes)
        The key whose value sets each estimate: AFT samples (states, forces
        and the DFT matrices of every contact element: about four arrays of
        ``n_samples x n_coeff`` per element), the prescribed march
        (``n_samples x n_periods``, about eight arrays) and the stored time
        history of time marching (displacement, velocity, acceleration of
        each output DOF).
    """
    m, a = scene.model, scene.analysis
    n_el = max(len(getattr(m, "contacts", ())), 1)
    out = []
    for name in ("hbm", "epmc"):
        sec = getattr(a, name)
        if sec is not None:
            n_coeff = sum(1 if h == 0 else 2 for h in set(sec.harmonics))
            out.append((f"analysis.{name}.n_samples",
                        8.0 * 4 * sec.n_samples * (n_coeff + 2) * n_el))
    if m.kind == "prescribed":
        out.append(("model.n_samples", 8.0 * 8 * m.n_samples * m.n_periods))
    tr = a.transient
    if tr is not None and not m.kind == "prescribed":
        periods = tr.max_periods if tr.history_periods == 0 else min(tr.history_periods,
                                                                      tr.max_periods)
        n_out = max(len(tr.output_dofs) + len(tr.output_points), 1)
        out.append(("analysis.transient.steps_per_period",
                    8.0 * 3 * n_out * tr.steps_per_period * periods / tr.decimate))
    return out
