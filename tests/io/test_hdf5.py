"""The result-file contract (DESIGN §4) and incremental writing."""

import os

import h5py
import numpy as np
import pytest

from jointsim import __version__
from jointsim import _toml
from jointsim.io import hdf5
from jointsim.io.hdf5 import COMMITTED, SCHEMA_VERSION, ResultWriter, open_result
from jointsim.run import run_scene
from jointsim.scene import load_scene

from .. import _safety as S
from .._scenes import ROOT

SEED = ROOT / "models" / "seed_fig3"


def test_contract_of_a_prescribed_run(tmp_path):
    scene = load_scene(SEED / "sin2.toml")
    out = run_scene(scene, tmp_path / "r.h5")
    with h5py.File(out, "r") as h5:
        a = h5.attrs
        assert a["schema_version"] == SCHEMA_VERSION
        assert a["jointsim_version"] == __version__
        assert _toml.loads(a["scene"])["joint"]["reversal"] == "scaled"
        assert "created" in a and a["status"] == "complete"
        ns = scene.model.n_samples
        for name in ("u", "f", "N"):
            assert h5[f"loops/{name}"].shape == (1, 1, ns)
            assert h5[f"loops/{name}"].dtype == np.float64
            assert "unit" in h5[f"loops/{name}"].attrs
        for name in ("dev_manifold", "dev_masing"):
            assert h5[f"masing/{name}"].shape == (1, 1)
        assert h5["masing/on_manifold"].dtype == bool
        assert h5["masing"].attrs["tol"] == 0.01

        def units_everywhere(name, obj):
            if isinstance(obj, h5py.Dataset):
                assert "unit" in obj.attrs, name
        h5.visititems(units_everywhere)
        # the loop is the last period of the stored history
        np.testing.assert_array_equal(h5["loops/f"][0, 0], h5["prescribed/f"][0, -ns:])


def test_interrupted_run_leaves_a_valid_file(tmp_path):
    scene = load_scene(SEED / "const.toml")
    path = tmp_path / "partial.h5"
    with pytest.raises(RuntimeError):
        with ResultWriter(path, scene) as w:
            for i in range(3):
                w.append("hbm/omega", np.float64(i), "rad/s")
            raise RuntimeError("solver blew up")
    with h5py.File(path, "r") as h5:
        assert h5.attrs["status"] == "failed"
        assert "solver blew up" in h5.attrs["message"]
        np.testing.assert_array_equal(h5["hbm/omega"][()], [0.0, 1.0, 2.0])


def test_resume_appends_and_rejects_another_scene(tmp_path):
    scene = load_scene(SEED / "const.toml")
    path = tmp_path / "r.h5"
    with ResultWriter(path, scene) as w:
        w.append("hbm/omega", np.float64(1.0), "rad/s")
        w.finish("interrupted", "stopped")
    with ResultWriter(path, scene, resume=True) as w:
        assert w.rows("hbm/omega") == 1
        w.append("hbm/omega", np.float64(2.0), "rad/s")
    with h5py.File(path, "r") as h5:
        assert list(h5["hbm/omega"][()]) == [1.0, 2.0]
        assert h5.attrs["status"] == "complete"
    other = load_scene(SEED / "const.toml", ["joint.mu=0.3"])
    with pytest.raises(ValueError, match="different scene"):
        ResultWriter(path, other, resume=True)


def test_append_shape_mismatch_is_an_error(tmp_path):
    scene = load_scene(SEED / "const.toml")
    with ResultWriter(tmp_path / "r.h5", scene) as w:
        w.append("x", np.zeros(3), "m")
        with pytest.raises(ValueError, match="does not fit"):
            w.append("x", np.zeros(4), "m")


def test_append_rows_matches_row_by_row_appends(tmp_path):
    """A block of rows lands exactly where one-row appends would put it, keeps its
    unit, and a block of the wrong width is refused."""
    scene = load_scene(SEED / "const.toml")
    rng = np.random.default_rng(1)
    data = rng.normal(size=(7, 3))
    with ResultWriter(tmp_path / "r.h5", scene) as w:
        for row in data[:2]:
            w.append("a", row, "m")
        assert w.append_rows("a", data[2:6], "m") == 6
        assert w.append_rows("a", data[6:6], "m") == 6      # an empty block is a no-op
        assert w.append("a", data[6], "m") == 7
        assert w.append_rows("b", data, "s", "doc") == 7
        with pytest.raises(ValueError, match="does not fit"):
            w.append_rows("b", np.zeros((2, 4)), "s")
    with h5py.File(tmp_path / "r.h5") as h5:
        assert np.array_equal(h5["a"][()], data) and np.array_equal(h5["b"][()], data)
        assert h5["b"].attrs["unit"] == "s" and h5["b"].attrs["doc"] == "doc"
        assert h5["a"].maxshape == (None, 3)


def test_rows_of_every_dtype_read_back_as_appended(tmp_path):
    """The low-level appends (numeric rows) and h5py's (strings) store what was given."""
    scene = load_scene(SEED / "const.toml")
    rows = {"f": np.array([[1.5, -2.0], [3.0, 4.25]]), "i": np.array([[1, -2], [3, 4]]),
            "b": np.array([[True, False], [False, True]]),
            "c": np.array([[1 + 2j, -3j], [0.5, 2 - 1j]]),
            "s": np.array([b"stick", b"slip"]), "u": np.zeros((2, 0))}
    with ResultWriter(tmp_path / "r.h5", scene) as w:
        for name, r in rows.items():
            w.append(f"g/{name}", r[0], "1")
            w.append_rows(f"g/{name}", r[1:], "1")
        w.append("g/f", np.array([7, 8]), "1")          # ints into a float dataset
    with h5py.File(tmp_path / "r.h5") as h5:
        for name, r in rows.items():
            assert h5[f"g/{name}"].dtype == r.dtype, name
            assert np.array_equal(h5[f"g/{name}"][:2], r), name
        assert h5["g/f"][2].tolist() == [7.0, 8.0]


def test_a_dataset_replaced_behind_the_writer_is_written_and_counted_afresh(tmp_path,
                                                                           monkeypatch):
    """The writer holds its datasets open between commits.  A dataset deleted and made
    again under the same name by other code (extendable, or not) gets the next rows and
    its group the counts of what the group holds now, as a scan of the file gives."""
    monkeypatch.setattr(hdf5, "COMMIT_INTERVAL_S", 0.0)   # every point committed at once
    scene = load_scene(SEED / "const.toml")
    path = tmp_path / "r.h5"
    with ResultWriter(path, scene) as w:
        for k in range(2):
            with w.commit():
                w.append("g/a", np.float64(k), "1")
                w.append("g/b", np.float64(k), "1")
        assert int(w.h5["g"].attrs[COMMITTED]) == 2
        del w.h5["g/b"]
        w.h5.create_dataset("g/b", shape=(0,), maxshape=(None,), dtype=float)
        with w.commit():
            w.append("g/a", np.float64(2), "1")
            w.append("g/b", np.float64(2), "1")
        assert w.h5["g/b"][()].tolist() == [2.0] and w.rows("g/b") == 1
        assert COMMITTED not in w.h5["g"].attrs             # a at 3 rows, b at 1
        del w.h5["g/b"]
        w.h5.create_dataset("g/b", data=np.zeros(5))      # not extendable: not counted
        with w.commit():
            w.append("g/a", np.float64(3), "1")
        counts = {}                  # the oracle: h5py's reading, object by object
        w.h5.visititems(lambda name, o: counts.__setitem__(name, o.attrs.get(COMMITTED)))
        assert counts["g"] == counts["g/a"] == 4 and counts["g/b"] is None
    with h5py.File(path, "r") as h5:
        assert h5["g/a"][()].tolist() == [0.0, 1.0, 2.0, 3.0]
        assert int(h5["g"].attrs[COMMITTED]) == 4


def test_a_status_set_after_held_points_reaches_the_file_after_them(tmp_path, monkeypatch):
    """A branch's status is set through ``group``: the points held before it are
    committed first, so a kill right after the status cannot leave a branch marked
    complete without its last points (``--resume`` would skip it).  Before this,
    ``finish_branch`` set the attribute directly and a SIGKILL there lost 7 of a
    branch's 100 points."""
    monkeypatch.setattr(hdf5, "COMMIT_INTERVAL_S", 1e9)
    scene = load_scene(SEED / "const.toml")
    w = ResultWriter(tmp_path / "status.h5", scene)
    for k in range(3):
        with w.commit():
            w.append("hbm/omega", np.float64(k), "rad/s")
    assert int(w.h5["hbm/omega"].attrs[COMMITTED]) == 1          # two points held
    w.group("hbm", branch0_status="complete")
    S.writer_killed(w)  # killed here
    with open_result(tmp_path / "status.h5") as h5:
        assert h5["hbm"].attrs["branch0_status"] == "complete"
        assert h5["hbm/omega"][()].tolist() == [0.0, 1.0, 2.0]


def test_a_signal_while_the_file_is_opened_marks_it_interrupted(tmp_path, monkeypatch):
    """SIGINT that arrives while the writer opens the file (after the file is in place,
    before the ``with`` block runs) waits until the file is whole, then marks it
    ``interrupted`` and drops the lock; before, the file was left ``running``."""
    import signal

    opened = ResultWriter._open

    def open_then_signal(self, *args):
        opened(self, *args)
        hdf5.interrupt_handler(signal.SIGINT, None)   # held: inside the open

    monkeypatch.setattr(ResultWriter, "_open", open_then_signal)
    path = tmp_path / "opening.h5"
    with pytest.raises(KeyboardInterrupt):
        ResultWriter(path, load_scene(SEED / "const.toml"))
    with open_result(path) as h5:
        assert h5.attrs["status"] == "interrupted"
        assert "stopped by SIGINT" in h5.attrs["message"]
    assert not hdf5.lock_path(path).exists()
    assert not [w for w in hdf5._OPEN_WRITERS.values() if w.path == path]


def test_a_first_point_interrupted_between_its_datasets_leaves_none_of_them(tmp_path):
    """SIGINT inside the first point's commit, between two of its new datasets (a loop
    set's Masing checks): the file, closed as interrupted, holds none of that point's
    datasets (before, ``eq4_ok`` without ``eq6_ok`` made ``jointsim info`` fail); a
    dataset committed before keeps its rows, and a resumed writer appends them anew."""
    scene = load_scene(SEED / "const.toml")
    path = tmp_path / "first.h5"
    with pytest.raises(KeyboardInterrupt):
        with ResultWriter(path, scene) as w:
            with w.commit():
                w.append("epmc/omega", 1.0, "rad/s")
            with w.commit():
                w.append("epmc/omega", 2.0, "rad/s")
                w.append("epmc/masing/eq4_ok", np.ones(3, dtype=bool), "1")
                raise KeyboardInterrupt("stopped by SIGINT")
    with open_result(path) as h5:
        assert h5.attrs["status"] == "interrupted"
        assert h5["epmc/omega"][()].tolist() == [1.0]
        assert "epmc/masing/eq4_ok" not in h5
    w = ResultWriter(path, scene, resume=True)
    with w.commit():
        w.append("epmc/omega", 2.0, "rad/s")
        w.append("epmc/masing/eq4_ok", np.ones(3, dtype=bool), "1")
        w.append("epmc/masing/eq6_ok", np.zeros(3, dtype=bool), "1")
    w.finish("complete", "done")
    with open_result(path) as h5:
        assert h5["epmc/omega"][()].tolist() == [1.0, 2.0]
        assert h5["epmc/masing/eq6_ok"].shape == (1, 3)


def test_a_group_written_whole_is_all_old_or_all_new_whatever_stops_it(tmp_path):
    """``whole_group``: a group read as a whole (``/epmc/control``) is replaced in one
    link move.  An interrupt between two of its datasets leaves the old group and no
    side group; a kill there (the file closed as the process left it) leaves the old
    group and a side group that the next write replaces.  Before this, SIGINT between
    two datasets left ``/epmc/control`` without ``dev_manifold`` and ``info`` failed."""
    scene = load_scene(SEED / "const.toml")
    path = tmp_path / "whole.h5"
    w = ResultWriter(path, scene)
    with w.whole_group("epmc/control", tol=0.01) as g:
        w.write(f"{g}/f", np.zeros(3), "N")
        w.write(f"{g}/dev_manifold", np.ones(3), "1")
    assert sorted(w.h5["epmc"]) == ["control"] and w.h5["epmc/control"].attrs["tol"] == 0.01
    with pytest.raises(KeyboardInterrupt):
        with w.whole_group("epmc/control", tol=0.02) as g:
            w.write(f"{g}/f", np.full(3, 5.0), "N")
            raise KeyboardInterrupt("stopped by SIGINT")
    assert sorted(w.h5["epmc"]) == ["control"]
    assert w.h5["epmc/control/f"][()].tolist() == [0.0] * 3
    cm = w.whole_group("epmc/control", tol=0.03)
    g = cm.__enter__()
    w.write(f"{g}/f", np.full(3, 7.0), "N")
    S.writer_killed(w)  # killed here
    with open_result(path) as h5:
        c = h5["epmc/control"]
        assert c.attrs["tol"] == 0.01 and sorted(c) == ["dev_manifold", "f"]
        assert c["f"][()].tolist() == [0.0] * 3
    w = ResultWriter(path, scene, resume=True)
    with w.whole_group("epmc/control", tol=0.04) as g:
        w.write(f"{g}/f", np.full(3, 8.0), "N")
        w.write(f"{g}/dev_manifold", np.ones(3), "1")
    w.finish("complete", "done")
    with open_result(path) as h5:
        assert sorted(h5["epmc"]) == ["control"] and h5["epmc/control"].attrs["tol"] == 0.04
        assert h5["epmc/control/f"][()].tolist() == [8.0] * 3


def test_fast_points_are_committed_together_and_none_is_lost_on_finish(tmp_path,
                                                                        monkeypatch):
    """Points that follow each other within ``COMMIT_INTERVAL_S`` are committed
    together: until then their rows are in the file and uncommitted (a kill loses
    them, as it loses a torn point); finishing, an interrupt's summary and a commit
    outside a point commit them, each at the rows it had when it was whole."""
    monkeypatch.setattr(hdf5, "COMMIT_INTERVAL_S", 1e9)
    scene = load_scene(SEED / "const.toml")
    w = ResultWriter(tmp_path / "held.h5", scene)
    for k in range(3):
        with w.commit():
            w.append("g/a", np.float64(k), "1")
            w.append("g/b", np.full(2, float(k)), "1")
    # the first point is committed at once (no commit before it), the next two are held
    assert int(w.h5["g/a"].attrs[COMMITTED]) == 1 and int(w.h5["g"].attrs[COMMITTED]) == 1
    # a point torn after them: committing what is held keeps its rows out
    w._txn = set()
    w.append("g/a", 9.0, "1")
    assert "committed points: g 3" in w.committed_summary()
    assert int(w.h5["g/a"].attrs[COMMITTED]) == int(w.h5["g/b"].attrs[COMMITTED]) == 3
    w._txn = None
    w.finish("interrupted", "stopped")
    with open_result(tmp_path / "held.h5") as h5:
        assert h5["g/a"][()].tolist() == [0.0, 1.0, 2.0]
        assert h5["g/b"].shape == (3, 2) and h5.attrs["status"] == "interrupted"

    # a kill while points are held loses them (and nothing else); resume trims them
    w = ResultWriter(tmp_path / "killed.h5", scene)
    for k in range(3):
        with w.commit():
            w.append("g/a", np.float64(k), "1")
    w.h5.flush()
    S.writer_killed(w)  # killed here
    with open_result(tmp_path / "killed.h5") as h5:
        assert h5["g/a"][()].tolist() == [0.0]
    with ResultWriter(tmp_path / "killed.h5", scene, resume=True) as w2:
        assert w2.rows("g/a") == 1

    # a held dataset deleted before the commit (a rewritten group) is not counted
    w = ResultWriter(tmp_path / "gone.h5", scene)
    for k in range(2):
        with w.commit():
            w.append("g/a", np.float64(k), "1")
            w.append("h/c", np.float64(k), "1")
    del w.h5["h"]
    w.finish("complete", "")
    with h5py.File(tmp_path / "gone.h5", "r") as h5:
        assert "h" not in h5 and int(h5["g"].attrs[COMMITTED]) == 2


def test_a_signal_while_a_point_is_recorded_waits_until_it_is_whole(tmp_path, monkeypatch):
    """SIGINT arriving while a finished point's datasets are recorded for their commit
    (the second of three here) is raised once the record is complete: the interrupted
    file then holds whole points only, every dataset at its group's count."""
    import signal

    from jointsim.io.open_datasets import OpenDatasets
    monkeypatch.setattr(hdf5, "COMMIT_INTERVAL_S", 1e9)
    old = signal.signal(signal.SIGINT, hdf5.interrupt_handler)
    calls = {"n": 0}
    real_rows = OpenDatasets.rows

    def rows(self, path):          # the record of a dataset's rows for the commit
        calls["n"] += 1
        if calls["n"] == 2:
            os.kill(os.getpid(), signal.SIGINT)
        return real_rows(self, path)
    path = tmp_path / "sig.h5"
    try:
        with pytest.raises(KeyboardInterrupt, match="SIGINT"):
            with ResultWriter(path, load_scene(SEED / "const.toml")) as w:
                with w.commit():
                    for name in ("g/a", "g/b", "g/c"):
                        w.append(name, np.float64(1.0), "1")
                monkeypatch.setattr(OpenDatasets, "rows", rows)
                with w.commit():
                    for name in ("g/a", "g/b", "g/c"):
                        w.append(name, np.float64(2.0), "1")
                raise AssertionError("the signal was not raised")
    finally:
        signal.signal(signal.SIGINT, old)
    with h5py.File(path, "r") as h5:
        assert h5.attrs["status"] == "interrupted"
        assert int(h5["g"].attrs[COMMITTED]) == 2
        assert all(h5[f"g/{n}"].shape == (2,) for n in "abc")


@pytest.mark.parametrize("stale", ["group", "dataset"])
def test_a_half_committed_point_is_dropped_from_the_whole_group(tmp_path, stale):
    """A kill inside a commit's final flush can put some committed counts on disk and
    not others.  Readers and --resume then keep the smaller count for every dataset of
    a one-row-per-point group: its rows stay aligned and the half-committed point is
    dropped (here: point 3 of 3, with the group's or one dataset's count stale)."""
    from jointsim.io.hdf5 import COMMITTED, open_result
    scene = load_scene(SEED / "const.toml")
    path = tmp_path / "r.h5"
    with ResultWriter(path, scene) as w:
        for k in range(3):
            with w.commit():
                w.append("hbm/omega", np.float64(k), "rad/s")
                w.append("hbm/X", np.full(2, float(k)), "m")
        w.finish("interrupted", "stopped")
    with h5py.File(path, "r+") as h5:     # as the killed flush left it
        if stale == "group":
            h5["hbm"].attrs[COMMITTED] = 2
        else:
            h5["hbm/X"].attrs[COMMITTED] = 2
    with open_result(path) as h5:
        assert h5["hbm/omega"].shape[0] == h5["hbm/X"].shape[0] == 2
        assert int(h5["hbm"].attrs[COMMITTED]) == 2
    with ResultWriter(path, scene, resume=True) as w:
        assert w.rows("hbm/omega") == w.rows("hbm/X") == 2


def test_loops_resumed_from_a_file_without_the_excess_stay_aligned(tmp_path):
    """Issue 14 added /masing/manifold_excess; a file written before it, resumed, gets
    no excess rows (which would misalign the points) and keeps every committed point."""
    import dataclasses

    from jointsim.contact.select import tangential_law
    from jointsim.io.hdf5 import open_result
    from jointsim.io.loops import write_loops
    from jointsim.masing import check_loops
    from jointsim.scene import Joint

    scene = load_scene(SEED / "const.toml")
    law = tangential_law("jenkins", "anchor", Joint(mu=0.1, kt=1.0), [1.0])
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    u, N = np.sin(t)[None], (5 + np.sin(t))[None]
    f = law.march(np.tile(u, 2), np.tile(N, 2), law.rest_state([5.0]))[0][:, -64:]
    rep = check_loops(u, f, N, law)
    old = dataclasses.replace(rep, manifold_excess=None, masing_excess=None)
    path = tmp_path / "r.h5"
    with ResultWriter(path, scene) as w:
        write_loops(w, 0, u, f, N, old, "SI", "prescribed")
        w.finish("interrupted", "stopped")
    with ResultWriter(path, scene, resume=True) as w:
        write_loops(w, 1, u, f, N, rep, "SI", "prescribed")
    with open_result(path) as h5:
        assert h5["prescribed/masing/dev_manifold"].shape[0] == 2
        assert "manifold_excess" not in h5["prescribed/masing"]
    # a new file has it, one row per point
    with ResultWriter(tmp_path / "n.h5", scene) as w:
        write_loops(w, 0, u, f, N, rep, "SI", "prescribed")
        write_loops(w, 1, u, f, N, rep, "SI", "prescribed")
    with open_result(tmp_path / "n.h5") as h5:
        assert h5["prescribed/masing/manifold_excess"].shape == (2, 1)


def _everything(path) -> dict:
    """Every attribute and dataset of a file, by path (soft links as their targets)."""
    out = {}
    with h5py.File(path, "r", locking=False) as h5:
        out["/"] = {k: str(v) for k, v in h5.attrs.items()}

        def visit(name, obj):
            out[name] = {k: str(v) for k, v in obj.attrs.items()}
            if isinstance(obj, h5py.Dataset):
                out[name + "[]"] = (obj[()].tolist(), obj.maxshape)
        h5.visititems(visit)
        out["links"] = {k: h5.get(k, getlink=True).path for k in h5
                        if isinstance(h5.get(k, getlink=True), h5py.SoftLink)}
    return out


def test_resume_copies_the_file_afresh_with_its_content(tmp_path):
    """--resume never appends to a killed file in place: it copies every object into a new
    file first (same attributes, rows, extendable shapes and soft links), then appends."""
    scene = load_scene(SEED / "const.toml")
    path = tmp_path / "r.h5"
    with ResultWriter(path, scene) as w:
        for i in range(4):
            with w.commit():
                w.append("hbm/omega", np.float64(i), "rad/s", doc="frequency")
                w.append("hbm/loops/u", np.arange(3.0) + i, "m")
        w.h5["loops"] = h5py.SoftLink("/hbm/loops")
        w.finish("interrupted", "stopped")
    before = _everything(path)
    inode = path.stat().st_ino
    with ResultWriter(path, scene, resume=True) as w:
        assert path.stat().st_ino != inode           # a new file, renamed into place
        after = _everything(path)
        w.append("hbm/omega", np.float64(9.0), "rad/s")
    assert not (tmp_path / "r.h5.new").exists()
    for key in ("status", "message", "pid"):         # what resuming itself changes
        before["/"].pop(key), after["/"].pop(key)
    assert after == before
    assert after["links"] == {"loops": "/hbm/loops"}
    assert after["hbm/omega[]"][1] == (None,)        # still extendable
    with h5py.File(path, "r") as h5:
        assert list(h5["hbm/omega"][()]) == [0.0, 1.0, 2.0, 3.0, 9.0]
        np.testing.assert_array_equal(h5["loops/u"][3], [3.0, 4.0, 5.0])


def test_resume_sets_aside_a_file_with_data_beyond_its_recorded_end(tmp_path, caplog):
    """A kill inside HDF5's flush can leave the superblock's end of file short of blocks
    that the metadata already points to: such a file reads whole as metadata (the old
    check passed it) but appending in place overwrites those blocks.  Built here by
    moving the recorded end back; --resume must find it damaged, set it aside and
    compute the run again."""
    import struct
    scene = load_scene(SEED / "const.toml")
    good = tmp_path / "good.h5"
    with ResultWriter(good, scene) as w:
        for i in range(4):
            with w.commit():
                w.append("hbm/X", np.full(50, float(i)), "m")
        w.finish("interrupted", "stopped")
    with h5py.File(good, "a") as h5:                 # rows whose data land at the file's end
        h5["hbm/X"].resize((200, 50))
        h5["hbm/X"][4:] = np.arange(196.0)[:, None]
    data = good.read_bytes()
    assert data[8] == 0, "expected a version-0 superblock (end of file address at byte 40)"
    path = tmp_path / "r.h5"

    def walks(p) -> bool:
        try:
            with h5py.File(p, "r") as h5:
                h5.visititems(lambda n, o: dict(o.attrs) and None)
            return True
        except (OSError, RuntimeError):
            return False

    def reads(p) -> bool:
        try:
            with h5py.File(p, "r") as h5:
                h5["hbm/X"][()]
            return True
        except (OSError, RuntimeError):
            return False
    for cut in range(len(data) - 8, len(data) // 2, -8):
        torn = bytearray(data)
        struct.pack_into("<Q", torn, 40, cut)
        path.write_bytes(bytes(torn))
        if walks(path) and not reads(path):
            break
    else:
        pytest.fail("no end-of-file address found that hides only data blocks")
    with ResultWriter(path, scene, resume=True) as w:
        assert w.rows("hbm/X") == 0                  # computed again from the start
    assert (tmp_path / "r.h5.damaged").exists()
    assert "damaged" in caplog.text
    with h5py.File(path, "r") as h5:
        assert h5.attrs["status"] == "complete"
