"""The exact-FRT scheduler: dedupe, waiting with a deadline, LRU, superseded versions, failures,
worker processes."""

from __future__ import annotations

import asyncio
import multiprocessing
import os
import pickle
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.engine import FRTEngine
from reach.frames import Pose
from service.runtime.demand import ExactDemand
from service.runtime.exact_worker import ExactTask, start_pool
from service.runtime.metrics import Metrics
from service.runtime.scheduler import (
    EXACT_OLDEST_AFTER_S,
    FRTKey,
    FRTScheduler,
    LRUCache,
)
from service.runtime.services import Services
from service.runtime.settings import Settings


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


def test_an_agent_keeps_its_two_latest_versions_only() -> None:
    s = FRTScheduler(workers=1, cache_size=100, metrics=Metrics())
    s.start()
    try:
        for version in range(1, 6):
            run(s, key("a", version), version)
            run(s, key("b", version), -version)
        for agent in ("a", "b"):
            assert [v for v in range(1, 6) if s.is_ready(key(agent, v))] == [4, 5]
        assert s.lookup(key("a", 5)) == 5 and s.lookup(key("b", 4)) == -4
        # Versions that restart (an agent deleted elsewhere and created again) are the latest too.
        run(s, key("a", 1), "again")
        assert s.lookup(key("a", 1)) == "again" and s.is_ready(key("a", 5))
        assert not s.is_ready(key("a", 4))
        # The stateless endpoint's sets (agent "") are bounded by the cache size only.
        for version in range(1, 6):
            run(s, key("", version), version)
        assert all(s.is_ready(key("", v)) for v in range(1, 6))
    finally:
        s.shutdown()


def test_conservative_cache_keeps_two_versions_and_forgets_agents() -> None:
    cache = LRUCache(size=3)
    for version in (1, 2, 3):
        assert cache.get_or_compute(key("a", version), lambda v=version: v) == (version, False)
    assert cache.get(key("a", 1)) is None and cache.get(key("a", 2)) == 2
    assert cache.get_or_compute(key("a", 3), lambda: "recomputed") == (3, True)
    cache.put(key("b", 1), "b1")
    cache.put(key("c", 1), "c1")  # over the size: the least recently used (a 2) goes
    assert len(cache) == 3 and cache.get(key("a", 2)) is None
    cache.forget("a")
    assert key("a", 3) not in cache and cache.get(key("b", 1)) == "b1" and len(cache) == 2
    for version in (4, 5, 6):  # b's list of keys shrank with the eviction: still two kept
        cache.put(key("b", version), version)
    assert [v for v in (1, 4, 5, 6) if key("b", v) in cache] == [5, 6]


def test_forgetting_an_agent_drops_its_exact_and_conservative_sets() -> None:
    services = Services.build(Settings())
    services.scheduler.start()
    try:
        run(services.scheduler, key("a", 1), "exact a")
        run(services.scheduler, key("b", 1), "exact b")
        for agent in ("a", "b"):
            services.conservative_cache.put(key(agent, 1), f"boxes {agent}")
        services.forget("a")
        assert not services.scheduler.is_ready(key("a", 1)) and key("a", 1) not in (
            services.conservative_cache
        )
        assert services.scheduler.lookup(key("b", 1)) == "exact b"
        assert services.conservative_cache.get(key("b", 1)) == "boxes b"
    finally:
        services.scheduler.shutdown()


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
    """Before any set has been timed, a queued set's turn cannot be foreseen: not waited for."""
    gate = threading.Event()
    scheduler.submit(key("busy", 1), lambda: gate.wait(5))  # occupies the only worker
    scheduler.submit(key("q", 1), lambda: "late")  # queued behind it

    async def scenario() -> None:
        assert scheduler.waitable(key("q", 1), lambda: "late", 2.0) is None  # answered at once
        gate.set()
        assert await scheduler.wait(key("q", 1), lambda: "late", 5.0) == "late"

    asyncio.run(scenario())


def test_a_queued_set_is_waited_for_when_its_turn_is_due(scheduler: FRTScheduler) -> None:
    """At the workers' recent pace (here: 0.1 s per set, one worker) the set queued last, which
    starts next, is due in about 0.2 s, within a 0.5 s wait, so a check waits for it; the one
    queued before it is due in about 0.3 s, past a 0.15 s wait."""
    gate = threading.Event()
    scheduler._typical_s = 0.1
    scheduler.submit(key("busy", 1), lambda: gate.wait(5))  # occupies the only worker
    scheduler.submit(key("earlier", 1), lambda: "earlier")
    scheduler.submit(key("later", 1), lambda: "later")
    finish = scheduler.queued_finish_s()
    assert finish[key("earlier", 1)] > finish[key("later", 1)] > 0.0
    assert scheduler.waitable(key("earlier", 1), lambda: "earlier", 0.15) is None
    waited = scheduler.waitable(key("later", 1), lambda: "later", 0.5)
    assert waited is not None and not waited.done()
    gate.set()
    assert waited.result(5) == "later"


def test_a_running_set_not_due_within_the_wait_is_not_waited_for(scheduler: FRTScheduler) -> None:
    """At the workers' recent pace (here: a minute per set) a running set cannot make a check's
    wait, so the check does not spend it; the set still lands in the cache."""
    gate = threading.Event()
    scheduler.submit(key("slow", 1), lambda: gate.wait(30) and "done")
    scheduler._typical_s = 60.0
    threading.Timer(0.2, gate.set).start()

    async def scenario() -> None:
        got = scheduler.waitable(key("slow", 1), lambda: "x", 30.0)
        assert got is None  # not waited for, though it finishes long before the timeout
        assert await scheduler.wait(key("slow", 1), lambda: "x", 30.0) == "done"

    asyncio.run(scenario())


def test_a_version_older_than_one_running_is_not_started(scheduler: FRTScheduler) -> None:
    gate = threading.Event()
    calls: list[str] = []
    running = scheduler.submit(key("a", 5), lambda: gate.wait(5))
    stale = scheduler.submit(key("a", 4), lambda: calls.append("stale"))
    assert stale.cancelled()
    gate.set()
    assert running.result(5) is True
    assert run(scheduler, key("b", 1), "next") == "next"  # the worker moved on
    assert calls == []


def test_a_newer_version_replaces_its_agents_queued_one_and_goes_first(
    scheduler: FRTScheduler,
) -> None:
    """An agent observed faster than its sets are computed is not starved by the others: its
    newest version replaces the queued one and, submitted last, starts first."""
    gate = threading.Event()
    order: list[str] = []
    scheduler.submit(key("busy", 1), lambda: gate.wait(5))
    x1 = scheduler.submit(key("x", 1), lambda: order.append("x1"))
    y1 = scheduler.submit(key("y", 1), lambda: order.append("y1"))
    scheduler.submit(key("x", 2), lambda: order.append("x2"))
    assert x1.cancelled()
    gate.set()
    y1.result(5)
    assert order == ["x2", "y1"]


def test_the_newest_set_starts_first_and_a_long_queued_one_next(scheduler: FRTScheduler) -> None:
    """Newest first while the oldest queued has waited less than EXACT_OLDEST_AFTER_S; past it,
    the oldest goes next (an agent observed rarely is not passed over for ever)."""
    gate = threading.Event()
    order: list[str] = []
    scheduler.submit(key("busy", 1), lambda: gate.wait(5))
    for agent in ("old", "a", "b"):
        scheduler.submit(key(agent, 1), lambda agent=agent: order.append(agent))
    # "old" has waited past the limit: it goes first, then the newest of the rest.
    scheduler._pending[key("old", 1)].submitted -= EXACT_OLDEST_AFTER_S + 0.1
    last = scheduler.submit(key("c", 1), lambda: order.append("c"))
    gate.set()
    last.result(5)
    for agent in ("a", "b"):
        scheduler.submit(key(agent, 1), lambda: None).result(5)
    assert order == ["old", "c", "b", "a"]


@pytest.fixture(scope="module")
def engine(analytic_model_path: Path) -> FRTEngine:
    return engine_for(ValueModel.load(analytic_model_path))


BOUNDS = np.array([-0.3, -2.0, -0.2, -1.0, 0.3, 1.5, 0.25, 2.0])


def test_exact_sets_pickle_with_their_lazy_parts(engine: FRTEngine) -> None:
    frt = engine.exact(Pose(3.0, -2.0, 0.4), 6.0, BOUNDS)
    copy = pickle.loads(pickle.dumps(frt))
    assert type(copy) is type(frt)
    assert copy.tube(copy.n_slices - 1).equals(frt.tube(frt.n_slices - 1))
    assert copy.slice(10).equals(frt.slice(10))  # drawn after the trip, from the shipped fields
    assert copy.geojson("slice", 2.0, 1.5) == frt.geojson("slice", 2.0, 1.5)


def test_an_exact_set_from_a_worker_holds_few_objects_for_the_garbage_collector(
    engine: FRTEngine,
) -> None:
    """Cached exact sets are what full collections walk: their slice fields and the outer windows'
    polygons must not come back as ~100 tracked objects each (35 ms pauses with 1024 cached)."""
    import gc

    frt = engine.exact(Pose(3.0, -2.0, 0.4), 6.0, BOUNDS)
    data = pickle.dumps(frt)
    gc.collect()
    before = len(gc.get_objects())
    copy = pickle.loads(data)
    gc.collect()
    assert len(gc.get_objects()) - before <= 30
    t_rel = np.linspace(0.0, 3.0, 40)
    xy = np.stack([np.linspace(-5, 30, 40), np.full(40, -1.0)], axis=1)
    assert np.array_equal(copy.clearance(xy, t_rel), frt.clearance(xy, t_rel))  # tubes rebuilt


def test_worker_processes_compute_the_same_set_as_threads(
    engine: FRTEngine, analytic_model_path: Path
) -> None:
    pose, v_start = Pose(3.0, -2.0, 0.4), 6.0
    here = engine.exact(pose, v_start, BOUNDS)
    s = FRTScheduler(workers=1, cache_size=4, metrics=Metrics())
    s.start()
    s.use_executor(start_pool(analytic_model_path, workers=1, nice=0))
    try:
        task = ExactTask(pose, v_start, BOUNDS, engine)
        there = asyncio.run(s.wait(key("p", 1), task, 60.0))
    finally:
        s.shutdown()
    assert there is not None and there is not here
    rng = np.random.default_rng(0)
    xy = rng.uniform(-20.0, 40.0, size=(300, 2))
    t_rel = rng.uniform(0.0, 3.0, size=300)
    assert np.array_equal(there.clearance(xy, t_rel), here.clearance(xy, t_rel))
    assert np.array_equal(there.clearance(xy), here.clearance(xy))
    assert there.slice(20).equals(here.slice(20))


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="Linux scheduling policies")
@pytest.mark.parametrize(("policy", "expected"), [("idle", "SCHED_IDLE"), ("batch", "SCHED_BATCH")])
def test_worker_processes_run_below_the_server(
    analytic_model_path: Path, policy: str, expected: str
) -> None:
    pool = start_pool(analytic_model_path, workers=1, nice=3, policy=policy)
    try:
        (pid,) = pool.pids
        assert os.sched_getscheduler(pid) == getattr(os, expected)
        assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the server's own is left alone
        niceness = os.getpriority(os.PRIO_PROCESS, pid) - os.getpriority(os.PRIO_PROCESS, 0)
        assert niceness == (3 if policy == "batch" else 0)
    finally:
        pool.shutdown()


class _DiesInAWorker:
    """A task that kills the worker process running it, but works in the server's own."""

    def __init__(self) -> None:
        self.parent = os.getpid()

    def __call__(self) -> str:
        if os.getpid() != self.parent:
            os._exit(1)
        return "on a thread"


def test_a_broken_worker_pool_falls_back_to_threads() -> None:
    s = FRTScheduler(workers=1, cache_size=4, metrics=Metrics())
    s.start()
    s.use_executor(ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")))
    s.refinement = lambda compute, result: None
    try:
        assert asyncio.run(s.wait(key("d", 1), _DiesInAWorker(), 60.0)) == "on a thread"
        assert run(s, key("d", 2), "still computing") == "still computing"
        assert s.refinement is None  # on threads refinements would hold the event loop's GIL
    finally:
        s.shutdown()


def test_demanded_agents_sets_start_before_the_others(scheduler: FRTScheduler) -> None:
    """Queued sets of agents a check came near go first (newest first among them); the rest
    after, by the usual rule."""
    scheduler.demand = ExactDemand(hold_s=60.0, size=16)
    scheduler.demand.note(["near-1", "near-2"])
    gate = threading.Event()
    order: list[str] = []
    scheduler.submit(key("busy", 1), lambda: gate.wait(5))
    for agent in ("near-1", "far-1", "near-2", "far-2"):
        scheduler.submit(key(agent, 1), lambda agent=agent: order.append(agent))
    last = scheduler.submit(key("far-3", 1), lambda: order.append("far-3"))
    gate.set()
    last.result(5)
    for agent in ("far-1", "far-2"):
        scheduler.submit(key(agent, 1), lambda: None).result(5)
    assert order == ["near-2", "near-1", "far-3", "far-2", "far-1"]
    starts = scheduler._metrics.exact_set_starts
    assert starts.labels("demanded")._value.get() == 2
    assert starts.labels("background")._value.get() >= 3


def test_the_sets_of_agents_a_trajectory_met_start_before_the_other_demanded_ones(
    scheduler: FRTScheduler,
) -> None:
    """Among demanded agents, those whose sets a check's trajectory met go first (newest first
    among them), then the ones it only came near, then the rest."""
    scheduler.demand = ExactDemand(hold_s=60.0, size=16)
    scheduler.demand.note(["near-1", "near-2"])
    scheduler.demand.note(["met-1", "met-2"], met=True)
    gate = threading.Event()
    order: list[str] = []
    scheduler.submit(key("busy", 1), lambda: gate.wait(5))
    for agent in ("met-1", "near-1", "far-1", "met-2", "near-2"):
        scheduler.submit(key(agent, 1), lambda agent=agent: order.append(agent))
    last = scheduler.submit(key("far-2", 1), lambda: order.append("far-2"))
    gate.set()
    last.result(5)
    scheduler.submit(key("far-1", 1), lambda: None).result(5)
    assert order == ["met-2", "met-1", "near-2", "near-1", "far-2", "far-1"]
    ready = scheduler._metrics.registry
    counts = {
        priority: ready.get_sample_value("frt_exact_ready_seconds_count", {"priority": priority})
        for priority in ("met", "demanded", "background")
    }
    # busy, far-2, far-1, and far-1 once more (evicted from a cache of two by then)
    assert counts == {"met": 2, "demanded": 2, "background": 4}


def test_a_met_agent_ranks_above_a_near_one_and_both_expire() -> None:
    demand = ExactDemand(hold_s=1.0, size=4)
    demand.note(["near"], now=10.0)
    demand.note(["met"], now=10.0, met=True)
    assert (demand.rank("met", now=10.5), demand.rank("near", now=10.5)) == (2, 1)
    assert demand.wants("met", now=10.5) and not demand.met("near", now=10.5)
    assert demand.rank("met", now=11.0) == demand.rank("near", now=11.0) == 0
    demand.note(["met"], now=12.0)  # near again, not met: its met mark has expired
    assert demand.rank("met", now=12.5) == 1
    demand.forget("met")
    assert demand.rank("met", now=12.5) == 0


def test_demand_expires_and_is_bounded() -> None:
    demand = ExactDemand(hold_s=1.0, size=2)
    demand.note(["a"], now=10.0)
    assert demand.wants("a", now=10.5) and not demand.wants("a", now=11.0)
    demand.note(["b", "c"], now=10.0)  # "a" is the oldest noted: dropped past the size
    assert not demand.wants("a", now=10.5) and demand.wants("c", now=10.5)
    demand.forget("c")
    assert not demand.wants("c", now=10.5)


def test_while_agents_are_demanded_the_others_sets_keep_off_one_worker() -> None:
    """Two workers: with no agent demanded both take background sets; once one is, background
    sets run on one worker at most, so a demanded agent's set starts at once beside them."""
    s = FRTScheduler(workers=2, cache_size=16, metrics=Metrics())
    s.start()
    s.demand = ExactDemand(hold_s=60.0, size=16)
    gate = threading.Event()
    started: list[str] = []

    def blocked(name: str) -> Callable[[], None]:
        return lambda: (started.append(name), gate.wait(5))  # type: ignore[func-returns-value]

    try:
        s.submit(key("far-1", 1), blocked("far-1"))
        s.submit(key("far-2", 1), blocked("far-2"))
        _until(lambda: len(started) == 2)  # nobody demanded: both workers busy
        gate.set()
        _until(lambda: s.is_ready(key("far-2", 1)) and s.is_ready(key("far-1", 1)))
        gate.clear()
        s.demand.note(["near"])
        s.submit(key("far-3", 1), blocked("far-3"))
        queued = s.submit(key("far-4", 1), blocked("far-4"))
        _until(lambda: len(started) == 3)
        time.sleep(0.1)
        assert not queued.running() and len(started) == 3  # the second worker kept free
        s.submit(key("near", 1), blocked("near"))
        _until(lambda: "near" in started)
        assert not queued.running()
        gate.set()
        queued.result(5)
    finally:
        gate.set()
        s.shutdown()


def _until(condition: Callable[[], bool], timeout_s: float = 5.0) -> None:
    end = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < end, "condition not reached"
        time.sleep(0.005)


def test_an_executor_of_depth_two_is_handed_two_sets_a_worker() -> None:
    """With ``use_executor(..., depth=2)`` the scheduler hands a worker its next set while it
    computes one (the pool keeps it at hand); a third stays queued, replaceable by a newer
    version."""
    s = FRTScheduler(workers=1, cache_size=16, metrics=Metrics())
    s.start()
    s.use_executor(ThreadPoolExecutor(1), depth=2)
    gate = threading.Event()
    try:
        first = s.submit(key("a", 1), lambda: gate.wait(5))
        second = s.submit(key("b", 1), lambda: "b")
        third = s.submit(key("c", 1), lambda: "c")
        assert first.running() and second.running() and not third.running()
        newer = s.submit(key("c", 2), lambda: "c2")
        assert third.cancelled()
        gate.set()
        assert (second.result(5), newer.result(5)) == ("b", "c2")
    finally:
        gate.set()
        s.shutdown()
