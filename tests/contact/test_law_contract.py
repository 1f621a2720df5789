"""The contract every tangential law of the selection table keeps.

Parametrised over :data:`jointsim.contact.select.TANGENTIAL_TABLE` (and the
frictionless law), so a new law is checked as soon as it has its row: a plain
NumPy reference (which the new law must add to ``REFERENCE`` below), tangents
against finite differences, the backbone against a marched monotone loading,
explicit state (a march split in two equals one march, inputs unchanged),
and its AFT march against repeated time marching with an AFT Jacobian that
matches finite differences.
"""
import numpy as np
import pytest
import scipy.sparse as sp

from jointsim.contact import AnchoredBank, LinearSpring, ManifoldBank, NoFriction, ScaledBank
from jointsim.contact.normal import GivenNormal, UnilateralPenalty
from jointsim.contact.select import FRICTIONLESS, TANGENTIAL_TABLE, tangential_law
from jointsim.model import ContactSet
from jointsim.scene import Joint
from jointsim.harmonics import HarmonicBasis
from jointsim.solvers.aft import AFT

from .. import _reference as ref

ROWS = [(law, rev, True) for law, rev in TANGENTIAL_TABLE] + [("jenkins", "anchor", False)]
IDS = [f"{law}-{rev}" if fr else "frictionless" for law, rev, fr in ROWS]

#: law class -> reference(u, N, law) marched from rest (plain NumPy, from DESIGN §2)
REFERENCE = {
    AnchoredBank: lambda u, N, law: ref.anchor_bank(u, N, law.k, law.g,
                                                    np.zeros(law.k.shape))[0],
    ScaledBank: lambda u, N, law: ref.scaled_bank(u, N, law.k, law.g, N[:, 0]),
    ManifoldBank: lambda u, N, law: ref.manifold_bank(u, N, law.k, law.g),
    LinearSpring: lambda u, N, law: law.k[:, :1] * u,
    NoFriction: lambda u, N, law: np.zeros_like(u),
}


def make(row, ne=3):
    law, rev, friction = row
    joint = Joint(law=law, reversal=rev, mu=0.2, kt=3.0, chi=-0.4, beta=0.3, n_sliders=6)
    return tangential_law(law, rev, joint, np.linspace(0.5, 1.5, ne), friction=friction)


def paths(rng, ne, nt, periods=1):
    t = np.linspace(0.0, 2 * np.pi * periods, nt * periods, endpoint=False)
    u = np.zeros((ne, t.size))
    for h in (1, 2, 3):
        u += 0.6 / h * (rng.normal(size=(ne, 1)) * np.cos(h * t)
                        + rng.normal(size=(ne, 1)) * np.sin(h * t))
    N = 2.0 + 0.8 * np.cos(t + rng.uniform(0, 6, size=(ne, 1)))
    return u, N


def test_table_and_reference_cover_every_law():
    classes = {cls for cls, _ in TANGENTIAL_TABLE.values()} | {FRICTIONLESS[0]}
    assert classes <= set(REFERENCE), "every law of the table needs a NumPy reference here"
    for cls in classes:
        assert cls.name and isinstance(cls.can_slip, bool) and isinstance(cls.has_force, bool)


@pytest.mark.parametrize("row", ROWS, ids=IDS)
def test_march_equals_numpy_reference(row):
    law = make(row)
    u, N = paths(np.random.default_rng(1), law.n_elements, 400)
    f, _, _, state = law.march(u, N, law.rest_state(N[:, 0]))
    np.testing.assert_allclose(f, REFERENCE[type(law)](u, N, law), rtol=1e-12, atol=1e-12)
    assert state.shape == (law.n_elements, law.state_size())


@pytest.mark.parametrize("row", ROWS, ids=IDS)
def test_tangents_match_finite_differences(row):
    law = make(row)
    rng = np.random.default_rng(2)
    u, N = paths(rng, law.n_elements, 50)
    _, _, _, s = law.march(u, N, law.rest_state(N[:, 0]))  # a state with history
    checked = 0
    for _ in range(40):
        u1, N1 = rng.normal(size=(law.n_elements, 1)), rng.uniform(0.5, 3, (law.n_elements, 1))
        f, dfdu, dfdN, _ = law.march(u1, N1, s)
        for arg, d in ((0, dfdu), (1, dfdN)):
            h = 1e-7
            dx = [np.zeros_like(u1), np.zeros_like(u1)]
            dx[arg][:] = h
            fp = law.march(u1 + dx[0], N1 + dx[1], s)[0]
            fm = law.march(u1 - dx[0], N1 - dx[1], s)[0]
            one_sided = (fp - f) / h, (f - fm) / h
            smooth = np.abs(one_sided[0] - one_sided[1]) < 1e-6   # no stick/slip switch
            np.testing.assert_allclose(d[smooth], ((fp - fm) / (2 * h))[smooth],
                                       rtol=1e-6, atol=1e-6)
            checked += int(smooth.sum())
    assert checked > 100


@pytest.mark.parametrize("row", ROWS, ids=IDS)
def test_backbone_is_the_marched_initial_loading(row):
    law = make(row)
    ne = law.n_elements
    x = np.tile(np.linspace(0.0, 2.0, 300), (ne, 1))
    N = np.full_like(x, 1.7)
    f = law.march(x, N, law.rest_state(N[:, 0]))[0]
    np.testing.assert_allclose(law.backbone(x, N), f, rtol=1e-12, atol=1e-12)
    if law.can_slip:
        np.testing.assert_allclose(f[:, -1], law.slip_force(N[:, -1]), rtol=1e-12)


@pytest.mark.parametrize("row", ROWS, ids=IDS)
def test_state_is_explicit(row):
    law = make(row)
    u, N = paths(np.random.default_rng(3), law.n_elements, 200)
    s0 = law.rest_state(N[:, 0])
    keep = s0.copy()
    f_all, _, _, s_all = law.march(u, N, s0)
    f1, _, _, s1 = law.march(u[:, :77], N[:, :77], s0)
    f2, _, _, s2 = law.march(u[:, 77:], N[:, 77:], s1)
    np.testing.assert_array_equal(s0, keep)   # the input state is never modified
    np.testing.assert_allclose(np.hstack([f1, f2]), f_all, rtol=0, atol=1e-14)
    np.testing.assert_allclose(s2, s_all, rtol=0, atol=1e-14)
    sub = law.subset([0, 2])
    np.testing.assert_allclose(sub.march(u[[0, 2]], N[[0, 2]], s0[[0, 2]])[0], f_all[[0, 2]],
                               rtol=0, atol=1e-14)


def contact_set(law, coupled):
    ne = law.n_elements
    eye = sp.identity(ne, format="csr")
    normal = (UnilateralPenalty if coupled else GivenNormal)(np.full(ne, 4.0))
    return ContactSet(eye, eye, np.full(ne, -0.5), np.full(ne, 2.0), np.ones(ne), law, normal,
                      np.zeros((ne, 2)))


@pytest.mark.parametrize("coupled", [False, True], ids=["fixed-N", "coupled-N"])
@pytest.mark.parametrize("row", ROWS, ids=IDS)
def test_aft_march_is_the_periodic_time_march_with_exact_jacobian(row, coupled):
    law = make(row)
    if not law.has_aft:
        pytest.skip(f"{type(law).__name__} has no AFT kernel (refused for HBM by select.py)")
    ne = law.n_elements
    basis = HarmonicBasis((0, 1, 2, 3), 64)
    aft = AFT(contact_set(law, coupled), basis, max_periods=200, periodic_tol=1e-13)
    rng = np.random.default_rng(4)
    U = rng.normal(size=(basis.n_coeff, ne)) * 0.5
    G = rng.normal(size=(basis.n_coeff, ne)) * 0.15 if coupled else None
    res = aft.evaluate(U, G)
    # the periodic state from repeated marching of the same samples
    u = (basis.Gam @ U).T
    N = res.N
    s = law.rest_state(N[:, 0])
    for _ in range(60):
        f, _, _, s = law.march(u, N, s)
    np.testing.assert_allclose(res.f, f, rtol=1e-9, atol=1e-9)
    # Jacobian of the force coefficients against central differences
    for X, J in ((U, res.Juu), (G, res.Jug)):
        if X is None:
            continue
        h = 1e-7
        for j in rng.choice(basis.n_coeff, 3, replace=False):
            dX = np.zeros_like(X)
            dX[j] = h
            args = lambda sign: (U + sign * dX, G) if X is U else (U, G + sign * dX)  # noqa: E731
            fd = (aft.evaluate(*args(1), jacobian=False).Ft
                  - aft.evaluate(*args(-1), jacobian=False).Ft) / (2 * h)
            np.testing.assert_allclose(J[:, :, j], fd, rtol=1e-5, atol=1e-6 * max(1, np.abs(fd).max()))
