"""Issue 13, case 2: the coupled lap joint's EPMC at higher harmonics.

At H = 0..11 (and 0..15), Nt = 256 the branch used to turn back at
log10 a = -3.5 (-3.93), creep at step_min and give up.  It was not a fold of
the branch: at that point the Jacobian is nearly singular in a direction made
of harmonic 10 of the edge elements' coordinates (elastic mode 4, 1568 Hz
stuck, is near 10 x 163.5 Hz: an internal resonance that the H = 7 branch
cannot see), so the tangent there is poor; the next tiny step landed a hair
behind, its secant pointed back, and the branch was turned round and retraced
itself point by point.  The stepper now orients the new tangent by the chord
over the last two steps (:meth:`Continuation._orientation`).  The Jacobian is
correct (checked against central differences at the failing point: 2e-12 of
|Jv| ~ 0.03..0.09 in every direction).  At H = 0..15 the branch now passes
log10 a = -4.05.

At H = 0..15 it then turned back at log10 a = -3.776 (1.67e-4) and retraced
itself down to -3.86, creeping (the retrace rule rejecting every longer step):
the tangent computed at that point was perpendicular to the secant that led
there to within 1.3 degrees (cos 0.022; the tangent of the point before and the
secant agree to cos 0.70), so orienting it by the secant was a coin flip, and it
came down on the wrong side.  Half a step on, the branch was running back along
its own points (point 114 at -3.858 matches point 52 at -3.859 in every
harmonic's norm to two digits; no second sheet, so no fold of a tongue).  A
tangent that nearly perpendicular to its secant is now oriented like the previous
tangent (:meth:`Continuation._new_tangent`, ``AMBIGUOUS_COS``); the rule fires
once on the branch, at that point, and the branch completes.

At H = 0..15 with Nt = 512 (the ``reference`` preset) it gave up at log10 a = -4.25,
before the resonance: a step of 0.2 from the stuck (linear) piece jumped the stuck
onset (-4.1535) and a corner remedy then sent the branch back down the piece it had
jumped.  The runner now ends the first leg of the continuation exactly at the onset
(:func:`jointsim.analyses.epmc.stuck_onset`), and the branch completes.
"""
import h5py
import numpy as np
import pytest

from jointsim.run import run_scene

from .._scenes import COUPLED, lap_scene
from ._line import line_continuation



def test_a_tiny_step_back_does_not_turn_the_branch_round():
    c = line_continuation()
    c.step()
    yk = c._yh
    y_prev = c.points[-2] / c.scale
    forward = (yk - y_prev) / np.linalg.norm(yk - y_prev)
    # a corrected point a hair behind the last one (its secant points back)
    yc = yk - 1e-4 * forward
    assert c._orientation(yk, yc) @ forward > 0.99
    # on a plain step the chord over two steps keeps the forward orientation
    assert c._orientation(yk, yk + 0.1 * forward) @ forward > 0.99


def test_a_tangent_perpendicular_to_its_secant_is_oriented_like_the_previous_one():
    c = line_continuation()
    c.step()
    yk = c._yh
    # a Jacobian whose null direction is e_lam, nearly perpendicular to the secant
    J = np.array([[1.0, 0.0]])
    t_prev = np.array([0.3, -1.0]) / np.hypot(0.3, 1.0)
    yc = yk + 0.01 * np.array([1.0, 0.1])          # secant at cos 0.0995 to e_lam
    t_new = c._new_tangent(J, yk, yc, t_prev)
    assert np.allclose(t_new, [0.0, -1.0])          # the previous tangent's side
    # a secant clearly on one side keeps the orientation it gives
    yc = yk + 0.01 * np.array([0.5, 1.0])
    assert np.allclose(c._new_tangent(J, yk, yc, t_prev), [0.0, 1.0])
    # both references nearly perpendicular: the secant decides
    t_side = np.array([1.0, -0.05]) / np.hypot(1.0, 0.05)
    yc = yk + 0.01 * np.array([1.0, 0.1])
    assert np.allclose(c._new_tangent(J, yk, yc, t_side), [0.0, 1.0])


#: the scene's own (default) mesh, not the coarse one of ``lap_scene``
DEFAULT_MESH = "model.mesh='../meshes/lap_joint_default.msh'"


@pytest.mark.slow
@pytest.mark.parametrize("H", [11, 15])
def test_coupled_lap_joint_epmc_at_higher_harmonics_completes(tmp_path, H):
    harmonics = ",".join(str(h) for h in range(H + 1))
    scene = lap_scene(COUPLED, ("epmc",), [DEFAULT_MESH, f"analysis.epmc.harmonics=[{harmonics}]",
                                           "analysis.epmc.n_samples=256"])
    out = run_scene(scene, tmp_path / f"h{H}.h5")
    with h5py.File(out, "r") as h5:
        g = h5["epmc"]
        assert g.attrs["branch_status"] == "complete", g.attrs["message"]
        lam = np.log10(g["amplitude"][()])
        assert lam[0] == pytest.approx(scene.analysis.epmc.log10_amplitude_start)
        assert lam[-1] == pytest.approx(scene.analysis.epmc.log10_amplitude_end)
        for k in ("omega", "damping_ratio", "X"):
            assert np.all(np.isfinite(g[k][()]))


def test_epmc_at_amplitudes_on_the_krylov_path(tmp_path):
    """``analysis.epmc.amplitudes`` with the structured (Krylov) Jacobian, which
    ``linear_solver = "auto"`` picks from 1200 unknowns on (the coupled lap joint at
    H = 0..15 has 1550): it used to index that Jacobian like an array and fail
    after the branch.  Oracle: the same solve on the dense path."""
    from jointsim.scene import load_scene
    from .._scenes import MODELS

    amps = [0.3, 1.2, 3.0]
    got = {}
    for solver in ("direct", "krylov"):
        sc = load_scene(MODELS / "hbm" / "sdof_jenkins_epmc.toml",
                        ["analysis.epmc.harmonics=[0, 1, 2, 3]", "analysis.epmc.n_samples=64",
                         f"analysis.epmc.amplitudes={amps}",
                         f"analysis.epmc.linear_solver='{solver}'"])
        with h5py.File(run_scene(sc, tmp_path / f"{solver}.h5"), "r") as h5:
            g = h5["epmc/at_amplitudes"]
            assert g["converged"][()].all()
            got[solver] = (g["omega"][()], g["damping_ratio"][()])
    np.testing.assert_allclose(got["krylov"][0], got["direct"][0], rtol=1e-9)
    np.testing.assert_allclose(got["krylov"][1], got["direct"][1], rtol=1e-6, atol=1e-12)


@pytest.mark.slow
def test_coupled_lap_joint_epmc_at_h15_nt512_completes(tmp_path):
    """The ``reference`` preset's EPMC (H = 0..15, Nt = 512, tolerance 1e-10) over the
    scene's whole range.  It used to give up at log10 a = -4.25: from the stuck
    (linear) piece a step of 0.2 jumped the stuck onset at -4.1535 and landed at -4.05
    on the nonlinear piece; the next steps stalled there (the 1:10 internal resonance
    makes the piece rough) and a corner remedy landed behind, on the untraced piece
    between the onset and -4.05, which the branch then ran down, back to the onset and
    along the stuck piece onto its own points.  The runner now ends the first leg of
    the continuation exactly at the onset (:func:`jointsim.analyses.epmc.stuck_onset`)."""
    harmonics = ",".join(str(h) for h in range(16))
    scene = lap_scene(COUPLED, ("epmc",), [DEFAULT_MESH, f"analysis.epmc.harmonics=[{harmonics}]",
                                           "analysis.epmc.n_samples=512",
                                           "analysis.epmc.tol=1e-10"])
    out = run_scene(scene, tmp_path / "h15_512.h5")
    with h5py.File(out, "r") as h5:
        g = h5["epmc"]
        assert g.attrs["branch_status"] == "complete", g.attrs["message"]
        for k in ("omega", "damping_ratio", "X", "amplitude"):
            assert np.all(np.isfinite(g[k][()]))
        lam = np.log10(g["amplitude"][()])
        assert lam[0] == pytest.approx(scene.analysis.epmc.log10_amplitude_start)
        assert lam[-1] == pytest.approx(scene.analysis.epmc.log10_amplitude_end)
        onset = g.attrs["log10_stuck_onset"]
        assert -4.16 < onset < -4.15
        assert np.min(np.abs(lam - onset)) < 1e-9   # a point at the onset
