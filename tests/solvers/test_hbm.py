"""Harmonic balance, continuation and EPMC (issue 4): checks against oracles."""

import h5py
import numpy as np
import pytest

from jointsim.model import build_model
from jointsim.results import NON_FINITE, STEP_TOO_SMALL
from jointsim.run import run_scene
from jointsim.scene import SceneError, load_scene, parse_scene
from jointsim.solvers.continuation import continue_branch
from jointsim.harmonics import HarmonicBasis, harmonic_amplitude
from jointsim.solvers.aft import AFT
from jointsim.solvers.hbm import HBMSystem, solve_point

from .._aft_reference import anchor_aft_numpy
from .._scenes import ROOT, four_dof

MODELS = ROOT / "models" / "hbm"


CASES = [("jenkins", "anchor", "fixed"), ("jenkins", "anchor", "coupled"),
         ("jenkins", "scaled", "fixed"), ("jenkins", "scaled", "coupled"),
         ("iwan4", "anchor", "fixed"), ("iwan4", "anchor", "coupled"),
         ("iwan4", "scaled", "coupled"), ("stuck", "anchor", "fixed"),
         ("stuck", "anchor", "coupled")]


@pytest.mark.parametrize("law,reversal,normal", CASES)
def test_jacobian_matches_finite_differences(law, reversal, normal):
    """Analytic dR/dz, dR/domega and dR/dxi against central differences, with slip,
    stick and (coupled) separation inside the period."""
    m = build_model(four_dof(law, reversal, normal))
    s = HBMSystem(m, (0, 1, 2, 3), 64)
    F = s.force_coefficients(0.3)
    z = np.random.default_rng(0).normal(size=s.n_z) * 0.4
    w, xi = 1.1, 0.05
    ev = s.evaluate(z, w, F, xi=xi, wrt=("omega", "xi"))
    if normal == "coupled":
        assert ev.aft.N.min() == 0.0 and ev.aft.N.max() > 0.0  # separates
    if law != "stuck":
        slip = np.isclose(np.abs(ev.aft.f), 0.3 * ev.aft.N, rtol=1e-12) & (ev.aft.N > 0)
        assert slip.any() and (~slip).any()

    def R(z_, w_=w, xi_=xi):
        return s.evaluate(z_, w_, F, xi=xi_, jacobian=False).R

    eps = 1e-7
    Jfd = np.column_stack([(R(z + eps * e) - R(z - eps * e)) / (2 * eps)
                           for e in np.eye(s.n_z)])
    scale = np.abs(Jfd).max()
    assert np.abs(ev.J - Jfd).max() <= 1e-6 * scale
    dw = (R(z, w + eps) - R(z, w - eps)) / (2 * eps)
    dxi = (R(z, w, xi + eps) - R(z, w, xi - eps)) / (2 * eps)
    assert np.abs(ev.dR["omega"] - dw).max() <= 1e-6 * np.abs(dw).max()
    assert np.abs(ev.dR["xi"] - dxi).max() <= 1e-6 * np.abs(dxi).max()


@pytest.mark.parametrize("normal", ["given", "unilateral"])
@pytest.mark.parametrize("n_sliders", [1, 6])
def test_aft_kernels_match_numpy_reference(normal, n_sliders):
    """Numba AFT (sparse history outer products + Fourier-sum diagonal) equals the
    dense forward-mode NumPy reference."""
    import scipy.sparse as sp

    from jointsim.contact.laws import AnchoredBank, iwan4_sliders
    from jointsim.contact.select import NORMAL_TABLE
    NORMAL_LAWS = {c.name: c for c in NORMAL_TABLE.values()}
    from jointsim.model import ContactSet
    ne = 5
    b = HarmonicBasis((0, 1, 2, 3, 5), 96)
    if n_sliders == 1:
        k, g = np.full((ne, 1), 1.0), np.full((ne, 1), 0.3)
    else:
        k, g = np.empty((ne, n_sliders)), np.empty((ne, n_sliders))
        for e in range(ne):
            k[e], g[e] = iwan4_sliders(1.0, 0.3, -0.5, 0.1, n_sliders)
    law = AnchoredBank(k, g, np.full(ne, 0.3))
    eye = sp.identity(ne, format="csr")
    cs = ContactSet(eye, eye, np.full(ne, -0.5), np.ones(ne), np.ones(ne), law,
                    NORMAL_LAWS[normal](np.ones(ne)), np.zeros((ne, 2)))
    rng = np.random.default_rng(3)
    U = rng.normal(size=(b.n_coeff, ne)) * 0.5
    G = rng.normal(size=(b.n_coeff, ne)) * 0.3
    coupled = normal != "given"
    r = AFT(cs, b).evaluate(U, G if coupled else None)
    Ft, Nc, Juu, Jug, JNN = anchor_aft_numpy(U, G, cs.gap0, cs.kn, k, g, cs.N0, b, coupled)
    assert np.allclose(r.Ft, Ft, rtol=0, atol=1e-13)
    assert np.allclose(r.Juu, Juu, rtol=0, atol=1e-13)
    if coupled:
        assert np.allclose(r.Jug, Jug, rtol=0, atol=1e-13)
        assert np.allclose(r.JNN, JNN, rtol=0, atol=1e-13)


def test_harmonic_basis_roundtrip_and_diag_product():
    b = HarmonicBasis((0, 1, 3, 4), 32)
    X = np.random.default_rng(1).normal(size=(b.n_coeff, 3))
    assert np.allclose(b.P @ b.samples(X), X, atol=1e-14)
    alpha = np.random.default_rng(2).normal(size=(2, 32))
    direct = np.einsum("kt,et,tj->ekj", b.P, alpha, b.Gam)
    assert np.allclose(b.diag_product(alpha), direct, atol=1e-14)


def _exact_linear(M, K, C, F, w):
    """Exact coefficients of harmonic 1 (complex solve)."""
    Xh = np.linalg.solve(K - w * w * M + 1j * w * C, F)
    return Xh.real, -Xh.imag


@pytest.mark.parametrize("proportional", [True, False])
def test_linear_system_reproduces_exact_frf(proportional):
    """Stuck law: HBM = linear FRF of K + Tt^T kt Tt to round-off, through the
    modal and the direct condensation."""
    C = None if proportional else [[0.05, 0.01, 0, 0], [0.01, 0.02, 0, 0.01],
                                   [0, 0, 0.03, 0], [0, 0.01, 0, 0.04]]
    sc = four_dof("stuck", "anchor", "fixed", C=C)
    m = build_model(sc)
    s = HBMSystem(m, (0, 1, 2, 3), 16)
    assert s.lin.modal == proportional or not proportional
    if not proportional:
        assert not s.lin.modal
    Tt = m.contacts.Tt.toarray()
    Klin = m.K.toarray() + Tt.T @ (m.contacts.law.kt[:, None] * Tt)
    M, Cm = m.M.toarray(), m.C.toarray()
    F = s.force_coefficients(0.7)
    for w in (0.3, 0.9, 1.31, 2.2):
        p = solve_point(s, w, F)
        xc, xs = _exact_linear(M, Klin, Cm, F[1], w)
        ref = np.abs(np.concatenate([xc, xs])).max()
        assert np.abs(p.X[1] - xc).max() <= 1e-13 * ref
        assert np.abs(p.X[2] - xs).max() <= 1e-13 * ref
        assert np.abs(p.X[[0, 3, 4, 5, 6]]).max() <= 1e-13 * ref


def test_linear_model_without_contacts():
    sc = load_scene(MODELS / "chain2_jenkins.toml", ["effects.friction=false"])
    m = build_model(sc)
    s = HBMSystem(m, (0, 1, 2), 8)
    assert s.n_z == 0
    F = s.force_coefficients(1.0)
    p = solve_point(s, 1.2, F)
    xc, xs = _exact_linear(m.M.toarray(), m.K.toarray(), m.C.toarray(), F[1], 1.2)
    assert np.allclose(p.X[1], xc, rtol=1e-14, atol=0)
    assert np.allclose(p.X[2], xs, rtol=1e-14, atol=1e-16)


def test_dependent_contact_coordinates_are_refused():
    d = {"model": {"kind": "lumped", "M": [[1.0]], "K": [[1.0]],
                   "contacts": [{"t_dof": 0, "N0": 1.0}, {"t_dof": 0, "N0": 1.0}]},
         "joint": {"law": "jenkins"}}
    m = build_model(parse_scene(d, "dup.toml"))
    with pytest.raises(ValueError, match="linearly dependent"):
        HBMSystem(m, (0, 1), 8)


def _describing_function(a, kt=0.25, Fs=0.2, k=1.0):
    """Backbone of the first-harmonic describing function (DESIGN §5)."""
    w, z = [], []
    for A in a:
        if kt * A <= Fs:
            c1, s1 = kt * A, 0.0
        else:
            b = np.arccos(1 - 2 * Fs / (kt * A))
            c1 = kt * A / np.pi * (b - np.sin(2 * b) / 2)
            s1 = -4 * Fs / np.pi * (1 - Fs / (kt * A))
        ww = np.sqrt(k + c1 / A)
        w.append(ww)
        z.append(-s1 / (2 * A * ww * ww))
    return np.array(w), np.array(z)


def test_epmc_sdof_jenkins_matches_describing_function(tmp_path):
    """Harmonics {0, 1}: EPMC backbone = describing-function backbone to 1e-5."""
    out = tmp_path / "epmc.h5"
    sc = load_scene(MODELS / "sdof_jenkins_epmc.toml",
                    ["analysis.epmc.harmonics=[0, 1]", "analysis.epmc.n_samples=4096"])
    run_scene(sc, out)
    with h5py.File(out) as h:
        a = h["epmc/amplitude"][()]
        w = h["epmc/omega"][()]
        f = h["epmc/frequency_hz"][()]
        zeta = h["epmc/damping_ratio"][()]
        assert h["epmc/X"].shape == (a.size, 3, 1)
        assert h["epmc/amplitude"].attrs["unit"]
        assert h["epmc"].attrs["success"]
        # the mode is fundamental-cosine only, amplitude = X_1c for m = 1
        assert np.allclose(h["epmc/X"][:, 1, 0], a, rtol=1e-9)
        assert h["loops/u"].shape[0] == a.size
    assert a.min() <= 0.11 and a.max() >= 99.0 and a.size >= 10
    W, Z = _describing_function(a)
    assert np.allclose(f, w / (2 * np.pi))
    assert np.abs(w / W - 1).max() <= 1e-5
    slipping = Z > 1e-4
    assert slipping.sum() >= 5 and (~slipping).sum() >= 2
    assert np.abs(zeta[slipping] / Z[slipping] - 1).max() <= 1e-5
    assert np.abs(zeta[~slipping]).max() <= 1e-9


def test_chain_stuck_branch_peak_equals_linear_frf_peak(tmp_path):
    """F = 0.01 stays stuck: every point is on the linear FRF of K + kt e2 e2^T and
    the refined peak equals its peak; F = 0.2 slips and its peak is lower."""
    from scipy.optimize import minimize_scalar
    out = tmp_path / "chain.h5"
    sc = load_scene(MODELS / "chain2_jenkins.toml", ["analysis.hbm.force_scale=[0.01, 0.2]",
                                                    "analysis.hbm.loops=all"])
    run_scene(sc, out)
    K = np.array([[2.0, -1.0], [-1.0, 2.25]])
    C = 0.01 * np.eye(2)

    def amp(w, F=0.01):
        return abs(np.linalg.solve(K - w * w * np.eye(2) + 1j * w * C, [F, 0.0])[0])

    r = minimize_scalar(lambda w: -amp(w), bounds=(1.0, 1.1), method="bounded",
                        options={"xatol": 1e-12})
    with h5py.File(out) as h:
        br = h["hbm/branch"][()]
        om, a = h["hbm/omega"][()], h["hbm/amplitude"][()]
        assert h["hbm/X"].shape == (br.size, 15, 2)
        for name in ("omega", "X", "amplitude", "iterations", "residual", "step"):
            assert "unit" in h[f"hbm/{name}"].attrs
        assert h["loops/u"].shape == (br.size, 1, 128)
        f = h["loops/f"][()]
        stuck = br == 0
        assert np.abs(f[stuck]).max() < 0.2          # never reaches the slip force
        assert np.abs(f[~stuck]).max() == pytest.approx(0.2, rel=1e-12)  # F = 0.2 slips
        assert np.abs(h["masing/dev_manifold"][()]).max() <= 1e-9  # constant N
        exact = np.array([amp(w) for w in om[stuck]])
        assert np.abs(a[stuck] - exact).max() <= 1e-6 * exact.max()
        assert h["hbm/peak_refined"][0]
        assert h["hbm/peak_amplitude"][0] == pytest.approx(-r.fun, rel=1e-9)
        assert h["hbm/peak_omega"][0] == pytest.approx(r.x, rel=1e-6)
        assert om[br == 1][-1] == pytest.approx(1.3, abs=1e-12)
        assert h["hbm/peak_amplitude"][1] < 20 * h["hbm/peak_amplitude"][0]


def _turns_and_multiplicity(om):
    d = np.diff(om)
    turns = int(np.sum(np.sign(d[1:]) != np.sign(d[:-1])))
    grid = np.linspace(om.min(), om.max(), 400)[1:-1]
    crossings = [int(np.sum((om[:-1] - w) * (om[1:] - w) < 0)) for w in grid]
    return turns, max(crossings)


@pytest.mark.parametrize("scene_file,min_peak", [("sdof_clearance_fold.toml", 6.5),
                                                 ("chain2_friction_fold.toml", 4.0)])
def test_continuation_passes_folds(tmp_path, scene_file, min_peak):
    """Hardening (clearance) and friction-softening FRCs: the branch turns, has three
    solutions at some frequency, and every point solves the equations."""
    out = tmp_path / "fold.h5"
    sc = load_scene(MODELS / scene_file, ["analysis.hbm.force_scale=[0.2]"]
                    if "clearance" in scene_file else [])
    run_scene(sc, out)
    with h5py.File(out) as h:
        om, a = h["hbm/omega"][()], h["hbm/amplitude"][()]
        assert h["hbm"].attrs["branch0_status"] == "complete"
        assert om[-1] == pytest.approx(sc.analysis.hbm.omega_end, abs=1e-12)
        assert np.all(h["hbm/residual"][()] <= sc.analysis.hbm.tol)
        q = h["hbm/q"][()]
    turns, mult = _turns_and_multiplicity(om)
    assert turns >= 2 and mult >= 3
    assert a.max() >= min_peak
    # an interior point re-solved at fixed frequency stays put (it is a solution)
    m = build_model(sc)
    s = HBMSystem(m, sc.analysis.hbm.harmonics, sc.analysis.hbm.n_samples)
    F = s.force_coefficients(sc.analysis.hbm.force_scale[0])
    i = int(np.argmax(a))
    p = solve_point(s, om[i], F, z0=q[i], tol=1e-9)
    assert p.convergence.success and p.convergence.iterations <= 3
    assert np.abs(p.z - q[i]).max() <= 1e-6 * np.abs(q[i]).max()


def test_error_falls_with_harmonics_at_a_rate():
    """2-DOF Jenkins chain near its slipping peak: the error of x(t) against H = 63
    falls like H^-p with a fitted p > 2.5."""
    sc = load_scene(MODELS / "chain2_jenkins.toml")
    m = build_model(sc)
    fine = HarmonicBasis((0, 1), 4096)

    def response(H):
        s = HBMSystem(m, tuple(range(H + 1)), 2048)
        p = solve_point(s, 1.02, s.force_coefficients(0.2), tol=1e-12)
        assert p.convergence.success
        Gam = HarmonicBasis(tuple(range(H + 1)), 4096).Gam
        return Gam @ p.X[:, 0]

    ref = response(63)
    Hs = np.array([1, 3, 5, 7, 9])
    err = np.array([np.abs(response(H) - ref).max() for H in Hs]) / np.abs(ref).max()
    assert np.all(np.diff(err) < 0)
    rate = -np.polyfit(np.log(Hs), np.log(err), 1)[0]
    assert rate > 2.5, rate
    del fine


def test_continuation_turning_points_on_a_circle():
    """R = z^2 + lam^2 - 1 from lam = -0.8 towards 2: passes lam = 1 (a turning point)
    and comes back, every point on the circle."""
    def fun(y):
        z, lam = y
        return np.array([z * z + lam * lam - 1.0]), np.array([[2 * z, 2 * lam]]), None

    br = continue_branch(fun, np.array([0.5, -0.8]), 2.0, scale=np.ones(2), rscale=1.0,
                         step=0.05, step_min=1e-8, step_max=0.1, max_points=200, tol=1e-12,
                         progress=False)
    z, lam = br.y[:, 0], br.y[:, 1]
    assert np.abs(z * z + lam * lam - 1).max() <= 1e-12
    assert lam.max() == pytest.approx(1.0, abs=1e-2) and z.min() < -0.5
    assert br.convergence.success and "turned back" in br.convergence.message


def test_continuation_gives_up_and_keeps_the_branch():
    """Past lam = 0.5 the residual is not finite: the step shrinks, the branch is kept
    and the reason is given."""
    def fun(y):
        z, lam = y
        if lam > 0.5:
            return np.array([np.nan]), np.array([[np.nan, np.nan]]), None
        return np.array([z - lam ** 2]), np.array([[1.0, -2 * lam]]), None

    seen = []
    br = continue_branch(fun, np.array([0.0, 0.0]), 1.0, scale=np.ones(2), rscale=1.0,
                         step=0.05, step_min=1e-5, step_max=0.1, max_points=500, tol=1e-12,
                         on_point=lambda i, y, info: seen.append(y[-1]), progress=False)
    assert not br.convergence.success
    assert br.convergence.status in (STEP_TOO_SMALL, NON_FINITE)
    assert "step_min" in br.convergence.message
    assert len(seen) == br.y.shape[0] >= 5
    assert 0.49 < br.y[-1, 1] <= 0.5


def test_continuation_stops_exactly_at_the_end():
    def fun(y):
        z, lam = y
        return np.array([z - np.sin(lam)]), np.array([[1.0, -np.cos(lam)]]), None

    br = continue_branch(fun, np.array([0.0, 0.0]), 3.0, scale=np.ones(2), rscale=1.0,
                         step=0.1, step_min=1e-8, step_max=0.3, max_points=100, tol=1e-12,
                         progress=False)
    assert br.convergence.success
    assert br.y[-1, 1] == 3.0 and br.y[-1, 0] == pytest.approx(np.sin(3.0), abs=1e-12)
    assert np.all(np.diff(br.y[:, 1]) > 0)


def run_interrupted_after(scene, path, n_points, monkeypatch, dataset="hbm/omega"):
    """Run a scene and press Ctrl-C when the file holds ``n_points`` rows of ``dataset``
    (HBM points by default)."""
    from jointsim.io import hdf5
    original = hdf5.ResultWriter.append

    def interrupting(self, name, row, unit, doc=""):
        if name == dataset and self.rows(dataset) >= n_points:
            raise KeyboardInterrupt
        return original(self, name, row, unit, doc)

    monkeypatch.setattr(hdf5.ResultWriter, "append", interrupting)
    with pytest.raises(KeyboardInterrupt):
        run_scene(scene, path)
    monkeypatch.setattr(hdf5.ResultWriter, "append", original)


def test_interrupted_run_resumes_to_the_same_branch(tmp_path, monkeypatch):
    """Ctrl-C after 12 points leaves a valid file; --resume completes the branch."""
    overrides = ["analysis.hbm.force_scale=[0.05, 0.2]", "analysis.hbm.harmonics=[0, 1, 3]",
                 "analysis.hbm.n_samples=32", "analysis.hbm.workers=1"]
    sc = load_scene(MODELS / "chain2_jenkins.toml", overrides)
    full = tmp_path / "full.h5"
    run_scene(sc, full)
    part = tmp_path / "part.h5"
    run_interrupted_after(sc, part, 12, monkeypatch)
    with h5py.File(part) as h:
        assert h.attrs["status"] == "interrupted"
        n0 = h["hbm/omega"].shape[0]
        assert n0 == 12 and h["hbm/X"].shape[0] == 12
    run_scene(sc, part, resume=True)
    with h5py.File(part) as h, h5py.File(full) as g:
        assert h.attrs["status"] == "complete"
        om, omf = h["hbm/omega"][()], g["hbm/omega"][()]
        assert np.array_equal(h["hbm/branch"][()][:12], g["hbm/branch"][()][:12])
        assert np.allclose(om[:12], omf[:12], rtol=0, atol=0)
        for b in (0, 1):
            assert h["hbm"].attrs[f"branch{b}_status"] == "complete"
            assert om[h["hbm/branch"][()] == b][-1] == pytest.approx(1.3, abs=1e-12)
        assert np.allclose(h["hbm/peak_amplitude"][()], g["hbm/peak_amplitude"][()],
                           rtol=1e-7)


def test_scene_checks_name_the_key(tmp_path):
    with pytest.raises(SceneError, match="analysis.hbm.response_dof"):
        load_scene(MODELS / "chain2_jenkins.toml", ["analysis.hbm.response_dof=5"])
    with pytest.raises(SceneError, match="analysis.hbm.n_samples"):
        load_scene(MODELS / "chain2_jenkins.toml", ["analysis.hbm.n_samples=8"])
    with pytest.raises(SceneError, match="analysis.hbm.min_periods"):
        load_scene(MODELS / "chain2_jenkins.toml", ["analysis.hbm.min_periods=9",
                                                    "analysis.hbm.max_periods=3"])


def test_harmonic_amplitude():
    b = HarmonicBasis((0, 1, 2), 8)
    X = np.array([[1.0], [3.0], [4.0], [0.0], [0.0]])
    assert harmonic_amplitude(b, X, 1)[0] == 5.0
    assert harmonic_amplitude(b, X, 0)[0] == 1.0


def test_a_workers_failed_truncations_reach_the_parent(tmp_path, monkeypatch):
    """A branch computed on a worker returns its preconditioner cache's failed
    truncations (PreconditionerCache.failed_truncations) with its result: the parent,
    which refines the peak, starts from them."""
    import jointsim.analyses.hbm as ah
    run_branch, finish = ah._run_branch, ah._Output.finish_branch
    seen = []

    def marked(job, **kw):
        kw["system"].preconditioner.failed_truncations = 5 + job.ib
        return run_branch(job, **kw)

    def recorded(self, ib, *args):
        out = finish(self, ib, *args)
        seen.append(self.system.preconditioner.failed_truncations)
        return out
    monkeypatch.setattr(ah, "_run_branch", marked)
    monkeypatch.setattr(ah._Output, "finish_branch", recorded)
    base = ["analysis.hbm.force_scale=[0.05, 0.2]", "analysis.hbm.harmonics=[0, 1, 3]",
            "analysis.hbm.n_samples=32", "analysis.hbm.workers=2"]
    run_scene(load_scene(MODELS / "chain2_jenkins.toml", base), tmp_path / "p.h5")
    assert len(seen) == 2 and min(seen) >= 5 and max(seen) == 6   # the largest so far


def test_parallel_branches_equal_serial_and_resume(tmp_path, monkeypatch):
    """Branches on two worker processes give the serial branches point for point
    (rows interleave; /hbm/branch tells them apart); an interrupted parallel run
    leaves a valid file that --resume completes."""
    base = ["analysis.hbm.force_scale=[0.05, 0.2]", "analysis.hbm.harmonics=[0, 1, 3]",
            "analysis.hbm.n_samples=32"]
    serial = run_scene(load_scene(MODELS / "chain2_jenkins.toml",
                                  base + ["analysis.hbm.workers=1"]), tmp_path / "s.h5")
    sc = load_scene(MODELS / "chain2_jenkins.toml", base + ["analysis.hbm.workers=2"])
    par = run_scene(sc, tmp_path / "p.h5")
    with h5py.File(serial) as s, h5py.File(par) as p:
        assert p["hbm"].attrs["workers"] == 2
        for b in (0, 1):
            ms, mp_ = s["hbm/branch"][()] == b, p["hbm/branch"][()] == b
            np.testing.assert_allclose(p["hbm/omega"][()][mp_], s["hbm/omega"][()][ms],
                                       rtol=1e-12)
            np.testing.assert_allclose(p["hbm/X"][()][mp_], s["hbm/X"][()][ms], rtol=1e-9,
                                       atol=1e-12)
        np.testing.assert_allclose(p["hbm/peak_amplitude"][()], s["hbm/peak_amplitude"][()],
                                   rtol=1e-10)
        assert p["loops/u"].shape == s["loops/u"].shape
    part = tmp_path / "part.h5"
    run_interrupted_after(sc, part, 12, monkeypatch)
    with h5py.File(part) as h:
        assert h.attrs["status"] == "interrupted" and h["hbm/omega"].shape[0] == 12
    run_scene(sc, part, resume=True)
    with h5py.File(part) as h, h5py.File(serial) as s:
        assert h.attrs["status"] == "complete"
        for b in (0, 1):
            assert h["hbm"].attrs[f"branch{b}_status"] == "complete"
            om = h["hbm/omega"][()][h["hbm/branch"][()] == b]
            assert om[-1] == pytest.approx(1.3, abs=1e-12)
        np.testing.assert_allclose(h["hbm/peak_amplitude"][()], s["hbm/peak_amplitude"][()],
                                   rtol=1e-7)


def test_refine_peak_of_a_slipping_branch_is_a_solved_maximum(tmp_path, monkeypatch):
    """The refined peak of the slipping chain branch (F = 0.2) is a harmonic-balance
    solution (Newton from the static state at the refined frequency gives the same
    amplitude) and a maximum (solves 1e-4 either side are lower); its solves start
    from the solved neighbours (few Newton iterations each); when the first start at
    every new frequency fails, the next start gives the same peak; when every start
    fails, the largest computed point comes back unrefined."""
    import dataclasses

    import jointsim.solvers.frc as frc
    out = tmp_path / "chain.h5"
    sc = load_scene(MODELS / "chain2_jenkins.toml", ["analysis.hbm.force_scale=[0.2]"])
    run_scene(sc, out)
    with h5py.File(out) as h:
        om, amp, X = h["hbm/omega"][()], h["hbm/amplitude"][()], h["hbm/X"][()]
        dof = int(h["hbm"].attrs["response_dof"])
        filed = h["hbm/peak_omega"][0], h["hbm/peak_amplitude"][0]
    hb = sc.analysis.hbm
    s = HBMSystem(build_model(sc), hb.harmonics, hb.n_samples)
    F = s.force_coefficients(0.2)
    Z = np.array([s.contact_coordinates(x) for x in X])
    w, a, ok, st = frc.refine_peak(s, F, om, Z, amp, dof, 1e-10)
    assert ok and st["failed"] == 0
    assert (w, a) == pytest.approx(filed, rel=1e-12)      # what the run wrote
    assert a > amp.max()
    assert st["iterations"] <= 2 * st["solves"]             # warm starts
    fund = [float(harmonic_amplitude(s.basis, solve_point(s, v, F, tol=1e-12).X[:, dof]))
            for v in (w, w * (1 - 1e-4), w * (1 + 1e-4))]
    assert fund[0] == pytest.approx(a, rel=1e-9)
    assert max(fund[1:]) < a

    # the peak is a kink (a slip onset between AFT samples): Brent approaches it by
    # golden sections, and 1e-10 of the frequency takes its 25 iterations; the default
    # tolerance gives the same maximum to about itself, in fewer solves
    with monkeypatch.context() as mp:
        mp.setattr(frc, "PEAK_XTOL", 1e-10)
        wt, at, okt, stt = frc.refine_peak(s, F, om, Z, amp, dof, 1e-10)
    assert okt and stt["solves"] == 28
    assert a == pytest.approx(at, rel=1e-7) and w == pytest.approx(wt, rel=1e-6)
    assert st["solves"] < stt["solves"]

    real, branch = frc.solve_point, {float(v) for v in om}

    def failing(first_only):
        """solve_point that fails at every new frequency (the branch's points solve
        from themselves): its first start only, or every start."""
        tried = set()

        def solve(system, omega, F, z0=None, **kw):
            sol = real(system, omega, F, z0=z0, **kw)
            w = float(omega)
            if w in branch or (first_only and w in tried):
                return sol
            tried.add(w)
            return dataclasses.replace(sol, convergence=dataclasses.replace(
                sol.convergence, success=False))
        return solve, tried

    solve, tried = failing(first_only=True)
    monkeypatch.setattr(frc, "solve_point", solve)
    w2, a2, ok2, st2 = frc.refine_peak(s, F, om, Z, amp, dof, 1e-10)
    assert ok2 and st2["failed"] == 0 and st2["solves"] >= 2 * len(tried)
    # the same maximum to the search's tolerance (other starts, other round-off)
    assert (w2, a2) == pytest.approx((w, a), rel=frc.PEAK_XTOL)

    # a largest computed point at the peak to round-off is confirmed (refined, that
    # point returned); one clearly above what the search finds is not
    monkeypatch.setattr(frc, "solve_point", real)
    i = int(np.argmax(amp))
    for bump, refined in ((1e-12, True), (1e-6, False)):
        high = amp.copy()
        high[i] = a * (1 + bump)
        w4, a4, ok4, _ = frc.refine_peak(s, F, om, Z, high, dof, 1e-10)
        assert ok4 == refined and (w4, a4) == (om[i], high[i])

    # every start fails at every new frequency: the largest point, unrefined (a
    # failed frequency is never reported as the peak)
    monkeypatch.setattr(frc, "solve_point", failing(first_only=False)[0])
    w3, a3, ok3, st3 = frc.refine_peak(s, F, om, Z, amp, dof, 1e-10)
    i = int(np.argmax(amp))
    assert not ok3 and st3["failed"] > 0 and (w3, a3) == (om[i], amp[i])
