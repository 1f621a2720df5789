"""Issue 13 (found by issue 12's converge ladder): the coupled lap joint's 20 N FRC
at H = 0..11, Nt = 256 (default mesh) gave up at 1033.36 rad/s after 176 points
("corrector failed at step_min").

What the branch did there (stored points of the failed run, replayed from them):
past the peak (1029.6 rad/s) the branch folds twice near 1032.2 rad/s (the
smallest singular value of dR/dz drops from 0.8-0.9 to 0.056 at point 105, omega
1032.215 -> 1032.241 -> 1032.444), the corrector then stalls at point 107 (residual
9.5e-4 after 13 iterations), a 4 times longer step "over a kink" lands 0.02 away at
1032.93, and from there the branch zig-zags: the sign of det [J; t] flips at points
110 and 116 although J is regular there (smallest singular values 2.6 and 2.5),
i.e. the stepper turned round twice; between 1033.0 and 1033.6 rad/s it runs along
two nearby pieces (the secant reverses at 110, 111, 117, 118 and 123) and then back
along itself at one Newton iteration per point, every longer try rejected as
landing on the traced branch, the step halving every 8 points down to step_min.
With ``joint.closing = "interpolated"`` (the re-closing anchor at the closing
instant, so the residual is continuous where a closing instant crosses a sample)
the same replay from point 104 passes 1032.2 to 1035.4 rad/s in 16 points at 3 to 5
iterations each.  So the failure comes from the sampled closing (a residual that
jumps a little at every closing-instant crossing) where the branch folds.

The fix: the landing at point 110 (1032.506 rad/s, on a piece running the other way)
came from a corner step; the stepper now rejects a point found by a remedy whose
tangent flips ``sign det [J; t]`` (:meth:`Continuation._flips`), and the branch
completes with the sampled closing too (191 points, 209 s wall at load 2-4).
Fast tests here: that check, and the failure message of a branch that still gives
up, which says what it did (:meth:`Continuation._lost_way`) and what to change
(:func:`~jointsim.solvers.frc_diagnosis.closing_advice`).  Slow: the branch itself,
with either closing.
"""
from types import SimpleNamespace

import h5py
import numpy as np
import pytest

from jointsim.run import run_scene
from jointsim.solvers.frc_diagnosis import closing_advice

from .._scenes import COUPLED, lap_scene
from ._line import line_continuation
from ._files import assert_all_finite



def test_a_failed_branch_says_it_zig_zagged_and_ran_back_along_itself():
    c = line_continuation()
    c.step()
    c.step()
    assert c.reversals == [] and c._lost_way(0) == ""
    # an accepted point straight behind the last one is a reversal
    y = c.points[-1] - 0.05 * (c.points[-1] - c.points[-2])
    c._accept(y / c.scale, c.infos[-1])
    assert [lam for _, lam in c.reversals] == [pytest.approx(y[-1])]
    msg = c._lost_way(3)
    assert "3 of its last corrector tries landed back on the branch already traced" in msg
    assert "reversed direction 1 times" in msg and f"{y[-1]:.8g}" in msg


def test_a_point_oriented_against_the_branch_is_flagged():
    """``sign det [J; t]`` is kept along a branch: on ``z = lam`` the tangent
    reversed at a regular point flips it (the landing of point 110 at 1032.506
    rad/s on the coupled lap joint); not after a turn at a non-smooth fold."""
    c = line_continuation(keep_orientation=True)
    c.step()
    J, t = np.array([[1.0, -1.0]]), c._t
    assert not c._flips(J, t)
    assert c._sign != 0
    assert c._flips(J, -t)
    c._turned = True
    assert not c._flips(J, -t)


def _sections(closing="sample", reversal="anchor", law="jenkins", normal="coupled",
              separation=True, friction=True):
    return (SimpleNamespace(closing=closing, reversal=reversal, law=law),
            SimpleNamespace(normal=normal, separation=separation, friction=friction))


def test_the_closing_advice_names_the_key_only_where_it_applies():
    msg = "corrector failed with the step shrunk below step_min = 1e-06 at lam = 1033.36"
    out = closing_advice(*_sections(), msg)
    assert out.startswith(msg) and "joint.closing = 'interpolated'" in out
    for kw in (dict(closing="interpolated"), dict(reversal="scaled"), dict(law="stuck"),
               dict(normal="fixed"), dict(separation=False), dict(friction=False)):
        assert closing_advice(*_sections(**kw), msg) == msg
    # not for other failures, nor twice
    assert closing_advice(*_sections(), "stopped at max_points = 10") == "stopped at max_points = 10"
    assert closing_advice(*_sections(), out) == out


#: the scene's own (default) mesh, not the coarse one of ``lap_scene``
DEFAULT_MESH = "model.mesh='../meshes/lap_joint_default.msh'"
H11 = "analysis.hbm.harmonics=[0,1,2,3,4,5,6,7,8,9,10,11]"


def _branch(tmp_path, name, *extra):
    scene = lap_scene(COUPLED, ("hbm",), [DEFAULT_MESH, H11, "analysis.hbm.n_samples=256",
                                          "analysis.hbm.force_scale=[2.0]",
                                          "analysis.hbm.workers=1", *extra])
    out = tmp_path / f"{name}.h5"
    try:
        run_scene(scene, out)
    except RuntimeError:
        pass   # a branch that gave up: its points and message are in the file
    assert_all_finite(out)
    with h5py.File(out, "r") as h5:
        g = h5["hbm"]
        return (g.attrs["branch0_status"], g.attrs["branch0_message"], g["omega"][()],
                scene)


@pytest.mark.slow
def test_the_20N_branch_at_H11_completes_with_interpolated_closing(tmp_path):
    status, message, omega, scene = _branch(tmp_path, "interp", "joint.closing='interpolated'")
    assert status == "complete", message
    assert omega[-1] == pytest.approx(scene.analysis.hbm.omega_end)


@pytest.mark.slow
def test_the_20N_branch_at_H11_with_sampled_closing_completes(tmp_path):
    """The failing branch itself (the scene's default ``joint.closing = "sample"``):
    191 points since the orientation check (it gave up after 176 before)."""
    status, message, omega, scene = _branch(tmp_path, "sample")
    assert status == "complete", message
    assert omega[-1] == pytest.approx(scene.analysis.hbm.omega_end)
