"""Shared fixtures and hypothesis profiles of the test suite.

Hypothesis profiles (select one with the environment variable
``HYPOTHESIS_PROFILE``; ``default`` when it is unset):

* ``default``: 60 examples per property, no deadline (numba compiles on first
  call, so a per-example deadline would flag the compilation);
* ``ci``: 20 examples, no deadline, no example database: quick and reproducible;
* ``thorough``: 600 examples, no deadline, for a run before a release.

Fixtures that build the coarse FE lap joint are session-scoped: building it
(mesh, assembly, Craig-Bampton, bolt preload) costs about a second and the
models are immutable, so every test file uses the same objects.  Small scenes
and paths are plain functions and constants in :mod:`tests._scenes`.
"""
from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

from jointsim.fem.assembly import build_structure
from jointsim.fem.mesh import read_mesh
from jointsim.model import build_model
from jointsim.scene import load_scene

from ._scenes import COARSE, COUPLED, FIXED, lap_scene

settings.register_profile("default", max_examples=60, deadline=None)
settings.register_profile("ci", max_examples=20, deadline=None, database=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("thorough", max_examples=600, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@pytest.fixture(scope="session")
def coarse_scene():
    """``models/lap_joint_nodes.toml`` (coupled normal load) on the coarse mesh."""
    return load_scene(COUPLED, [COARSE])


@pytest.fixture(scope="session")
def coarse_structure(coarse_scene):
    """The full (unreduced) FE structure of :func:`coarse_scene`."""
    m = coarse_scene.model
    return build_structure(read_mesh(coarse_scene.resolve(m.mesh)), E=m.E, nu=m.nu, rho=m.rho,
                           thickness=m.thickness, bolts=m.bolts,
                           suspension_stiffness=m.suspension_stiffness)


@pytest.fixture(scope="session")
def coarse_model(coarse_scene):
    """The structural model of :func:`coarse_scene` (reduced, preloaded)."""
    return build_model(coarse_scene)


@pytest.fixture(scope="session")
def coarse_fixed_model():
    """``models/lap_joint_fixed_n_nodes.toml`` (fixed normal load) on the coarse mesh."""
    return build_model(load_scene(FIXED, [COARSE]))


@pytest.fixture(scope="session")
def coarse_lap_coupled():
    """The coupled lap joint on the coarse mesh with only its modes analysis."""
    return build_model(lap_scene(COUPLED))


@pytest.fixture(scope="session")
def coarse_lap_fixed():
    """The fixed-N lap joint on the coarse mesh with only its modes analysis."""
    return build_model(lap_scene(FIXED))
