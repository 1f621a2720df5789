"""End to end: `jointsim run` of the lap joint (coarse mesh), post-processing, ROM scene."""

import h5py
import numpy as np
import pytest

from jointsim.cli import main
from jointsim.post.tables import info_text

from .._scenes import ROOT

SCENE = ROOT / "models" / "lap_joint_nodes.toml"
COARSE = "model.mesh='../meshes/lap_joint_coarse.msh'"


def modes_only(text: str) -> str:
    """The scene text without its analysis tables other than [analysis.modes]
    (the nonlinear analyses of the scene are tested in test_hbm_fe.py)."""
    out, keep = [], True
    for line in text.splitlines():
        s = line.strip()
        if s.startswith("[") and not s.startswith("[["):
            keep = not s.startswith("[analysis.") or s == "[analysis.modes]"
        if keep:
            out.append(line)
    return "\n".join(out) + "\n"


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    d = tmp_path_factory.mktemp("fe_run")
    scene = d / "lap_joint_nodes.toml"
    scene.write_text(modes_only(SCENE.read_text()).replace(
        "../meshes/lap_joint_default.msh", str(ROOT / "meshes" / "lap_joint_default.msh")))
    out = d / "lap.h5"
    rc = main(["run", str(scene), "-o", str(out), "--set",
               f"model.mesh='{ROOT / 'meshes' / 'lap_joint_coarse.msh'}'",
               "--set", "analysis.modes.export_rom=lap_rom.npz", "-q"])
    assert rc == 0
    return out


def test_result_file_contract(result):
    with h5py.File(result, "r") as h5:
        assert h5.attrs["status"] == "complete"
        N = h5["static/N"][()]
        assert N.shape == (17,) and h5["static/N"].attrs["unit"] == "N"
        assert N.sum() == pytest.approx(36e3, rel=1e-9)
        f = h5["modes/frequency_hz"][()]
        assert h5["modes/frequency_hz"].attrs["unit"] == "Hz"
        el = h5["modes/elastic"][()]
        assert list(el[:4]) == [False, False, False, True]
        assert np.all(f[:3] < 5.0)  # suspension modes below 5 Hz
        # first elastic bending: below the monolithic beam (the joint is
        # compliant), but not absurdly (docs/fe.md: where it lands and why)
        mono = h5["modes/monolithic_hz"][()]
        assert 0.5 * mono[3] < f[3] < mono[3]
        full = h5["modes/frequency_hz_full"][()]
        np.testing.assert_allclose(f[3:8], full[3:8], rtol=1e-3)
        for name in ("contacts/area", "contacts/position", "modes/shapes",
                     "modes/shapes_full", "mesh/points", "mesh/quad9"):
            assert "unit" in h5[name].attrs
        a = h5["model"].attrs
        assert a["n_full_dof"] == 612 and a["n_contacts"] == 17
        assert a["n_dof"] == a["n_retained"] + a["n_cb_modes"] == 78 + 30
        # mass-normalised shapes: phi^T M phi = I (reduced mass from the ROM file)
        rom = np.load(result.parent / "lap_rom.npz")
        phi = h5["modes/shapes"][()]
        np.testing.assert_allclose(phi @ rom["M"] @ phi.T, np.eye(len(f)), atol=1e-8)


def test_post_writes_pressure_modes_and_paraview_files(result, tmp_path):
    import meshio
    assert main(["post", str(result), "-d", str(tmp_path), "-q"]) == 0
    names = {p.name for p in tmp_path.iterdir()}
    assert {"interface_pressure.png", "mode_shapes.png", "fe_modes.vtu",
            "fe_interface.vtu"} <= names
    m = meshio.read(tmp_path / "fe_modes.vtu")
    with h5py.File(result, "r") as h5:
        shapes = h5["modes/shapes_full"][()]
        node_dofs = h5["mesh/node_dofs"][()]
        f = h5["modes/frequency_hz"][()]
        p = h5["static/pressure"][()]
    key = f"mode_4_{f[3]:.1f}Hz"
    np.testing.assert_allclose(m.point_data[key][:, :2], shapes[3][node_dofs])
    assert m.cells[0].type == "quad9"
    itf = meshio.read(tmp_path / "fe_interface.vtu")
    np.testing.assert_allclose(itf.point_data["pressure"], p)
    text = info_text(result)
    assert "Linear modes" in text and "sum N0 = 36000" in text


def test_rom_scene_runs_from_the_exported_file(result, tmp_path):
    rom = result.parent / "lap_rom.npz"
    scene = tmp_path / "rom.toml"
    base = modes_only(SCENE.read_text())
    start = base.index("[model]")
    end = base.index("[joint]")
    scene.write_text(base[:start] + f"[model]\nkind = \"rom\"\nfile = \"{rom}\"\n\n"
                     + base[end:].replace('point = "excitation", direction = "y"', "dof = 3")
                     .replace("full_model = true", "full_model = false")
                     .replace("monolithic = true", "monolithic = false"))
    out = tmp_path / "rom.h5"
    assert main(["run", str(scene), "-o", str(out), "-q"]) == 0
    with h5py.File(out, "r") as a, h5py.File(result, "r") as b:
        np.testing.assert_allclose(a["modes/frequency_hz"][()], b["modes/frequency_hz"][()],
                                   rtol=1e-9)
        np.testing.assert_allclose(a["static/N"][()], b["static/N"][()], rtol=0,
                                   atol=1e-9 * b["static/N"][()].max())


@pytest.mark.parametrize("override,key", [
    ("model.bolts.0.tag=bolt9", "model.bolts[0].tag"),
    ("model.retain_points=['nowhere']", "model.retain_points"),
    ("model.interface_lower=top", "model.interface_lower"),
    ("excitation.loads.0.point=nowhere", "excitation.loads[0].point"),
])
def test_bad_fe_scene_names_the_key(override, key):
    from jointsim import _toml
    from jointsim.model import build_model
    from jointsim.scene import SceneError, apply_overrides, parse_scene
    data = apply_overrides(_toml.loads(modes_only(SCENE.read_text())), [COARSE, override],
                           str(SCENE))
    scene = parse_scene(data, str(SCENE), SCENE.parent)
    with pytest.raises(SceneError) as err:
        build_model(scene)
    assert err.value.key == key and "lap_joint_nodes.toml" in str(err.value)
