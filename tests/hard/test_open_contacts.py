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


# -- item 11: effects.separation = false is named where it does nothing ----------------
def test_separation_false_with_fixed_normal_load_warns(tmp_path, caplog):
    from jointsim.analyses.modes import separation_warning
    for path in (MODELS / "seed_fig3" / "const.toml", MODELS / "hbm" / "chain2_jenkins.toml"):
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            msg = separation_warning(load_scene(path, ["effects.separation=false"]))
        assert "effects.separation = false has no effect" in msg
        assert any("effects.separation" in r.getMessage() for r in caplog.records)
        assert separation_warning(load_scene(path)) == ""
    out = tmp_path / "p.h5"
    run_scene(load_scene(MODELS / "seed_fig3" / "const.toml", ["effects.separation=false"]), out)
    with h5py.File(out) as h:
        assert "no effect" in h["prescribed"].attrs["separation_warning"]
    # coupled normal load: the key matters, no warning
    assert separation_warning(load_scene(FOLD, ["effects.separation=false"])) == ""


def test_separation_false_on_fe_names_the_bilateral_preload():
    from jointsim.analyses.modes import separation_warning
    from .._scenes import COARSE, FIXED
    msg = separation_warning(load_scene(FIXED, [COARSE, "effects.separation=false"]))
    assert "bilateral" in msg and "effects.separation" in msg
