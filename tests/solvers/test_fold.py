"""Non-smooth folds: a kink of a piecewise-smooth residual whose two pieces are not
coherently oriented (issue 14: EPMC of the coarse lap joint with the scaled law).

Oracle: the piecewise-linear system ``x = lam``, ``lam + y + c |y| = 0`` with its
analytic branch (``lam = (c - 1) y`` for ``y < 0``, ``lam = -(1 + c) y`` for
``y > 0``).  For ``c = 2`` the orientation ``sign det [J; t]`` flips at ``y = 0``:
the branch turns back there by ``arccos(-5 / sqrt(57))`` = 131 degrees, no
hyperplane just beyond the kink cuts it, and Newton cycles between the pieces.
For ``c = 0.5`` the pieces are coherently oriented and the branch crosses.
"""
import numpy as np
import pytest

from jointsim.solvers.continuation import continue_branch
from jointsim.solvers.discontinuity import explain_failure, orientation_fold


def system(c):
    def fun(v):
        x, y, lam = v
        R = np.array([x - lam, lam + y + c * abs(y)])
        J = np.array([[1.0, 0.0, -1.0], [0.0, 1.0 + c * np.sign(y), 1.0]])
        return R, J, None
    return fun


def branch(c, lam_end):
    return continue_branch(system(c), np.array([-(c - 1.0), -1.0, -(c - 1.0)]),
                           lam_end, scale=np.ones(3), rscale=1.0, step=0.1, step_min=1e-6,
                           step_max=0.2, max_points=200, tol=1e-12, max_iter=20)


def test_orientation_fold_finds_the_flip_and_the_turn():
    fun = system(2.0)
    y0, y1 = np.array([-0.1, -0.1, -0.1]), np.array([0.13, 0.13, 0.13])
    f = orientation_fold(lambda v: fun(v)[1], y0, y1)
    assert f is not None and f.sign_before == -f.sign_after
    assert 0.5 * (f.s_before + f.s_after) == pytest.approx(0.1 / 0.23, abs=1e-9)   # y = 0
    assert f.cos_pieces == pytest.approx(5.0 / np.sqrt(57.0), rel=1e-12)
    assert "turns back by about 131 degrees" in f.describe()
    coherent = system(0.5)
    # along its branch: from lam = -0.5 y (y < 0) to lam = -1.5 y (y > 0)
    assert orientation_fold(lambda v: coherent(v)[1], np.array([0.05, -0.1, 0.05]),
                            np.array([-0.075, 0.05, -0.075])) is None


def test_continuation_turns_at_a_non_smooth_fold():
    """c = 2: the branch comes up along lam = y (y < 0), turns at the kink and goes on
    along lam = -3 y (y > 0) until it leaves the range through its start."""
    br = branch(2.0, 3.0)
    assert br.convergence.success, br.convergence.message
    y = br.y
    assert y[:, 1].max() > 0.3           # went on beyond the kink
    beyond = y[y[:, 1] > 0]
    np.testing.assert_allclose(beyond[:, 2], -3.0 * beyond[:, 1], atol=1e-12)
    np.testing.assert_allclose(beyond[:, 0], beyond[:, 2], atol=1e-12)
    assert -0.01 < y[:, 2].max() < 0.0   # it turned near the fold at lam = 0


def test_coherent_kink_is_crossed():
    br = branch(0.5, -3.0)
    assert br.convergence.success, br.convergence.message
    y = br.y
    assert y[:, 1].max() > 0.0 and y[-1, 2] == pytest.approx(-3.0)
    np.testing.assert_allclose(y[y[:, 1] > 0, 2], -1.5 * y[y[:, 1] > 0, 1], atol=1e-12)


def test_failure_message_names_the_fold():
    fun = system(2.0)
    msg = explain_failure("gave up", "ADVICE", lambda v: fun(v)[0],
                          np.array([-2e-3, -2e-3, -2e-3]), np.array([-1e-3, -1e-3, -1e-3]),
                          jac=lambda v: fun(v)[1], y_ahead=np.array([1e-3, 1e-3, 1e-3]))
    assert msg.startswith("gave up; ADVICE")
    assert "non-smooth fold" in msg and "no jump found" in msg


@pytest.mark.slow
def test_lap_joint_epmc_with_the_scaled_law_turns_at_the_fold_then_stops_at_a_jump(tmp_path):
    """models/lap_joint_nodes.toml on the coarse mesh, EPMC only, joint.reversal = "scaled": the
    branch turns back at the non-smooth fold near log10 a = -4.2723 (it gave up there
    before) and stops later at a true residual jump, which the message names."""
    from pathlib import Path

    import h5py

    from jointsim import _toml
    from jointsim.run import run_scene
    from jointsim.scene import parse_scene

    path = Path(__file__).resolve().parents[2] / "models" / "lap_joint_nodes.toml"
    data = _toml.loads(path.read_text(encoding="utf-8"))
    data["model"]["mesh"] = "../meshes/lap_joint_coarse.msh"
    data["joint"]["reversal"] = "scaled"
    for key in ("hbm", "qsma"):
        data["analysis"].pop(key, None)
    scene = parse_scene(data, str(path), path.parent)
    with pytest.raises(RuntimeError) as err:
        run_scene(scene, tmp_path / "x.h5")
    assert "the residual jumps by" in str(err.value)
    with h5py.File(tmp_path / "x.h5") as h5:
        lam = np.log10(h5["epmc/amplitude"][()])
    assert len(lam) > 32 and np.any(np.diff(lam) > 0)
    turns = np.nonzero(np.diff(np.sign(np.diff(lam))))[0]
    assert len(turns) >= 2   # turned back once more after the first turn (at the fold)
    assert lam[-1] == pytest.approx(-4.27188, abs=1e-4)
