"""Time marching (issue 5): integrator accuracy, consistent tangent, steady states,
energy balance, separation, free decay, step cutting and the result file."""
from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest

from jointsim.model import build_model
from jointsim.results import STEP_TOO_SMALL
from jointsim.scene import SceneError
from jointsim.solvers import generalized_alpha as GA
from jointsim.harmonics import dft_matrix
from jointsim.loads import LoadFunction
from jointsim.solvers.generalized_alpha import GeneralizedAlpha
from jointsim.solvers.periodic import ExtremumTracker, decay_estimates
from jointsim.solvers.static import static_start
from jointsim.solvers.transient import free_decay, march_steady, rigid_modes

from .._transient_scenes import (jenkins_backbone, jenkins_dissipation, lumped, separating,
                                sdof_jenkins, two_dof_jenkins)


# --------------------------------------------------------------------------
# integrator
# --------------------------------------------------------------------------
@pytest.mark.parametrize("rho", [1.0, 0.6, 0.0])
def test_order_two_on_linear_oscillator(rho):
    """Forced, damped linear oscillator from rest: error at t = 6 vs the exact
    solution, fitted log-log slope 2."""
    m, c, k, F, w = 1.0, 0.2, 4.0, 1.0, 1.3
    sc = lumped([[m]], [[k]], [[c]],
                loads=[{"dof": 0, "force": {"harmonics": [{"h": 1, "cos": F}]}}])
    model = build_model(sc)
    force = LoadFunction(model, w)
    # exact: particular X cos + Y sin plus the homogeneous part matching x0 = v0 = 0
    Z = complex(k - m * w * w, c * w)
    Xp = F / Z                                        # x_p = Re(Xp e^{iwt})
    wn, zeta = np.sqrt(k / m), c / (2.0 * np.sqrt(k * m))
    wd = wn * np.sqrt(1.0 - zeta ** 2)
    x0p, v0p = Xp.real, -w * Xp.imag
    A = -x0p
    B = (-v0p + zeta * wn * A) / wd
    t_end = 6.0

    def exact(t):
        return ((Xp * np.exp(1j * w * t)).real
                + np.exp(-zeta * wn * t) * (A * np.cos(wd * t) + B * np.sin(wd * t)))

    hs, errs = [], []
    for n in (320, 640, 1280, 2560):
        ga = GeneralizedAlpha(model, force, rho_inf=rho)
        s = ga.start(0.0, np.zeros(1), np.zeros(1), np.zeros((0, 0)))
        for s in ga.march(s, np.linspace(0.0, t_end, n + 1)[1:]):
            pass
        hs.append(t_end / n)
        errs.append(abs(s.x[0] - exact(t_end)))
    slope = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert 1.9 < slope < 2.1, (slope, errs)


def test_alpha_parameters_match_chung_hulbert():
    am, af, g, b = GA.alpha_parameters(1.0)
    assert (am, af, g, b) == (0.5, 0.5, 0.5, 0.25)
    am, af, g, b = GA.alpha_parameters(0.0)
    assert np.allclose((am, af, g, b), (-1.0, 0.0, 1.5, 1.0))


def _marched(sc, n_steps, h, rho=0.8):
    model = build_model(sc)
    tr = sc.analysis.transient
    force = LoadFunction(model, tr.omega)
    st = static_start(model)
    ga = GeneralizedAlpha(model, force, rho_inf=rho)
    s = ga.start(0.0, st.x, np.zeros(model.n_dof), st.contact.state)
    for s in ga.march(s, h * np.arange(1, n_steps + 1)):
        pass
    return ga, s


def _fd_jacobian(fun, x, eps):
    J = np.empty((fun(x).size, x.size))
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = eps
        J[:, i] = (fun(x + e) - fun(x - e)) / (2.0 * eps)
    return J


def _regime(ga, s, x1, d=1e-5):
    """Tangents at x1 and at x1 +- d along every DOF; None if they differ (a kink
    is near), else the tangent blocks and the normal load at x1."""
    found = None
    for k in range(-1, x1.size):
        x = x1.copy()
        if k >= 0:
            x[k] += d
        for sgn in ((1.0,) if k < 0 else (1.0, -1.0)):
            xx = x1 + sgn * (x - x1)
            ev = ga.cmap.evaluate(ga.cmap.B @ xx, s.contact.state)
            key = (tuple(ev.duu), tuple(ev.dug != 0.0), tuple(ev.N > 0.0))
            if found is None:
                found = key
            elif key != found:
                return None
    return found


def _state_in_regime(sc, h, want, n_max=2000):
    """March until the next step's trial point lies well inside the wanted regime."""
    model = build_model(sc)
    tr = sc.analysis.transient
    force = LoadFunction(model, tr.omega)
    st = static_start(model)
    ga = GeneralizedAlpha(model, force, rho_inf=0.8)
    s = ga.start(0.0, st.x, np.zeros(model.n_dof), st.contact.state)
    rng = np.random.default_rng(3)
    for _ in range(n_max):
        s = ga.step(s, s.t + h)
        x1 = s.x + h * s.v + 0.5 * h * h * s.a + 1e-4 * rng.standard_normal(model.n_dof)
        reg = _regime(ga, s, x1)
        if reg is not None and want(reg, ga):
            return ga, s, x1
    raise AssertionError("regime not reached")


CASES = {
    # stuck Jenkins: tangent kt
    "jenkins_stuck": (lambda: sdof_jenkins({"omega": 1.0}, F=0.5),
                      lambda reg, ga: reg[0][0] == 0.25),
    # slipping Jenkins: zero tangent in u
    "jenkins_slip": (lambda: sdof_jenkins({"omega": 1.0}, F=0.5),
                     lambda reg, ga: reg[0][0] == 0.0),
    # Iwan with some sliders stuck and some slipping
    "iwan_partial": (lambda: dataclasses.replace(
        two_dof_jenkins(1.2, F=0.3, transient={}),
        joint=dataclasses.replace(two_dof_jenkins(1.2).joint, law="iwan4", n_sliders=8)),
        lambda reg, ga: 0.0 < reg[0][0] < 0.25 - 1e-12),
    # scaled reversal law, stuck after a reversal: the tangent carries the history
    "scaled_stuck": (lambda: sdof_jenkins({"omega": 1.0}, F=0.5, reversal="scaled"),
                     lambda reg, ga: reg[0][0] == 0.25),
    # coupled normal load, in contact and slipping: df/dg = mu dN/dg != 0
    "coupled_slip": (lambda: separating({"omega": 0.8}, tangential=3.0),
                     lambda reg, ga: reg[2][0] and reg[0][0] == 0.0 and reg[1][0]),
    # coupled normal load, in contact and stuck
    "coupled_stuck": (lambda: separating({"omega": 0.8}),
                      lambda reg, ga: reg[2][0] and reg[0][0] == 2.0),
}


@pytest.mark.parametrize("case", list(CASES))
def test_step_tangent_matches_finite_differences(case):
    """The consistent tangent of one step (full and condensed) vs central differences,
    with the history fixed at the start of the step."""
    make, want = CASES[case]
    h = 2 * np.pi / 64
    ga, s, x1 = _state_in_regime(make(), h, want)
    J = ga.tangent(s, h, x1)
    Jfd = _fd_jacobian(lambda x: ga.residual(s, h, x), x1, 1e-7)
    assert np.allclose(J, Jfd, rtol=1e-6, atol=1e-7 * np.abs(J).max())
    y1 = ga.cmap.B @ x1
    r, Jc = ga.condensed_residual(s, h, y1)
    Jcfd = _fd_jacobian(lambda y: ga.condensed_residual(s, h, y)[0], y1, 1e-7)
    assert np.allclose(Jc, Jcfd, rtol=1e-6, atol=1e-7 * np.abs(Jc).max())
    if case != "jenkins_slip":  # the contact part of the tangent is exercised
        assert np.abs(J - np.asarray(ga._factor(ga.snap(h)).S)).max() > 1e-3


def test_converged_step_satisfies_the_balance():
    sc = separating({"omega": 0.8})
    h = 2 * np.pi / 128
    ga, s = _marched(sc, 50, h)
    s1 = ga.step(s, s.t + h)
    R = ga.residual(s, h, s1.x)
    scale = np.abs(ga.M @ s1.a).max() + np.abs(ga.K @ s1.x).max()
    assert np.abs(R).max() < 1e-9 * scale
    # the state is committed: stepping again from s gives the same result
    s1b = ga.step(s, s.t + h)
    assert np.array_equal(s1.x, s1b.x)


def test_failed_step_is_cut_into_halves(monkeypatch):
    """A step whose Newton solve fails is replaced by two half steps."""
    sc = sdof_jenkins({"omega": 1.0}, F=0.5)
    h = 2 * np.pi / 64
    ga, s = _marched(sc, 20, h)
    ref = GeneralizedAlpha(ga.model, ga.force, rho_inf=0.8)
    half = ref.step(ref.step(s, s.t + h / 2), s.t + h)
    real = GA.condensed_newton
    big = ga.snap(h)

    def flaky(cmap, G, *args, **kw):
        if np.allclose(G, ga._factor(big).G):   # fail at the full step size only
            raise GA.NewtonFailure("injected")
        return real(cmap, G, *args, **kw)

    monkeypatch.setattr(GA, "condensed_newton", flaky)
    out = ga.step(s, s.t + h)
    assert ga.stats.cuts == 1 and ga.stats.deepest_cut == 1
    assert np.allclose(out.x, half.x, rtol=1e-12, atol=1e-14)
    ga.max_cuts = 0
    with pytest.raises(GA.StepFailure, match="injected"):
        ga.step(s, s.t + h)


def test_step_failure_is_reported_and_keeps_results(monkeypatch):
    sc = sdof_jenkins({"omega": 1.0, "steps_per_period": 32, "max_cuts": 2,
                       "max_periods": 10})
    model = build_model(sc)
    real = GA.condensed_newton
    calls = {"n": 0}

    def flaky(*args, **kw):
        calls["n"] += 1
        if calls["n"] > 100:   # about three periods in, every solve fails
            raise GA.NewtonFailure("injected")
        return real(*args, **kw)

    monkeypatch.setattr(GA, "condensed_newton", flaky)
    res = march_steady(model, sc.analysis.transient, progress=False, fused=False)
    assert not res.convergence.success
    assert res.convergence.status == STEP_TOO_SMALL
    assert "injected" in res.convergence.message
    assert res.last is not None and np.all(np.isfinite(res.X))  # kept what it had


# --------------------------------------------------------------------------
# steady states
# --------------------------------------------------------------------------
def test_linear_steady_state_matches_frf():
    w = 1.3
    sc = lumped([[1.0, 0.0], [0.0, 2.0]], [[3.0, -1.0], [-1.0, 2.0]],
                [[0.1, 0.0], [0.0, 0.05]],
                loads=[{"dof": 0, "force": {"constant": 0.5,
                                            "harmonics": [{"h": 1, "cos": 1.0, "sin": 0.3},
                                                          {"h": 3, "cos": 0.2}]}}],
                transient={"omega": w, "steady_tol": 1e-9, "harmonics": [0, 1, 2, 3]})
    model = build_model(sc)
    res = march_steady(model, sc.analysis.transient, progress=False)
    assert res.convergence.success
    M, K, C = (m.toarray() for m in (model.M, model.K, model.C))
    X = res.X
    assert np.allclose(X[0], np.linalg.solve(K, [0.5, 0.0]), rtol=1e-8)
    for h, (fc, fs), rows in ((1, (1.0, 0.3), (1, 2)), (3, (0.2, 0.0), (5, 6))):
        Z = K - (h * w) ** 2 * M + 1j * h * w * C
        Xc = np.linalg.solve(Z, np.array([fc - 1j * fs, 0.0]))   # x = Re(Xc e^{i h w t})
        got = X[rows[0]] - 1j * X[rows[1]]
        # discretisation error O((h w dt)^2) with 256 steps per period
        assert np.abs(got - Xc).max() < 2e-3 * np.abs(Xc).max()
    assert np.abs(X[3:5]).max() < 1e-8   # harmonic 2 is not forced


@pytest.mark.parametrize("rho,tol", [(1.0, 1e-8), (0.9, 1e-3)])
def test_energy_balance_of_forced_steady_state(rho, tol):
    """Input work = viscous + friction dissipation over a steady period; the friction
    part equals the Jenkins loop area 4 Fs (A - Fs/kt) of the marched slip."""
    sc = sdof_jenkins({"omega": 0.9, "rho_inf": rho, "steady_tol": 1e-8}, C=0.1, F=0.5)
    model = build_model(sc)
    res = march_steady(model, sc.analysis.transient, progress=False)
    assert res.convergence.success
    e = res.energy
    assert abs(e.input - e.viscous - e.friction) <= tol * e.input
    u = res.last.u[0]
    A = 0.5 * np.ptp(u)
    assert e.friction == pytest.approx(jenkins_dissipation(A), rel=1e-3)
    assert e.friction > 0.3 * e.input  # the friction part matters


def test_separation_marches_stably_with_zero_force_while_open():
    sc = separating({"omega": 0.8, "steady_tol": 1e-7, "steps_per_period": 128})
    model = build_model(sc)
    res = march_steady(model, sc.analysis.transient, progress=False)
    assert res.convergence.success, res.convergence.message
    p = res.last
    assert np.all(np.isfinite(p.x)) and np.all(np.isfinite(p.f))
    open_ = p.N[0] == 0.0
    assert 0.1 < open_.mean() < 0.9           # separated for part of the period
    assert np.all(p.f[0][open_] == 0.0)       # exactly zero force while separated
    assert p.N.max() > 0.0 and np.abs(p.f).max() > 0.0
    assert res.energy.relative < 1e-3


def test_transient_and_dft_agree_with_known_signal():
    n, w = 64, 2.5
    t = 3 * (2 * np.pi / w) + np.arange(n) * (2 * np.pi / w) / n
    x = 0.3 + 1.2 * np.cos(w * t) - 0.4 * np.sin(w * t) + 0.1 * np.sin(3 * w * t)
    X = dft_matrix((0, 1, 2, 3), n, w, t[0]) @ x
    assert np.allclose(X, [0.3, 1.2, -0.4, 0, 0, 0, 0.1], atol=1e-13)


# --------------------------------------------------------------------------
# free decay
# --------------------------------------------------------------------------
def test_decay_estimates_are_exact_for_linear_damped_oscillation():
    wn, zeta, off = 3.0, 0.02, 0.7
    wd = wn * np.sqrt(1 - zeta ** 2)
    t = np.linspace(0.0, 30.0, 20001)
    q = off + np.exp(-zeta * wn * t) * np.cos(wd * t + 0.4)
    dq = np.exp(-zeta * wn * t) * (-zeta * wn * np.cos(wd * t + 0.4)
                                   - wd * np.sin(wd * t + 0.4))
    tr = ExtremumTracker()
    for a, b, c in zip(t, q, dq):
        tr.add(a, b, c)
    kinds = np.array(tr.kind)
    assert np.all(kinds[1:] != kinds[:-1])
    tc, amp, f, z = decay_estimates(tr.t, tr.q)
    assert tc.size > 10
    assert np.allclose(f, wd / (2 * np.pi), rtol=1e-7)
    assert np.allclose(z, zeta, rtol=1e-6)
    # the half swing decays like the envelope
    assert np.allclose(amp[1:] / amp[:-1], np.exp(-zeta * wn * np.pi / wd), rtol=1e-6)


def test_free_decay_of_sdof_jenkins_follows_backbone():
    """m = k = 1, kt = 0.25, Fs = 0.2: frequency within 1% of the first-harmonic
    backbone (EPMC with H = {0, 1}) over the whole ring-down."""
    sc = lumped([[1.0]], [[1.0]], contacts=[{"t_dof": 0, "N0": 1.0}],
                joint={"law": "jenkins", "kt": 0.25, "mu": 0.2},
                transient={"amplitude": 6.0, "max_periods": 14, "steps_per_period": 96})
    model = build_model(sc)
    res = free_decay(model, sc.analysis.transient, progress=False)
    assert res.convergence.success, res.convergence.message
    assert res.omega_linear == pytest.approx(np.sqrt(1.25))
    assert res.amplitude.max() > 5.0 and res.amplitude.min() < 0.9  # slip to stick
    fb, zb = jenkins_backbone(res.amplitude)
    assert np.abs(res.frequency_hz / fb - 1.0).max() < 1e-2
    # damping from the decrement: within 15% of the first-harmonic value while
    # the element slips well (the decay per cycle biases it, see docs/transient.md)
    big = res.amplitude > 2.0
    assert np.abs(res.damping_ratio[big] / zb[big] - 1.0).max() < 0.15


# --------------------------------------------------------------------------
# scene keys and the result file
# --------------------------------------------------------------------------
def test_scene_checks_name_the_key():
    with pytest.raises(SceneError, match="analysis.transient.amplitude"):
        sdof_jenkins({"omega": 0.0})
    with pytest.raises(SceneError, match=r"analysis.transient.output_dofs\[0\]"):
        sdof_jenkins({"omega": 1.0, "output_dofs": [3]})
    with pytest.raises(SceneError, match="analysis.transient.steps_per_period"):
        sdof_jenkins({"omega": 1.0, "steps_per_period": 12, "harmonics": [0, 1, 7]})
    with pytest.raises(SceneError, match="analysis.transient.omega"):
        lumped([[1.0]], [[1.0]], transient={"omega": 1.0})


def _all_datasets(h5):
    out = []
    h5.visititems(lambda n, o: out.append((n, o)) if isinstance(o, h5py.Dataset) else None)
    return out


def test_run_scene_writes_steady_results(tmp_path):
    from jointsim.run import run_scene
    sc = sdof_jenkins({"omega": 1.0, "steady_tol": 1e-5, "steps_per_period": 64,
                       "decimate": 4, "harmonics": [0, 1, 3]}, C=0.1, law="iwan4")
    out = run_scene(sc, tmp_path / "r.h5")
    with h5py.File(out) as h5:
        assert h5.attrs["status"] == "complete"
        for name, ds in _all_datasets(h5):
            assert "unit" in ds.attrs, name
        g = h5["transient"]
        assert g.attrs["success"] and g.attrs["kind"] == "steady"
        assert h5["transient/harmonics"].shape == (5, 1)
        assert list(h5["transient/harmonic_numbers"][()]) == [0, 1, 3]
        nper = g.attrs["iterations"]
        assert h5["transient/t"].shape[0] == (nper * 64) // 4 + 1
        assert h5["transient/period_change"].shape == (nper,)
        # constant N: an Iwan element's loop is on its Masing curve exactly
        assert h5["loops/u"].shape == (1, 1, 64)
        assert h5["masing/dev_masing"][0, 0] < 1e-9
        assert g.attrs["energy_relative"] < 1e-3
    from jointsim.post import make_figures
    from jointsim.post.tables import info_text
    figs = sorted(p.name for p in make_figures(out, tmp_path / "figs"))
    assert figs == ["transient_convergence.png", "transient_history.png",
                    "transient_loops.png"]
    text = info_text(out)
    assert "Time marching (steady)" in text and "first-harmonic amplitude" in text


def test_run_scene_writes_free_decay(tmp_path):
    from jointsim.run import run_scene
    sc = lumped([[1.0]], [[1.0]], contacts=[{"t_dof": 0, "N0": 1.0}],
                joint={"law": "jenkins", "kt": 0.25, "mu": 0.2},
                transient={"amplitude": 3.0, "max_periods": 6, "steps_per_period": 64})
    out = run_scene(sc, tmp_path / "d.h5")
    with h5py.File(out) as h5:
        assert h5.attrs["status"] == "complete"
        n = h5["transient/amplitude"].shape[0]
        assert n > 4
        for name in ("frequency_hz", "damping_ratio", "time"):
            assert h5[f"transient/{name}"].shape == (n,)
        for name, ds in _all_datasets(h5):
            assert "unit" in ds.attrs, name
        assert h5["transient"].attrs["kind"] == "free_decay"
    from jointsim.post import make_figures
    from jointsim.post.tables import info_text
    figs = sorted(p.name for p in make_figures(out, tmp_path / "figs"))
    assert figs == ["transient_backbone.png", "transient_history.png"]
    assert "Time marching (free_decay)" in info_text(out)


@pytest.mark.parametrize("frictionless,u_expected,f_expected", [
    (False, 1.0 - 0.5 * 10.0 / 10.5, 0.5 * 10.0 / 10.5),  # the slider slips to mu N
    (True, 1.0, 0.0),                                     # no friction while loading
])
def test_static_start_with_coupled_normal_load(frictionless, u_expected, f_expected):
    """DOF 1 pushed by 1 into a penalty contact (kn = 10, spring 0.5): N = 10/10.5;
    DOF 0 pulled by 1 against a spring of 1 and a Jenkins slider (kt = 2, mu = 0.5).
    Stuck, the slider would carry 2/3 > mu N: the law lets it slip to mu N."""
    sc = lumped([[1.0, 0.0], [0.0, 1.0]], [[1.0, 0.0], [0.0, 0.5]],
                contacts=[{"t_dof": 0, "n_dof": 1, "gap0": 0.0}],
                joint={"law": "jenkins", "kt": 2.0, "mu": 0.5, "kn": 10.0},
                effects={"normal": "coupled"},
                loads=[{"dof": 1, "force": -1.0}, {"dof": 0, "force": 1.0}])
    model = build_model(sc)
    st = static_start(model, frictionless=frictionless)
    N = 10.0 / 10.5
    assert st.x[1] == pytest.approx(-1.0 / 10.5, rel=1e-10)
    assert st.contact.N[0] == pytest.approx(N, rel=1e-10)
    assert st.x[0] == pytest.approx(u_expected, rel=1e-10)
    assert st.contact.f[0] == pytest.approx(f_expected, rel=1e-10, abs=1e-14)
    if frictionless:  # the slider rests, unloaded, at the preloaded slip
        assert st.contact.state[0, 0] == pytest.approx(1.0, rel=1e-10)
    else:             # anchored where it stopped slipping: f = kt (u - w) = mu N
        assert 2.0 * (st.x[0] - st.contact.state[0, 0]) == pytest.approx(0.5 * N, rel=1e-10)


def test_static_start_below_the_slip_limit_is_the_stuck_linearisation():
    """A small pull keeps the slider stuck: the start is the stuck static state of
    every solver, 1 = x0 + kt x0 -> x0 = 1/3 with a force kt x0 = 2/3 < mu N."""
    sc = lumped([[1.0]], [[1.0]], contacts=[{"t_dof": 0, "N0": 10.0}],
                joint={"law": "jenkins", "kt": 2.0, "mu": 0.5},
                loads=[{"dof": 0, "force": 1.0}])
    model = build_model(sc)
    st = static_start(model)
    assert st.x[0] == pytest.approx(1.0 / 3.0, rel=1e-12)
    assert np.array_equal(st.x, model.linearisation.x0)
    assert st.contact.f[0] == pytest.approx(2.0 / 3.0, rel=1e-12)


def test_static_start_resolves_an_initial_interference():
    """gap0 = -0.1 and no load: the penalty force N = 10 (0.1 - x1) balances 0.5 x1."""
    sc = lumped([[1.0, 0.0], [0.0, 1.0]], [[1.0, 0.0], [0.0, 0.5]],
                contacts=[{"t_dof": 0, "n_dof": 1, "gap0": -0.1}],
                joint={"law": "jenkins", "kt": 2.0, "mu": 0.5, "kn": 10.0},
                effects={"normal": "coupled"})
    model = build_model(sc)
    st = static_start(model)
    # 0.5 x1 - N = 0 with N = 10 (0.1 - x1)  ->  x1 = 1 / 10.5
    assert st.x[1] == pytest.approx(1.0 / 10.5, rel=1e-12)
    assert st.contact.N[0] == pytest.approx(0.5 / 10.5, rel=1e-12)
    assert st.x[0] == 0.0


def test_static_start_from_the_model_preload_state():
    """A model that carries its preload state (``model.preload``, as FE models do)
    starts from it when it is an equilibrium: no Newton iteration."""
    import dataclasses

    import scipy.sparse as sp

    from jointsim.model import Preload
    sc = separating({"omega": 0.8})
    a = static_start(build_model(sc))
    model = build_model(sc)
    n = model.n_dof
    model = dataclasses.replace(model, linearisation=None, preload=Preload(
        x0=a.x.copy(), result=None, f_clamp=np.zeros(n), K_bolt=sp.csr_matrix((n, n)),
        time_s=0.0))
    b = static_start(model)
    assert b.source == "model" and b.iterations == 0
    assert np.allclose(b.x, a.x, rtol=1e-12, atol=1e-15)


def test_steady_change_leaves_out_the_rigid_body_modes():
    """A free mass on a slider pair: the rigid-body mode (a drift of the whole
    structure) does not count in the period-to-period change, the elastic motion
    does."""
    sc = lumped([[1.0, 0.0], [0.0, 1.0]], [[1.0, -1.0], [-1.0, 1.0]], [[0.1, 0.0], [0.0, 0.1]],
                loads=[{"dof": 0, "force": {"harmonics": [{"h": 1, "cos": 1.0}]}}],
                transient={"omega": 2.0})
    model = build_model(sc)
    rig = rigid_modes(model)
    assert rig.n == 1 and np.allclose(np.abs(rig.shapes[0]), np.sqrt(0.5))
    x = np.array([[1.0, 1.0], [0.3, -0.3]])
    assert np.allclose(rig.elastic(x), [[0.0, 0.0], [0.3, -0.3]])
    cut = rigid_modes(model, cutoff_hz=0.0)   # an explicit cutoff of 0: nothing left out
    assert cut.n == 0 and np.array_equal(cut.elastic(x), x)


def _bouncing(rho, fused, correct=True, n=3000):
    """A mass bouncing on a penalty contact 1000x stiffer than its spring, with steps
    ten times longer than the contact lasts.  Returns the energy history."""
    kn, gap0 = 1.0e6, 0.3
    sc = lumped([[1.0, 0.0], [0.0, 1.0]], [[1.0, 0.0], [0.0, 0.01]],
                contacts=[{"t_dof": 0, "n_dof": 1, "gap0": gap0}],
                joint={"kn": kn}, effects={"normal": "coupled", "friction": False})
    model = build_model(sc)
    ga = GeneralizedAlpha(model, LoadFunction(model, 0.0), rho_inf=rho, fused=fused)
    ga.cmap.unilateral = correct
    s = ga.start(0.0, np.zeros(2), np.array([0.0, -1.0]), np.zeros((1, 0)))
    h = 0.07   # the contact lasts pi / 1000 = 0.003
    _, x, v, _u, _f, N = ga.march_block(s, h * np.arange(n))
    assert (N > 0).any() and (N == 0).any()       # it bounces
    return np.array([0.5 * vv @ vv + 0.5 * (xx[0] ** 2 + 0.01 * xx[1] ** 2)
                     + 0.5 * kn * min(gap0 + xx[1], 0.0) ** 2 for xx, vv in zip(x, v)])


@pytest.mark.parametrize("rho", [1.0, 0.9, 0.0])
@pytest.mark.parametrize("fused", [True, False])
def test_unresolved_stiff_impacts_do_not_gain_energy(rho, fused):
    """With the energy-consistent normal force the energy is conserved for
    rho_inf = 1 and only lost for rho_inf < 1."""
    E = _bouncing(rho, fused, n=3000 if fused else 800)
    if rho == 1.0:
        assert np.abs(E / E[0] - 1.0).max() < 1e-8
    else:
        assert E.max() <= E[0] * (1.0 + 1e-6) and E[-1] < 0.5 * E[0]


def test_plain_force_averaging_pumps_energy_into_stiff_impacts():
    """The reason for the correction: without it the same bounces gain energy."""
    E = _bouncing(1.0, fused=False, correct=False, n=1000)
    assert E.max() > 1.5 * E[0]


def test_linear_start_skips_the_transient():
    """Starting on the discrete linear steady response, a linear structure is periodic
    from the first period, where a start from rest waits for the decay."""
    tr = {"omega": 1.3, "steady_tol": 1e-6, "steps_per_period": 256, "max_periods": 3000}
    loads = [{"dof": 0, "force": {"constant": 0.5, "harmonics": [{"h": 1, "cos": 1.0},
                                                                 {"h": 2, "sin": 0.3}]}}]
    M, K, C = [[1.0, 0.0], [0.0, 2.0]], [[3.0, -1.0], [-1.0, 2.0]], [[0.01, 0.0], [0.0, 0.01]]
    rest = march_steady(build_model(lumped(M, K, C, loads=loads, transient=tr)),
                        lumped(M, K, C, loads=loads, transient=tr).analysis.transient,
                        progress=False)
    sc = lumped(M, K, C, loads=loads, transient={**tr, "start": "linear"})
    lin = march_steady(build_model(sc), sc.analysis.transient, progress=False)
    assert rest.convergence.success and lin.convergence.success
    assert lin.convergence.iterations == 3                 # min_periods
    assert lin.period_change[-1] < 1e-12                   # periodic to round-off
    assert np.allclose(lin.X, rest.X, rtol=0, atol=1e-5 * np.abs(rest.X).max())


def test_linear_start_with_a_stuck_joint():
    """Below the slip limit a Jenkins joint is linear (stuck): the linear start is
    its steady state, and the march stays there without slipping."""
    sc = sdof_jenkins({"omega": 0.9, "start": "linear", "steady_tol": 1e-7,
                       "steps_per_period": 128}, C=0.1, F=0.02)
    res = march_steady(build_model(sc), sc.analysis.transient, progress=False)
    assert res.convergence.success and res.convergence.iterations <= 6
    Z = 1.25 - 0.81 + 0.09j                  # stuck: k + kt - w^2 m + i w c
    assert abs(res.X[1, 0] - 1j * res.X[2, 0] - 0.02 / Z) < 2e-3 * abs(0.02 / Z)
    assert np.abs(res.last.f).max() < 0.2    # never at the slip force


def test_rigid_modes_of_the_free_free_lap_joint():
    """The coarse lap joint hangs from soft springs: three suspension modes below
    5 Hz are detected; a rigid translation of the reduced model is (nearly) all
    rigid-body motion, and the first bending mode has none."""
    from pathlib import Path

    from jointsim.scene import load_scene
    from jointsim.solvers.modes import stuck_modes
    root = Path(__file__).resolve().parents[2]
    model = build_model(load_scene(root / "models" / "lap_joint_nodes.toml",
                                   ["model.mesh='../meshes/lap_joint_coarse.msh'"]))
    rig = rigid_modes(model)
    assert rig.n == 3
    modes = stuck_modes(model, 5)
    assert np.all(modes.frequency_hz[~modes.elastic] < 5.0) and (~modes.elastic).sum() == 3
    for axis in (".x", ".y"):
        t = np.array([1.0 if lab.endswith(axis) else 0.0 for lab in model.dof_labels])
        assert np.linalg.norm(rig.elastic(t)) < 1e-3 * np.linalg.norm(t)
    bending = modes.shapes[np.flatnonzero(modes.elastic)[0]]
    assert np.allclose(rig.elastic(bending), bending, rtol=0, atol=1e-12 * np.abs(bending).max())
