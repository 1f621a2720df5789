"""The command line end to end: run, post, info."""
from pathlib import Path

from jointsim.cli import main

SEED = Path(__file__).resolve().parents[1] / "models" / "seed_fig3"


def test_run_post_info(tmp_path, capsys):
    out = tmp_path / "sep.h5"
    assert main(["run", str(SEED / "sep.toml"), "-o", str(out), "--post", "-q"]) == 0
    figs = sorted((tmp_path / "sep_figures").glob("*.png"))
    assert [f.name for f in figs] == ["loop_manifold.png", "time_history.png"]
    assert all(f.stat().st_size > 10_000 for f in figs)
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "dev_manifold" in text and "on manifold: 1/1" in text


def test_post_grid_of_several_runs(tmp_path):
    files = []
    for case in ("const", "sin2"):
        out = tmp_path / f"{case}.h5"
        assert main(["run", str(SEED / f"{case}.toml"), "-o", str(out), "-q"]) == 0
        files.append(str(out))
    assert main(["post", *files, "-d", str(tmp_path / "figs"), "-q"]) == 0
    assert (tmp_path / "figs" / "fig3_grid.png").exists()
    assert (tmp_path / "figs" / "const" / "loop_manifold.png").exists()


def test_check_command(tmp_path, capsys):
    assert main(["check", str(SEED / "sin1.toml"), "--set", "joint.reversal=anchor"]) == 0
    assert "bank_anchor" in capsys.readouterr().out


def test_check_command_on_the_default_scene_generates_its_mesh(capsys):
    """``jointsim check models/lap_joint.toml``: the mesh generated from the scene's keys
    (2.5 mm along the lap: 48 interface edges, so 96 Gauss contact points), its size
    printed, not a failure to read ``model.mesh``; a coarser ``--set`` is a new mesh."""
    assert main(["check", str(SEED.parents[0] / "lap_joint.toml")]) == 0
    out = capsys.readouterr().out
    assert "generated lap joint (dx_lap=0.0025" in out and "mesh not read" not in out
    assert "contact at 2 Gauss points per interface edge" in out
    assert main(["check", str(SEED.parents[0] / "lap_joint.toml"), "--set", "model.dx_lap=0.01",
                 "--set", "model.dx_full=0.02", "--set", "model.ny_half=2"]) == 0
    assert "generated lap joint (dx_lap=0.01" in capsys.readouterr().out
