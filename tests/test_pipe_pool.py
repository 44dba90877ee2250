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
