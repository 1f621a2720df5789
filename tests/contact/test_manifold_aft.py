"""The AFT kernel of the manifold reversal law (issue 14).

Oracles:

* the time-domain manifold kernel (:meth:`ManifoldBank.march`, prescribed
  motion), marched from rest over the same number of periods: the AFT forces
  must equal it to round-off on random multi-harmonic, multi-reversal paths
  with varying N and separation;
* central finite differences of the AFT force coefficients with respect to the
  harmonic coefficients of ``u`` and of the normal gap (coupled unilateral N);
* at constant N the manifold law is Masing's rule applied to the bank's
  backbone, which the anchored bank (Jenkins, Iwan) obeys exactly: forces and
  Jacobians of the two AFT kernels agree, and so does the HBM FRC of
  ``models/hbm/chain2_jenkins.toml``.
"""
import numpy as np
import pytest
import scipy.sparse as sp

from jointsim.contact.normal import UnilateralPenalty
from jointsim.contact.select import tangential_law
from jointsim.harmonics import HarmonicBasis
from jointsim.model import ContactSet
from jointsim.scene import Joint
from jointsim.solvers.aft import AFT

from .._aft_reference import aft_history_fd

H = (0, 1, 2, 3, 4, 5)


def law_of(name, reversal="manifold", ne=30):
    joint = Joint(law=name, reversal=reversal, mu=0.3, kt=2.0, chi=-0.5, beta=0.2,
                  n_sliders=8, iwan_spacing="uniform")
    return tangential_law(name, reversal, joint, np.linspace(0.6, 1.4, ne))


def random_coefficients(basis, ne, seed, amp=0.6):
    """Random 5-harmonic slip coefficients (many reversals per period)."""
    rng = np.random.default_rng(seed)
    U = np.zeros((basis.n_coeff, ne))
    U[1:] = rng.normal(size=(basis.n_coeff - 1, ne)) * amp
    U[0] = rng.normal(size=ne) * 0.1
    return U, rng


def reversals(u):
    """Reversals of each row of ``u`` per period (sign changes of the increment)."""
    du = np.diff(np.concatenate([u, u[:, :1]], axis=1), axis=1)
    s = np.sign(du)
    return np.sum(s != np.roll(s, 1, axis=1), axis=1)


@pytest.mark.parametrize("name", ["jenkins", "iwan4"])
def test_aft_forces_are_the_time_march_on_the_converged_cycle(name):
    """30 random paths, N = 2 + N1 cos(h t + p), every third one separating."""
    ne = 30
    law = law_of(name, ne=ne)
    basis = HarmonicBasis(H, 256)
    U, rng = random_coefficients(basis, ne, 1)
    u = np.ascontiguousarray((basis.Gam @ U).T)
    t = 2 * np.pi * np.arange(basis.n_samples) / basis.n_samples
    N1 = np.where(np.arange(ne) % 3 == 0, rng.uniform(2.5, 4.0, ne), rng.uniform(0.3, 1.8, ne))
    N = 2.0 + N1[:, None] * np.cos(rng.integers(1, 4, ne)[:, None] * t
                                   + rng.uniform(0, 6, ne)[:, None])
    f, au, ag, Juu, Jug, periods, change = law.aft(u, N, np.zeros_like(N), basis, 2, 100,
                                                   1e-12, False)
    assert np.all(change <= 1e-12)
    assert np.sum(reversals(u) > 2) >= 25            # multi-reversal paths
    assert np.sum((N <= 0).any(axis=1)) == 10          # separation on every third
    for e in range(ne):
        s = law.subset([e]).rest_state(N[e:e + 1, 0])
        sub = law.subset([e])
        for _ in range(periods[e]):
            fm, dfdu, dfdN, s = sub.march(u[e:e + 1], N[e:e + 1], s)
        np.testing.assert_allclose(f[e], fm[0], rtol=0, atol=1e-13 * np.abs(fm).max())
        np.testing.assert_allclose(au[e], dfdu[0], rtol=0, atol=1e-13 * np.abs(dfdu).max())


def coupled_set(law):
    ne = law.n_elements
    eye = sp.identity(ne, format="csr")
    return ContactSet(eye, eye, np.full(ne, -0.5), np.full(ne, 2.0), np.ones(ne), law,
                      UnilateralPenalty(np.full(ne, 4.0)), np.zeros((ne, 2)))


def _assert_history_jacobian(aft, U, G, res, columns):
    """``res.Juu`` and ``res.Jug`` against central differences, to 1e-6 of their
    largest entry, on the coefficient rows ``columns``."""
    J = {"u": res.Juu, "g": res.Jug}
    scale = {k: np.abs(v).max() for k, v in J.items()}
    for which, j, fd in aft_history_fd(aft, U, G, columns):
        np.testing.assert_allclose(J[which][:, :, j], fd, rtol=0, atol=1e-6 * scale[which],
                                   err_msg=f"d/d{which} row {j}")


@pytest.mark.parametrize("name", ["jenkins", "iwan4"])
def test_aft_jacobian_against_central_differences(name):
    """dF/dU and dF/dG (coupled, separating N) of every coefficient, 1e-6 relative
    to the largest entry of the block (columns can vanish: the mean of u does not
    change the force once the path has reversed)."""
    ne = 8
    law = law_of(name, ne=ne)
    basis = HarmonicBasis(H, 256)
    U, rng = random_coefficients(basis, ne, 7)
    G = rng.normal(size=(basis.n_coeff, ne)) * 0.12
    aft = AFT(coupled_set(law), basis, max_periods=100, periodic_tol=1e-13)
    res = aft.evaluate(U, G)
    u = (basis.Gam @ U).T
    assert np.sum(reversals(u) > 2) >= 6 and np.any(res.N <= 0)
    assert np.any(np.abs(res.f) >= 0.3 * res.N - 1e-12)   # some slip
    _assert_history_jacobian(aft, U, G, res, range(basis.n_coeff))


@pytest.mark.parametrize("name", ["jenkins", "iwan4"])
def test_deeply_nested_loops_overflow_the_stack_with_exact_derivatives(name):
    """u = e(t) cos(40 t + p) with an envelope that shrinks then grows: about 40
    nested open reversals, more than the stack holds (MF_DEPTH), so the oldest are
    forgotten (companion rows shifted), then the loops close one by one.  (The
    envelope and phases are asymmetric: a path with u(t) = u(2 pi - t) closes its
    loops exactly at a sample, where the force jumps under varying N.)"""
    from jointsim.contact._kernels import MF_DEPTH, MF_TOP
    kf, ne, nt = 40, 3, 512
    basis = HarmonicBasis(range(kf + 2), nt)
    t = 2 * np.pi * np.arange(nt) / nt
    u = np.array([(0.55 + 0.45 * np.cos(t + 0.3 * np.sin(t))) * np.cos(kf * t + ph)
                  for ph in (0.17, 0.3, 1.1)])
    U = np.linalg.lstsq(basis.Gam, u.T, rcond=None)[0]
    u = (basis.Gam @ U).T
    G = np.zeros((basis.n_coeff, ne))
    G[1:4] = np.random.default_rng(2).normal(size=(3, ne)) * 0.2
    law = law_of(name, ne=ne)
    aft = AFT(coupled_set(law), basis, max_periods=100, periodic_tol=1e-13)
    res = aft.evaluate(U, G)
    s, depth = law.rest_state(res.N[:, 0]), 0
    for _ in range(int(res.periods.max())):
        for i in range(0, nt, 4):
            f, _, _, s = law.march(u[:, i:i + 4], res.N[:, i:i + 4], s)
            depth = max(depth, s[:, MF_TOP].max())
    assert depth == MF_DEPTH and np.any(res.N <= 0)
    np.testing.assert_allclose(res.f[:, -4:], f, rtol=0, atol=1e-13)
    _assert_history_jacobian(aft, U, G, res, range(0, basis.n_coeff, 3))   # every third row


@pytest.mark.parametrize("name", ["jenkins", "iwan4"])
def test_at_constant_normal_load_the_manifold_aft_is_the_anchor_aft(name):
    ne = 12
    basis = HarmonicBasis(H, 128)
    U, _ = random_coefficients(basis, ne, 3)
    N = np.full((ne, basis.n_samples), 1.5)
    out = {}
    for rev in ("anchor", "manifold"):
        law = law_of(name, rev, ne)
        u = np.ascontiguousarray((basis.Gam @ U).T)
        f, au, _ag, Juu, _Jug, _p, _c = law.aft(u, N, np.zeros_like(N), basis, 2, 100, 1e-13,
                                                 False)
        J = Juu.copy()
        basis.add_diag_product(J, au, False)
        out[rev] = (f, J)
    fa, Ja = out["anchor"]
    fm, Jm = out["manifold"]
    np.testing.assert_allclose(fm, fa, rtol=0, atol=1e-12 * np.abs(fa).max())
    np.testing.assert_allclose(Jm, Ja, rtol=0, atol=1e-10 * np.abs(Ja).max())


def _anchor_and_manifold_runs(scene_file, tmp_path, read) -> dict:
    """``read(h5)`` of the scene's result file with each reversal law, by law."""
    import h5py

    from jointsim.run import run_scene
    from jointsim.scene import load_scene

    data = {}
    for rev in ("anchor", "manifold"):
        out = run_scene(load_scene(scene_file, [f'joint.reversal="{rev}"']),
                        tmp_path / f"{rev}.h5")
        with h5py.File(out) as h5:
            data[rev] = read(h5)
    return data


@pytest.mark.slow
def test_constant_n_frc_with_the_manifold_law_is_the_anchor_frc(tmp_path):
    """models/hbm/chain2_jenkins.toml, three force levels: the same FRC to 1e-10, and the
    same refined peaks to the peak search's own tolerance (``frc.PEAK_XTOL``: Brent's
    search takes other steps on residuals 1e-10 apart; on an Intel Xeon the gross-slip
    level's peak amplitudes differ by 2.3e-8, round 45)."""
    from jointsim.solvers.frc import PEAK_XTOL

    def read(h5):
        br = h5["hbm/branch"][()]
        # rows of the branches interleave when they run in parallel
        order = np.lexsort((np.arange(br.size), br))
        d = {k: h5["hbm/" + k][()][order] for k in ("branch", "omega", "X")}
        d["peaks"] = h5["hbm/peak_amplitude"][()]
        return d

    data = _anchor_and_manifold_runs("models/hbm/chain2_jenkins.toml", tmp_path, read)
    a, m = data["anchor"], data["manifold"]
    np.testing.assert_array_equal(a["branch"], m["branch"])
    for k in ("omega", "X"):
        np.testing.assert_allclose(m[k], a[k], rtol=0, atol=1e-10 * np.abs(a[k]).max())
    np.testing.assert_allclose(m["peaks"], a["peaks"], rtol=PEAK_XTOL, atol=0)


@pytest.mark.slow
def test_constant_n_epmc_with_the_manifold_law_is_the_anchor_epmc(tmp_path):
    """models/hbm/sdof_jenkins_epmc.toml: the EPMC backbone of both laws to 1e-10."""
    data = _anchor_and_manifold_runs(
        "models/hbm/sdof_jenkins_epmc.toml", tmp_path,
        lambda h5: {k: h5["epmc/" + k][()] for k in ("omega", "amplitude", "damping_ratio")})
    for k, a in data["anchor"].items():
        np.testing.assert_allclose(data["manifold"][k], a, rtol=0, atol=1e-10 * np.abs(a).max())
