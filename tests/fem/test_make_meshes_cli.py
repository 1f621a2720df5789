"""meshes/make_meshes.py keeps its command line (issue 10): ``--dx-lap --dx-full
--ny-half -o`` as a command (the way benchmarks/scale.py and users call it), a partial
set refused, and the file it writes accepted by ``model.mesh`` beside the scene's own
generation keys (``model.dx_lap``...; their equivalence is
tests/fem/test_interface.py::test_generated_scene_builds_the_same_model_as_the_mesh_file)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from jointsim.model import build_model
from jointsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "meshes" / "make_meshes.py"


def _run(*args):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True,
                          text=True, env=env)


def test_make_meshes_command_line_and_model_mesh(tmp_path):
    out = tmp_path / "lap_17.msh"
    r = _run("--dx-lap", "0.015", "--dx-full", "0.03", "--ny-half", "1", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert out.exists() and "dx_lap 15 mm" in r.stdout
    # a lap spacing of 30 mm / k gives 8 k + 1 node-to-node pairs (benchmarks/scale.py)
    sc = load_scene(ROOT / "models" / "lap_joint_nodes.toml", [f"model.mesh='{out}'"])
    assert sc.model.generate is None
    assert build_model(sc).contacts.n_elements == 17


def test_make_meshes_refuses_a_partial_resolution(tmp_path):
    out = tmp_path / "x.msh"
    for args in (("--dx-lap", "0.015", "-o", str(out)),
                 ("--dx-lap", "0.015", "--dx-full", "0.03", "--ny-half", "1")):
        r = _run(*args)
        assert r.returncode == 2
        assert "--dx-lap, --dx-full, --ny-half and -o" in r.stderr
        assert not out.exists()
