"""The Galerkin interface reduction of ``benchmarks/interface_reduction.py`` (issue 10)
on the coarse fixed-N FE joint: exact when its basis holds the solution, not otherwise;
the structured projection of the Jacobian equals the dense one."""
import numpy as np

from benchmarks.interface_reduction import project_jacobian, reduced_solve
from jointsim.solvers.hbm import HBMSystem, solve_point

OMEGA, FORCE = 1000.0, 20.0     # rad/s, force scale: a slipping point of the coarse joint


def test_reduced_solve_is_exact_when_its_basis_holds_the_solution(coarse_lap_fixed):
    """A slipping point (H = 0..3): Newton on the reduced system from the preload
    converges to the full point to round-off with the complete basis and with the span
    of the point's own contact-coordinate rows (n_c = 7 shapes of n_r = 17), on both
    linear-solver paths, and misses it by 16 % with two of those shapes."""
    s = HBMSystem(coarse_lap_fixed, (0, 1, 2, 3), 32, linear_solver="direct")
    F = s.force_coefficients(FORCE)
    pt = solve_point(s, OMEGA, F)
    assert pt.convergence.success
    assert np.ptp(s.slips(pt.X), axis=1).max() > 1e-5       # it slips: a nonlinear point
    z0 = s.static_coordinates()
    D = (pt.z - z0).reshape(s.n_c, s.n_r)
    own = np.linalg.qr(D.T)[0]                              # (n_r, n_c)
    sk = HBMSystem(coarse_lap_fixed, (0, 1, 2, 3), 32, linear_solver="krylov")
    for system in (s, sk):
        for V in (np.eye(s.n_r), own):
            z, its, ok, _ = reduced_solve(system, V, z0, z0, OMEGA, F)
            assert ok, its
            assert np.abs(z - pt.z).max() <= 1e-10 * np.abs(D).max()
    z, _, _, _ = reduced_solve(s, own[:, :2], z0, z0, OMEGA, F)
    assert np.abs(z - pt.z).max() > 0.05 * np.abs(D).max()


def test_structured_projection_equals_the_dense_one(coarse_lap_coupled):
    """Coupled N (slip, gap and their coupling blocks) at a state where elements slip
    (the stuck linear response to force scale 20, the first Newton iterate): the
    projection from the pieces equals ``P^T J P`` of the dense Jacobian to round-off."""
    s = HBMSystem(coarse_lap_coupled, (0, 1, 2, 3), 32, linear_solver="krylov")
    F = s.force_coefficients(FORCE)
    z = solve_point(s, OMEGA, F, max_iter=1).z
    J = s.evaluate(z, OMEGA, F, wrt=()).J
    assert np.abs(J.Jug).max() > 0 and np.abs(J.JNN).max() > 0
    V = np.linalg.qr(np.random.default_rng(1).standard_normal((s.n_r, 5)))[0]
    P = np.kron(np.eye(s.n_c), V)                           # z = P w (harmonic-major)
    dense = P.T @ J.to_dense() @ P
    assert np.abs(project_jacobian(J, V) - dense).max() <= 1e-12 * np.abs(dense).max()


def test_a_branch_on_the_complete_basis_is_the_full_branch(coarse_lap_fixed):
    """``follow_branch`` on the identity basis (the reduced machinery: the affine map,
    the projected Jacobian and its frequency column, the reduced scales) follows the
    same FRC branch as the full system: the same points to 1e-8 (force scale 20,
    H = 0..3, 940..1060 rad/s across the slipping resonance)."""
    from types import SimpleNamespace

    from benchmarks.interface_reduction import follow_branch
    from jointsim.solvers.frc import frc_scales
    s = HBMSystem(coarse_lap_fixed, (0, 1, 2, 3), 32, linear_solver="krylov")
    a = SimpleNamespace(omega_start=940.0, omega_end=1060.0, step=0.01, step_min=1e-6,
                        step_max=0.1, max_points=200, tol=1e-10, max_iter=20)
    F = s.force_coefficients(FORCE)
    z0 = s.static_coordinates()
    first = solve_point(s, a.omega_start, F)
    assert first.convergence.success
    y0 = np.append(first.z, a.omega_start)
    scale, rscale = frc_scales(s, F, a.omega_start, a.omega_end)
    full, bf, _ = follow_branch(s, F, y0, a, scale, rscale, None, z0)
    red, br, _ = follow_branch(s, F, y0, a, scale, rscale, np.eye(s.n_r), z0)
    assert bf.convergence.success and br.convergence.success
    assert len(full) == len(red) > 10
    full, red = np.array(full), np.array(red)
    assert np.abs(full[:, -1] - red[:, -1]).max() <= 1e-8 * a.omega_end
    assert np.abs(full[:, :-1] - red[:, :-1]).max() <= 1e-8 * np.abs(full[:, :-1]).max()
