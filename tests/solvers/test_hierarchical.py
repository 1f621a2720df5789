"""The hierarchical interface operator (jointsim.solvers.hierarchical): the bisection
tree, the HODLR product against the dense one, ``S_h`` of every harmonic against the
formed Schur complement, and the Krylov path with it against the dense direct path."""

import numpy as np
import pytest

from jointsim.solvers import hierarchical as hi


def _kernel_parts(n: int = 300, seed: int = 1):
    """Three smooth kernels on points of a line (numerically low rank off the diagonal)
    and the points, shuffled, two coordinates at each."""
    rng = np.random.default_rng(seed)
    x = np.repeat(np.sort(rng.uniform(0.0, 1.0, n // 2)), 2)
    d = np.abs(x[:, None] - x[None, :])
    parts = [1.0 / (1.0 + 40.0 * d) + 3.0 * np.eye(n), np.exp(-5.0 * d), np.cos(2.0 * d)]
    perm = rng.permutation(n)
    return [G[np.ix_(perm, perm)] for G in parts], x[perm, None]


def test_bisection_tree_orders_every_coordinate_and_keeps_a_position_together():
    """Every coordinate once; leaves of at most ``leaf`` coordinates tile the order;
    each cut cluster's halves are its children; the two coordinates at one position
    share a leaf; along a line the leaves are intervals (no leaf's span overlaps
    another's)."""
    _, pos = _kernel_parts()
    order, levels, leaves = hi.bisection_tree(pos, leaf=32)
    n = pos.shape[0]
    assert np.array_equal(np.sort(order), np.arange(n))
    assert leaves[0][0] == 0 and all(a[1] == b[0] for a, b in zip(leaves, leaves[1:]))
    assert leaves[-1][1] == n and all(hi_ - lo <= 32 for lo, hi_ in leaves)
    spans = sorted((pos[order[lo:hi_], 0].min(), pos[order[lo:hi_], 0].max())
                   for lo, hi_ in leaves)
    assert all(a[1] < b[0] for a, b in zip(spans, spans[1:]))
    leaf_of = np.empty(n, dtype=int)
    for k, (lo, hi_) in enumerate(leaves):
        leaf_of[order[lo:hi_]] = k
    for p in np.unique(pos[:, 0]):
        assert np.unique(leaf_of[pos[:, 0] == p]).size == 1
    assert levels[0] == [(0, levels[1][0][2], n)]
    for upper, lower in zip(levels, levels[1:]):
        cuts = {(lo, mid) for lo, mid, _ in upper} | {(mid, hi_) for _, mid, hi_ in upper}
        assert all((lo, hi_) in cuts for lo, _, hi_ in lower)


@pytest.mark.parametrize("complex_s", [False, True])
def test_hodlr_product_equals_the_dense_one_within_its_tolerance(complex_s):
    """``sum_p s_p G_p X`` by :class:`HODLR` against the dense product, for real and
    complex ``s`` per column: within the truncations' sum (``levels x`` each part's
    tolerance times ``|s^p|``) in the 2-norm; with a tolerance of 1e-10 the storage is
    below half of the dense parts' and a part below its tolerance is dropped."""
    parts, pos = _kernel_parts()
    n = parts[0].shape[0]
    tree = hi.bisection_tree(pos, leaf=32)
    tols = [1e-10 * np.linalg.norm(G, 2) for G in parts]
    parts.append(1e-17 * np.ones((n, n)))           # below its tolerance: dropped
    tols.append(1e-12)
    H = hi.HODLR(parts, tols, tree)
    assert H.powers == [0, 1, 2] and H.compression < 0.5
    rng = np.random.default_rng(2)
    X = rng.normal(size=(n, 5)) + 1j * rng.normal(size=(n, 5))
    s = rng.uniform(0.5, 2.0, 5) * (np.exp(0.7j) if complex_s else 1.0)
    spow = np.stack([s ** p for p in H.powers])
    Y = H.apply(X, spow)
    for j in range(5):
        ref = sum(spow[k, j] * (parts[p] @ X[:, j]) for k, p in enumerate(H.powers))
        bound = len(tree[1]) * sum(abs(spow[k, j]) * tols[p] for k, p in enumerate(H.powers))
        assert np.linalg.norm(Y[:, j] - ref) <= bound * np.linalg.norm(X[:, j])
        assert np.linalg.norm(Y[:, j] - ref) > 0.0          # truncated, not dense


@pytest.fixture
def small_tree(monkeypatch):
    """The hierarchical form from any size, on leaves of 12 coordinates."""
    import jointsim.solvers.preconditioner as pm
    monkeypatch.setattr(hi, "HIERARCHICAL_MIN_ROWS", 0)
    monkeypatch.setattr(pm, "HIERARCHICAL_STAGE_MIN_ROWS", 0)
    monkeypatch.setattr(pm, "SOLVED_STAGE_COLUMNS", 1.0)
    monkeypatch.setattr(hi, "LEAF_ROWS", 12)


@pytest.mark.parametrize("xi", [0.0, 3.0])
def test_interface_products_equal_the_formed_schur_complement(small_tree, coarse_lap_coupled,
                                                              xi):
    """``S_h x_h`` through the hierarchical form (``G(s)`` plus the basis ``F`` and each
    harmonic's ``M_h``) against the formed ``S_h``
    (:meth:`~jointsim.solvers.condensation.ReducedLinear.schur_low_rank_damping`) at
    harmonics 0 to 7 of 300 rad/s (the split applies), forced (``xi = 0``) and
    self-excited: to 1e-10 of the product; the tree has at least two levels."""
    from jointsim.solvers.hbm import HBMSystem
    system = HBMSystem(coarse_lap_coupled, tuple(range(8)), 32, linear_solver="krylov")
    fb = system.harmonic_blocks(300.0, xi)
    prod = fb.hierarchical
    assert prod is not None and len(hi.InterfaceHierarchy.of(system.lin).tree[1]) >= 2
    rng = np.random.default_rng(4)
    X = rng.normal(size=(system.n_r, 8, 2)) + 1j * rng.normal(size=(system.n_r, 8, 2))
    Y = prod.apply(X)
    for i in range(8):
        ref = fb.schur(i) @ X[:, i]
        assert np.abs(Y[:, i] - ref).max() <= 1e-10 * np.abs(ref).max(), i


def test_krylov_path_with_the_hierarchical_form_agrees_with_the_dense_path(
        small_tree, monkeypatch):
    """Fixed-frequency solves of the coarse FE lap joint (coupled N with separation, force
    scale 20, harmonics 0 to 3) by GMRES with ``J v`` through the hierarchical form and
    by the dense direct path: the same points to 1e-8 in X and the same Newton
    iterations; the structured Jacobian's product equals its dense form to 1e-10."""
    from jointsim.analyses.hbm import _system
    from jointsim.model import build_model
    from jointsim.solvers.hbm import solve_point

    from .._scenes import ROOT, lap_scene
    used = []
    orig = hi.InterfaceProducts.apply
    monkeypatch.setattr(hi.InterfaceProducts, "apply",
                        lambda self, X: used.append(1) or orig(self, X))
    recs = {}
    for solver in ("direct", "krylov"):
        sc = lap_scene(ROOT / "models" / "lap_joint_nodes.toml", ("modes", "hbm"),
                       ["analysis.hbm.harmonics=[0,1,2,3]", "analysis.hbm.n_samples=64",
                        f"analysis.hbm.linear_solver='{solver}'"])
        s = _system(build_model(sc), sc.analysis.hbm)
        F = s.force_coefficients(20.0)
        pts = [solve_point(s, w, F) for w in (900.0, 960.0)]
        recs[solver] = ([p.X for p in pts], [p.convergence.iterations for p in pts])
        if solver == "krylov":
            ev = s.evaluate(pts[0].z, 900.0, F)
            v = np.random.default_rng(5).normal(size=s.n_z)
            ref = ev.J.to_dense() @ v
            assert np.abs(ev.J.matvec(v) - ref).max() <= 1e-10 * np.abs(ref).max()
    assert used
    (Xd, itd), (Xk, itk) = recs["direct"], recs["krylov"]
    for a, b in zip(Xd, Xk):
        assert np.abs(a - b).max() <= 1e-8 * np.abs(a).max()
    assert itd == itk and max(itd) > 2


def test_a_loose_solves_harmonic_stage_is_the_hierarchical_factorisation(small_tree,
                                                                         monkeypatch):
    """For a loose solve (the error indicators' GMRES tolerance) the harmonic stage is
    :class:`~jointsim.solvers.hierarchical.HierarchicalInverse` (no ``n_r x n_r`` array):
    on the coarse FE lap joint at a slipping point (force scale 20, harmonics 0 to 3) its
    ``P_h^-1`` has a backward error below 1e-6 against ``S_h`` plus the harmonic
    projection of the element tangents, and the whole preconditioner (with its exact
    low-rank stage) solves ``J`` to 1e-4.  Where the low-rank stage needs more columns
    of ``P_h^-1`` than ``SOLVED_STAGE_COLUMNS n_r``, the dense stage is built instead."""
    import jointsim.solvers.preconditioner as pm
    from jointsim.analyses.hbm import _system
    from jointsim.model import build_model
    from jointsim.solvers.hbm import solve_point
    from jointsim.solvers.preconditioner import HarmonicPreconditioner
    from jointsim.solvers.tangent_projection import add_projected_tangent

    from .._scenes import ROOT, lap_scene
    sc = lap_scene(ROOT / "models" / "lap_joint_nodes.toml", ("modes", "hbm"),
                   ["analysis.hbm.harmonics=[0,1,2,3]", "analysis.hbm.n_samples=64",
                    "analysis.hbm.linear_solver='krylov'"])
    s = _system(build_model(sc), sc.analysis.hbm)
    F = s.force_coefficients(20.0)
    z = solve_point(s, 900.0, F).z
    s.krylov_rtol = 1e-3
    J = s.evaluate(z, 900.0, F).J
    P = HarmonicPreconditioner(J)
    assert P.Psolve is not None and P.Pinv is None and P.S is None and P.lowrank is not None
    rng = np.random.default_rng(0)
    X = rng.normal(size=(4, s.n_r, 2)) + 1j * rng.normal(size=(4, s.n_r, 2))
    X[0] = X[0].real                           # harmonic 0 is real
    Y = P._inverse_times(X)
    for i in range(4):
        B = np.array(J.schur(i))
        add_projected_tangent(B, J, i, P.proj)
        assert np.abs(B @ Y[i] - X[i]).max() <= 1e-6 * np.abs(X[i]).max(), i
    b = rng.normal(size=s.n_z)
    ref = np.linalg.solve(J.to_dense(), b)
    assert np.abs(P.solve(b) - ref).max() <= 1e-4 * np.abs(ref).max()
    monkeypatch.setattr(pm, "SOLVED_STAGE_COLUMNS", 0.0)
    P = HarmonicPreconditioner(J)
    assert P.Psolve is None and P.lowrank is not None
    assert np.abs(P.solve(b) - ref).max() <= 1e-4 * np.abs(ref).max()


def test_the_pieces_shared_with_forked_workers_are_made_once(small_tree, coarse_lap_coupled):
    """``HBMSystem.prepare_forks`` makes, before workers fork, the stuck flexibility and
    the hierarchical form for every harmonic up to ``omega_max`` (its quasi-static split
    at ``2 h_max omega_max``); a system on the same condensation (a worker's, an
    indicator's) then uses that form at every lower frequency, none made again."""
    from jointsim.solvers.hbm import HBMSystem
    harmonics = tuple(range(8))
    system = HBMSystem(coarse_lap_coupled, harmonics, 32, linear_solver="krylov")
    assert "flexibility" not in vars(system.lin)
    system.prepare_forks(400.0)
    assert vars(system.lin)["flexibility"] is not None
    hier = hi.InterfaceHierarchy.of(system.lin)
    form = hier._form
    assert form is not None and form.nu_max == 2.0 * 7 * 400.0
    other = HBMSystem(coarse_lap_coupled, harmonics + (8, 9), 32, linear_solver="krylov",
                      lin=system.lin)
    for omega in (250.0, 310.0, 400.0 * 7 / 9):
        assert other.harmonic_blocks(omega).hierarchical is not None
    assert hier._form is form


def test_hodlr_columns_are_read_from_its_factors():
    """:meth:`HODLR.columns`: the columns of ``sum_p spow[p, h] G_p`` for several ``h``
    (complex factors) equal the product with unit vectors to round-off and the dense
    sums' columns within the truncations' sum; a repeated column and every leaf's are
    served, and so are some rows only, added to an array."""
    parts, pos = _kernel_parts()
    n = parts[0].shape[0]
    tree = hi.bisection_tree(pos, leaf=32)
    tols = [1e-10 * np.linalg.norm(G, 2) for G in parts]
    H = hi.HODLR(parts, tols, tree)
    rng = np.random.default_rng(7)
    spow = rng.normal(size=(3, 4)) + 1j * rng.normal(size=(3, 4))
    cols = np.concatenate([[0, n - 1, 17, 17], rng.choice(n, 30, replace=False)])
    C = H.columns(cols, spow)
    assert C.shape == (4, n, cols.size)
    E = np.zeros((n, cols.size))
    E[cols, np.arange(cols.size)] = 1.0
    bound = len(tree[1]) * np.abs(spow).sum(axis=0)[:, None] * max(tols)
    for h in range(4):
        by_apply = H.apply(E.astype(complex), np.repeat(spow[:, h:h + 1], cols.size, axis=1))
        assert np.abs(C[h] - by_apply).max() <= 1e-13 * np.abs(by_apply).max()
        dense = sum(spow[p, h] * parts[p][:, cols] for p in range(3))
        err = np.linalg.norm(C[h] - dense, axis=0)
        assert np.all(err <= bound[h]) and err.max() > 0.0
    # some rows, in any order (a repeated one too), and added to an array
    rows = np.concatenate([[n - 1, 3, 3], rng.choice(n, 20, replace=False)])
    base = rng.normal(size=(4, rows.size, cols.size)) + 0j
    got = H.columns(cols, spow, rows, add_to=base.copy())
    assert np.abs(got - base - C[:, rows]).max() <= 1e-14 * np.abs(C).max()
