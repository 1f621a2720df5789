"""Presets of ``jointsim run --preset fast|balanced|reference``.

A preset is a set of ``--set`` items for the numerical dials of
:mod:`jointsim.converge`; it fills only the keys that the scene does not give
**explicitly**.  A key is explicit when it is written in the scene file or
given with ``--set``: the raw TOML table (before defaults) with the ``--set``
items applied has it.  A preset key of an analysis is added only when the
scene has that ``[analysis.<name>]`` table (a preset never adds an analysis).

The values were chosen from the ladders of ``jointsim converge`` on the
committed lap-joint scenes (README, "What accuracy costs"):

* ``fast``: the quickest setting that still gets the qualitative picture
  (frequencies within 1 %, damping within about 10 %);
* ``balanced``: within about 1e-2 in every quantity of the study on the
  fixed-N joint (measured: 1.9e-2, the EPMC damping at a = 1e-3, compared
  at exactly solved amplitudes);
* ``reference``: the ladders' most refined setting.

Measured on both study scenes (README, "Presets"): on the coupled joint the
damping converges slowly in H (H = 7 is 16 % off H = 23), so ``balanced`` is
not within 1e-2 there and ``reference`` is not converged to 1e-4 on either
joint.  The coupled joint's ``reference`` EPMC (H = 0..15, Nt = 512, tolerance
1e-10) used to give up at log10 a = -4.25 (a step over the stuck onset, README
"EPMC hard cases"); since the EPMC runner ends the continuation's first leg at
the onset (:func:`jointsim.analyses.epmc.stuck_onset`) it completes.
``fast`` takes 64 samples: with 32 the coupled joint's 20 N FRC is lost
where its re-closing anchors jump between samples.
"""
from __future__ import annotations

import logging
from pathlib import Path

from . import _toml
from .scene import SceneError, apply_overrides

log = logging.getLogger(__name__)

#: preset -> {scene key: value}; harmonics are 0..H
PRESETS: dict[str, dict[str, object]] = {
    "fast": {
        "analysis.hbm.harmonics": list(range(0, 4)),
        # 32 samples lose the coupled joint's 20 N FRC (its re-closing anchors jump
        # between samples: README, "Presets"); 64 complete it
        "analysis.hbm.n_samples": 64,
        "analysis.epmc.harmonics": list(range(0, 4)),
        "analysis.epmc.n_samples": 64,
        "analysis.transient.steps_per_period": 64,
        "analysis.qsma.n_steps": 30,
        "joint.iwan_rtol": 0.1,
    },
    "balanced": {
        "analysis.hbm.harmonics": list(range(0, 8)),
        "analysis.hbm.n_samples": 128,
        "analysis.epmc.harmonics": list(range(0, 8)),
        "analysis.epmc.n_samples": 128,
        "analysis.transient.steps_per_period": 256,
        "analysis.qsma.n_steps": 60,
        "joint.iwan_rtol": 0.01,
    },
    "reference": {
        "analysis.hbm.harmonics": list(range(0, 16)),
        "analysis.hbm.n_samples": 512,
        "analysis.hbm.tol": 1e-10,
        "analysis.epmc.harmonics": list(range(0, 16)),
        "analysis.epmc.n_samples": 512,
        "analysis.epmc.tol": 1e-10,
        "analysis.transient.steps_per_period": 1024,
        "analysis.qsma.n_steps": 120,
        "joint.iwan_rtol": 0.003,
    },
}


def _has(data: dict, key: str) -> bool:
    node = data
    for p in key.split("."):
        if not isinstance(node, dict) or p not in node:
            return False
        node = node[p]
    return True


def preset_overrides(scene_path, preset: str, overrides=()) -> list[str]:
    """The ``--set`` items a preset adds to a scene (the keys not given explicitly).

    Parameters
    ----------
    scene_path : str or Path
        The scene file.
    preset : {'fast', 'balanced', 'reference'}
    overrides : sequence of str
        The user's ``--set`` items (explicit, they win).

    Returns
    -------
    list of str
        To be placed *before* the user's overrides.

    Raises
    ------
    SceneError
        For an unknown preset or an unreadable scene.
    """
    file = str(scene_path)
    if preset not in PRESETS:
        raise SceneError(file, "--preset", f"must be one of {sorted(PRESETS)}, got {preset!r}")
    p = Path(scene_path)
    if not p.is_file():
        raise SceneError(file, "", "does not exist or is not a file")
    try:
        data = _toml.loads(p.read_text(encoding="utf-8"))
    except (_toml.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SceneError(file, "", f"is not valid TOML: {exc}") from None
    data = apply_overrides(data, list(overrides), file)
    out = []
    for key, value in PRESETS[preset].items():
        section = key.rsplit(".", 1)[0]
        if section.startswith("analysis.") and not _has(data, section):
            continue
        if _has(data, key):
            log.debug("preset %s: %s is explicit, kept", preset, key)
            continue
        out.append(f"{key}={value!r}" if isinstance(value, float) else f"{key}={value}")
    return out
