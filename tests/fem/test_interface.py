"""Interface discretisation (node pairs and Gauss points), generated meshes, weighted fractions.

Oracles: exact kinematics (a rigid translation gives no slip and no gap; a
uniform or quadratic relative motion is reproduced exactly by the quadratic
edge interpolation), the interface area ``L_lap x depth``, the same model from
a mesh file and from the scene's generation parameters, and hand-computed
weighted fractions.  The convergence test checks that f1 falls
monotonically, with shrinking increments, under uniform
refinement of a cantilever with an interface (docs/fe.md has the measured
lap-joint table, where the contact patch and the point bolts keep f1 from
converging monotonically with either discretisation).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from jointsim._schema import SceneError
from jointsim.fem.assembly import build_structure
from jointsim.fem.generate import LapJointGeometry, generated_lap_joint
from jointsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "models" / "lap_joint_nodes.toml"
GEO = LapJointGeometry()


def _structure(points, n_gauss=3, res=(0.015, 0.03, 1)):
    mesh = generated_lap_joint(*res)
    return build_structure(mesh, E=200e9, nu=0.29, rho=7800.0, thickness=0.0254,
                           contact_points=points, contact_gauss=n_gauss)


def _upper_dofs(st):
    """DOFs of the upper body (the right beam) and their positions."""
    basis = st.basis
    cells = st.mesh.cell_sets["beam_right"]
    dofs = np.unique(basis.element_dofs[:, cells])
    return dofs, basis.doflocs[:, dofs]


CASES = [("nodes", 1), ("gauss", 1), ("gauss", 2), ("gauss", 3), ("gauss", 4)]


@pytest.mark.parametrize("points,ng", CASES)
def test_operators_reproduce_rigid_and_relative_motion(points, ng):
    st = _structure(points, ng)
    it = st.interface
    Tt, Tn = it.operators(st.n_dof)
    # rigid translation of the whole structure: no slip, no gap change
    x = np.zeros(st.n_dof)
    x[0::2], x[1::2] = 3e-6, -2e-6
    assert np.abs(Tt @ x).max() < 1e-20 and np.abs(Tn @ x).max() < 1e-20
    # upper body translated: uniform slip and opening, exactly
    dofs, loc = _upper_dofs(st)
    x = np.zeros(st.n_dof)
    x[dofs[dofs % 2 == 0]] = 5e-6
    x[dofs[dofs % 2 == 1]] = 1e-6
    np.testing.assert_allclose(Tt @ x, 5e-6, rtol=1e-12)
    np.testing.assert_allclose(Tn @ x, 1e-6, rtol=1e-12)
    # a quadratic tangential field on the upper body is interpolated exactly at the points
    xs = loc[0, dofs % 2 == 0]
    x = np.zeros(st.n_dof)
    x[dofs[dofs % 2 == 0]] = 1e-3 * xs ** 2 + 2e-5 * xs
    pos = it.position[:, 0]
    np.testing.assert_allclose(Tt @ x, 1e-3 * pos ** 2 + 2e-5 * pos, rtol=1e-10, atol=1e-18)


@pytest.mark.parametrize("points,ng", CASES)
def test_areas_sum_to_the_interface_area(points, ng):
    it = _structure(points, ng, res=(0.01, 0.02, 2)).interface
    assert it.area.sum() == pytest.approx(GEO.lap_length * 0.0254, rel=1e-12)
    assert np.all(np.diff(it.position[:, 0]) >= 0)       # sorted along the interface
    n_edges = 12
    assert it.n_elements == (2 * n_edges + 1 if points == "nodes" else ng * n_edges)
    np.testing.assert_allclose(it.frame[:, 0], [[1.0, 0.0]] * it.n_elements, atol=1e-14)
    np.testing.assert_allclose(it.frame[:, 1], [[0.0, 1.0]] * it.n_elements, atol=1e-14)


def test_gauss3_integrates_the_interface_stiffness_exactly():
    """Tt^T A Tt with 3 points = the exact edge integral (4 points agree to round-off)."""
    K = []
    for ng in (3, 4, 6):
        st = _structure("gauss", ng)
        Tt, _ = st.interface.operators(st.n_dof)
        K.append((Tt.T @ (Tt.multiply(st.interface.area[:, None]))).toarray())
    scale = np.abs(K[-1]).max()
    assert np.abs(K[0] - K[-1]).max() < 1e-12 * scale
    assert np.abs(K[1] - K[-1]).max() < 1e-12 * scale


def test_renumbered_keeps_the_interpolation():
    st = _structure("gauss", 2)
    it = st.interface
    perm = np.random.default_rng(0).permutation(st.n_dof)
    r = it.renumbered(perm)
    Tt, Tn = it.operators(st.n_dof)
    Rt, Rn = r.operators(st.n_dof)
    x = np.random.default_rng(1).standard_normal(st.n_dof)
    y = np.empty_like(x)
    y[perm] = x                       # DOF i of the old numbering is perm[i] now
    np.testing.assert_allclose(Rt @ y, Tt @ x, rtol=1e-13, atol=1e-16)
    np.testing.assert_allclose(Rn @ y, Tn @ x, rtol=1e-13, atol=1e-16)


def test_generated_scene_builds_the_same_model_as_the_mesh_file(tmp_path):
    import sys
    sys.path.insert(0, str(ROOT / "meshes"))
    try:
        import make_meshes
    finally:
        sys.path.pop(0)
    from jointsim.model import build_model
    path = tmp_path / "lap.msh"
    assert make_meshes.main(["--dx-lap", "0.015", "--dx-full", "0.03", "--ny-half", "1",
                             "-o", str(path)]) == 0
    for points in ("nodes", "gauss"):
        cp = f"model.contact_points='{points}'"
        a = build_model(load_scene(SCENE, [f"model.mesh='{path}'", cp]))
        b = build_model(load_scene(SCENE, ["model.mesh=''", "model.dx_lap=0.015",
                                           "model.dx_full=0.03", "model.ny_half=1", cp]))
        assert a.n_dof == b.n_dof and a.contacts.n_elements == b.contacts.n_elements
        for ma, mb in ((a.K, b.K), (a.M, b.M)):
            np.testing.assert_allclose(mb.toarray(), ma.toarray(), rtol=1e-8,
                                       atol=1e-10 * abs(ma).max())
        np.testing.assert_allclose(b.contacts.N0, a.contacts.N0, rtol=1e-7,
                                   atol=1e-9 * a.contacts.N0.max())
        assert "generated lap joint (dx_lap=0.015" in b.fe.mesh_file


def test_mesh_and_generation_keys_are_exclusive():
    with pytest.raises(SceneError) as e:
        load_scene(SCENE, ["model.dx_lap=0.005"])
    assert e.value.key == "model.dx_lap" and "model.mesh" in e.value.message
    with pytest.raises(SceneError) as e:
        load_scene(SCENE, ["model.mesh=''"])
    assert e.value.key == "model.mesh"
    s = load_scene(SCENE, ["model.mesh=''", "model.dx_lap=0.005"])
    assert s.model.generate == {"dx_lap": 0.005, "dx_full": 0.02, "ny_half": 2}
    assert load_scene(SCENE).model.generate is None


def test_generation_parameters_that_miss_a_bolt_name_the_key():
    from jointsim.model import build_model
    s = load_scene(SCENE, ["model.mesh=''", "model.dx_lap=0.007"])   # 30 mm / 7 mm
    with pytest.raises(SceneError) as e:
        build_model(s)
    assert e.value.key == "model.dx_lap" and "no node" in e.value.message


def _layered_cantilever_f1(dx, ny_half, points, n_gauss, k=1e10):
    """First frequency of two stacked layers bonded by interface springs k [N/m^3]."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from jointsim.fem.generate import layered_beam_mesh
    from jointsim.fem.interface import _facet_index
    from jointsim.fem.mesh import from_meshio
    mesh = from_meshio(layered_beam_mesh(0.2, 0.02, dx, ny_half))
    st = build_structure(mesh, E=200e9, nu=0.29, rho=7800.0, thickness=0.02,
                         contact_points=points, contact_gauss=n_gauss)
    Tt, Tn = st.interface.operators(st.n_dof)
    A = sp.diags(k * st.interface.area)
    K = st.K + Tt.T @ A @ Tt + Tn.T @ A @ Tn
    b = st.basis
    fixed = b.get_dofs(facets=_facet_index(b.mesh, mesh.edges("clamp"), "clamp")).all()
    free = np.setdiff1d(np.arange(st.n_dof), fixed)
    w2 = spla.eigsh(K[free][:, free].tocsc(), 2, st.M[free][:, free].tocsc(), sigma=0,
                    return_eigenvectors=False)
    return float(np.sqrt(w2.min()) / (2 * np.pi))


def test_interface_refinement_converges_monotonically_on_a_layered_cantilever():
    """Rayleigh-Ritz oracle: nested meshes and an exactly integrated interface energy
    (3 Gauss points) make f1 fall monotonically; 3 refinements (4 meshes)."""
    f = [_layered_cantilever_f1(0.02 / 2 ** i, 2 ** i, "gauss", 3) for i in range(4)]
    d = np.diff(f)
    assert np.all(d < 0), f
    assert np.all(np.abs(d[1:]) < 0.5 * np.abs(d[:-1])), f
    # the interface springs matter: well below the bonded (k -> large) value
    assert f[-1] < 0.7 * _layered_cantilever_f1(0.02, 1, "gauss", 3, k=1e14)


class _Sets:
    """The fields of study.LoopSets that the fractions read."""

    def __init__(self, loaded, on_manifold, on_masing):
        self.loaded = np.array(loaded, dtype=bool)
        self.on_manifold = np.array(on_manifold, dtype=bool)
        self.on_masing = np.array(on_masing, dtype=bool)


def test_weighted_fractions_by_hand():
    from jointsim.post import study
    sets = _Sets(loaded=[[1, 1, 1, 0], [0, 0, 0, 0]],
                 on_manifold=[[1, 0, 1, 1], [1, 1, 1, 1]],
                 on_masing=[[0, 0, 1, 1], [0, 0, 0, 0]])
    w = np.array([1.0, 2.0, 3.0, 10.0])
    man, mas, total = study.weighted_fractions(sets, w)
    assert man[0] == pytest.approx(4 / 6) and mas[0] == pytest.approx(3 / 6)
    assert total[0] == 6.0 and np.isnan(man[1]) and np.isnan(mas[1]) and total[1] == 0
    cm, cs, n = study.manifold_fractions(sets)
    assert cm[0] == pytest.approx(2 / 3) and cs[0] == pytest.approx(1 / 3)
    assert list(n) == [3, 0]
    # splitting an element in two halves (a finer mesh) keeps the weighted share
    split = _Sets(loaded=[[1, 1, 1, 1, 0]], on_manifold=[[1, 0, 1, 1, 1]],
                  on_masing=[[0, 0, 1, 1, 1]])
    m2, s2, _ = study.weighted_fractions(split, np.array([1.0, 2.0, 1.5, 1.5, 10.0]))
    assert m2[0] == pytest.approx(man[0]) and s2[0] == pytest.approx(mas[0])
    with pytest.raises(ValueError):
        study.weighted_fractions(sets, np.ones(3))
