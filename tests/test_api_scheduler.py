"""The exact-FRT scheduler: dedupe, waiting with a deadline, LRU, superseded versions, failures."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator

import pytest

from service.metrics import Metrics
from service.scheduler import FRTKey, FRTScheduler


@pytest.fixture
def scheduler() -> Iterator[FRTScheduler]:
    s = FRTScheduler(workers=1, cache_size=2, metrics=Metrics())
    s.start()
    yield s
    s.shutdown()


def key(agent: str, version: int) -> FRTKey:
    return FRTKey.of(agent, version, [float(version), 1.0])


def run(scheduler: FRTScheduler, k: FRTKey, value: object) -> object:
    """Compute ``k`` and wait until it is cached (done-callbacks may run after ``result()``)."""
    return asyncio.run(scheduler.wait(k, lambda: value, 5.0))


def test_keys_depend_on_the_inputs() -> None:
    assert FRTKey.of("a", 1, [1.0, 2.0]) == FRTKey.of("a", 1, [1.0, 2.0])
    assert FRTKey.of("a", 1, [1.0, 2.0]) != FRTKey.of("a", 1, [1.0, 2.5])


def test_wait_returns_none_at_the_deadline_and_the_result_lands_later(
    scheduler: FRTScheduler,
) -> None:
    release = threading.Event()
    calls = []

    def slow() -> str:
        calls.append(1)
        release.wait(5)
        return "exact"

    async def scenario() -> None:
        assert await scheduler.wait(key("a", 1), slow, 0.01) is None
        assert await scheduler.wait(key("a", 1), slow, 0.0) is None  # under way: not started again
        release.set()
        assert await scheduler.wait(key("a", 1), slow, 5.0) == "exact"

    asyncio.run(scenario())
    assert calls == [1]
    assert scheduler.is_ready(key("a", 1)) and scheduler.lookup(key("a", 1)) == "exact"


def test_cache_is_a_bounded_lru(scheduler: FRTScheduler) -> None:
    for version in (1, 2, 3):
        assert run(scheduler, key("s", version), version) == version
    assert not scheduler.is_ready(key("s", 1))
    assert scheduler.is_ready(key("s", 2)) and scheduler.is_ready(key("s", 3))


def test_superseded_queued_versions_are_cancelled(scheduler: FRTScheduler) -> None:
    gate = threading.Event()
    blocker = scheduler.submit(key("x", 1), lambda: gate.wait(5))
    old = scheduler.submit(key("a", 1), lambda: "old")
    new = scheduler.submit(key("a", 2), lambda: "new")
    assert old.cancelled()
    gate.set()
    assert blocker.result(5) is True and new.result(5) == "new"


def test_failures_are_not_cached(scheduler: FRTScheduler) -> None:
    def boom() -> str:
        raise RuntimeError("engine failed")

    async def scenario() -> None:
        assert await scheduler.wait(key("f", 1), boom, 5.0) is None
        assert await scheduler.wait(key("f", 1), lambda: "ok", 5.0) == "ok"

    asyncio.run(scenario())


def test_forget_drops_an_agents_sets(scheduler: FRTScheduler) -> None:
    run(scheduler, key("a", 1), 1)
    scheduler.forget("a")
    assert not scheduler.is_ready(key("a", 1))


def test_queued_sets_are_not_waited_for_by_collision_checks(scheduler: FRTScheduler) -> None:
    gate = threading.Event()
    scheduler.submit(key("busy", 1), lambda: gate.wait(5))  # occupies the only worker
    scheduler.submit(key("q", 1), lambda: "late")  # queued behind it

    async def scenario() -> None:
        loop = asyncio.get_running_loop()
        start = loop.time()
        assert await scheduler.wait(key("q", 1), lambda: "late", 2.0, wait_if_queued=False) is None
        assert loop.time() - start < 0.5
        gate.set()
        assert await scheduler.wait(key("q", 1), lambda: "late", 5.0) == "late"

    asyncio.run(scenario())
