"""Sharding batches of control jobs over worker processes (``controller.shard``): the same results as
one process, a worker's error raised as the project's error, and no worker left afterwards."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

import warp_shape as ws
from warp_shape.cli import main
from warp_shape.controller import ControlSettings
from warp_shape.controller.shard import (IDLE_AFTER, WORKERS_VARIABLE, WorkerError, WorkerPool, available_cores, current_pool,
                                         resolve_workers, worker_pool)

#: the model-based controller cut short: every stage of it runs, in seconds on 162 vertices
QUICK = ControlSettings(max_steps=60, inverse_iterations=1, inverse_plans="warm never")


@pytest.fixture(scope="module")
def small_design():
    """A 162-vertex display for the oval and the heart: one IPAM placed by the paper's rule."""
    targets = [ws.target("oval"), ws.target("heart")]
    res = ws.design(ws.icosphere(2, 0.04), targets, actuators=1, placement="paper", workers=1,
                    control_settings=ControlSettings(method="paper", max_steps=60), codesign="off")
    return res.design, targets


def _gone(pids) -> bool:
    return not any(os.path.exists(f"/proc/{pid}") for pid in pids)


def _same(a, b) -> None:
    """Two control results, bit for bit."""
    assert a.objective == b.objective and a.pcc == b.pcc and a.control_steps == b.control_steps
    np.testing.assert_array_equal(a.achieved.vertices, b.achieved.vertices)
    np.testing.assert_array_equal(a.ipam_pressures, b.ipam_pressures)
    for k in a.history:
        np.testing.assert_array_equal(a.history[k], b.history[k], err_msg=k)


def test_two_workers_give_each_target_its_single_target_run_bit_for_bit(small_design):
    """A sharded batch is one single-world job per target: the results are those of ``control``
    in this process, bit for bit, and within round-off of the batch of worlds (whose worlds share the
    smallest internal step of any of them)."""
    d, targets = small_design
    sharded = ws.control_many(d, targets, settings=QUICK.replace(workers=2), passive_cells=[[], [0]])
    alone = [ws.control(d, targets[0], settings=QUICK), ws.control(d, targets[1], settings=QUICK, passive_cells=[0])]
    for a, b in zip(sharded, alone):
        _same(a, b)
        assert a.design is d and a.refinement["method"] == "inverse"
    batch = ws.control_many(d, targets, settings=QUICK.replace(workers=1), passive_cells=[[], [0]])
    for a, b in zip(sharded, batch):
        assert abs(a.objective - b.objective) < 1e-4
        assert np.abs(a.achieved.vertices - b.achieved.vertices).max() < 1e-4  # m
        np.testing.assert_array_equal(a.passive_cells, b.passive_cells)


def test_a_design_run_on_two_workers_places_the_same_actuators_and_fits_as_well():
    """The design loop on a run's pool of 2 (started once) against one process: the same actuator
    sets, every round's objectives within 1e-4."""
    targets = [ws.target("oval"), ws.target("heart")]
    kw = dict(actuators=1, refine_rounds=1, candidates=2, control_settings=QUICK, codesign="off")  # the placement
    one = ws.design(ws.icosphere(2, 0.04), targets, workers=1, **kw)
    two = ws.design(ws.icosphere(2, 0.04), targets, workers=2, **kw)
    assert [(a["face_a"], a["face_b"]) for a in one.added] == [(a["face_a"], a["face_b"]) for a in two.added]
    np.testing.assert_allclose(two.objective_by_round, one.objective_by_round, atol=1e-4)
    assert two.passive_ipams == one.passive_ipams and two.passive_cells == one.passive_cells


def test_a_worker_error_is_the_projects_error_and_the_pool_is_gone(small_design):
    d, targets = small_design
    with worker_pool(2) as pool:
        pids = pool.start().pids
        assert len(pids) == 2 and current_pool() is pool
        with pytest.raises(ws.DesignError, match=r"passive_ipams must be indices in 0\.\.0"):
            ws.control_many(d, targets, settings=QUICK, passive_ipams=[[0], [3]])
        assert pool.pids == [] and _gone(pids)
    assert current_pool() is None


def _exit_now(code, *, progress=None):
    os._exit(code)


def _sleep(seconds, *, progress=None):
    for _ in range(int(seconds / 0.05)):
        progress(0, 1, 0, 1)
        time.sleep(0.05)
    return os.getpid()


def test_a_worker_that_dies_is_a_worker_error_and_the_others_are_ended():
    pool = WorkerPool(2)
    pids = pool.start().pids
    with pytest.raises(WorkerError, match=r"ended \(exit code 3\).*--workers 1"):
        pool.run(_exit_now, [(3,), (3,)])
    assert pool.pids == [] and _gone(pids)


def test_ctrl_c_is_the_callers_and_ends_the_pool():
    """A worker ignores SIGINT (the terminal sends it to every process of the group); a
    KeyboardInterrupt in the caller while jobs run ends every worker."""
    pool = WorkerPool(2)
    pids = pool.start().pids
    os.kill(pids[0], signal.SIGINT)
    assert sorted(pool.run(_sleep, [(0.1,), (0.1,)])) == sorted(pids)  # both alive, both worked

    def press(job, payload):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        pool.run(_sleep, [(5.0,), (5.0,)], progress=press)
    assert pool.pids == [] and _gone(pids)


def test_worker_counts(monkeypatch):
    monkeypatch.delenv(WORKERS_VARIABLE, raising=False)
    assert resolve_workers(0) == available_cores() >= 1 and resolve_workers(3) == 3
    monkeypatch.setenv(WORKERS_VARIABLE, "1")
    assert resolve_workers(0) == 1 and resolve_workers(2) == 2
    with worker_pool(0) as pool:
        assert pool is None and current_pool() is None
    monkeypatch.setenv(WORKERS_VARIABLE, "many")
    with pytest.raises(ws.DesignError, match=f"{WORKERS_VARIABLE} must be a whole number >= 1"):
        resolve_workers(0)
    for bad in (-1, 1.5, True):
        with pytest.raises(ws.DesignError, match="workers must be"):
            ws.DesignSettings(workers=bad)
        with pytest.raises(ws.DesignError, match="workers must be"):
            ws.ControlSettings(workers=bad)


def test_cli_workers_flag_is_bounded(capsys):
    assert main(["design", "--workers", "-2", "--out", "unused"]) == 2
    assert "--workers takes 0 or 1..1024" in capsys.readouterr().err


IDLE_DIR = "WARP_SHAPE_TEST_IDLE_DIR"


def _mark_idle():
    """An idle task: a file named by the worker's pid, in the folder the test names."""
    (Path(os.environ[IDLE_DIR]) / str(os.getpid())).write_text("idle")


def _fail_idle():
    raise RuntimeError("an idle task that fails")


def test_idle_tasks_run_once_in_every_worker_while_it_waits(tmp_path, monkeypatch):
    monkeypatch.setenv(IDLE_DIR, str(tmp_path))
    pool = WorkerPool(2)
    pool.when_idle(_fail_idle)  # its failure is ignored: the worker goes on
    pool.when_idle(_mark_idle)
    try:
        pids = pool.start().pids
        deadline = time.monotonic() + 60
        while len(list(tmp_path.iterdir())) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(str(p) for p in pids)
        assert sorted(pool.run(_sleep, [(0.01,), (0.01,)])) == sorted(pids)  # both alive, both work
        for p in tmp_path.iterdir():
            p.unlink()
        time.sleep(3 * IDLE_AFTER)
        assert not list(tmp_path.iterdir())  # once per worker
    finally:
        pool.close()
    assert _gone(pids)
