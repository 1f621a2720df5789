"""Issue 13 item 10: a joint with every contact open at the static state is named, not silent."""
from __future__ import annotations

import logging

import h5py

from jointsim.run import run_scene
from jointsim.scene import load_scene

from .._scenes import MODELS

FOLD = MODELS / "hbm" / "chain2_friction_fold.toml"


def _model_only(tmp_path, overrides):
    """The fold scene without its analyses (only the model tables are written)."""
    text = FOLD.read_text().split("[analysis.hbm]")[0]
    p = tmp_path / "fold_model.toml"
    p.write_text(text)
    return load_scene(p, overrides)


def test_all_open_at_static_state_warns_and_is_recorded(tmp_path, caplog):
    """gap0 = +0.2 instead of the -0.2 interference: the static solve leaves the one
    element open (static gap = gap0 = 0.2 exactly, since nothing loads it at rest)."""
    out = tmp_path / "open.h5"
    with caplog.at_level(logging.WARNING):
        run_scene(_model_only(tmp_path, ["model.contacts.0.gap0=0.2"]), out)
    msg = [r.getMessage() for r in caplog.records if "open at the static state" in
           r.getMessage()]
    assert len(msg) == 1 and "n_sign" in msg[0] and "all 1 contact" in msg[0]
    with h5py.File(out) as h:
        assert bool(h["static"].attrs["all_open"]) is True


def test_closed_joint_does_not_warn(tmp_path, caplog):
    out = tmp_path / "closed.h5"
    for ov in ([], ["model.contacts.0.n_sign=-1"]):  # the interference closes either way
        out.unlink(missing_ok=True)
        with caplog.at_level(logging.WARNING):
            run_scene(_model_only(tmp_path, ov), out)
        assert not any("open at the static state" in r.getMessage() for r in caplog.records)
        with h5py.File(out) as h:
            assert bool(h["static"].attrs["all_open"]) is False
