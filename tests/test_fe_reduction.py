"""Craig-Bampton reduction and ROM files."""
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from jointsim.fem.assembly import build_structure
from jointsim.fem.build import reduce_structure, retained_dofs
from jointsim.fem.mesh import read_mesh
from jointsim.io.rom import load_rom, save_rom
from jointsim.model import build_model
from jointsim.fem.reduction import craig_bampton
from jointsim.scene import SceneError, load_scene
from jointsim.solvers.modes import eigenmodes, full_stuck_stiffness, stuck_modes

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "models" / "lap_joint.toml"


def scene_for(mesh="coarse", extra=()):
    return load_scene(SCENE, [f"model.mesh='../meshes/lap_joint_{mesh}.msh'", *extra])


@pytest.fixture(scope="module")
def coarse_structure():
    s = scene_for()
    m = s.model
    return build_structure(read_mesh(s.resolve(m.mesh)), E=m.E, nu=m.nu, rho=m.rho,
                           thickness=m.thickness, bolts=m.bolts,
                           suspension_stiffness=m.suspension_stiffness)


@pytest.fixture(scope="module")
def coarse_model():
    return build_model(scene_for())


@pytest.mark.parametrize("n_modes", [0, 12])
def test_craig_bampton_is_exact_for_static_loads_on_retained_dofs(coarse_structure, n_modes):
    st = coarse_structure
    B, _ = retained_dofs(st)
    cb = craig_bampton(st.K, st.M, B, n_modes)
    rng = np.random.default_rng(3)
    f = np.zeros(st.n_dof)
    f[B] = rng.standard_normal(B.size)
    x = spla.spsolve(st.K.tocsc(), f)
    xr = np.linalg.solve(cb.K, cb.T.T @ f)
    # exact = the expanded reduced solution satisfies the full equations to
    # round-off: normwise backward error ~ eps; the forward error is that times
    # cond(K) ~ 1e11 (soft suspension springs under a load with a resultant)
    xe = cb.T @ xr
    backward = np.linalg.norm(st.K @ xe - f, 1) / (
        spla.norm(st.K, 1) * np.linalg.norm(xe, 1) + np.linalg.norm(f, 1))
    assert backward < 1e-13
    np.testing.assert_allclose(xr[:B.size], x[B], rtol=0, atol=1e-5 * np.abs(x).max())
    np.testing.assert_allclose(cb.T @ xr, x, rtol=0, atol=1e-5 * np.abs(x).max())
    # the modal coordinates carry no static load
    if n_modes:
        assert np.abs(xr[B.size:]).max() < 1e-9 * np.abs(xr).max()
    # basis identity on retained DOFs, mass-normalised fixed-interface modes
    np.testing.assert_array_equal(cb.T[B, :B.size], np.eye(B.size))
    np.testing.assert_allclose(np.diag(cb.M)[B.size:], 1.0, rtol=1e-9)


@pytest.mark.parametrize("mesh", ["coarse", "default"])
def test_reduced_frequencies_match_the_full_model(mesh):
    """First 5 elastic stuck-joint frequencies within 0.1 % with the default n_modes."""
    model = build_model(scene_for(mesh))
    assert model.fe.cb.n_modes == 30
    red = stuck_modes(model, 12, suspension_hz=20.0)
    f_full, _ = eigenmodes(full_stuck_stiffness(model), model.fe.structure.M, 12)
    el = red.elastic
    assert el.sum() >= 5 and not el[:3].any()  # three suspension modes first
    err = np.abs(red.frequency_hz[el][:5] / f_full[el][:5] - 1)
    assert np.all(err < 1e-3), err
    # Craig-Bampton frequencies are upper bounds that converge with n_modes
    assert np.all(red.frequency_hz[el][:5] >= f_full[el][:5] * (1 - 1e-9))


def test_more_fixed_interface_modes_converge(coarse_structure):
    st = coarse_structure
    f_ref, _ = eigenmodes(st.K, st.M, 10)
    errs = []
    for n in (0, 5, 20):
        rom, cb = reduce_structure(st, n)
        f, _ = eigenmodes(rom.K, rom.M, 10)
        errs.append(np.abs(f[3:8] / f_ref[3:8] - 1).max())
    assert errs[0] > errs[1] > errs[2]


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


def test_craig_bampton_modes_are_deterministic(coarse_structure):
    """Two reductions of the same structure are identical, mode signs included
    (the eigensolver's start vector is fixed, each mode's largest entry is positive)."""
    st = coarse_structure
    B, _ = retained_dofs(st)
    a = craig_bampton(st.K, st.M, B, 12)
    b = craig_bampton(st.K, st.M, B, 12)
    np.testing.assert_array_equal(a.T, b.T)
    modes = a.T[:, B.size:]
    assert np.all(modes[np.argmax(np.abs(modes), axis=0), np.arange(modes.shape[1])] > 0)
