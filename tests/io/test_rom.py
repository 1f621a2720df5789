"""ROM files (:mod:`jointsim.io.rom`): export and import round trip in every
format, MATLAB-style files, and errors that name the key."""
import numpy as np
import pytest
import scipy.sparse as sp

from jointsim.io.rom import load_rom, save_rom
from jointsim.model import build_model
from jointsim.scene import SceneError, load_scene
from jointsim.solvers.modes import stuck_modes

from .._scenes import COUPLED as SCENE


@pytest.mark.parametrize("ext", [".npz", ".mat", ".h5"])
def test_rom_export_import_round_trip(tmp_path, coarse_model, ext):
    path = save_rom(tmp_path / f"rom{ext}", coarse_model.rom)
    rom_scene = load_scene(SCENE, ["model={kind='rom', file='" + str(path) + "'}",
                                   "excitation.loads.0.point=''",
                                   f"excitation.loads.0.dof={coarse_model.points['excitation']}"])
    rom_model = build_model(rom_scene)
    a = stuck_modes(coarse_model, 10).frequency_hz
    b = stuck_modes(rom_model, 10).frequency_hz
    np.testing.assert_allclose(b, a, rtol=1e-9)
    np.testing.assert_allclose(rom_model.contacts.N0, coarse_model.contacts.N0, rtol=0,
                               atol=1e-9 * coarse_model.contacts.N0.max())
    np.testing.assert_allclose(rom_model.f_static, coarse_model.f_static, rtol=1e-9,
                               atol=1e-9 * np.abs(coarse_model.f_static).max())
    assert rom_model.points == coarse_model.points
    assert rom_model.dof_labels == coarse_model.dof_labels
    np.testing.assert_array_equal(rom_model.load_dofs, coarse_model.load_dofs)


def test_one_based_mat_file_from_matlab(tmp_path, coarse_model):
    """A hand-written MATLAB-style file (1-based indices, sparse K, no frame) imports."""
    import scipy.io
    rom = coarse_model.rom
    it = rom.interface
    data = {"M": rom.M, "K": sp.csr_matrix(rom.K), "lower_dofs": it.lower_dofs + 1,
            "upper_dofs": it.upper_dofs + 1, "area": it.area, "index_base": 1,
            "bolt_lower_dofs": np.where(rom.bolts.lower_dofs >= 0, rom.bolts.lower_dofs + 1, 0),
            "bolt_upper_dofs": np.where(rom.bolts.upper_dofs >= 0, rom.bolts.upper_dofs + 1, 0),
            "bolt_axis": rom.bolts.axis, "bolt_stiffness": rom.bolts.stiffness,
            "bolt_preload": rom.bolts.preload, "point_response": rom.points["response"] + 1}
    scipy.io.savemat(tmp_path / "m.mat", data)
    back = load_rom(tmp_path / "m.mat")
    np.testing.assert_array_equal(back.interface.lower_dofs, it.lower_dofs)
    np.testing.assert_array_equal(back.bolts.upper_dofs, rom.bolts.upper_dofs)
    np.testing.assert_allclose(back.interface.frame, it.frame)
    assert back.points == {"response": rom.points["response"]}
    np.testing.assert_allclose(back.K, rom.K)


def test_bad_rom_file_names_the_key(tmp_path):
    np.savez(tmp_path / "bad.npz", M=np.eye(2))
    scene = load_scene(SCENE, ["model={kind='rom', file='" + str(tmp_path / "bad.npz") + "'}",
                               "excitation.loads=[]"])
    with pytest.raises(SceneError, match="model.file.*'K'"):
        build_model(scene)
