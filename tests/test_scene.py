"""Scene loading, overrides, validation errors and the resolved-TOML writer."""
import math
import textwrap
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from jointsim import _toml
from jointsim.cli import main
from jointsim.scene import SceneError, apply_overrides, load_scene, parse_value

MODELS = Path(__file__).resolve().parents[1] / "models"

PRESCRIBED = """
[model]
kind = "prescribed"
omega = 6.283185307179586
n_periods = 3
n_samples = 64
u_t = { harmonics = [{ h = 1, sin = 1.0 }] }
N = 5.0

[joint]
law = "jenkins"
mu = 0.1
kt = 1.0
"""

LUMPED = """
[model]
kind = "lumped"
M = [[1.0, 0.0], [0.0, 1.0]]
K = [[2.0, -1.0], [-1.0, 2.0]]
[[model.contacts]]
t_dof = 1
N0 = 1.0

[[excitation.loads]]
dof = 0
force = { harmonics = [{ h = 1, cos = 0.1 }] }
"""


def write(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def test_seed_scenes_load():
    for name in ("const", "sin1", "sin2", "sep"):
        s = load_scene(MODELS / "seed_fig3" / f"{name}.toml")
        assert s.model.kind == "prescribed"
        assert s.joint.reversal == "scaled"
        assert s.kernels().tangential == "bank_scaled"


def test_overrides_types_and_strings(tmp_path):
    p = write(tmp_path, PRESCRIBED)
    s = load_scene(p, ["joint.mu=0.25", "joint.reversal=scaled", "model.n_samples=128",
                       "effects.separation=false", "scene.name=hello world"])
    assert s.joint.mu == 0.25 and s.joint.reversal == "scaled"
    assert s.model.n_samples == 128 and s.effects.separation is False
    assert s.scene.name == "hello world"
    # the resolved text carries the overrides and reads back to the same scene
    again = _toml.loads(s.text)
    assert again["joint"]["mu"] == 0.25 and again["model"]["n_samples"] == 128


def test_override_into_array_of_tables(tmp_path):
    p = write(tmp_path, LUMPED)
    s = load_scene(p, ["model.contacts.0.N0=2.5"])
    assert s.model.contacts[0].N0 == 2.5


def test_parse_value():
    assert parse_value("3") == 3 and parse_value("0.5") == 0.5
    assert parse_value("true") is True and parse_value("[1, 2]") == [1, 2]
    assert parse_value("anchor") == "anchor"


def test_signal_shorthand_and_clip(tmp_path):
    p = write(tmp_path, PRESCRIBED)
    s = load_scene(p, ["model.N={ constant = 3.0, harmonics = [{ h = 2, sin = 4.0 }], "
                       "clip_at_zero = true }"])
    assert s.model.N.clip_at_zero and s.model.N.harmonics[0].h == 2


def test_signal_from_file(tmp_path):
    (tmp_path / "N.txt").write_text("# t value\n0 1\n0.5 3\n")
    p = write(tmp_path, PRESCRIBED)
    s = load_scene(p, ['model.N={ file = "N.txt" }'])
    assert s.model.N.file == "N.txt"


def test_defaults_in_resolved_text(tmp_path):
    s = load_scene(write(tmp_path, PRESCRIBED))
    data = _toml.loads(s.text)
    assert data["effects"] == {"normal": "fixed", "separation": True, "friction": True}
    assert data["analysis"]["masing"]["tol"] == 0.01


# --------------------------------------------------------------------------
# bad scenes: one clear line naming the file and the key, non-zero exit, no output
# --------------------------------------------------------------------------
BAD = [
    # (description, scene text, overrides, key expected in the message)
    ("wrong type", PRESCRIBED.replace("mu = 0.1", 'mu = "high"'), [], "joint.mu"),
    ("missing key", PRESCRIBED.replace("omega = 6.283185307179586\n", ""), [], "model.omega"),
    ("unknown law", PRESCRIBED.replace('law = "jenkins"', 'law = "coulomb"'), [], "joint.law"),
    ("negative mu", PRESCRIBED.replace("mu = 0.1", "mu = -0.1"), [], "joint.mu"),
    ("missing mesh", '[model]\nkind = "fe"\nmesh = "nowhere/lap.msh"\n', [], "model.mesh"),
    ("unknown key", PRESCRIBED.replace("mu = 0.1", "muu = 0.1"), [], "joint.muu"),
    ("unknown section", PRESCRIBED + "\n[jiont]\nmu = 1\n", [], "jiont"),
    ("bad TOML", PRESCRIBED.replace("mu = 0.1", "mu = = 0.1"), [], "not valid TOML"),
    ("unknown key from --set", PRESCRIBED, ["joint.kappa=3"], "joint.kappa"),
    ("malformed --set", PRESCRIBED, ["joint.mu"], "joint.mu"),
    ("bool for a number", PRESCRIBED.replace("kt = 1.0", "kt = true"), [], "joint.kt"),
    ("too few samples", PRESCRIBED.replace("n_samples = 64", "n_samples = 2"), [],
     "model.n_samples"),
    ("unknown model kind", PRESCRIBED.replace('kind = "prescribed"', 'kind = "beam"'), [],
     "model.kind"),
    ("scaled reversal for stuck law", PRESCRIBED, ["joint.law=stuck", "joint.reversal=scaled"],
     "joint.reversal"),
    ("coupled normal on prescribed motion", PRESCRIBED, ["effects.normal=coupled"],
     "effects.normal"),
    ("non-square matrix", LUMPED.replace("[0.0, 1.0]]", "[0.0, 1.0, 3.0]]"), [], "model.M"),
    ("DOF out of range", LUMPED.replace("t_dof = 1", "t_dof = 5"), [],
     "model.contacts[0].t_dof"),
    ("fixed normal without N0", LUMPED.replace("N0 = 1.0", ""), [], "model.contacts[0].N0"),
    ("missing signal file", PRESCRIBED, ['model.N={ file = "gone.csv" }'], "model.N.file"),
    ("harmonic number zero", PRESCRIBED.replace("h = 1, sin", "h = 0, sin"), [],
     "model.u_t.harmonics[0].h"),
    ("invalid enum in effects", PRESCRIBED + '\n[effects]\nnormal = "sometimes"\n', [],
     "effects.normal"),
    ("aliasing in hbm", LUMPED + "\n[analysis.hbm]\nomega_start = 0.8\nomega_end = 1.3\n"
     "n_samples = 8\n", [], "analysis.hbm.n_samples"),
]


@pytest.mark.parametrize("desc,text,overrides,key", BAD, ids=[b[0] for b in BAD])
def test_bad_scene_is_one_clear_line_and_writes_nothing(tmp_path, capsys, desc, text,
                                                         overrides, key):
    scene = write(tmp_path, text)
    out = tmp_path / "out" / "result.h5"
    args = ["run", str(scene), "-o", str(out)]
    for o in overrides:
        args += ["--set", o]
    code = main(args)
    err = capsys.readouterr().err.strip()
    assert code != 0
    assert len(err.splitlines()) == 1, err
    assert str(scene) in err, err
    assert key in err, err
    assert not out.exists() and not out.parent.exists()


def test_missing_scene_file(tmp_path, capsys):
    code = main(["run", str(tmp_path / "nope.toml"), "-o", str(tmp_path / "x.h5")])
    assert code != 0 and "nope.toml" in capsys.readouterr().err
    assert not (tmp_path / "x.h5").exists()


def test_error_message_format(tmp_path):
    p = write(tmp_path, PRESCRIBED.replace("mu = 0.1", "mu = -0.1"))
    with pytest.raises(SceneError) as exc:
        load_scene(p)
    assert str(exc.value) == f"{p}: joint.mu must be >= 0, got -0.1"


def test_unknown_key_suggests(tmp_path):
    p = write(tmp_path, PRESCRIBED.replace("kt = 1.0", "kT = 1.0"))
    with pytest.raises(SceneError, match="did you mean 'joint.kt'"):
        load_scene(p)


def test_apply_overrides_does_not_mutate():
    data = {"joint": {"mu": 0.1}}
    out = apply_overrides(data, ["joint.mu=0.3"], "f.toml")
    assert data["joint"]["mu"] == 0.1 and out["joint"]["mu"] == 0.3


# --------------------------------------------------------------------------
# the TOML writer reads back what it wrote
# --------------------------------------------------------------------------
keys = st.text(alphabet="abcdefghijklmnopqrstuvwxyz_-0123456789 .\"", min_size=1, max_size=8)
scalars = (st.booleans() | st.integers(-10**12, 10**12)
           | st.floats(allow_nan=False) | st.text(max_size=12))
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4), max_leaves=8)
tables = st.recursive(st.dictionaries(keys, values, max_size=4),
                      lambda inner: st.dictionaries(keys, inner | st.lists(inner, min_size=1,
                                                                          max_size=2),
                                                    max_size=3),
                      max_leaves=6)


def _same(a, b):
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b and type(a) is type(b)


@given(tables)  # examples: the hypothesis profile (tests/conftest.py)
def test_toml_round_trip(data):
    assert _same(_toml.loads(_toml.dumps(data)), data)
