"""Bad input is refused before any file is touched (issue 11).

Every case runs the real CLI in-process (``jointsim.cli.main``; a few as a
subprocess) on a small scene written to ``tmp_path``, with ``--overwrite`` and
an existing result file in place, and checks: a non-zero exit, exactly one
``error:`` line naming the scene file and the key, the existing file unchanged
byte for byte and no other file created (no lock side file, no stub).
"""
from __future__ import annotations

import subprocess
import sys

import h5py
import numpy as np
import pytest

from jointsim.cli import main

from ._safety import ROOT, env

LUMPED = """
[model]
kind = "lumped"
units = "nondimensional"
M = [[1.0, 0.0], [0.0, 1.0]]
K = [[2.0, -1.0], [-1.0, 2.0]]
C = [[0.01, 0.0], [0.0, 0.01]]
contacts = [{ t_dof = 1, t_ref = -1, N0 = 1.0 }]

[joint]
law = "jenkins"
kt = 0.25
mu = 0.2

[excitation]
loads = [{ dof = 0, force = { harmonics = [{ h = 1, cos = 1.0 }] } }]

[analysis.hbm]
harmonics = [0, 1, 2, 3]
n_samples = 32
omega_start = 0.8
omega_end = 1.3
force_scale = [0.05]
"""

PRESCRIBED = """
[model]
kind = "prescribed"
u_t = { harmonics = [{ h = 1, cos = 1.0 }] }
N = 1.0
omega = 1.0
n_samples = 64

[joint]
kt = 1.0
mu = 0.5
"""

HBM = "analysis.hbm"
TR = ("[analysis.transient]\nomega = 1.0\nsteps_per_period = 64\nmax_periods = 20\n")
EPMC = ("[analysis.epmc]\nharmonics = [0, 1, 2, 3]\nn_samples = 32\n"
        "log10_amplitude_start = -1.0\nlog10_amplitude_end = 1.0\n")

#: (id, base scene, extra TOML text appended, --set overrides, key named in the message)
CASES = [
    # model matrices: shapes, symmetry, definiteness
    ("M-not-square", LUMPED, "", ["model.M=[[1.0, 0.0], [0.0]]"], "model.M"),
    ("M-empty", LUMPED, "", ["model.M=[]"], "model.M"),
    ("K-wrong-size", LUMPED, "", ["model.K=[[1.0]]"], "model.K"),
    ("C-wrong-size", LUMPED, "", ["model.C=[[1.0]]"], "model.C"),
    ("M-not-symmetric", LUMPED, "", ["model.M=[[1.0, 0.1], [0.0, 1.0]]"], "model.M"),
    ("K-not-symmetric", LUMPED, "", ["model.K=[[2.0, -1.0], [-0.5, 2.0]]"], "model.K"),
    ("C-not-symmetric", LUMPED, "", ["model.C=[[0.01, 0.002], [0.0, 0.01]]"], "model.C"),
    ("M-singular", LUMPED, "", ["model.M=[[0.0, 0.0], [0.0, 1.0]]"], "model.M"),
    ("M-negative", LUMPED, "", ["model.M=[[-1.0, 0.0], [0.0, 1.0]]"], "model.M"),
    ("M-zero", LUMPED, "", ["model.M=[[0.0, 0.0], [0.0, 0.0]]"], "model.M"),
    ("K-negative-definite", LUMPED, "", ["model.K=[[-2.0, 1.0], [1.0, -2.0]]"], "model.K"),
    ("K-indefinite", LUMPED, "", ["model.K=[[1.0, 2.0], [2.0, 1.0]]"], "model.K"),
    ("C-negative-definite", LUMPED, "", ["model.C=[[-0.01, 0.0], [0.0, -0.01]]"], "model.C"),
    ("C-indefinite", LUMPED, "", ["model.C=[[0.01, 0.0], [0.0, -0.01]]"], "model.C"),
    ("M-string", LUMPED, "", ["model.M='eye'"], "model.M"),
    ("M-entry-string", LUMPED, "", ["model.M=[[1.0, 'a'], [0.0, 1.0]]"], "model.M[0][1]"),
    ("M-nan", LUMPED, "", ["model.M=[[nan, 0.0], [0.0, 1.0]]"], "model.M[0][0]"),
    # contacts
    ("contact-dof-range", LUMPED, "", ["model.contacts.0.t_dof=5"], "model.contacts[0].t_dof"),
    ("contact-ref-same", LUMPED, "", ["model.contacts.0.t_ref=1"], "model.contacts[0].t_ref"),
    ("contact-N0-negative", LUMPED, "", ["model.contacts.0.N0=-1.0"], "model.contacts[0].N0"),
    ("contact-area-zero", LUMPED, "", ["model.contacts.0.area=0.0"], "model.contacts[0].area"),
    ("contact-n_sign", LUMPED, "", ["model.contacts.0.n_sign=2"], "model.contacts[0].n_sign"),
    ("contact-unknown-key", LUMPED, "", ["model.contacts.0.tdof=1"], "model.contacts[0].tdof"),
    ("contact-coupled-no-ndof", LUMPED, "", ["effects.normal=coupled"],
     "model.contacts[0].n_dof"),
    ("contact-N0-missing", LUMPED.replace(", N0 = 1.0", ""), "", [], "model.contacts[0].N0"),
    # model section
    ("model-kind", LUMPED, "", ["model.kind=lumpy"], "model.kind"),
    ("model-units", LUMPED, "", ["model.units=imperial"], "model.units"),
    ("model-unknown-key", LUMPED, "", ["model.mass=1.0"], "model.mass"),
    # joint, effects, damping
    ("joint-mu-negative", LUMPED, "", ["joint.mu=-0.1"], "joint.mu"),
    ("joint-mu-string", LUMPED, "", ["joint.mu='high'"], "joint.mu"),
    ("joint-law", LUMPED, "", ["joint.law=coulomb"], "joint.law"),
    ("joint-reversal", LUMPED, "", ["joint.reversal=none"], "joint.reversal"),
    ("joint-closing-fixed-n", LUMPED, "", ["joint.closing=interpolated"], "joint.closing"),
    ("joint-closing-value", LUMPED, "", ["joint.closing=midpoint"], "joint.closing"),
    ("joint-unknown-key", LUMPED, "", ["joint.muu=0.2"], "joint.muu"),
    ("effects-normal", LUMPED, "", ["effects.normal=free"], "effects.normal"),
    ("effects-friction-type", LUMPED, "", ["effects.friction=1"], "effects.friction"),
    ("damping-kind", LUMPED, "", ["damping.kind=viscous"], "damping.kind"),
    ("damping-alpha-negative", LUMPED, "", ["damping.alpha=-1.0"], "damping.alpha"),
    ("damping-zeta-negative", LUMPED, "", ["damping.zeta=[-0.01]"], "damping.zeta"),
    # excitation and forces
    ("load-dof-range", LUMPED, "", ["excitation.loads.0.dof=7"], "excitation.loads[0].dof"),
    ("load-dof-missing", LUMPED, "", ["excitation.loads=[{force=1.0}]"],
     "excitation.loads[0].dof"),
    ("load-harmonic-zero", LUMPED, "",
     ["excitation.loads=[{dof=0, force={harmonics=[{h=0, cos=1.0}]}}]"],
     "excitation.loads[0].force.harmonics[0].h"),
    ("load-force-string", LUMPED, "", ["excitation.loads=[{dof=0, force='big'}]"],
     "excitation.loads[0].force"),
    ("load-file-missing", LUMPED, "", ["excitation.loads=[{dof=0, force={file='no.csv'}}]"],
     "excitation.loads[0].force.file"),
    ("load-file-directory", LUMPED, "", ["excitation.loads=[{dof=0, force={file='.'}}]"],
     "excitation.loads[0].force.file"),
    ("load-file-unsupported", LUMPED, "", ["excitation.loads=[{dof=0, force={file='f.csv'}}]"],
     "excitation.loads[0].force.file"),
    ("load-clip-unsupported", LUMPED, "",
     ["excitation.loads=[{dof=0, force={harmonics=[{h=1, cos=1.0}], clip_at_zero=true}}]"],
     "excitation.loads[0].force.clip_at_zero"),
    ("load-file-and-constant", LUMPED, "",
     ["excitation.loads=[{dof=0, force={file='f.csv', constant=1.0}}]"],
     "excitation.loads[0].force.file"),
    ("load-clip-transient", LUMPED.split("[analysis.hbm]")[0], TR,
     ["excitation.loads=[{dof=0, force={harmonics=[{h=1, cos=1.0}], clip_at_zero=true}}]"],
     "excitation.loads[0].force.clip_at_zero"),
    # analysis.hbm
    ("hbm-force-scale-empty", LUMPED, "", [f"{HBM}.force_scale=[]"], f"{HBM}.force_scale"),
    ("hbm-force-scale-zero", LUMPED, "", [f"{HBM}.force_scale=[0.0]"],
     f"{HBM}.force_scale[0]"),
    ("hbm-force-scale-some-zero", LUMPED, "", [f"{HBM}.force_scale=[0.1, 0.0]"],
     f"{HBM}.force_scale[1]"),
    ("hbm-force-scale-number", LUMPED, "", [f"{HBM}.force_scale=0.1"], f"{HBM}.force_scale"),
    ("hbm-n-samples-absurd", LUMPED, "", [f"{HBM}.n_samples=1000000000000"],
     f"{HBM}.n_samples"),
    ("hbm-n-samples-float", LUMPED, "", [f"{HBM}.n_samples=1e10"], f"{HBM}.n_samples"),
    ("hbm-n-samples-aliasing", LUMPED, "", [f"{HBM}.n_samples=6"], f"{HBM}.n_samples"),
    ("hbm-no-harmonic-1", LUMPED, "", [f"{HBM}.harmonics=[0, 2]"], f"{HBM}.harmonics"),
    ("hbm-repeated-harmonic", LUMPED, "", [f"{HBM}.harmonics=[0, 1, 1]"], f"{HBM}.harmonics"),
    ("hbm-negative-harmonic", LUMPED, "", [f"{HBM}.harmonics=[-1, 1]"], f"{HBM}.harmonics"),
    ("hbm-omega-zero", LUMPED, "", [f"{HBM}.omega_start=0.0"], f"{HBM}.omega_start"),
    ("hbm-omega-equal", LUMPED, "", [f"{HBM}.omega_end=0.8"], f"{HBM}.omega_end"),
    ("hbm-omega-missing", LUMPED.replace("omega_end = 1.3\n", ""), "", [], f"{HBM}.omega_end"),
    ("hbm-step-order", LUMPED, "", [f"{HBM}.step_min=1.0"], f"{HBM}.step_min"),
    ("hbm-periods-order", LUMPED, "", [f"{HBM}.min_periods=60"], f"{HBM}.min_periods"),
    ("hbm-response-dof", LUMPED, "", [f"{HBM}.response_dof=9"], f"{HBM}.response_dof"),
    ("hbm-response-point", LUMPED, "", [f"{HBM}.response_point=tip"], f"{HBM}.response_point"),
    ("hbm-workers-negative", LUMPED, "", [f"{HBM}.workers=-1"], f"{HBM}.workers"),
    ("hbm-linear-solver", LUMPED, "", [f"{HBM}.linear_solver=lu"], f"{HBM}.linear_solver"),
    ("hbm-loops", LUMPED, "", [f"{HBM}.loops=some"], f"{HBM}.loops"),
    ("hbm-unknown-key", LUMPED, "", [f"{HBM}.omega_stop=2.0"], f"{HBM}.omega_stop"),
    # analysis.epmc
    ("epmc-amplitudes-equal", LUMPED, EPMC, ["analysis.epmc.log10_amplitude_end=-1.0"],
     "analysis.epmc.log10_amplitude_end"),
    ("epmc-amplitude-outside", LUMPED, EPMC, ["analysis.epmc.amplitudes=[100.0]"],
     "analysis.epmc.amplitudes[0]"),
    ("epmc-mode-zero", LUMPED, EPMC, ["analysis.epmc.mode=0"], "analysis.epmc.mode"),
    ("epmc-n-samples-absurd", LUMPED, EPMC, ["analysis.epmc.n_samples=1000000000000"],
     "analysis.epmc.n_samples"),
    # analysis.transient
    ("transient-rho", LUMPED, TR, ["analysis.transient.rho_inf=1.5"],
     "analysis.transient.rho_inf"),
    ("transient-free-decay-no-amplitude", LUMPED, TR, ["analysis.transient.omega=0.0"],
     "analysis.transient.amplitude"),
    ("transient-force-scale-zero", LUMPED, TR, ["analysis.transient.force_scale=0.0"],
     "analysis.transient.force_scale"),
    ("transient-steps-aliasing", LUMPED, TR, ["analysis.transient.steps_per_period=8"],
     "analysis.transient.steps_per_period"),
    ("transient-history-absurd", LUMPED, TR,
     ["analysis.transient.steps_per_period=100000000", "analysis.transient.max_periods=100000"],
     "analysis.transient.steps_per_period"),
    ("transient-output-dof", LUMPED, TR, ["analysis.transient.output_dofs=[4]"],
     "analysis.transient.output_dofs[0]"),
    ("transient-output-point", LUMPED, TR, ["analysis.transient.output_points=['tip']"],
     "analysis.transient.output_points"),
    ("transient-no-loads", LUMPED.split("[excitation]")[0], TR, [],
     "analysis.transient.omega"),
    # prescribed model
    ("prescribed-n-samples-absurd", PRESCRIBED, "",
     ["model.n_samples=10000000", "model.n_periods=10000"], "model.n_samples"),
    ("prescribed-omega-zero", PRESCRIBED, "", ["model.omega=0.0"], "model.omega"),
    ("prescribed-N-file-bad", PRESCRIBED, "", ["model.N={file='bad.csv'}"], "model.N.file"),
    ("prescribed-N-file-three-columns", PRESCRIBED, "", ["model.N={file='three.csv'}"],
     "model.N.file"),
    ("prescribed-N-file-decreasing", PRESCRIBED, "", ["model.N={file='back.csv'}"],
     "model.N.file"),
    ("prescribed-N-file-dir", PRESCRIBED, "", ["model.N={file='.'}"], "model.N.file"),
    # FE and ROM models
    ("fe-mesh-directory", "[model]\nkind = 'fe'\nmesh = '.'\n[joint]\nkt = 1.0\nmu = 0.1\n", "",
     [], "model.mesh"),
    ("fe-mesh-garbage", "[model]\nkind = 'fe'\nmesh = 'junk.msh'\n[joint]\nkt = 1.0\n"
                        "mu = 0.1\n", "", [], "model.mesh"),
    ("fe-mesh-and-dx", "[model]\nkind = 'fe'\nmesh = 'junk.msh'\ndx_lap = 0.01\n[joint]\n"
                       "kt = 1.0\nmu = 0.1\n", "", [], "model.dx_lap"),
    ("fe-nu", "[model]\nkind = 'fe'\ndx_lap = 0.01\nnu = 0.5\n[joint]\nkt = 1.0\nmu = 0.1\n",
     "", [], "model.nu"),
    ("rom-missing", "[model]\nkind = 'rom'\nfile = 'none.npz'\n[joint]\nkt = 1.0\nmu = 0.1\n",
     "", [], "model.file"),
    ("rom-garbage", "[model]\nkind = 'rom'\nfile = 'junk.npz'\n[joint]\nkt = 1.0\nmu = 0.1\n",
     "", [], "model.file"),
    ("rom-lacks-K", "[model]\nkind = 'rom'\nfile = 'short.npz'\n[joint]\nkt = 1.0\n"
                    "mu = 0.1\n", "", [], "model.file"),
    # the file as a whole, sections, overrides
    ("unknown-section", LUMPED, "[analyses]\nx = 1\n", [], "analyses"),
    ("missing-model", "[joint]\nkt = 1.0\n", "", [], "model"),
    ("set-not-key-value", LUMPED, "", ["joint.mu"], "joint.mu"),
    ("set-into-value", LUMPED, "", ["joint.mu.x=1"], "joint.mu"),
    ("set-index-range", LUMPED, "", ["model.contacts.3.N0=1.0"], "model.contacts.3"),
]


def _files(d) -> dict:
    return {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}


@pytest.fixture
def scene_dir(tmp_path):
    """A folder with the side files the cases name and a finished result file."""
    (tmp_path / "f.csv").write_text("t,F\n0.0, 0.0\n3.0, 1.0\n6.0, 0.0\n")
    (tmp_path / "bad.csv").write_text("0.0, 1.0\n1.0, one\n")
    (tmp_path / "three.csv").write_text("0 1 2\n1 2 3\n")
    (tmp_path / "back.csv").write_text("0 1\n2 2\n1 3\n")
    (tmp_path / "junk.msh").write_text("this is not a mesh\n")
    (tmp_path / "junk.npz").write_text("this is not a reduced model\n")
    np.savez(tmp_path / "short.npz", M=np.eye(2))
    out = tmp_path / "out.h5"
    with h5py.File(out, "w") as h5:  # stands for an earlier result; must survive as it is
        h5.attrs["status"] = "complete"
        h5["x"] = np.arange(10.0)
    return tmp_path


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_refused_and_writes_nothing(case, scene_dir, capsys):
    name, base, extra, overrides, key = case
    scene = scene_dir / f"{name}.toml"
    scene.write_text(base + "\n" + extra)
    before = _files(scene_dir)
    args = ["run", str(scene), "-o", str(scene_dir / "out.h5"), "--overwrite", "-q"]
    for o in overrides:
        args += ["--set", o]
    rc = main(args)
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert rc != 0
    assert len(err) == 1, err
    assert str(scene) in err[0] and key in err[0], err[0]
    assert _files(scene_dir) == before  # nothing created, nothing changed


def test_enough_cases():
    assert len(CASES) >= 60


@pytest.mark.parametrize("case", [c for c in CASES if c[0] in
                                  ("K-not-symmetric", "hbm-force-scale-zero", "fe-mesh-garbage")],
                         ids=lambda c: c[0])
def test_bad_input_as_a_process(case, scene_dir):
    name, base, extra, overrides, key = case
    scene = scene_dir / f"{name}.toml"
    scene.write_text(base + "\n" + extra)
    before = _files(scene_dir)
    args = [sys.executable, "-m", "jointsim.cli", "run", str(scene), "-o",
            str(scene_dir / "new.h5"), "-q"]
    for o in overrides:
        args += ["--set", o]
    r = subprocess.run(args, cwd=ROOT, env=env(), capture_output=True, text=True, timeout=120)
    err = [line for line in r.stderr.splitlines() if line.startswith("error:")]
    assert r.returncode != 0
    assert len(err) == 1 and str(scene) in err[0] and key in err[0], r.stderr
    assert _files(scene_dir) == before


def test_comma_separated_signal_file_is_read(tmp_path, capsys):
    """The README's ``N.csv`` with commas (and a header) drives a prescribed run."""
    (tmp_path / "N.csv").write_text("t,N\n" + "".join(
        f"{t:.6f}, {1.0 + 0.5 * np.cos(t):.12f}\n" for t in np.linspace(0, 2 * np.pi, 65)[:-1]))
    (tmp_path / "Ns.txt").write_text("".join(
        f"{t:.6f} {1.0 + 0.5 * np.cos(t):.12f}\n" for t in np.linspace(0, 2 * np.pi, 65)[:-1]))
    outs = []
    for f in ("N.csv", "Ns.txt"):
        scene = tmp_path / f"{f}.toml"
        scene.write_text(PRESCRIBED.replace("N = 1.0", f"N = {{ file = '{f}' }}"))
        out = tmp_path / f"{f}.h5"
        assert main(["run", str(scene), "-o", str(out), "-q"]) == 0
        outs.append(out)
    from jointsim.io.hdf5 import open_result
    with open_result(outs[0]) as a, open_result(outs[1]) as b:
        names = [k for k in a["prescribed"] if isinstance(a["prescribed"][k], h5py.Dataset)]
        assert names
        for k in names:  # the same numbers whatever the separator
            np.testing.assert_array_equal(a["prescribed"][k][()], b["prescribed"][k][()])
