"""A scene declares its physics, and nothing else is computed."""

import numpy as np
import pytest

import jointsim.contact._kernels as kernels
from jointsim.contact import NoFriction
from jointsim.model import build_model
from jointsim.scene import load_scene
from jointsim.solvers.contact_map import ContactMap
from jointsim.solvers.hbm import HBMSystem, solve_point

from .._scenes import CHAIN2, ROOT

CHAIN = CHAIN2


def forbid_normal_contact(monkeypatch):
    def boom(*args, **kwargs):
        raise AssertionError("normal contact was evaluated in a fixed-N scene")
    monkeypatch.setattr(kernels, "normal_penalty", boom)


def test_fixed_normal_load_never_evaluates_a_gap(monkeypatch):
    model = build_model(load_scene(CHAIN))
    assert not model.contacts.coupled
    with pytest.raises(RuntimeError, match="no gap is evaluated"):
        model.contacts.normal.load(np.zeros((1, 4)))
    forbid_normal_contact(monkeypatch)
    hbm = HBMSystem(model, (0, 1, 2, 3), 32)
    assert hbm.n_r == model.contacts.n_elements  # slips only, no gap coordinates
    p = solve_point(hbm, 1.0, hbm.force_coefficients(0.05))
    assert p.convergence.success
    cmap = ContactMap(model.contacts)
    assert cmap.n_c == model.contacts.n_elements and not cmap.coupled


def test_coupled_normal_load_adds_gap_coordinates(tmp_path):
    scene = load_scene(ROOT / "models" / "hbm" / "chain2_friction_fold.toml")
    model = build_model(scene)
    assert model.contacts.coupled
    hbm = HBMSystem(model, (0, 1), 64)
    assert hbm.n_r == 2 * model.contacts.n_elements


def test_frictionless_scene_has_no_tangential_law():
    scene = load_scene(ROOT / "models" / "hbm" / "sdof_clearance_fold.toml")
    model = build_model(scene)
    assert isinstance(model.contacts.law, NoFriction) and not model.contacts.law.has_force
    hbm = HBMSystem(model, (0, 1), 64)
    assert not hbm.friction and hbm.n_r == model.contacts.n_elements  # gaps only
