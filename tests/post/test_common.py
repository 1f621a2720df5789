"""The tangential law stored in ``/contacts`` (mu, k, g and the ``law`` attribute):
post-processing rebuilds the model's law from the file without the scene."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from jointsim.model import build_model
from jointsim.post.common import law_from_file
from jointsim.run import run_scene

from .._transient_scenes import lumped


def _scene(law, reversal="anchor", friction=True):
    """Two elements of different areas (so k differs per element), no analysis."""
    return lumped([[1.0, 0.0], [0.0, 1.0]], [[2.0, -1.0], [-1.0, 2.0]],
                  contacts=[{"t_dof": 0, "N0": 1.0, "area": 1.0},
                            {"t_dof": 1, "N0": 2.0, "area": 2.5}],
                  joint={"law": law, "reversal": reversal, "kt": 0.25, "mu": 0.2,
                         "n_sliders": 6},
                  effects={"friction": friction})


@pytest.mark.parametrize("law, reversal, friction", [
    ("jenkins", "anchor", True), ("iwan4", "scaled", True), ("stuck", "anchor", True),
    ("jenkins", "anchor", False)])
def test_law_rebuilt_from_the_file_equals_the_models(tmp_path, law, reversal, friction):
    sc = _scene(law, reversal, friction)
    expected = build_model(sc).contacts.law
    out = run_scene(sc, tmp_path / "c.h5")
    with h5py.File(out, "r") as h5:
        g = h5["contacts"]
        assert g.attrs["law"] == law and g.attrs["reversal"] == reversal
        assert g.attrs["kernel"] == expected.name
        assert h5["contacts/mu"].shape == (2,) and h5["contacts/mu"].attrs["unit"] == "1"
        assert h5["contacts/k"].shape == expected.k.shape
        assert h5["contacts/g"].shape == expected.g.shape
        assert "unit" in h5["contacts/k"].attrs and "unit" in h5["contacts/g"].attrs
        rebuilt = law_from_file(h5)
    assert type(rebuilt) is type(expected)
    for name in ("k", "g", "mu"):
        assert np.array_equal(getattr(rebuilt, name), getattr(expected, name)), name


def test_old_files_fall_back_to_the_stored_scene(tmp_path):
    sc = _scene("iwan4")
    expected = build_model(sc).contacts.law
    out = run_scene(sc, tmp_path / "c.h5")
    with h5py.File(out, "a") as h5:
        for name in ("mu", "k", "g"):
            del h5[f"contacts/{name}"]
    with h5py.File(out, "r") as h5:
        rebuilt = law_from_file(h5)
    for name in ("k", "g", "mu"):
        assert np.allclose(getattr(rebuilt, name), getattr(expected, name), rtol=1e-14), name
