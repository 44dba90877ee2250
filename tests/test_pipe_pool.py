"""The pipe-fed process pool: results, errors, a dying worker, shutdown."""

from __future__ import annotations

import os
from concurrent.futures import BrokenExecutor

import pytest

from service.runtime.pipe_pool import PipePool

_STATE: dict[str, int] = {}


def _init(value: int) -> None:
    _STATE["value"] = value


def _add(x: int) -> tuple[int, int]:
    return _STATE["value"] + x, os.getpid()


def _fail(message: str) -> None:
    raise ValueError(message)


def _die() -> None:
    os._exit(3)


def test_tasks_run_in_initialised_workers_and_errors_come_back() -> None:
    pool = PipePool(2, _init, (40,), timeout_s=60.0)
    try:
        futures = [pool.submit(_add, i) for i in range(6)]  # more tasks than workers: queued
        results = [f.result(timeout=30) for f in futures]
        assert [r for r, _ in results] == [40 + i for i in range(6)]
        assert {pid for _, pid in results} <= set(pool.pids)
        assert os.getpid() not in {pid for _, pid in results}
        with pytest.raises(ValueError, match="no"):
            pool.submit(_fail, "no").result(timeout=30)
        assert pool.submit(_add, 2).result(timeout=30)[0] == 42  # a failure breaks nothing
    finally:
        pool.shutdown()
    with pytest.raises(RuntimeError):
        pool.submit(_add, 1)


def test_a_dying_worker_breaks_the_pool() -> None:
    pool = PipePool(1, _init, (0,), timeout_s=60.0)
    try:
        with pytest.raises(BrokenExecutor):
            pool.submit(_die).result(timeout=30)
        with pytest.raises(BrokenExecutor):
            pool.submit(_add, 1)
    finally:
        pool.shutdown()


def _wait_for(path: str) -> float:
    """Block until ``path`` exists (a gate the test opens); the time it started waiting."""
    import time

    started = time.time()
    while not os.path.exists(path):
        time.sleep(0.01)
    return started


def test_a_worker_holds_up_to_depth_tasks_and_answers_them_in_order(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """With ``depth`` 2 a busy worker is sent its next task before it answers the first (it
    reads it on its own once it has written a result); a third waits in the pool's queue."""
    gate = str(tmp_path / "open")
    pool = PipePool(1, _init, (0,), timeout_s=60.0, depth=2)
    try:
        futures = [pool.submit(_wait_for, gate) for _ in range(3)]
        (worker,) = pool._workers
        assert len(worker.futures) == 2 and len(pool._queue) == 1
        assert all(f.running() for f in futures[:2]) and not futures[2].running()
        open(gate, "w").close()
        started = [f.result(timeout=30) for f in futures]
        assert started == sorted(started)  # run one after the other, in order
        assert pool.submit(_add, 5).result(timeout=30)[0] == 5
    finally:
        pool.shutdown()
    with pytest.raises(ValueError):
        PipePool(1, _init, (0,), depth=0)
