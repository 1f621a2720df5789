"""FE mesh generation, tags, assembly sanity and interface pairing."""

import numpy as np
import pytest

from jointsim.fem.assembly import (assemble_plane_stress, build_structure, merge_coincident,
                                   vector_basis)
from jointsim.fem.generate import RESOLUTIONS, lap_joint_mesh
from jointsim.fem.mesh import from_meshio, read_mesh, write_mesh
from jointsim.scene import Bolt

from .._scenes import ROOT

MESHES = ROOT / "meshes"
DEPTH = 0.0254


@pytest.fixture(scope="module")
def coarse():
    return read_mesh(MESHES / "lap_joint_coarse.msh")


def test_committed_meshes_match_the_script(tmp_path):
    """The committed files are what make_meshes.py writes (same nodes, cells, tags)."""
    for name, res in RESOLUTIONS.items():
        committed = read_mesh(MESHES / f"lap_joint_{name}.msh")
        fresh = read_mesh(write_mesh(lap_joint_mesh(*res), tmp_path / f"{name}.msh"))
        np.testing.assert_allclose(committed.points, fresh.points, atol=1e-15)
        np.testing.assert_array_equal(committed.quads, fresh.quads)
        assert committed.point_sets.keys() == fresh.point_sets.keys()
        assert (MESHES / f"lap_joint_{name}.msh").stat().st_size < 1_000_000


def test_tags_are_where_the_geometry_says(coarse):
    p = coarse.points
    for k, xb in enumerate((-0.03, 0.0, 0.03), start=1):
        np.testing.assert_allclose(p[coarse.point(f"bolt{k}_lower")], [xb, 0.0], atol=1e-12)
        np.testing.assert_allclose(p[coarse.point(f"bolt{k}_upper")], [xb, 0.0254], atol=1e-12)
    for side in ("interface_lower", "interface_upper"):
        e = coarse.edges(side)
        xy = p[e.ravel()]
        np.testing.assert_allclose(xy[:, 1], 0.0127, atol=1e-12)
        assert xy[:, 0].min() == pytest.approx(-0.06) and xy[:, 0].max() == pytest.approx(0.06)
    # the two bodies are disjoint: no node is shared between their quads
    left = set(coarse.quads[coarse.cell_sets["beam_left"]].ravel())
    right = set(coarse.quads[coarse.cell_sets["beam_right"]].ravel())
    assert not left & right
    # total area = 2 x (300 x 25.4 + 120 x 12.7) mm^2
    q = p[coarse.quads]
    x, y = q[..., 0], q[..., 1]
    area = 0.5 * (x * np.roll(y, -1, 1) - np.roll(x, -1, 1) * y).sum()
    assert area == pytest.approx(2 * (0.3 * 0.0254 + 0.12 * 0.0127), rel=1e-12)


def test_mass_and_rigid_modes(coarse):
    """Total mass = rho x volume; rigid translations and rotation have zero strain energy."""
    b = vector_basis(coarse)
    K, M = assemble_plane_stress(b, 200e9, 0.29, 7800.0, DEPTH)
    ux = np.zeros(b.N)
    ux[0::2] = 1.0
    assert ux @ M @ ux == pytest.approx(7800 * DEPTH * 2 * (0.3 * 0.0254 + 0.12 * 0.0127),
                                        rel=1e-12)
    X, Y = b.doflocs[0], b.doflocs[1]
    rot = np.where(np.arange(b.N) % 2 == 0, -Y, X)
    for v in (ux, np.roll(ux, 1), rot):
        assert abs(v @ K @ v) < 1e-9 * 200e9 * DEPTH


def test_tributary_areas_are_consistent_quadratic_weights(coarse):
    st = build_structure(coarse, E=200e9, nu=0.29, rho=7800.0, thickness=DEPTH)
    it = st.interface
    L = 0.015  # coarse lap element length
    assert it.n_elements == 2 * 8 + 1
    assert it.area.sum() == pytest.approx(0.12 * DEPTH, rel=1e-12)
    # corners (even index) L/6 per adjacent edge, midsides (odd) 2L/3
    np.testing.assert_allclose(it.area[1::2], 2 * L / 3 * DEPTH, rtol=1e-10)
    np.testing.assert_allclose(it.area[2:-1:2], 2 * L / 6 * DEPTH, rtol=1e-10)
    np.testing.assert_allclose(it.area[[0, -1]], L / 6 * DEPTH, rtol=1e-10)
    # frames: tangent +x, normal +y (from the lower into the upper body)
    np.testing.assert_allclose(it.frame[:, 0], [[1, 0]] * it.n_elements, atol=1e-12)
    np.testing.assert_allclose(it.frame[:, 1], [[0, 1]] * it.n_elements, atol=1e-12)
    # pairs coincide and are sorted along x
    pos_lo = st.basis.doflocs[:, it.lower_dofs[:, 0]].T
    pos_up = st.basis.doflocs[:, it.upper_dofs[:, 0]].T
    np.testing.assert_allclose(pos_lo, pos_up, atol=1e-12)
    assert np.all(np.diff(pos_lo[:, 0]) > 0)


def test_bolt_springs_and_clamping_forces(coarse):
    bolts = [Bolt(tag="bolt2", preload=12e3, stiffness=2e8)]
    st = build_structure(coarse, E=200e9, nu=0.29, rho=7800.0, thickness=DEPTH, bolts=bolts)
    b = st.bolts[0]
    np.testing.assert_allclose(b.axis, [0, 1])
    assert st.f_clamp[b.lower[1]] == 12e3 and st.f_clamp[b.upper[1]] == -12e3
    assert np.count_nonzero(st.f_clamp) == 2
    e = np.zeros(st.n_dof)
    e[b.upper[1]] = 1.0  # unit elongation
    assert e @ st.K_bolt @ e == pytest.approx(2e8)


def test_glued_mesh_merges_the_coincident_nodes(coarse):
    b = vector_basis(coarse)
    P = merge_coincident(b)
    # coincident nodes: the interface (2x8+1) and the step faces at x = +-60 mm
    # (2 faces x (2x1+1) nodes, of which the interface end node is already counted)
    n_shared = 17 + 2 * 2
    assert P.shape == (b.N, b.N - 2 * n_shared)


def test_bad_mesh_names_the_problem(tmp_path):
    import meshio
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    m = meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2]]))])
    with pytest.raises(ValueError, match="triangle"):
        from_meshio(m, "x.msh")
    m = meshio.Mesh(pts + [0, 0, 1], [("triangle", np.array([[0, 1, 2]]))])
    with pytest.raises(ValueError, match="not planar"):
        from_meshio(m, "x.msh")
