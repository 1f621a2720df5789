"""The condensation onto the contact coordinates (jointsim.solvers.condensation): the
three kinds of ``E`` (modal, low-rank damping, full), their derivatives against finite
differences, and ``E^-1`` against a dense solve."""

import numpy as np
import pytest

from jointsim.solvers.condensation import DynamicProducts, ReducedLinear, _LowRankE
from jointsim.solvers.welded import low_rank_factors
from jointsim.solvers.frequency_blocks import FrequencyBlocks


def _structure(kind: str, n: int = 14, n_r: int = 4, seed: int = 0):
    """M, K (SPD), C of the named damping kind, and T (n_r, n)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    K = A @ A.T + n * np.eye(n)
    B = rng.normal(size=(n, n)) / 3
    M = B @ B.T + np.eye(n)
    if kind == "modal":                      # Rayleigh: diagonal in the modes
        C = 0.02 * M + 1e-3 * K
    elif kind == "lowrank":                  # two damped directions
        U = rng.normal(size=(n, 2))
        C = U @ np.diag([0.3, 0.1]) @ U.T
    else:                                    # full rank, not proportional
        D = rng.normal(size=(n, n)) / 4
        C = D @ D.T + 0.05 * np.eye(n)
    T = rng.normal(size=(n_r, n))
    return M, K, C, T


def _apply_E(E, y):
    if isinstance(E, _LowRankE):
        return E.d * y + E.U @ (E.s * (E.U.T @ y))
    return E * y if E.ndim == 1 else E @ y


@pytest.mark.parametrize("kind", ["modal", "lowrank", "direct"])
def test_derivative_products_match_finite_differences(kind):
    """``dproducts`` (d/domega at harmonic h, d/dxi) against central differences of
    ``(A q + B y, B' q + E y)`` built from ``blocks``."""
    lin = ReducedLinear(*_structure(kind))
    assert lin.kind == kind
    rng = np.random.default_rng(1)
    q = rng.normal(size=lin.n_r) + 1j * rng.normal(size=lin.n_r)
    y = rng.normal(size=lin.n_y) + 1j * rng.normal(size=lin.n_y)
    h, omega, xi, eps = 3, 1.7, 0.04, 1e-6

    def products(w, x):
        A, B, Bp, E = lin.blocks(h * w, x)
        return A @ q + B @ y, Bp @ q + _apply_E(E, y)
    for wrt, plus, minus in (("omega", products(omega + eps, xi), products(omega - eps, xi)),
                             ("xi", products(omega, xi + eps), products(omega, xi - eps))):
        dq, dy = lin.dproducts(h * omega, xi, wrt, h, q, y)
        fq, fy = ((p - m) / (2 * eps) for p, m in zip(plus, minus))
        assert np.abs(dq - fq).max() <= 1e-7 * np.abs(fq).max()
        assert np.abs(dy - fy).max() <= 1e-7 * np.abs(fy).max()
        assert lin.dproducts(h * omega, xi, wrt, h, q, y, parts="y")[0] is None


@pytest.mark.parametrize("kind,factors", [("modal", False), ("lowrank", True),
                                          ("lowrank", False)])
def test_batched_derivative_products_equal_the_per_harmonic_ones(kind, factors):
    """``DynamicProducts.derivatives`` (every harmonic at once) against ``dproducts``
    harmonic by harmonic (checked against finite differences above), with
    self-excitation; a low-rank damping by its factors and by its dense blocks."""
    lin = ReducedLinear(*_structure(kind))
    if not factors:
        lin.KMC_lowc = None
    rng = np.random.default_rng(4)
    harmonics, omega, xi = np.array([0, 1, 2, 5]), 1.7, 0.04
    Q = rng.normal(size=(lin.n_r, 4)) + 1j * rng.normal(size=(lin.n_r, 4))
    Y = rng.normal(size=(lin.n_y, 4)) + 1j * rng.normal(size=(lin.n_y, 4))
    dyn = DynamicProducts(lin, harmonics * omega, xi)
    for wrt in ("omega", "xi"):
        dq, dy = dyn.derivatives(wrt, omega, harmonics, Q, Y)
        for j, h in enumerate(harmonics):
            rq, ry = lin.dproducts(h * omega, xi, wrt, h, Q[:, j], Y[:, j])
            assert np.abs(dq[:, j] - rq).max() <= 1e-13 * max(np.abs(rq).max(), 1.0)
            assert np.abs(dy[:, j] - ry).max() <= 1e-13 * max(np.abs(ry).max(), 1.0)


@pytest.mark.parametrize("kind", ["modal", "lowrank"])
def test_dynamic_products_equal_the_schur_complements(kind):
    """``DynamicProducts.apply`` (every harmonic at once, real BLAS-3 products) against
    ``S_h = A - B E^-1 B'`` formed from ``blocks`` per harmonic (with self-excitation,
    harmonic 0 included, several columns per harmonic; a damping of low rank by its
    factors); a full ``E`` is refused."""
    lin = ReducedLinear(*_structure(kind))
    assert (lin.KMC_lowc is not None) == (kind == "lowrank")
    rng = np.random.default_rng(3)
    harmonics, omega, xi = (0, 1, 2, 5), 1.7, 0.04
    X = rng.normal(size=(lin.n_r, 4, 3)) + 1j * rng.normal(size=(lin.n_r, 4, 3))
    Y = DynamicProducts(lin, np.array(harmonics) * omega, xi).apply(X)
    for j, h in enumerate(harmonics):
        A, B, Bp, E = lin.blocks(h * omega, xi)
        S = A - B @ lin.solve_E(lin.factor_E(E), Bp)
        ref = S @ X[:, j, :]
        assert np.abs(Y[:, j, :] - ref).max() <= 1e-12 * np.abs(ref).max()
    with pytest.raises(ValueError, match="modal or low-rank"):
        DynamicProducts(ReducedLinear(*_structure("direct")), [omega], xi)


@pytest.mark.parametrize("kind", ["modal", "lowrank", "direct"])
def test_solve_E_is_the_inverse(kind):
    """``solve_E`` of the factorised ``E`` (one and several right-hand sides, and the
    transpose) against a dense solve of ``E`` applied to the identity."""
    lin = ReducedLinear(*_structure(kind))
    E = lin.blocks(2.3, 0.01)[3]
    Ed = np.column_stack([_apply_E(E, e) for e in np.eye(lin.n_y, dtype=complex)])
    Ef = lin.factor_E(E)
    rng = np.random.default_rng(2)
    b = rng.normal(size=(lin.n_y, 3)) + 1j * rng.normal(size=(lin.n_y, 3))
    ref = np.linalg.solve(Ed, b)
    assert np.abs(lin.solve_E(Ef, b) - ref).max() <= 1e-10 * np.abs(ref).max()
    assert np.abs(lin.solve_E(Ef, b[:, 0]) - ref[:, 0]).max() <= 1e-10 * np.abs(ref).max()
    reft = np.linalg.solve(Ed.T, b[:, 1])
    assert np.abs(lin.solve_E(Ef, b[:, 1], trans=True) - reft).max() \
        <= 1e-10 * np.abs(reft).max()


@pytest.mark.parametrize("n, n_r", [(14, 4), (40, 12)])
def test_low_rank_damping_schur_equals_the_complex_blocks(n, n_r):
    """``S_h`` with low-rank damping by Woodbury's formula (``schur_low_rank_damping``:
    one real product for a forced response, a complex one with self-excitation)
    against ``A - B E^-1 B'`` of the complex blocks, at harmonic 0, off and near a
    resonance of the welded structure, with and without self-excitation (also through
    ``FrequencyBlocks``); without a low-rank damping the blocks serve."""
    lin = ReducedLinear(*_structure("lowrank", n=n, n_r=n_r))
    Wq, Wy, c = lin.damping_factors
    assert c.size == 2 and Wq.shape == (n_r, 2) and Wy.shape == (n - n_r, 2)
    near = 0.999 * np.sqrt(lin.lam[0] / lin.myy[0])       # a welded-structure mode
    for xi in (0.0, 0.05, -0.3):
        for nu in (0.0, 0.37, 1.7, 5.0, near):
            A, B, Bp, E = lin.blocks(nu, xi)
            ref = A - B @ lin.solve_E(lin.factor_E(E), Bp)
            S = lin.schur_low_rank_damping(nu, xi)
            assert np.abs(S - ref).max() <= 1e-11 * np.abs(ref).max(), (nu, xi)
    harmonics, omega = (0, 1, 3), 1.1
    for xi in (0.0, 0.05):
        fb = FrequencyBlocks(lin, harmonics, omega, xi)
        for i, h in enumerate(harmonics):
            A, B, Bp, E = lin.blocks(h * omega, xi)
            ref = A - B @ lin.solve_E(lin.factor_E(E), Bp)
            assert np.abs(fb.schur(i) - ref).max() <= 1e-11 * np.abs(ref).max()
    assert ReducedLinear(*_structure("modal")).damping_factors is None
    assert ReducedLinear(*_structure("direct")).damping_factors is None


def _wide_spectrum(n: int = 80, n_r: int = 8, seed: int = 3):
    """M, K, C (damping of rank 2) and T of a structure whose modes span 8 decades of
    stiffness (most of them quasi-static at low frequency)."""
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    K = (Q * np.logspace(0, 8, n)) @ Q.T
    B = rng.normal(size=(n, n)) / 3
    M = B @ B.T + np.eye(n)
    U = rng.normal(size=(n, 2))
    return M, 0.5 * (K + K.T), U @ np.diag([0.3, 0.1]) @ U.T, rng.normal(size=(n_r, n))


def test_quasi_static_modes_enter_s_h_by_their_expansion(coarse_lap_coupled):
    """``schur_low_rank_damping`` with the welded structure's modes above
    ``QUASI_STATIC_RATIO nu`` summed once as ``sum_p s^p C_p``, with and without
    self-excitation (``s = nu^2 + i nu xi``; ``_b_dinv_bp``) against ``A - B E^-1 B'`` of the complex blocks: on a structure of
    8 decades of stiffness (to 1e-12 of its stiffness: both sides cancel) and on the
    coarse lap joint at harmonics 0 to 15 of 300 rad/s (to 1e-12 of ``S_h``; the split
    used where half its modes or more are quasi-static, the lowest of them at 2.5e4
    rad/s; the sums lowered mode by mode as the frequency rises equal those formed
    afresh); with the ratio 0, the full product."""
    import jointsim.solvers.condensation as cm
    from jointsim.solvers.hbm import HBMSystem
    lap = HBMSystem(coarse_lap_coupled, tuple(range(8)), 32, linear_solver="krylov").lin
    wide = ReducedLinear(*_wide_spectrum())
    for lin, nus, scale in (
            (wide, (0.0, 0.37, 0.8, 1.2, 5.0, 40.0), np.abs(wide.K["qq"]).max()),
            (lap, [h * 300.0 for h in range(16)], None)):
        assert lin.kind == "lowrank"
        used = 0
        for nu, xi in [(nu, xi) for nu in nus for xi in (0.0, 0.02 * nu)]:
            A, B, Bp, E = lin.blocks(nu, xi)
            ref = A - B @ lin.solve_E(lin.factor_E(E), Bp)
            S = lin.schur_low_rank_damping(nu, xi)
            tol = 1e-12 * (scale if scale is not None else np.abs(ref).max())
            assert np.abs(S - ref).max() <= tol, (nu, xi)
            split = lin._quasi_static(nu)
            if split is not None:
                used += nu > 0
                assert split[0].size <= lin.n_y // 2
        assert used >= 4
    # the sums, lowered as the frequency rose, equal those formed afresh
    lap._quasi = None
    for nu in (300.0, 700.0, 1500.0):
        split = lap._quasi_static(nu)
    assert split is not None and lap._quasi[0] == 3000.0
    C = split[1]
    assert np.abs(C - lap._quasi_sums(lap._quasi[2])).max() <= 1e-12 * np.abs(C).max()
    lin = ReducedLinear(*_wide_spectrum())
    cm_ratio = cm.QUASI_STATIC_RATIO
    try:
        cm.QUASI_STATIC_RATIO = 0.0
        assert lin._quasi_static(1.0) is None
    finally:
        cm.QUASI_STATIC_RATIO = cm_ratio


def testlow_rank_factors_reproduce_a_low_rank_matrix_and_refuse_a_full_one():
    """``low_rank_factors``: a symmetric indefinite matrix of rank 5 (n = 90) is
    rebuilt from its factors to round-off, split after ``n_r`` rows; one of full rank
    and one of rank 40 (above n / 3 = 30) give None, as does a zero matrix."""
    rng = np.random.default_rng(7)
    n, n_r = 90, 20
    U = rng.normal(size=(n, 5))
    C = U @ np.diag([3.0, -1.0, 0.5, 2.0, -0.2]) @ U.T
    Wq, Wy, c = low_rank_factors(C, n_r)
    assert c.size == 5 and Wq.shape == (n_r, 5) and Wy.shape == (n - n_r, 5)
    W = np.vstack([Wq, Wy])
    assert np.abs((W * c) @ W.T - C).max() <= 1e-12 * np.abs(C).max()
    A = rng.normal(size=(n, n))
    V = rng.normal(size=(n, 40))
    for full in (A + A.T, V @ V.T, np.zeros((n, n))):
        assert low_rank_factors(full, n_r) is None


@pytest.mark.parametrize("kind", ["modal", "lowrank", "direct", "undamped"])
def test_transformed_blocks_are_the_congruence(kind):
    """The blocks of ``K``, ``M``, ``C`` in the coordinates ``(q, y)`` (``K`` and ``M`` by
    symmetric congruences on two threads and turned by the welded modes, the yy blocks
    known, ``diag(lam)``, ``I``, ``Z' C Z``; a damping of low rank from its factors,
    round 43) equal ``V' A V``, ``V = [Psi, Z]``, formed in full.  The low-rank damping
    is found as its two factors (none for a Rayleigh or a full damping; rank 0 for no
    damping, whose condensation is modal), and the condensation's ``damping_factors``
    rebuild ``V' C V``."""
    M, K, C, T = _structure("modal" if kind == "undamped" else kind)
    if kind == "undamped":
        C = np.zeros_like(C)
    lin = ReducedLinear(M, K, C, T)
    assert lin.kind == ("modal" if kind == "undamped" else kind)
    rank = {"lowrank": 2, "undamped": 0}.get(kind)
    if rank is None:
        assert lin.damping_low_rank is None
    else:
        assert lin.damping_low_rank[0].shape == (lin.n, rank)
    V = np.hstack([lin.Psi, lin.Z])
    r, y = slice(0, lin.n_r), slice(lin.n_r, lin.n)
    for A, blocks in ((K, lin.K), (M, lin.M), (C, lin.C)):
        At = V.T @ A @ V
        for b, (i, j) in {"qq": (r, r), "qy": (r, y), "yq": (y, r), "yy": (y, y)}.items():
            assert np.abs(blocks[b] - At[i, j]).max() <= 1e-12 * max(np.abs(At).max(),
                                                                       1e-300), b
    if kind == "lowrank":
        Wq, Wy, c = lin.damping_factors
        W = np.vstack([Wq, Wy])
        Ct = V.T @ C @ V
        assert np.abs((W * c) @ W.T - Ct).max() <= 1e-12 * np.abs(Ct).max()
        assert np.abs(W.T @ W - np.eye(c.size)).max() <= 1e-13


@pytest.mark.parametrize("kind", ["modal", "lowrank", "direct"])
def test_psi_is_the_right_inverse_of_t_and_z_its_null_space(kind):
    """``Psi`` (from the QR factors of ``T'``, round 48) equals ``T' (T T')^-1`` and ``T
    Psi = I``; ``T Z = 0`` and ``Z`` is M-orthonormal (modal, low-rank) or orthonormal
    (direct); rows of ``T`` that are linearly dependent are refused."""
    M, K, C, T = _structure(kind, n=16, n_r=5, seed=3)
    lin = ReducedLinear(M, K, C, T)
    ref = T.T @ np.linalg.inv(T @ T.T)
    assert np.abs(lin.Psi - ref).max() <= 1e-13 * np.abs(ref).max()
    assert np.abs(T @ lin.Psi - np.eye(5)).max() <= 1e-13
    assert np.abs(T @ lin.Z).max() <= 1e-13 * np.abs(T).max() * np.abs(lin.Z).max()
    G = lin.Z.T @ (M if kind != "direct" else np.eye(16)) @ lin.Z
    assert np.abs(G - np.eye(11)).max() <= 1e-12
    T[4] = T[0] - 2.0 * T[2]
    with pytest.raises(ValueError, match="linearly dependent"):
        ReducedLinear(M, K, C, T)


@pytest.mark.parametrize("kind", ["modal", "lowrank", "direct"])
def test_block_products_equal_the_formed_blocks(kind):
    """``block_times`` (real products, the block not formed) equals the complex block of
    ``blocks`` times a vector, and its transpose, at a frequency and self-excitation."""
    M, K, C, T = _structure(kind)
    lin = ReducedLinear(M, K, C, T)
    nu, xi = 3.7, 0.4
    A, B, Bp, _ = lin.blocks(nu, xi)
    rng = np.random.default_rng(4)
    for b, X in (("qq", A), ("qy", B), ("yq", Bp)):
        for transpose in (False, True):
            Y = X.T if transpose else X
            v = rng.normal(size=Y.shape[1]) + 1j * rng.normal(size=Y.shape[1])
            got = lin.block_times(b, nu, xi, v, transpose=transpose)
            assert np.abs(got - Y @ v).max() <= 1e-13 * np.abs(Y).max() * np.abs(v).sum()


@pytest.mark.parametrize("dtype", [np.float32, np.complex64, np.float64, np.complex128])
def test_stacked_inverse_in_the_blocks_precision(dtype):
    """``jointsim.linalg.stacked_inverse``: the inverses of a stack (and of one block) in
    the blocks' precision, against a double inverse to that precision's rounding times
    the blocks' condition number (about 30 here), or with ``in_double`` a double inverse
    rounded; a singular block gets the stack's pseudo-inverse."""
    from jointsim.linalg import stacked_inverse
    rng = np.random.default_rng(5)
    n = 60
    A = rng.normal(size=(3, n, n)) + 4.0 * np.sqrt(n) * np.eye(n)
    if np.iscomplexobj(np.zeros(0, dtype)):
        A = A + 1j * rng.normal(size=(3, n, n))
    A = A.astype(dtype)
    X = stacked_inverse(A)
    ref = np.linalg.inv(A.astype(np.complex128))
    eps = np.finfo(dtype).eps
    assert X.dtype == dtype
    assert np.abs(X - ref).max() <= 100 * n * eps * np.abs(ref).max()
    one = stacked_inverse(A[1])
    assert one.dtype == dtype and np.abs(one - ref[1]).max() <= 100 * n * eps * np.abs(ref).max()
    if eps > 1e-10:     # in double and rounded: a double inverse of the blocks, rounded
        wide = np.promote_types(dtype, np.float64)
        got = stacked_inverse(A, in_double=True)
        assert got.dtype == dtype
        assert np.array_equal(got, np.linalg.inv(A.astype(wide)).astype(dtype))
    S = A.copy()
    S[2, :, 0] = 0.0                                     # singular
    P = stacked_inverse(S)
    assert np.abs(P[2] - np.linalg.pinv(S[2].astype(np.complex128))).max() \
        <= 1e3 * n * eps * np.abs(P[2]).max()


def test_packed_symmetric_products_are_the_full_blocks_products():
    """``jointsim.linalg.PackedSymmetric``: each block times its vector from the upper
    triangle alone (complex symmetric blocks in single and double precision, the
    preconditioner's mix), to the blocks' rounding; a block flagged not symmetric is
    multiplied whole (its lower triangle matters), and a symmetric block's lower triangle
    is not read."""
    from jointsim.linalg import PackedSymmetric
    rng = np.random.default_rng(8)
    n = 37
    A = rng.normal(size=(4, n, n)) + 1j * rng.normal(size=(4, n, n))
    A = A + A.transpose(0, 2, 1)
    A[3] += np.triu(rng.normal(size=(n, n)), 1)                  # not symmetric
    x = rng.normal(size=(4, n)) + 1j * rng.normal(size=(4, n))
    ref = np.einsum("hij,hj->hi", A, x)
    blocks = [A[0].astype(np.complex64), A[1], A[2].astype(np.complex64), A[3]]
    got = PackedSymmetric(blocks, [True, True, True, False]).times(x)
    assert got.dtype == np.complex128 and got.shape == x.shape
    scale = np.abs(A).max() * np.abs(x).sum(axis=1)
    for h, eps in enumerate((1e-6, 1e-14, 1e-6, 1e-14)):
        assert np.abs(got[h] - ref[h]).max() <= eps * scale[h]
    real = PackedSymmetric([A[0].real, A[3].real.astype(np.float32)], [True, False])
    want = np.einsum("hij,hj->hi", A[[0, 3]].real, x[[0, 3]])     # a real block, complex x
    assert np.abs(real.times(x[[0, 3]]) - want).max() <= 1e-6 * np.abs(want).max()
    lower_changed = [B.copy() for B in blocks]
    for B in lower_changed[:3]:
        B[np.tril_indices(n, -1)] = 7.0
    again = PackedSymmetric(lower_changed, [True, True, True, False]).times(x)
    assert np.array_equal(again, got)


def test_mixed_times_keeps_the_double_blocks_in_double():
    """``jointsim.linalg.mixed_times``: the stacked products in the stack's single
    precision, but for the blocks given in double, which are used instead."""
    from jointsim.linalg import mixed_times
    rng = np.random.default_rng(9)
    P = rng.normal(size=(3, 20, 12)) + 1j * rng.normal(size=(3, 20, 12))
    X = rng.normal(size=(3, 12, 2)) + 1j * rng.normal(size=(3, 12, 2))
    ref = np.matmul(P, X)
    got = mixed_times(P.astype(np.complex64), {1: P[1]}, X)
    assert got.dtype == np.complex128 and got.shape == ref.shape
    err = np.abs(got - ref).max(axis=(1, 2)) / np.abs(ref).max(axis=(1, 2))
    assert err[1] <= 1e-15 and 1e-10 < err[0] <= 1e-6 and 1e-10 < err[2] <= 1e-6
    real = mixed_times(P.real.astype(np.float32), {}, X)         # real blocks, complex X
    want = np.matmul(P.real, X)
    assert np.abs(real - want).max() <= 1e-6 * np.abs(want).max()


def test_symmetric_congruence_is_the_product_on_any_threads():
    """``jointsim.linalg.symmetric_congruence``: ``V' A V`` of a symmetric ``A`` (dense and
    sparse) by blocks on one side of the diagonal equals the whole product to round-off,
    is symmetric, and is the same on one thread and on three (blocks of 7 columns)."""
    import scipy.sparse as sp

    from jointsim.linalg import symmetric_congruence
    rng = np.random.default_rng(11)
    n, m = 40, 30
    B = rng.normal(size=(n, n))
    V = rng.normal(size=(n, m))
    for A in (B + B.T, sp.random(n, n, density=0.2, random_state=3)):
        A = A + A.T if sp.issparse(A) else A
        ref = V.T @ (A @ V)
        one = symmetric_congruence(V, A, threads=1, columns=7)
        three = symmetric_congruence(V, A, threads=3, columns=7)
        assert np.abs(one - ref).max() <= 1e-13 * np.abs(ref).max()
        assert np.array_equal(one, one.T) and np.array_equal(one, three)
        both = symmetric_congruence(V, A, threads=1, columns=7, both_sides=True)
        assert np.array_equal(both, both.T)
        assert np.abs(both - 0.5 * (ref + ref.T)).max() <= 1e-13 * np.abs(ref).max()
        assert np.array_equal(both, symmetric_congruence(V, A, threads=3, columns=7,
                                                         both_sides=True))


def test_the_condensations_stuck_frequencies_are_the_shift_invert_ones():
    """On the default lap joint (96 Gauss points, 428 reduced DOFs) the stuck joint's
    first elastic frequencies seen from the condensation (where ``S(nu^2) + diag(k)`` is
    singular, undamped, ``S`` from the blocks of ``K`` and ``M`` in the coordinates
    ``(q, y)``) equal the shift-invert modes of ``(K_stuck, M)`` (Lanczos on SuperLU's
    pivoted factors) to 1e-8: the round-off of a structure of condition number about
    1e11 (measured on the first 2.5e-9 on OpenBLAS's threads, 6.6e-11 on one;
    ``stuck_modes``, on the unpivoted factors of :func:`~jointsim.fem.reduction.spd_lu`,
    is 1.3e-8 from that reference)."""
    from pathlib import Path

    import scipy.sparse.linalg as spla

    from jointsim.model import build_model
    from jointsim.scene import load_scene
    from jointsim.solvers.hbm import HBMSystem
    from jointsim.solvers.modes import stuck_modes
    model = build_model(load_scene(Path(__file__).parents[2] / "models" / "lap_joint.toml"))
    lin = HBMSystem(model, (0, 1), 16, linear_solver="krylov").lin
    k = lin.flexibility.k
    lam, myy = np.diag(lin.K["yy"]), np.diag(lin.M["yy"])

    def mu(s):                   # the eigenvalue of S(s) + diag(k) nearest 0
        B0 = lin.K["qy"] - s * lin.M["qy"]
        S = lin.K["qq"] - s * lin.M["qq"] - (B0 / (lam - s * myy)) @ B0.T + np.diag(k)
        w = np.linalg.eigvalsh(0.5 * (S + S.T))
        return w[np.argmin(np.abs(w))]
    modes = stuck_modes(model, 8)
    w2 = np.sort(spla.eigsh(model.linearisation.K.tocsc(), k=8, M=model.M.tocsc(), sigma=0.0,
                            which="LM", tol=1e-15)[0])
    for f in (np.sqrt(w2) / (2 * np.pi))[modes.elastic][:4]:
        s0, s1 = (2 * np.pi * f) ** 2 * (1 - 1e-7), (2 * np.pi * f) ** 2 * (1 + 1e-7)
        m0, m1 = mu(s0), mu(s1)
        for _ in range(8):                        # secant on mu(s) = 0
            if m1 == m0:
                break
            s0, m0, s1 = s1, m1, s1 - m1 * (s1 - s0) / (m1 - m0)
            m1 = mu(s1)
        assert abs(np.sqrt(s1) / (2 * np.pi) / f - 1) <= 1e-8
