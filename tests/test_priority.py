"""Collision checks before observations on the event loop (service.runtime.priority)."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import pytest

from service.flows import agents, checks
from service.runtime.priority import ChecksFirst
from service.runtime.settings import Settings
from service.wire.errors import AgentNotFoundError
from service.wire.schemas import (
    CollisionCheckRequest,
    MultiCollisionCheckRequest,
    ObservationRequest,
)
from tests.fixtures.payloads import observation

TRAJECTORY = [{"t": 0.1 * i, "x": 20.0, "y": 0.0} for i in range(3)]


def test_an_observation_goes_at_once_when_no_check_is_in_flight() -> None:
    assert asyncio.run(ChecksFirst().observation_turn()) == 0.0


def test_an_observation_waits_for_the_checks_in_flight() -> None:
    priority = ChecksFirst(max_hold_s=10.0)
    events: list[str] = []

    async def check(name: str, seconds: float) -> None:
        with priority.check():
            events.append(f"{name} starts")
            await asyncio.sleep(seconds)
            events.append(f"{name} ends")

    async def observe() -> None:
        await priority.observation_turn()
        events.append("observation")

    async def main() -> None:
        first = asyncio.create_task(check("check 1", 0.03))
        second = asyncio.create_task(check("check 2", 0.06))
        await asyncio.sleep(0)
        await asyncio.gather(observe(), first, second)

    asyncio.run(main())
    assert events == ["check 1 starts", "check 2 starts", "check 1 ends", "check 2 ends",
                      "observation"]  # fmt: skip
    assert priority.checks_in_flight == 0


def test_a_stream_of_checks_holds_an_observation_back_for_max_hold_only() -> None:
    priority = ChecksFirst(max_hold_s=0.02)

    async def main() -> tuple[float, int]:
        with priority.check():
            held = await priority.observation_turn()
            return held, priority.checks_in_flight

    held, in_flight = asyncio.run(main())
    assert held >= 0.02 and in_flight == 1  # it went while the check was still in flight


def test_the_turns_of_one_frame_hold_it_back_for_max_hold_together() -> None:
    """Each later turn is given what is left of ``max_hold_s``: once it is spent, a turn yields
    and goes on while the check is still in flight."""
    priority = ChecksFirst(max_hold_s=0.02)

    async def main() -> list[float]:
        with priority.check():
            held = [await priority.observation_turn()]
            for _ in range(3):
                held.append(await priority.observation_turn(priority.max_hold_s - sum(held)))
            return held

    held = asyncio.run(main())
    assert held[0] >= 0.02 and held[1:] == [0.0, 0.0, 0.0]


def test_a_check_that_fails_still_lets_observations_go() -> None:
    priority = ChecksFirst(max_hold_s=10.0)

    async def main() -> float:
        waiting = asyncio.create_task(priority.observation_turn())
        with pytest.raises(RuntimeError), priority.check():
            await asyncio.sleep(0.01)
            raise RuntimeError("boom")
        return await asyncio.wait_for(waiting, 5.0)

    held = asyncio.run(main())
    assert 0.0 < held < 5.0  # released when the check failed, not at max_hold_s
    assert priority.checks_in_flight == 0


class _RecordingStore:
    """Answers no agent, recording how many checks were in flight when asked."""

    def __init__(self, priority: ChecksFirst) -> None:
        self.priority = priority
        self.seen: list[int] = []

    async def get(self, agent_id: str) -> None:
        self.seen.append(self.priority.checks_in_flight)

    async def get_many(self, ids: list[str], shared: bool = False) -> list[None]:
        self.seen.append(self.priority.checks_in_flight)
        return [None] * len(ids)


def _services() -> SimpleNamespace:
    priority = ChecksFirst(max_hold_s=10.0)
    return SimpleNamespace(
        settings=Settings(),
        priority=priority,
        store=_RecordingStore(priority),
        require_engine=lambda: None,
    )


def test_both_checks_are_in_flight_while_they_run() -> None:
    services = _services()
    one = CollisionCheckRequest.model_validate({"trajectory": TRAJECTORY})
    many = MultiCollisionCheckRequest.model_validate({"trajectory": TRAJECTORY, "agent_ids": ["a"]})
    with pytest.raises(AgentNotFoundError):
        asyncio.run(checks.check_agent(services, "a", one, 0.0))  # type: ignore[arg-type]
    answer = asyncio.run(checks.check_agents_at_once(services, many, 0.0))  # type: ignore[arg-type]
    assert answer.missing == ["a"]
    assert services.store.seen == [1, 1]
    assert services.priority.checks_in_flight == 0


def test_an_observation_starts_its_work_after_the_check_in_flight() -> None:
    services = _services()
    events: list[str] = []

    def require_engine() -> None:
        events.append("observation works")
        raise LookupError("stop here")

    services.require_engine = require_engine
    request = ObservationRequest.model_validate(observation(1.0))

    async def check() -> None:
        with services.priority.check():
            await asyncio.sleep(0.03)
            events.append("check ends")

    async def main() -> None:
        task = asyncio.create_task(check())
        await asyncio.sleep(0)
        with pytest.raises(LookupError):
            await agents.observe(services, "a", request)  # type: ignore[arg-type]
        await task

    asyncio.run(main())
    assert events == ["check ends", "observation works"]
