"""Issue 13 item 9: ``jointsim info`` and ``jointsim post`` read every file jointsim writes.

For every analysis kind (modes, QSMA, EPMC, HBM, steady and free-decay
transient with its cross-check, prescribed motion) a small lumped scene is run
to completion, to a forced failure (``max_points = 2``, one Newton iteration,
an unreachable tolerance) and to an interruption (``KeyboardInterrupt`` raised
from a monkeypatched writer call, before the group's first dataset and after
a few), and both commands are run on the file through :func:`jointsim.cli.main`.
"""
from __future__ import annotations

import h5py
import pytest

from jointsim.cli import main
from jointsim.io import hdf5
from jointsim.run import run_scene
from jointsim.scene import load_scene

from .._scenes import MODELS

#: the 2-DOF chain with every structural analysis, small enough to run in about a second
FULL = (MODELS / "transient" / "chain2_crosscheck.toml").read_text().replace(
    "n_samples = 512", "n_samples = 32").replace(
    "harmonics = [0, 1, 2, 3, 4, 5, 6, 7]", "harmonics = [0, 1, 3]").replace(
    "steps_per_period = 1024", "steps_per_period = 64").replace(
    "max_periods = 3000", "max_periods = 400").replace(
    "steady_tol = 1e-8", "steady_tol = 1e-4").replace(
    "omega_start = 0.8", "omega_start = 1.1").replace(
    "omega_end = 1.3", "omega_end = 1.2") + """
[analysis.modes]
n_modes = 2

[analysis.qsma]
mode = 1
rigid_cutoff_hz = 0.001
n_steps = 8
log10_amplitude_start = -2
log10_amplitude_end = 0.5

[analysis.epmc]
mode = 1
rigid_cutoff_hz = 0.001
harmonics = [0, 1, 3]
n_samples = 32
log10_amplitude_start = -2
log10_amplitude_end = 0.5
"""

#: case -> (scene, overrides) of the forced failures
FAILURES = {
    "epmc_first_point": ("spectral", ["analysis.epmc.tol=1e-300"]),
    "epmc_max_points": ("spectral", ["analysis.epmc.max_points=2"]),
    "hbm_first_point": ("march", ["analysis.hbm.tol=1e-300"]),
    "hbm_max_points": ("march", ["analysis.hbm.max_points=2"]),
    "qsma_tolerance": ("spectral", ["analysis.qsma.tol=1e-30"]),
    "transient_not_steady": ("march", ["analysis.transient.max_periods=3"]),
    "transient_step": ("march", ["analysis.transient.newton_tol=1e-300",
                                "analysis.transient.max_cuts=0"]),
    "free_decay_step": ("decay", ["analysis.transient.newton_tol=1e-300",
                                  "analysis.transient.max_cuts=0"]),
}

#: group whose writes are interrupted -> scene
INTERRUPTED = {"modes": "spectral", "qsma": "spectral", "epmc": "spectral", "hbm": "march",
               "transient": "march", "crosscheck": "march", "decay": "decay",
               "prescribed": "prescribed"}


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    d = tmp_path_factory.mktemp("scenes")
    paths = {"decay": d / "decay.toml",
             "prescribed": MODELS / "seed_fig3" / "const.toml"}
    for name, keep in (("full", None), ("spectral", ("modes", "qsma", "epmc")),
                       ("march", ("hbm", "transient"))):
        paths[name] = d / f"{name}.toml"
        paths[name].write_text(_keep_analyses(FULL, keep))
    paths["decay"].write_text((MODELS / "transient" / "jenkins_free_decay.toml").read_text()
                     .replace("steps_per_period = 256", "steps_per_period = 32")
                     .replace("max_periods = 30", "max_periods = 8"))
    return paths


def _keep_analyses(text, keep):
    """Scene text without the ``[analysis.*]`` sections not in ``keep`` (None: all)."""
    out, on = [], True
    for line in text.splitlines():
        s = line.strip()
        if s.startswith("[") and not s.startswith("[["):
            on = keep is None or not s.startswith("[analysis.") or s[10:-1] in keep
        if on:
            out.append(line)
    return "\n".join(out) + "\n"


def interrupt_writes(monkeypatch, group, after):
    """Raise KeyboardInterrupt at the writer call that would store ``group``'s dataset ``after``+1."""
    count = {"n": 0}
    for meth in ("write", "append", "append_rows"):
        original = getattr(hdf5.ResultWriter, meth)

        def patched(self, name, *args, _original=original, **kw):
            if name.split("/")[0] == group:
                if count["n"] >= after:
                    raise KeyboardInterrupt
                count["n"] += 1
            return _original(self, name, *args, **kw)

        monkeypatch.setattr(hdf5.ResultWriter, meth, patched)


def read_back(path, tmp_path, capsys):
    """``jointsim info`` and ``jointsim post`` on a file: both succeed, info names the status."""
    assert main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    with h5py.File(path) as h:
        status = h.attrs["status"]
    assert f"status: {status}" in text
    assert main(["post", str(path), "--outdir", str(tmp_path / "figs")]) == 0
    capsys.readouterr()
    return status, text


@pytest.mark.parametrize("scene", [pytest.param("full", marks=pytest.mark.slow), "spectral",
                                   "decay", "prescribed"])
def test_complete_files_are_read(scene, scenes, tmp_path, capsys):
    out = tmp_path / "r.h5"
    run_scene(load_scene(scenes[scene]), out)
    status, _ = read_back(out, tmp_path, capsys)
    assert status == "complete"


@pytest.mark.parametrize("case", sorted(FAILURES))
def test_failed_files_are_read(case, scenes, tmp_path, capsys):
    scene, overrides = FAILURES[case]
    out = tmp_path / "r.h5"
    with pytest.raises(RuntimeError):
        run_scene(load_scene(scenes[scene], overrides), out)
    status, text = read_back(out, tmp_path, capsys)
    assert status == "failed"


@pytest.mark.parametrize("after", [0, pytest.param(2, marks=pytest.mark.slow)])
@pytest.mark.parametrize("group", sorted(INTERRUPTED))
def test_interrupted_files_are_read(group, after, scenes, tmp_path, capsys, monkeypatch):
    scene = INTERRUPTED[group]
    interrupt_writes(monkeypatch, "transient" if group == "decay" else group, after)
    out = tmp_path / "r.h5"
    with pytest.raises(KeyboardInterrupt):
        run_scene(load_scene(scenes[scene]), out)
    monkeypatch.undo()
    status, _ = read_back(out, tmp_path, capsys)
    assert status == "interrupted"
