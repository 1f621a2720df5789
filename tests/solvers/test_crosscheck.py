"""Cross-check of time marching against harmonic balance: per-harmonic differences
and the DC offset left by the slider history (issue 5)."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from jointsim.analyses.crosscheck import cross_check_file
from jointsim.io.hbm_points import read_hbm_solutions
from jointsim.io.hdf5 import ResultWriter
from jointsim.model import build_model
from jointsim.solvers.crosscheck import (cross_check, explain_dc, hbm_reference, hbm_solution_at,
                                         memory_elements)
from jointsim.solvers.transient import march_steady

from .._transient_scenes import lumped, two_dof_jenkins


def _two_dof(F, C=0.05):
    """The issue-4 2-DOF Jenkins scene with more damping (faster to steady state)."""
    sc = two_dof_jenkins(1.0, F=F, C=C, transient={"steady_tol": 1e-8, "steps_per_period": 64,
                                                   "max_periods": 3000})
    return sc, build_model(sc)


def test_dc_offset_from_slider_history_is_flagged_as_legitimate():
    """A stuck Jenkins element keeps the force its history left: two marches from
    different anchors reach the same harmonics and different DC parts."""
    sc, m = _two_dof(F=0.01)
    tr = sc.analysis.transient
    a = march_steady(m, tr, progress=False)
    state = m.contacts.law.rest_state([1.0])
    state[:] = 0.3  # the anchor displaced by an earlier load
    b = march_steady(m, tr, progress=False, initial=(np.zeros(2), np.zeros(2), state))
    assert a.convergence.success and b.convergence.success
    loops = (b.last.f[:, :-1], b.last.N[:, :-1])
    cc = cross_check(b.X, b.harmonics, a.X, a.harmonics, model=m, loops=loops)
    assert cc.agree and cc.dc_history
    assert cc.dc_diff > 0.1
    assert cc.rel_diff[1:].max() < 1e-6
    assert cc.memory.tolist() == [True]
    # the locked-in force: K d0 = -Tt^T df; here the slider force moved by df
    d0 = b.X[0] - a.X[0]
    df, dN, res = explain_dc(d0, m)
    assert res < 1e-6 and df[0] == pytest.approx(cc.df[0])
    assert df[0] == pytest.approx(b.last.f[0].mean() - a.last.f[0].mean(), rel=1e-6)


def test_real_disagreements_are_flagged():
    sc, m = _two_dof(F=0.3)   # the element slips every period: no memory
    res = march_steady(m, sc.analysis.transient, progress=False)
    assert res.convergence.success
    loops = (res.last.f[:, :-1], res.last.N[:, :-1])
    assert memory_elements(*loops, m.contacts.law).tolist() == [False]
    same = cross_check(res.X, res.harmonics, res.X, res.harmonics, model=m, loops=loops)
    assert same.agree and same.rel_diff.max() == 0.0
    # a DC offset on a slipping element cannot come from its history
    Xb = res.X.copy()
    Xb[0] += 0.05 * np.linalg.norm(res.X[1:3])
    dc = cross_check(res.X, res.harmonics, Xb, res.harmonics, model=m, loops=loops)
    assert not dc.agree and not dc.dc_history and "does not explain" in dc.verdict
    # a first harmonic 0.5% off
    Xb = res.X.copy()
    Xb[1:3] *= 1.005
    h1 = cross_check(res.X, res.harmonics, Xb, res.harmonics, model=m, loops=loops)
    assert not h1.agree
    assert h1.rel_diff[1] == pytest.approx(0.005 / 1.005, rel=1e-9)


def _linear_frf(M, K, C, f_cos, w, harmonics, n_dof):
    """Exact coefficients of the steady response to f_cos cos(w t)."""
    Z = K - w * w * M + 1j * w * C
    Xc = np.linalg.solve(Z, f_cos)
    X = np.zeros((2 * len(harmonics) - 1, n_dof))
    X[1], X[2] = Xc.real, -Xc.imag
    return X


def test_cross_check_file_reads_the_hbm_contract(tmp_path):
    """/hbm/omega, /hbm/X, /hbm/harmonics of DESIGN §4, here filled with the exact
    linear solution (which HBM reproduces to round-off), vs time marching."""
    w = 1.2
    sc = lumped([[1.0, 0.0], [0.0, 1.0]], [[2.0, -1.0], [-1.0, 2.0]],
                [[0.05, 0.0], [0.0, 0.05]],
                loads=[{"dof": 0, "force": {"harmonics": [{"h": 1, "cos": 0.2}]}}],
                transient={"omega": w, "steady_tol": 1e-9, "steps_per_period": 512,
                           "harmonics": [0, 1, 2, 3]})
    m = build_model(sc)
    M, K, C = (a.toarray() for a in (m.M, m.K, m.C))
    hs = (0, 1, 2, 3)
    omegas = np.array([1.0, w, 1.4])
    X = np.stack([_linear_frf(M, K, C, np.array([0.2, 0.0]), om, hs, 2) for om in omegas])
    res = march_steady(m, sc.analysis.transient, progress=False)
    with ResultWriter(tmp_path / "x.h5", sc) as wr:
        wr.write("hbm/omega", omegas, "rad/s")
        wr.write("hbm/X", X, "m")
        wr.write("hbm/harmonics", np.array(hs), "1")
        cc = cross_check_file(wr, sc, m, res)
        assert cc is not None and cc.agree
        # generalized-alpha period error O((w h)^2) with 512 steps per period
        assert cc.rel_diff[1] < 1e-4
        g = wr.h5["crosscheck"]
        # the stored point at the frequency is taken as it is
        assert g.attrs["hbm_source"] == "stored point 1"
        assert list(g.attrs["hbm_points"]) == [1]
        assert g.attrs["agree"]
    with h5py.File(tmp_path / "x.h5") as h5:
        for name in ("rel_diff", "rel_own", "amplitude_hbm", "harmonics"):
            assert "unit" in h5["crosscheck"][name].attrs
        # between stored points the stored solution is interpolated, and says so (only
        # to seed a Newton solve at the frequency)
        pt = hbm_solution_at(read_hbm_solutions(h5), 1.1)
        assert pt.interpolated and pt.points == (0, 1)
        assert np.allclose(pt.X, 0.5 * (X[0] + X[1]))
        assert hbm_solution_at(read_hbm_solutions(h5), 2.0) is None
        # ... and the reference at 1.1 is solved, not interpolated: the exact FRF
        ref = hbm_reference(read_hbm_solutions(h5), sc, m, 1.1, 1.0)
        assert ref.convergence.success and ref.source.startswith("solved at omega")
        exact = _linear_frf(M, K, C, np.array([0.2, 0.0]), 1.1, hs, 2)
        assert np.allclose(ref.X, exact, rtol=0, atol=1e-13)


def test_hbm_branches_and_force_scales(tmp_path):
    """/hbm/branch indexes /hbm/force_scale (one per branch): only the branch of the
    requested force scale is used, and brackets never span two branches."""
    sc = lumped([[1.0]], [[1.0]], transient={"amplitude": 1.0})
    omegas = np.array([0.8, 0.9, 1.1, 0.8, 0.95, 1.2])
    branch = np.array([0, 0, 0, 1, 1, 1])
    X = np.zeros((6, 3, 1))
    X[:, 1, 0] = np.arange(6.0)          # cos coefficient = point index
    with ResultWriter(tmp_path / "b.h5", sc) as wr:
        wr.write("hbm/omega", omegas, "rad/s")
        wr.write("hbm/X", X, "m")
        wr.write("hbm/harmonics", np.array([0, 1]), "1")
        wr.write("hbm/branch", branch, "1")
        wr.write("hbm/force_scale", np.array([1.0, 2.0]), "1")
        a = hbm_solution_at(read_hbm_solutions(wr.h5), 1.0, force_scale=1.0)
        b = hbm_solution_at(read_hbm_solutions(wr.h5), 1.0, force_scale=2.0)
        assert a.points == (1, 2) and a.X[1, 0] == pytest.approx(1.5)
        assert b.points == (4, 5) and b.X[1, 0] == pytest.approx(4.0 + 0.05 / 0.25)
        # the jump from point 2 (branch 0, w = 1.1) to 3 (branch 1, w = 0.8) is no bracket
        assert hbm_solution_at(read_hbm_solutions(wr.h5), 1.15, force_scale=1.0) is None
