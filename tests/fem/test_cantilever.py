"""Biquadratic plane-stress elements against Euler-Bernoulli cantilever frequencies.

The cantilever is slender (L/h = 200) so that shear deformation and rotary
inertia, which Euler-Bernoulli neglects and plane stress includes, shift the
third frequency by less than 0.05 %: the remaining error is discretisation.
"Default resolution" is the default mesh's element length along the beams
(20 mm) with one element through the thickness.
"""
import numpy as np
import scipy.sparse.linalg as spla

from jointsim.fem.assembly import assemble_plane_stress, vector_basis
from jointsim.fem.generate import RESOLUTIONS, beam_mesh
from jointsim.fem.interface import _facet_index
from jointsim.fem.mesh import from_meshio

E, NU, RHO, DEPTH = 200e9, 0.29, 7800.0, 0.0254
L, H = 0.72, 0.0036
BETA_L = np.array([1.8751040687, 4.6940911330, 7.8547574382])


def euler_bernoulli():
    I, A = DEPTH * H ** 3 / 12, DEPTH * H
    return BETA_L ** 2 / (2 * np.pi * L ** 2) * np.sqrt(E * I / (RHO * A))


def cantilever_frequencies(dx, ny=1):
    mesh = from_meshio(beam_mesh(L, H, dx, ny))
    b = vector_basis(mesh)
    K, M = assemble_plane_stress(b, E, NU, RHO, DEPTH)
    fixed = b.get_dofs(facets=_facet_index(b.mesh, mesh.edges("clamp"), "clamp")).all()
    free = np.setdiff1d(np.arange(b.N), fixed)
    w2 = spla.eigsh(K[free][:, free].tocsc(), 4, M[free][:, free].tocsc(), sigma=0,
                    return_eigenvectors=False)
    return np.sqrt(np.sort(w2)[:3]) / (2 * np.pi)


def test_cantilever_default_resolution_within_one_percent():
    dx_default = RESOLUTIONS["default"][1]
    err = np.abs(cantilever_frequencies(dx_default) / euler_bernoulli() - 1)
    assert np.all(err < 0.01), err


def test_cantilever_error_falls_under_refinement():
    errs = np.array([np.abs(cantilever_frequencies(dx) / euler_bernoulli() - 1)
                     for dx in (0.08, 0.04, 0.02, 0.01)])
    assert np.all(np.diff(errs, axis=0) < 0), errs
    # quadratic elements: the third mode's error drops by more than 4x per halving
    assert np.all(errs[:-1, 2] / errs[1:, 2] > 4.0), errs[:, 2]


def test_batched_stiffness_equals_the_scikit_fem_form(monkeypatch):
    """The element matrices by batched products (``plane_stress_stiffness``) give
    scikit-fem's ``BilinearForm`` of ``t sigma(u) : eps(v)`` (the oracle) to round-off,
    on a beam mesh with two elements through the height; blocks of 7 elements (the
    last one partial) give the same matrix."""
    import jointsim.fem.assembly as asm
    from skfem import BilinearForm
    from skfem.helpers import ddot, eye, sym_grad, trace

    b = vector_basis(from_meshio(beam_mesh(L, H, 0.01, 2)))
    lam, mu = asm.plane_stress_lame(E, NU)

    @BilinearForm
    def form(u, v, w):
        eps = sym_grad(u)
        return DEPTH * ddot(2.0 * mu * eps + lam * eye(trace(eps), 2), sym_grad(v))
    ref = form.assemble(b).tocsr()
    K = asm.plane_stress_stiffness(b, lam, mu, DEPTH)
    assert abs(K - ref).max() <= 1e-13 * abs(ref).max()
    n_el = b.mesh.t.shape[1]
    monkeypatch.setattr(asm, "STIFFNESS_BLOCK", 7)
    assert n_el > 7 and n_el % 7
    assert abs(asm.plane_stress_stiffness(b, lam, mu, DEPTH) - K).max() == 0.0
