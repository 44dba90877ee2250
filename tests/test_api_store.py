"""The agent store: atomic updates with the timestamp check, TTL, capacity, no lost updates."""

from __future__ import annotations

import asyncio
import json
import threading
import time

import pytest

from service.runtime.stores import (
    AgentState,
    AgentStore,
    InMemoryAgentStore,
    StoreFullError,
    UpdateFn,
)
from service.wire.errors import StaleTimestampError


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def state(agent_id: str, timestamp: float, version: int = 1) -> AgentState:
    return AgentState(
        agent_id=agent_id,
        timestamp=timestamp,
        x=1.0,
        y=2.0,
        heading=0.5,
        speed=3.0,
        belief={"betas": [0.03, 1.0], "log_probs": [-0.69, -0.69]},
        prediction={"dt": 0.5, "mean": [[0.0, 0.0]], "cov": [[[1.0, 0.0], [0.0, 1.0]]]},
        control_bounds=[-1.0, -2.0, -1.0, -2.0, 1.0, 2.0, 1.0, 2.0],
        config={"gamma": 0.1},
        frt_version=version,
    )


def put(store: AgentStore, agent_id: str, timestamp: float) -> AgentState:
    def fn(previous: AgentState | None) -> AgentState:
        version = previous.frt_version + 1 if previous else 1
        return state(agent_id, timestamp, version)

    return asyncio.run(store.update(agent_id, fn, timestamp=timestamp))


def test_state_is_json_round_trippable() -> None:
    original = state("a", 1.5)
    assert AgentState.from_dict(json.loads(json.dumps(original.to_dict()))) == original


def test_in_memory_store_follows_the_protocol() -> None:
    assert isinstance(InMemoryAgentStore(ttl_s=1, max_agents=1), AgentStore)


def test_update_get_delete() -> None:
    store = InMemoryAgentStore(ttl_s=60, max_agents=10)
    assert asyncio.run(store.get("a")) is None
    assert put(store, "a", 1.0).frt_version == 1
    assert put(store, "a", 2.0).frt_version == 2
    got = asyncio.run(store.get("a"))
    assert got is not None and got.timestamp == 2.0 and got.frt_version == 2
    assert asyncio.run(store.ids()) == ["a"] and asyncio.run(store.count()) == 1
    assert asyncio.run(store.delete("a")) is True
    assert asyncio.run(store.delete("a")) is False
    assert asyncio.run(store.get("a")) is None


def test_timestamps_must_increase() -> None:
    store = InMemoryAgentStore(ttl_s=60, max_agents=10)
    put(store, "a", 5.0)
    for stale in (5.0, 4.0):
        with pytest.raises(StaleTimestampError) as info:
            put(store, "a", stale)
        assert info.value.status == 409
    assert asyncio.run(store.get("a")).timestamp == 5.0  # type: ignore[union-attr]


def test_a_failing_update_changes_nothing() -> None:
    store = InMemoryAgentStore(ttl_s=60, max_agents=10)
    put(store, "a", 1.0)

    def bad(previous: AgentState | None) -> AgentState:
        assert previous is not None and previous.frt_version == 1
        raise ValueError("no")

    with pytest.raises(ValueError):
        asyncio.run(store.update("a", bad, timestamp=2.0))
    got = asyncio.run(store.get("a"))
    assert got is not None and got.frt_version == 1 and got.timestamp == 1.0


def test_returned_states_are_copies() -> None:
    store = InMemoryAgentStore(ttl_s=60, max_agents=10)
    put(store, "a", 1.0)
    got = asyncio.run(store.get("a"))
    assert got is not None
    got.control_bounds[0] = 42.0
    assert asyncio.run(store.get("a")).control_bounds[0] == -1.0  # type: ignore[union-attr]


def test_get_many_reads_copies_in_the_order_asked() -> None:
    store = InMemoryAgentStore(ttl_s=60, max_agents=10)
    put(store, "a", 1.0)
    put(store, "b", 2.0)
    got = asyncio.run(store.get_many(["b", "unknown", "a"]))
    assert [s.agent_id if s else None for s in got] == ["b", None, "a"]
    assert got[0] == asyncio.run(store.get("b"))
    got[0].prediction["mean"][0][0] = 42.0  # type: ignore[union-attr]
    assert asyncio.run(store.get("b")).prediction["mean"][0][0] == 0.0  # type: ignore[union-attr]


def test_shared_reads_share_the_state_written_and_plain_reads_copy_it() -> None:
    store = InMemoryAgentStore(ttl_s=60, max_agents=10)
    written = put(store, "a", 1.0)
    (shared,) = asyncio.run(store.get_many(["a"], shared=True))
    assert shared is written  # no copy made for readers that only read
    (again,) = asyncio.run(store.get_many(["a"], shared=True))
    copy = asyncio.run(store.get("a"))
    assert again is written and copy == written and copy is not written
    copy.control_bounds[0] = 42.0  # type: ignore[union-attr]
    assert asyncio.run(store.get("a")).control_bounds[0] == -1.0  # type: ignore[union-attr]


def test_ttl_expires_agents_and_updates_refresh_it() -> None:
    clock = FakeClock()
    store = InMemoryAgentStore(ttl_s=10, max_agents=10, clock=clock)
    put(store, "a", 1.0)
    put(store, "b", 1.0)
    clock.now += 6
    put(store, "a", 2.0)  # refreshes a only
    clock.now += 6
    assert asyncio.run(store.get("a")) is not None
    assert asyncio.run(store.get("b")) is None
    assert asyncio.run(store.count()) == 1
    clock.now += 11
    assert asyncio.run(store.ids()) == []


def test_capacity_refuses_new_agents_until_some_expire() -> None:
    clock = FakeClock()
    store = InMemoryAgentStore(ttl_s=10, max_agents=2, clock=clock)
    put(store, "a", 1.0)
    put(store, "b", 1.0)
    with pytest.raises(StoreFullError) as info:
        put(store, "c", 1.0)
    assert info.value.status == 503
    put(store, "a", 2.0)  # known agents can still be updated
    clock.now += 11
    put(store, "c", 1.0)
    assert sorted(asyncio.run(store.ids())) == ["c"]


def test_concurrent_updates_of_one_agent_lose_nothing() -> None:
    store = InMemoryAgentStore(ttl_s=60, max_agents=10)
    put(store, "a", 0.0)
    threads, per_thread = 8, 25

    def bump(previous: AgentState | None) -> AgentState:
        assert previous is not None
        seen = previous.frt_version
        time.sleep(0.0001)  # invite a race: another thread would overwrite this update
        previous.frt_version = seen + 1
        return previous

    def worker() -> None:
        for _ in range(per_thread):
            asyncio.run(store.update("a", bump))

    pool = [threading.Thread(target=worker) for _ in range(threads)]
    for t in pool:
        t.start()
    for t in pool:
        t.join()
    assert asyncio.run(store.get("a")).frt_version == 1 + threads * per_thread  # type: ignore[union-attr]


def test_update_many_is_update_of_each_agent() -> None:
    """One pass over a frame's agents: each agent's update as ``update`` would make it, the
    refused ones (stale, full, their function's APIError) answered in place and unchanged."""
    from service.wire.errors import FieldError

    clock = FakeClock()
    store = InMemoryAgentStore(ttl_s=10, max_agents=4, clock=clock)
    put(store, "old", 5.0)
    put(store, "bad", 1.0)
    put(store, "keep", 1.0)

    def refuse(_: AgentState | None) -> AgentState:
        raise FieldError("prediction", "refused")

    def next_of(agent_id: str, timestamp: float) -> UpdateFn:
        return lambda prev: state(agent_id, timestamp, prev.frt_version + 1 if prev else 1)

    before = asyncio.run(store.get_many(["old", "bad"]))
    clock.now += 6
    results = asyncio.run(
        store.update_many(
            [
                ("keep", next_of("keep", 2.0), 2.0),
                ("old", next_of("old", 4.0), 4.0),  # stale
                ("bad", refuse, 2.0),
                ("new", next_of("new", 2.0), 2.0),
                ("full", next_of("full", 2.0), 2.0),  # the fifth agent
            ]
        )
    )
    assert [type(r).__name__ for r in results] == [
        "AgentState", "StaleTimestampError", "FieldError", "AgentState", "StoreFullError",
    ]  # fmt: skip
    assert results[0] == state("keep", 2.0, 2) and results[3] == state("new", 2.0, 1)
    assert results[1].status == 409 and results[1].last == 5.0  # type: ignore[union-attr]
    assert asyncio.run(store.get_many(["old", "bad", "full"])) == [*before, None]
    clock.now += 6  # only the agents written by the batch had their TTL refreshed
    assert sorted(asyncio.run(store.ids())) == ["keep", "new"]
    with pytest.raises(ValueError):
        asyncio.run(store.update_many([("a", next_of("a", 1.0), None)] * 2))


def test_update_many_writes_nothing_when_a_function_fails_unexpectedly() -> None:
    store = InMemoryAgentStore(ttl_s=60, max_agents=10)

    def broken(_: AgentState | None) -> AgentState:
        raise RuntimeError("a bug")

    with pytest.raises(RuntimeError):
        asyncio.run(store.update_many([("a", lambda _: state("a", 1.0), 1.0), ("b", broken, 1.0)]))
    assert asyncio.run(store.count()) == 0


def test_update_many_and_updates_of_the_same_agents_lose_nothing() -> None:
    store = InMemoryAgentStore(ttl_s=60, max_agents=10)
    ids = ["a", "b", "c"]
    for agent_id in ids:
        put(store, agent_id, 0.0)

    def bump(previous: AgentState | None) -> AgentState:
        assert previous is not None
        seen = previous.frt_version
        time.sleep(0.0001)
        previous.frt_version = seen + 1
        return previous

    def frames(order: list[str]) -> None:
        for _ in range(20):
            asyncio.run(store.update_many([(agent_id, bump, None) for agent_id in order]))

    def singles() -> None:
        for _ in range(20):
            for agent_id in ids:
                asyncio.run(store.update(agent_id, bump))

    pool = [threading.Thread(target=frames, args=(ids,)), threading.Thread(target=singles)]
    pool.append(threading.Thread(target=frames, args=(ids[::-1],)))  # another order: no deadlock
    for t in pool:
        t.start()
    for t in pool:
        t.join(timeout=30)
    assert not any(t.is_alive() for t in pool)
    got = asyncio.run(store.get_many(ids))
    assert [s.frt_version for s in got] == [1 + 3 * 20] * 3  # type: ignore[union-attr]
