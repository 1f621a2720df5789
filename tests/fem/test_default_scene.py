"""The committed default scenes are the converged interface (issue 10, round 15).

``models/lap_joint.toml`` and ``models/lap_joint_fixed_n.toml`` generate their mesh
from the scene (2.5 mm along the lap), put 2 Gauss contact points on each
interface edge with stiffness proportional to the preload pressure, and load the
bolts through washers.  Oracles: the bolt preload (3 x 12 kN) for sum N0; the
nominal pressure 36 kN / (120 mm x 25.4 mm) for ``kt_pressure``; the Richardson
limit of the 3-Gauss-point stuck f1 sequence, 163.545 Hz (docs/fe.md, README
"Interface resolution study"), within the issue's 0.2 %; and the node-pair scene
for the keys the two interfaces share.
"""
from __future__ import annotations

import numpy as np
import pytest

from jointsim.scene import load_scene

from .._scenes import MODELS

COUPLED = MODELS / "lap_joint.toml"
FIXED = MODELS / "lap_joint_fixed_n.toml"
NODES = MODELS / "lap_joint_nodes.toml"
#: Richardson limit of the stuck f1 under interface refinement [Hz] (docs/fe.md).
F1_LIMIT_HZ = 163.545


def test_default_scenes_declare_the_converged_interface():
    for path in (COUPLED, FIXED):
        scene = load_scene(path)
        m, j = scene.model, scene.joint
        assert m.mesh is None and (m.dx_lap, m.dx_full, m.ny_half) == (0.0025, 0.005, 8)
        assert (m.contact_points, m.contact_gauss, m.bolt_washer_radius) == ("gauss", 2, 0.01)
        assert j.kt_pressure == pytest.approx(36e3 / (0.12 * 0.0254), rel=1e-4)
        assert j.kn_pressure == j.kt_pressure
    # the two scenes differ in the normal load (and the coupled run's ends), not in
    # the structure; the node-pair scene keeps the rest of the physics
    c, f, n = load_scene(COUPLED), load_scene(FIXED), load_scene(NODES)
    assert (c.effects.normal, f.effects.normal) == ("coupled", "fixed")
    assert c.model == f.model and c.joint == f.joint
    assert (c.model.E, c.model.bolts, c.joint.mu, c.joint.kt) == \
        (n.model.E, n.model.bolts, n.joint.mu, n.joint.kt)
    assert n.model.contact_points == "nodes" and n.joint.kt_pressure is None


@pytest.mark.slow
def test_default_scene_builds_the_converged_stuck_joint():
    """The model of the default scene: 96 contact points, the bolts' 36 kN carried by
    the 74 closed ones, and a stuck f1 within 0.2 % of the refinement limit."""
    from jointsim.model import build_model
    from jointsim.solvers.modes import elastic_mode
    model = build_model(load_scene(COUPLED))
    c = model.contacts
    assert c.N0.size == 96 and int((c.N0 > 0).sum()) == 74
    assert c.N0.sum() == pytest.approx(36e3, rel=1e-9)
    f1 = elastic_mode(model, 1).omega / (2 * np.pi)
    assert abs(f1 / F1_LIMIT_HZ - 1) < 2e-3, f1
