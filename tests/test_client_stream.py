"""The SDK's WebSocket sessions (``WS /v1/stream``) against a real uvicorn process: every operation,
errors that leave the session usable, late answers skipped, and overlapping async calls in order."""

from __future__ import annotations

import asyncio
import uuid
from collections.abc import Iterator

import numpy as np
import pytest
from frt_client import (
    NO_RETRY,
    AsyncFRTClient,
    ConflictError,
    DeadlineError,
    FRTClient,
    FRTError,
    NotFoundError,
    Stream,
    UnavailableError,
    ValidationError,
    calls,
)

from tests.conftest import LiveServer

pytestmark = pytest.mark.slow

PREDICTION = {
    "dt": 0.5,
    "mean": np.zeros((6, 2)),
    "cov": np.tile(np.diag([0.01, 0.25]), (6, 1, 1)),
}
BOUNDS = [-0.2, -1.0, -0.2, -1.0, 0.2, 1.0, 0.2, 1.0]


def agent_id() -> str:
    return f"ws-{uuid.uuid4().hex[:8]}"


@pytest.fixture
def stream(live_server: LiveServer) -> Iterator[Stream]:
    with FRTClient(live_server.url) as client, client.stream(timeout=10.0) as session:
        yield session


def test_every_operation_over_the_blocking_stream(stream: Stream) -> None:
    agent, other = agent_id(), agent_id()
    first = stream.observe(agent, timestamp=1.0, state=(0, 0, 0, 5), prediction=PREDICTION)
    assert first.agent_id == agent and first.frt_version == 1
    second = stream.observe(
        agent,
        timestamp=1.5,
        state=(2.5, 0, 0, 5),
        prediction=PREDICTION,
        observed_action=np.array([1.7, 0.0]),
    )
    assert second.action_scored and second.beta < first.beta
    stream.observe(other, timestamp=1.0, state=(100, 100, 0, 5), prediction=PREDICTION)
    assert stream.get_agent(agent).frt_version == 2

    trajectory = np.array([[1.6, 2.5, 0.0], [1.7, 50.0, 50.0]])
    check = stream.collision_check(agent, trajectory, mode="time_indexed", deadline_ms=50)
    assert check.collision and check.first_collision_index == 0 and check.clearance[1] > 0
    many = stream.collision_check_many(trajectory, [agent, other, "ws-unknown"])
    assert many.missing == ["ws-unknown"]
    assert many.by_agent()[agent].collision and not many.by_agent()[other].collision
    assert agent in stream.collision_check_many(trajectory).by_agent()

    shapes = stream.contours(  # numpy scalars and arrays anywhere
        agent,
        slices=np.array([1.0], dtype=np.float32),
        include=np.array(["C"]),
        tube=np.bool_(True),
        collision_radius=np.float32(2.0),
    )
    assert shapes.tube is not None and shapes.tube.C is not None and shapes.tube.K is None
    assert shapes.collision_radius == 2.0
    assert [s.t for s in shapes.slices] == [1.0]
    stateless = stream.frt((0, 0, 0, 5), control_bounds=BOUNDS, trajectory=[(0.5, 0.0, 0.0)])
    assert stateless.collision is not None and stateless.collision.collision

    assert stream.delete_agent(agent).deleted
    assert 0 < stream.ping() < 5


def test_errors_over_the_stream_keep_the_session_usable(stream: Stream) -> None:
    agent = agent_id()
    with pytest.raises(NotFoundError) as missing:
        stream.get_agent(agent)
    assert missing.value.status == 404

    stream.observe(agent, timestamp=2.0, state=(0, 0, 0, 5), prediction=PREDICTION)
    with pytest.raises(ConflictError) as stale:
        stream.observe(agent, timestamp=1.0, state=(0, 0, 0, 5), prediction=PREDICTION)
    assert stale.value.status == 409

    bad = {**PREDICTION, "cov": [[[1.0, 2.0], [3.0, 4.0]]] * 6}
    with pytest.raises(ValidationError) as invalid:
        stream.observe(agent, timestamp=3.0, state=(0, 0, 0, 5), prediction=bad)
    assert invalid.value.status == 422 and invalid.value.field == "prediction.cov.0"

    with pytest.raises(FRTError):  # the model card has no stream operation: use HTTP
        stream.send(calls.model())
    assert stream.get_agent(agent).frt_version == 1


def test_a_late_answer_is_skipped_and_the_next_call_gets_its_own(live_server: LiveServer) -> None:
    agent = agent_id()
    with FRTClient(live_server.url) as client, client.stream(timeout=0.0005) as hasty:
        client.observe(agent, timestamp=0.0, state=(0, 0, 0, 5), prediction=PREDICTION)
        with pytest.raises(DeadlineError):
            hasty.contours(agent, slices=[0.5, 1.0, 1.5, 2.0, 2.5, 3.0])
        hasty.timeout = 10.0
        view = hasty.get_agent(agent)  # the contours answer arrives first and is skipped
        assert view.agent_id == agent


def test_a_closed_stream_reports_unavailable(live_server: LiveServer) -> None:
    with FRTClient(live_server.url) as client:
        session = client.stream().open()
        session.close()
        assert session.ping() > 0  # a call on a closed session opens it again
        session.close()
    with FRTClient("http://127.0.0.1:1", retry=NO_RETRY) as nowhere:  # nothing listens there
        with pytest.raises(UnavailableError) as caught:
            nowhere.stream().open()
        assert caught.value.status is None


def test_async_stream_overlapping_calls_keep_the_order_of_observations(
    live_server: LiveServer,
) -> None:
    agent = agent_id()
    count = 20

    async def run() -> None:
        async with AsyncFRTClient(live_server.url) as client, client.stream() as stream:
            # All in flight at once; the service handles a session's messages in order, so the
            # increasing timestamps never conflict and each observation bumps the version by one.
            results = await asyncio.gather(
                *(
                    stream.observe(
                        agent,
                        timestamp=float(k),
                        state=(0.5 * k, 0, 0, 5),
                        prediction=PREDICTION,
                        observed_action=None if k == 0 else (0.0, 0.0),
                    )
                    for k in range(count)
                )
            )
            assert [r.frt_version for r in results] == list(range(1, count + 1))
            assert [r.timestamp for r in results] == [float(k) for k in range(count)]

            far = [(float(count), -500.0, -500.0)]
            checks, view = await asyncio.gather(
                asyncio.gather(*(stream.collision_check(agent, far) for _ in range(10))),
                stream.get_agent(agent),
            )
            assert all(not c.collision for c in checks) and view.frt_version == count
            with pytest.raises(NotFoundError):
                await stream.get_agent(agent_id())
            assert await stream.ping() > 0
            assert (await stream.delete_agent(agent)).deleted

    asyncio.run(run())
