"""Error indicators computed on forked workers (:mod:`jointsim.analyses.indicator_pool`).

Oracle: the serial run (``analysis.epmc.workers = 1``, each point's indicators computed
in the continuation's process, as before the pool).  The pool must give the same
``error_*`` rows (to 1e-9 relative: numba-parallel and serial AFT kernels may differ in
the last digits) and every other dataset bit for bit; an interrupted run resumed must
give the same indicators as an uninterrupted one; a worker that dies loses only the
row it was computing.
"""
import logging
import os
import re

import h5py
import numpy as np
import pytest

from jointsim.analyses.indicator_pool import InOrder, IndicatorPool, PointIndicators
from jointsim.io.hbm_points import missing_error_indicators
from jointsim.io.hdf5 import ResultWriter
from jointsim.run import run_scene
from jointsim.scene import load_scene
from jointsim.solvers.indicators import ToleranceWatch

from .._scenes import COUPLED, MODELS, NO_FULL, lap_scene
from .test_hbm import run_interrupted_after

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="the pool forks")

SDOF = MODELS / "hbm" / "sdof_jenkins_epmc.toml"
#: the SDOF Jenkins EPMC, cheaper harmonics (the indicators on)
QUICK = ["analysis.epmc.harmonics=[0, 1, 3, 5]", "analysis.epmc.n_samples=64",
         "analysis.epmc.loop_amplitudes=[3.0]"]


def _datasets(path, prefix="epmc"):
    out = {}
    with h5py.File(path, "r") as h5:
        h5[prefix].visititems(lambda n, o: out.__setitem__(n, o[()])
                              if isinstance(o, h5py.Dataset) else None)
        attrs = dict(h5[prefix].attrs)
    return out, attrs


def assert_same_run(pooled, serial, rtol=1e-9):
    """Every ``error_*`` row equal to ``rtol`` (none NaN), every other dataset bit-identical."""
    a, attrs = _datasets(pooled)
    b, _ = _datasets(serial)
    assert sorted(a) == sorted(b)
    n_err = 0
    for k in b:
        if k.startswith("error_"):
            n_err += 1
            assert not np.isnan(a[k]).any() and not np.isnan(b[k]).any(), k
            scale = np.maximum(np.abs(b[k]), 1e-300)
            assert np.all(np.abs(a[k] - b[k]) <= rtol * scale), (k, a[k], b[k])
        else:
            assert a[k].shape == b[k].shape and a[k].dtype == b[k].dtype, k
            assert np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"), k
    assert n_err == 6
    return attrs


def test_auto_workers_compute_a_small_systems_indicators_in_the_process(tmp_path):
    """``workers = 0`` below ``POOL_MIN_UNKNOWNS`` (the one-DOF EPMC: 15 unknowns) starts
    no pool, and gives the serial run's file; an explicit count is kept, and 0 on a
    system of that size or more is one worker per core."""
    from jointsim.analyses import indicator_pool as ip
    run_scene(load_scene(SDOF, QUICK + ["analysis.epmc.workers=0"]), tmp_path / "auto.h5")
    run_scene(load_scene(SDOF, QUICK + ["analysis.epmc.workers=1"]), tmp_path / "serial.h5")
    attrs = assert_same_run(tmp_path / "auto.h5", tmp_path / "serial.h5")
    assert attrs["indicator_workers"] == 1
    with h5py.File(tmp_path / "auto.h5", "r") as h5:
        assert h5["epmc/y"].shape[1] < ip.POOL_MIN_UNKNOWNS
    assert ip.pool_workers(0, n_unknowns=ip.POOL_MIN_UNKNOWNS - 1) == 1
    assert ip.pool_workers(2, n_unknowns=15) == 2
    assert ip.pool_workers(0, n_unknowns=ip.POOL_MIN_UNKNOWNS) == (os.cpu_count() or 1)


def test_pool_gives_the_serial_indicators_on_the_sdof_epmc(tmp_path):
    sc1 = load_scene(SDOF, QUICK + ["analysis.epmc.workers=1"])
    sc2 = load_scene(SDOF, QUICK + ["analysis.epmc.workers=2"])
    run_scene(sc1, tmp_path / "serial.h5")
    run_scene(sc2, tmp_path / "pool.h5")
    attrs = assert_same_run(tmp_path / "pool.h5", tmp_path / "serial.h5")
    assert attrs["indicator_workers"] == 2
    with h5py.File(tmp_path / "serial.h5", "r") as h5:
        assert h5["epmc"].attrs["indicator_workers"] == 1
        assert h5["epmc/omega"].shape[0] > 30


@pytest.mark.slow
def test_pool_gives_the_serial_indicators_on_the_coarse_fe_joint(tmp_path):
    """Coupled N, through the stuck onset into microslip."""
    ov = NO_FULL + ["analysis.epmc.log10_amplitude_start=-4.5",
                    "analysis.epmc.log10_amplitude_end=-3.3"]
    assert_same_run(*_pool_and_serial(tmp_path, "epmc", ov))


def _pool_and_serial(tmp_path, analysis: str, ov: list[str]):
    """Run the coupled coarse FE joint's ``analysis`` with 2 workers and with 1; the
    two result files (pool, serial)."""
    out = []
    for workers in (2, 1):
        f = tmp_path / f"workers{workers}.h5"
        run_scene(lap_scene(COUPLED, ("modes", analysis),
                            ov + [f"analysis.{analysis}.workers={workers}"]), f)
        out.append(f)
    return out


@pytest.mark.parametrize("workers", [2, pytest.param(1, marks=pytest.mark.slow)])
def test_interrupted_run_resumes_to_the_same_indicators(tmp_path, monkeypatch, workers):
    """Ctrl-C after 20 points (indicators of the last ones still on the workers: NaN
    in the file); --resume computes them and continues: every row as uninterrupted."""
    sc = load_scene(SDOF, QUICK + [f"analysis.epmc.workers={workers}"])
    full = tmp_path / "full.h5"
    run_scene(sc, full)
    part = tmp_path / "part.h5"
    run_interrupted_after(sc, part, 20, monkeypatch, dataset="epmc/amplitude")
    with h5py.File(part, "r") as h5:
        assert h5.attrs["status"] == "interrupted" and h5["epmc/omega"].shape[0] == 20
        assert h5["epmc/error_estimate"].shape[0] == 20
    run_scene(sc, part, resume=True)
    with h5py.File(part, "r") as h5:
        assert h5.attrs["status"] == "complete"
        assert missing_error_indicators(h5, "epmc").size == 0
    a, _ = _datasets(part)
    b, _ = _datasets(full)
    for k in b:
        if k.startswith("error_"):
            assert np.allclose(a[k], b[k], rtol=1e-9, atol=0), (k, np.abs(a[k] / b[k] - 1).max())
        elif k in ("y", "omega", "xi", "X"):
            assert np.abs(a[k] - b[k]).max() <= 1e-8 * np.abs(b[k]).max(), k


def test_nan_rows_of_a_complete_file_are_computed_on_resume(tmp_path):
    """A complete file whose indicator rows 3 and 7 are NaN (a worker died there)
    gets them on --resume, equal to the stored run's, nothing else recomputed."""
    sc = load_scene(SDOF, QUICK + ["analysis.epmc.workers=2"])
    out = tmp_path / "e.h5"
    run_scene(sc, out)
    ref, _ = _datasets(out)
    with h5py.File(out, "a") as h5:
        for name in h5["epmc"]:
            if name.startswith("error_"):
                h5["epmc"][name][[3, 7]] = np.nan
        assert list(missing_error_indicators(h5, "epmc")) == [3, 7]
    run_scene(sc, out, resume=True)
    got, _ = _datasets(out)
    for k in ref:
        if k.startswith("error_"):
            assert np.allclose(got[k], ref[k], rtol=1e-9, atol=0), k
        else:
            assert np.array_equal(got[k], ref[k], equal_nan=True), k


#: the test process: the functions below kill a forked worker only (the draining
#: process computes the rows no worker is left for, IndicatorPool.drain)
TEST_PID = os.getpid()


def _square_or_die(x, die_at):
    if x == die_at and os.getpid() != TEST_PID:
        os._exit(3)
    return x * x


def _die_in_a_worker(x):
    if os.getpid() != TEST_PID:
        os._exit(1)
    return -x


def test_a_dying_worker_loses_only_its_row():
    """Rows queued behind the one a worker died on go on (to the other worker, or to
    this process once it drains).  Row 1 is the second worker's first: the results are
    polled until it has died on it, before the drain (which could otherwise compute
    the row here if the worker had not started it yet)."""
    import time

    with IndicatorPool(lambda x: _square_or_die(x, 1), 2, "test") as pool:
        for r in range(12):
            pool.submit(r, r)
        got = {}
        deadline = time.monotonic() + 60.0
        while not pool.lost and time.monotonic() < deadline:
            got.update(pool.poll(timeout=0.5))
        pool.drain(got.__setitem__)
    assert pool.lost == [1]
    assert got == {r: (None if r == 1 else r * r) for r in range(12)}


def _pid_after(x, wait_at):
    """``(x squared, the computing process)``; a worker sleeps on row ``wait_at``."""
    import time
    if x == wait_at and os.getpid() != TEST_PID:
        time.sleep(1.0)
    return x * x, os.getpid()


def test_the_drain_computes_here_the_rows_no_worker_has_started(caplog):
    """A row queued behind a busy worker's is taken back off its queue and computed by
    the draining process (once: the worker does not compute it too); every row's result
    comes once, and the same as from a worker."""
    with IndicatorPool(lambda x: _pid_after(x, 0), 1, "test") as pool:
        for r in range(2):
            pool.submit(r, r)
        assert pool.pending == 2 and pool._queued()
        got = {}

        def once(row, res):
            assert row not in got
            got[row] = res
        with caplog.at_level(logging.INFO, logger="jointsim.analyses.indicator_pool"):
            pool.drain(once)
        assert pool.pending == 0 and not pool._queued()
        assert pool.poll(timeout=0.2) == []      # nothing more comes from the worker
    assert {r: v[0] for r, v in got.items()} == {0: 0, 1: 1}
    pids = [v[1] for v in got.values()]
    assert pids.count(TEST_PID) == 1 and len(set(pids)) == 2
    assert "1 point(s)' error indicators computed here while draining" in caplog.text


def test_the_drain_leaves_the_backlog_to_the_workers():
    """Rows beyond ``DEPTH`` a worker wait in the backlog; while a worker is alive the
    drain leaves them to it (taken here, a row would hold back the worker's next ones):
    with one worker busy on row 0 and rows 2 and 3 in the backlog, rows 0 to 2 are the
    worker's (row 1 was assigned to it while the backlog still waited, row 2 from the
    backlog); only row 3, queued behind row 2 once the backlog is empty, may be taken."""
    from jointsim.analyses.indicator_pool import DEPTH

    with IndicatorPool(lambda x: _pid_after(x, 0), 1, "test") as pool:
        for r in range(DEPTH + 2):
            pool.submit(r, r)
        assert len(pool.backlog) == 2
        got = {}
        pool.drain(got.__setitem__)
    assert {r: v[0] for r, v in got.items()} == {r: r * r for r in range(DEPTH + 2)}
    assert all(got[r][1] != TEST_PID for r in range(DEPTH + 1))


def test_every_worker_dead_loses_only_their_rows_without_hanging():
    """The rows the dead workers were computing are lost; this process computes the rest."""
    with IndicatorPool(_die_in_a_worker, 2, "test") as pool:
        for r in range(6):
            pool.submit(r, r)
        got = {}
        pool.drain(got.__setitem__)
    assert 1 <= len(pool.lost) <= 2 and sorted(got) == list(range(6))
    assert got == {r: (None if r in pool.lost else -r) for r in range(6)}


def _interrupted_in_numba(x):
    # what a signal handled while a numba kernel runs looks like to the caller
    try:
        raise KeyboardInterrupt("stopped by SIGINT")
    except KeyboardInterrupt as e:
        raise SystemError("returned a result with an exception set") from e


def test_an_interrupt_inside_a_row_is_not_a_failed_row():
    """A row whose computation is interrupted (the parent computing the rows no worker
    is left for) raises the interrupt instead of reporting the row as failed and going
    on; a row's own error is still reported."""
    from jointsim.analyses.indicator_pool import _compute

    assert _compute(_fail_on_three, 3, (3,)) == ("error", 3, "ValueError: three")
    with pytest.raises(SystemError) as info:
        _compute(_interrupted_in_numba, 0, (0,))
    assert isinstance(info.value.__cause__, KeyboardInterrupt)


def _fail_on_three(x):
    if x == 3:
        raise ValueError("three")
    return x + 1


@pytest.mark.parametrize("workers_alive", [True, False])
def test_a_row_that_raises_is_reported_and_the_rest_go_on(workers_alive):
    """In a worker or, once no worker is left, in this process: ``(row, None)``, the
    message kept in ``errors``, every other row computed."""
    with IndicatorPool(_fail_on_three, 2, "test") as pool:
        if not workers_alive:
            for w in pool.workers:
                w["proc"].kill()
                w["proc"].join()
            assert pool.poll() == [] and not any(w["alive"] for w in pool.workers)
        for r in range(6):
            pool.submit(r, r)
        got = {}
        pool.drain(got.__setitem__)
    assert got == {r: (None if r == 3 else r + 1) for r in range(6)}
    assert pool.errors == [(3, "ValueError: three")] and pool.lost == []


def test_epmc_whose_indicator_workers_all_die_computes_the_rest_itself(tmp_path,
                                                                        monkeypatch, caplog):
    """A real run: every indicator worker dies on its first point (a forked process
    exits); the continuing process computes every other point's indicators, equal to
    the serial run's, and only the points the workers died on stay NaN (warned)."""
    from jointsim.solvers.indicators import ErrorEstimator

    run_scene(load_scene(SDOF, QUICK + ["analysis.epmc.workers=1"]), tmp_path / "s.h5")
    epmc = ErrorEstimator.epmc

    def die_in_a_worker(self, *args, **kw):
        if os.getpid() != TEST_PID:
            os._exit(1)
        return epmc(self, *args, **kw)

    monkeypatch.setattr(ErrorEstimator, "epmc", die_in_a_worker)
    run_scene(load_scene(SDOF, QUICK + ["analysis.epmc.workers=2"]), tmp_path / "p.h5")
    got, _ = _datasets(tmp_path / "p.h5")
    ref, _ = _datasets(tmp_path / "s.h5")
    lost = np.flatnonzero(np.isnan(got["error_estimate"]))
    assert 1 <= lost.size <= 2 and got["error_estimate"].size > 30
    for k in ref:
        if k.startswith("error_"):
            keep = np.ones(ref[k].shape[0], dtype=bool)
            keep[lost] = False
            assert np.allclose(got[k][keep], ref[k][keep], rtol=1e-9, atol=0), k
    assert any("no indicator worker is left" in r.getMessage() for r in caplog.records)


def test_in_order_releases_rows_in_registration_order():
    o = InOrder()
    for r in (2, 5, 9):
        o.expect(r)
    assert o.add(9, "c") == [] and o.add(5, "b") == []
    assert o.add(2, "a") == [(2, "a"), (5, "b"), (9, "c")]


def test_set_row_overwrites_a_committed_row(tmp_path):
    sc = load_scene(SDOF, QUICK)
    with ResultWriter(tmp_path / "w.h5", sc) as w:
        with w.commit():
            w.append_rows("epmc/omega", np.arange(3.0), "rad/s")
        with w.commit():
            w.set_row("epmc/omega", 1, 7.0)
        with pytest.raises(IndexError):
            w.set_row("epmc/omega", 3, 1.0)
    with h5py.File(tmp_path / "w.h5", "r") as h5:
        assert list(h5["epmc/omega"][()]) == [0.0, 7.0, 2.0]
        assert h5["epmc/omega"].attrs["committed_rows"] == 3


def test_the_tolerance_warning_names_the_first_point_in_row_order(tmp_path, caplog):
    """Results coming back in reverse order still warn about the first row above tol."""
    from jointsim.solvers.indicators import ErrorIndicators

    sc = load_scene(SDOF, QUICK)
    with ResultWriter(tmp_path / "w.h5", sc) as w:
        with w.commit():
            for name in ("omega", "error_estimate", "error_truncation", "error_aliasing",
                         "error_force_tail", "error_frequency", "error_damping"):
                w.append_rows(f"epmc/{name}", np.full(4, np.nan), "1")
        inds = PointIndicators(w, "epmc", None, ToleranceWatch(1e-2, "epmc"), 1)
        for r in range(4):
            inds.order.expect(r)
            inds.where[r] = (0, f"row {r}")
        for r in (3, 2, 1, 0):
            inds._write(r, ErrorIndicators(0.1 * r, 0.0, 0.1 * r, 0.0))
    warned = [rec.getMessage() for rec in caplog.records if rec.levelname == "WARNING"]
    assert len(warned) == 1 and "at point 1 (row 1)" in warned[0]
    with h5py.File(tmp_path / "w.h5", "r") as h5:
        assert np.allclose(h5["epmc/error_estimate"][()], [0.0, 0.1, 0.2, 0.3])


# -- FRC: one branch in this process, its indicators on the pool ---------------------
CHAIN = MODELS / "hbm" / "chain2_jenkins.toml"
CHAIN_QUICK = ["analysis.hbm.force_scale=[0.2]", "analysis.hbm.harmonics=[0, 1, 3]",
               "analysis.hbm.n_samples=32"]


def _frc_same(pooled, serial):
    a, attrs = _datasets(pooled, "hbm")
    b, _ = _datasets(serial, "hbm")
    assert sorted(a) == sorted(b)
    for k in b:
        if k.startswith("error_"):
            assert not np.isnan(a[k]).any(), k
            assert np.allclose(a[k], b[k], rtol=1e-9, atol=0), k
        else:
            assert np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"), k
    return attrs


def test_frc_pool_gives_the_serial_indicators(tmp_path):
    run_scene(load_scene(CHAIN, CHAIN_QUICK + ["analysis.hbm.workers=1"]), tmp_path / "s.h5")
    run_scene(load_scene(CHAIN, CHAIN_QUICK + ["analysis.hbm.workers=2"]), tmp_path / "p.h5")
    attrs = _frc_same(tmp_path / "p.h5", tmp_path / "s.h5")
    assert attrs["indicator_workers"] == 2
    with h5py.File(tmp_path / "p.h5", "r") as h5:
        assert h5["hbm/omega"].shape[0] > 50


@pytest.mark.parametrize("extra", [[], ["effects.friction=false"]],
                         ids=["slipping", "no_contact_unknowns"])
def test_frc_workers_leave_the_indicators_to_the_parent_once_a_core_is_free(
        tmp_path, caplog, monkeypatch, extra):
    """Two branches on two workers: once one is done and a core is free, the worker still
    running leaves some of its next points' indicators to the parent (at most
    ``DEFER_BACKLOG`` waiting at a time), which computes them as it writes the points
    (their number is logged).  The lumped branches are too quick to overlap reliably,
    so branch 0's worker starts its branch only once the parent has signalled the free
    core (when branch 1 is done).  Every row equals the serial run's (branch by branch:
    the rows of the two runs interleave differently); without friction the chain has no
    contact unknowns and every indicator is 0 (they were left NaN once)."""
    import jointsim.analyses.hbm as hbm_runner

    ov = ["analysis.hbm.force_scale=[0.001, 0.2]", "analysis.hbm.harmonics=[0, 1, 3]",
          "analysis.hbm.n_samples=32"] + extra
    run_scene(load_scene(CHAIN, ov + ["analysis.hbm.workers=1"]), tmp_path / "s.h5")
    process = hbm_runner._branch_process

    def late(job, job_args, queue, parent_pid, defer=None):
        if job.ib == 0 and not defer.wait(120):
            raise RuntimeError("no free core signalled")
        process(job, job_args, queue, parent_pid, defer)
    monkeypatch.setattr(hbm_runner, "_branch_process", late)
    with caplog.at_level(logging.INFO, logger="jointsim.analyses.hbm"):
        run_scene(load_scene(CHAIN, ov + ["analysis.hbm.workers=2"]), tmp_path / "p.h5")
    assert "a core is free: the error indicators of branch(es) [0]" in caplog.text
    n = re.findall(r"hbm: (\d+) point\(s\)' error indicators computed here", caplog.text)
    a, _ = _datasets(tmp_path / "p.h5", "hbm")
    b, _ = _datasets(tmp_path / "s.h5", "hbm")
    assert len(n) == 1 and 1 <= int(n[0]) <= np.count_nonzero(a["branch"] == 0), n
    for branch in (0, 1):
        ma, mb = a["branch"] == branch, b["branch"] == branch
        for k in b:
            if k.startswith("error_"):
                assert not np.isnan(a[k]).any(), k
                assert np.allclose(a[k][ma], b[k][mb], rtol=1e-9, atol=0), k
                assert not extra or not a[k].any(), k
            elif k in ("omega", "q", "X"):
                assert np.array_equal(a[k][ma], b[k][mb]), k


def test_deferral_leaves_at_most_the_backlog_to_the_parent():
    """:class:`Deferral`: no point is left before a core is free; then the workers leave
    points while the parent holds fewer than ``DEFER_BACKLOG`` (whichever worker), and
    each one the parent computes lets one more go."""
    import multiprocessing as mp

    from jointsim.analyses.forking import DEFER_BACKLOG, Deferral
    d = Deferral(mp.get_context("fork"), 3)
    assert not d.take(0) and not d.started and not d.wait(0.01)
    d.start()
    assert d.started and d.wait(0.01)
    assert [d.take(k % 2) for k in range(DEFER_BACKLOG + 2)] == \
        [True] * DEFER_BACKLOG + [False, False]
    d.computed()
    assert d.take(2) and not d.take(0)
    for _ in range(DEFER_BACKLOG):
        d.computed()
    assert all(d.take(1) for _ in range(DEFER_BACKLOG)) and not d.take(1)


def test_frc_interrupted_with_indicators_pending_resumes_to_the_same_file(tmp_path,
                                                                          monkeypatch):
    sc = load_scene(CHAIN, CHAIN_QUICK + ["analysis.hbm.workers=2"])
    run_scene(sc, tmp_path / "full.h5")
    part = tmp_path / "part.h5"
    run_interrupted_after(sc, part, 30, monkeypatch)
    run_scene(sc, part, resume=True)
    with h5py.File(part, "r") as h5:
        assert h5.attrs["status"] == "complete"
    a, _ = _datasets(part, "hbm")
    b, _ = _datasets(tmp_path / "full.h5", "hbm")
    for k in b:
        if k.startswith("error_"):   # the points before the interrupt as they were,
            # those after it retrace the branch to round-off (1e-9 of ||q||), and so do
            # their indicators (some are round-off themselves, 1e-17)
            assert np.allclose(a[k][:30], b[k][:30], rtol=1e-9, atol=0), k
            assert not np.isnan(a[k]).any(), k
            assert np.abs(a[k] - b[k]).max() <= 1e-6 * np.abs(b[k]).max(), k
        elif k in ("omega", "q", "X"):
            assert np.abs(a[k] - b[k]).max() <= 1e-8 * np.abs(b[k]).max(), k


@pytest.mark.slow
def test_frc_pool_gives_the_serial_indicators_on_the_coarse_fe_joint(tmp_path):
    """One coupled-N branch at force scale 20 around the resonance."""
    ov = NO_FULL + ["analysis.hbm.force_scale=[20.0]", "analysis.hbm.omega_start=960",
                    "analysis.hbm.omega_end=1000"]
    _frc_same(*_pool_and_serial(tmp_path, "hbm", ov))
