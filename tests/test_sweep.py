"""Parameter sweeps on dask.distributed."""
from pathlib import Path

import h5py
import pytest

from jointsim.cli import main
from jointsim.sweep import expand, plan

SEED = Path(__file__).resolve().parents[1] / "models" / "seed_fig3"


def test_expand_is_a_cartesian_product():
    combos = expand(["joint.mu=0.1,0.2", "joint.reversal=anchor,scaled,anchor"], "f")
    assert len(combos) == 6
    assert combos[0] == ("joint.mu=0.1", "joint.reversal=anchor")
    assert expand(['model.N={ constant = 1.0, clip_at_zero = true },2.0'], "f") == [
        ("model.N={ constant = 1.0, clip_at_zero = true }",), ("model.N=2.0",)]


def test_a_bad_variant_stops_the_sweep_before_anything_runs(tmp_path, capsys):
    code = main(["sweep", str(SEED / "sin1.toml"), "--vary", "joint.mu=0.1,-0.2",
                 "-o", str(tmp_path / "sw")])
    assert code == 2 and "joint.mu must be >= 0" in capsys.readouterr().err
    assert not (tmp_path / "sw").exists()


def test_sweep_runs_every_variant(tmp_path):
    pytest.importorskip("distributed")
    out = tmp_path / "sw"
    code = main(["sweep", str(SEED / "sin2.toml"), "--vary", "joint.reversal=anchor,scaled",
                 "--vary", "joint.mu=0.1,0.05", "--set", "model.n_samples=256",
                 "-o", str(out), "--workers", "2", "-q"])
    assert code == 0
    variants = plan(SEED / "sin2.toml", ["joint.reversal=anchor,scaled", "joint.mu=0.1,0.05"],
                    out, ["model.n_samples=256"])
    with h5py.File(out / "sweep.h5", "r") as idx:
        assert [s.decode() for s in idx["status"][()]] == ["complete"] * 4
    for v in variants:
        with h5py.File(v.output, "r") as h5:
            dev = h5["masing/dev_manifold"][0, 0]
            scaled = "joint.reversal=scaled" in v.overrides
            # the scaled law is on its manifold, the physical one is not (sin2)
            assert (dev < 1e-12) if scaled else (dev > 0.05)
            assert h5["loops/u"].shape[-1] == 256
