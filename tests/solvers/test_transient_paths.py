"""The three ways of marching give the same trajectory: the fused numba kernel, the
Python stepper with dense matrices, and the Python stepper with sparse matrices;
and the hand-over between the fused kernel and the Python stepper is seamless."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from jointsim.model import build_model
from jointsim.solvers import generalized_alpha as GA
from jointsim.solvers import _transient_kernels as TK
from jointsim.loads import LoadFunction
from jointsim.solvers.generalized_alpha import GeneralizedAlpha
from jointsim.solvers.static import static_start

from .._transient_scenes import lumped, separating, sdof_jenkins, two_dof_jenkins


def _iwan():
    sc = two_dof_jenkins(1.2, F=0.3)
    return dataclasses.replace(sc, joint=dataclasses.replace(sc.joint, law="iwan4",
                                                              n_sliders=10))


SCENES = {
    "jenkins": lambda: sdof_jenkins({"omega": 1.0}, F=0.5),
    "iwan": _iwan,
    "separating": lambda: separating({"omega": 0.8}, tangential=2.0),
    "bilateral": lambda: dataclasses.replace(
        separating({"omega": 0.8}),
        effects=dataclasses.replace(separating({"omega": 0.8}).effects, separation=False)),
    "stuck_law": lambda: dataclasses.replace(
        sdof_jenkins({"omega": 1.0}), joint=dataclasses.replace(
            sdof_jenkins({"omega": 1.0}).joint, law="stuck")),
    "linear": lambda: lumped([[1.0, 0.0], [0.0, 2.0]], [[3.0, -1.0], [-1.0, 2.0]],
                             [[0.1, 0.0], [0.0, 0.05]],
                             loads=[{"dof": 1, "force": {"constant": 0.2, "harmonics": [
                                 {"h": 1, "cos": 1.0}, {"h": 2, "sin": 0.3}]}}],
                             transient={"omega": 1.1}),
}


def _march_block(sc, fused, n_steps=300, steps_per_period=64):
    model = build_model(sc)
    w = sc.analysis.transient.omega
    force = LoadFunction(model, w)
    st = static_start(model)
    ga = GeneralizedAlpha(model, force, rho_inf=0.85, fused=fused)
    s = ga.start(0.0, st.x, np.zeros(model.n_dof), st.contact.state)
    t = np.arange(n_steps + 1) * (2 * np.pi / w / steps_per_period)
    return ga, ga.march_block(s, t)


@pytest.mark.parametrize("name", list(SCENES))
def test_fused_kernel_matches_python_stepper(name):
    sc = SCENES[name]()
    ga_f, (sf, xf, vf, uf, ff, Nf) = _march_block(sc, fused=True)
    ga_p, (sp_, xp, vp, up, fp, Np) = _march_block(sc, fused=False)
    assert ga_f.fused and not ga_p.fused
    scale = np.abs(xp).max()
    assert np.abs(xf - xp).max() <= 1e-9 * scale
    assert np.abs(vf - vp).max() <= 1e-9 * np.abs(vp).max()
    if ga_p.cmap.n_e:
        assert np.abs(ff - fp).max() <= 1e-9 * max(np.abs(fp).max(), 1e-300)
        assert np.array_equal(Nf == 0.0, Np == 0.0) or name != "separating"
        assert np.allclose(sf.contact.state, sp_.contact.state, rtol=1e-9, atol=1e-12)
    if name == "separating":
        assert (Nf == 0.0).any() and np.all(ff[Nf == 0.0] == 0.0)


def test_sparse_path_matches_dense(monkeypatch):
    sc = SCENES["separating"]()
    _, (_, xd, *_rest) = _march_block(sc, fused=False, n_steps=150)
    monkeypatch.setattr(GA, "DENSE_MAX_DOF", 0)
    ga, (_, xs, *_rest2) = _march_block(sc, fused=True, n_steps=150)
    assert not ga.dense and not ga.fused
    assert np.abs(xs - xd).max() <= 1e-9 * np.abs(xd).max()


def test_handover_from_fused_kernel_to_stepper(monkeypatch):
    """The kernel stops where its Newton solve fails; the Python stepper redoes that
    step (cutting it if needed) and the kernel resumes: same result as no failure."""
    sc = SCENES["iwan"]()
    _, (s_ref, x_ref, *_r) = _march_block(sc, fused=True, n_steps=200)
    real = TK.march_dense
    calls = {"n": 0}

    def stops_early_consistent(times, h, *args):
        # the first three calls report a failure at step 8 (with the arrays and
        # the state after step 7, as the kernel does)
        calls["n"] += 1
        if calls["n"] <= 3 and times.size > 8:
            out = real(times[:8], h, *args)
            n_full = times.size
            X, V, A, PHI = (np.vstack([o, np.zeros((n_full - 8,) + o.shape[1:])])
                            for o in out[2:6])
            U, F, NN = (np.hstack([o, np.zeros((o.shape[0], n_full - 8))])
                        for o in out[6:9])
            return (7, out[1], X, V, A, PHI, U, F, NN, out[9])
        return real(times, h, *args)

    monkeypatch.setattr(TK, "march_dense", stops_early_consistent)
    ga, (s, x, *_r2) = _march_block(sc, fused=True, n_steps=200)
    assert calls["n"] >= 4
    assert np.abs(x - x_ref).max() <= 1e-10 * np.abs(x_ref).max()
    assert np.allclose(s.contact.state, s_ref.contact.state, rtol=1e-10, atol=1e-14)
