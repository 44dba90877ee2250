"""The SDK against a real uvicorn process serving the analytic model (tests/conftest.py): round
trips, the error of every status, retries (and what is never retried), and the package's tiers.

The analytic model's set at time t is a disc of radius 0.5 + w t centred (v_start t, 0) ahead of the
human, so "a point at the human is in C" and "a point 100 m away is clear" are ground truth.
"""

from __future__ import annotations

import logging
import re
import socket
import subprocess
import sys
import tomllib
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from frt_client import (
    NO_RETRY,
    AuthError,
    ConflictError,
    DeadlineError,
    FRTClient,
    FRTError,
    HumanState,
    NotFoundError,
    PayloadTooLargeError,
    Prediction,
    RetryPolicy,
    ServerError,
    UnavailableError,
    ValidationError,
)
from frt_client.errors import from_status

from tests.conftest import LiveServer

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
FAST_RETRY = RetryPolicy(retries=3, backoff_s=0.01, max_backoff_s=0.05)
TOKEN = "s3cret-token"
BOUNDS = [-0.2, -1.0, -0.2, -1.0, 0.2, 1.0, 0.2, 1.0]  # contract order


def agent_id() -> str:
    return f"sdk-{uuid.uuid4().hex[:8]}"


def prediction(steps: int = 6) -> dict[str, object]:
    """Mean zero, sd 0.1 rad/s and 0.5 m/s² per step, as numpy arrays."""
    return {
        "dt": 0.5,
        "mean": np.zeros((steps, 2)),
        "cov": np.tile(np.diag([0.01, 0.25]), (steps, 1, 1)),
    }


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def retries_logged(caplog: pytest.LogCaptureFixture) -> int:
    return sum(1 for r in caplog.records if r.name == "frt_client.retry")


def request_count(url: str, route: str, method: str, status: int) -> float:
    """How many requests the service itself counted for a route and status (its /metrics)."""
    text = httpx.get(f"{url}/metrics", timeout=5.0).text
    total = 0.0
    for line in text.splitlines():
        if not line.startswith("frt_http_request_duration_seconds_count{"):
            continue
        labels = dict(re.findall(r'(\w+)="([^"]*)"', line))
        if labels == {"route": route, "method": method, "status": str(status)}:
            total += float(line.rsplit(" ", 1)[1])
    return total


@pytest.fixture
def client(live_server: LiveServer) -> Iterator[FRTClient]:
    with FRTClient(live_server.url, retry=FAST_RETRY) as frt:
        yield frt


@pytest.fixture(scope="module")
def locked_server(start_server: Callable[..., LiveServer], tmp_path_factory) -> LiveServer:
    """A server with a bearer token and no loadable model: 401 without the token, 503 with it."""
    missing = tmp_path_factory.mktemp("nomodel") / "missing.onnx"
    return start_server(ready=False, auth_token=TOKEN, model_path=str(missing))


# ---------------------------------------------------------------------------------- round trips


def test_health_readiness_and_model_card(client: FRTClient) -> None:
    assert client.health().status == "ok"
    ready = client.ready()
    assert ready.ready and ready.model == "analytic-disc"
    card = client.model()
    assert card.name == "analytic-disc" and card.semantics == "set" and card.delta == 0.0
    assert card.ranges["v_start"] == [0.0, 20.0] and card.card["sha256"]


def test_get_agent_can_wait_for_the_exact_frt(client: FRTClient) -> None:
    """``wait_frt_ms``: one request that answers once the exact set of the current version is
    ready (the analytic model's set takes milliseconds), instead of polling ``frt_ready``."""
    agent = agent_id()
    client.observe(agent, timestamp=1.0, state=(0.0, 0.0, 0.0, 5.0), prediction=prediction())
    view = client.get_agent(agent, wait_frt_ms=5000)
    assert view.frt_ready and view.frt_version == 1


def test_observe_can_wait_for_its_exact_frt(client: FRTClient) -> None:
    """``observe(wait_frt_ms=...)``: the observation's answer says the new version's exact set is
    ready, and the agent's view agrees without waiting."""
    agent = agent_id()
    result = client.observe(
        agent, timestamp=1.0, state=(0.0, 0.0, 0.0, 5.0), prediction=prediction(), wait_frt_ms=5000
    )
    assert result.frt_ready and result.frt_version == 1
    view = client.get_agent(agent)
    assert view.frt_ready and view.frt_version == 1


def test_observations_take_numpy_models_and_tuples(client: FRTClient) -> None:
    agent = agent_id()
    first = client.observe(
        agent, timestamp=10.0, state=np.array([0.0, 0.0, 0.0, 5.0]), prediction=prediction()
    )
    assert first.agent_id == agent and first.frt_version == 1 and not first.action_scored
    assert first.belief.beta_low == pytest.approx(0.5)

    # A far-off action (17 sd in steering) moves the belief to beta_low and widens the bounds.
    second = client.observe(
        agent,
        timestamp=np.float64(10.5),
        state=HumanState(x=2.5, y=0.0, heading=0.0, speed=5.0),
        prediction=Prediction(**prediction()),
        observed_action=(1.7, 0.0),
        config={"gamma": 0.075},
    )
    assert second.action_scored and second.frt_version == 2
    assert second.beta < first.beta and second.belief.beta_low > 0.9
    assert second.control_bounds.u1_max_start > first.control_bounds.u1_max_start

    view = client.get_agent(agent)
    assert view.frt_version == 2 and view.timestamp == 10.5
    assert view.beta == pytest.approx(second.beta)
    assert view.state == {"x": 2.5, "y": 0.0, "heading": 0.0, "speed": 5.0}
    assert view.config is not None and view.config.collision_radius == 1.5
    assert view.hypotheses is not None and view.hypotheses.beta_low == pytest.approx(0.03)


def test_collision_checks_for_one_agent_and_for_several(client: FRTClient) -> None:
    a, b = agent_id(), agent_id()
    client.observe(a, timestamp=1.0, state=(0.0, 0.0, 0.0, 5.0), prediction=prediction())
    client.observe(b, timestamp=1.0, state=(100.0, 100.0, 0.0, 5.0), prediction=prediction())

    through_a = np.array([[1.1 + 0.1 * i, 0.5 * i, 0.0] for i in range(20)])
    hit = client.collision_check(a, through_a, mode="time_indexed", deadline_ms=50)
    assert hit.collision and hit.first_collision_index == 0
    assert hit.first_collision_time == pytest.approx(1.1)
    assert len(hit.clearance) == 20 and hit.clearance[0] < 0
    assert hit.agent_id == a and hit.mode == "time_indexed" and hit.collision_radius == 1.5

    far = [{"t": 1.1, "x": -200.0, "y": -200.0}]
    assert not client.collision_check(a, far).collision

    many = client.collision_check_many(through_a, [a, b, "sdk-never-seen"])
    assert many.collision and many.missing == ["sdk-never-seen"]
    by_agent = many.by_agent()
    assert by_agent[a].collision and not by_agent[b].collision

    everyone = client.collision_check_many(far, None)
    assert {a, b} <= set(everyone.by_agent()) and not everyone.by_agent()[a].collision


def test_contours_and_the_stateless_frt(client: FRTClient) -> None:
    agent = agent_id()
    client.observe(agent, timestamp=3.0, state=(5.0, -2.0, 1.0, 4.0), prediction=prediction())
    shapes = client.contours(agent, slices=np.array([1.0, 2.0]), include=["K", "C"])
    assert shapes.agent_id == agent and shapes.timestamp == 3.0
    assert shapes.tube is not None and shapes.tube.K is not None and shapes.tube.C is not None
    assert shapes.tube.C["type"] in ("Polygon", "MultiPolygon")
    assert [s.t for s in shapes.slices] == [1.0, 2.0]
    assert [s.time for s in shapes.slices] == [4.0, 5.0]
    only_k = client.contours(agent, include=["K"], tube=True)
    assert only_k.tube is not None and only_k.tube.C is None and only_k.slices == []

    result = client.frt(
        np.array([0.0, 0.0, 0.0, 5.0]),
        control_bounds=np.array(BOUNDS),
        trajectory=[(0.5, 0.0, 0.0), (0.5, 90.0, 0.0)],
        contours={"slices": [1.5], "include": ["C"]},
    )
    assert result.collision is not None and result.collision.collision
    assert result.collision.clearance[0] < 0 < result.collision.clearance[1]
    assert result.contours is not None and result.contours.slices[0].C is not None
    from_prediction = client.frt((0, 0, 0, 5), prediction=prediction(), beta=0.5)
    assert from_prediction.beta == 0.5 and from_prediction.contours is not None


def test_delete_forgets_the_agent(client: FRTClient) -> None:
    agent = agent_id()
    client.observe(agent, timestamp=0.0, state=(0, 0, 0, 1), prediction=prediction())
    gone = client.delete_agent(agent)
    assert gone.deleted and gone.agent_id == agent
    with pytest.raises(NotFoundError):
        client.get_agent(agent)


# -------------------------------------------------------------------------------- error mapping


def test_422_names_the_field(client: FRTClient) -> None:
    bad = prediction(1)
    bad["cov"] = [[[1.0, 2.0], [3.0, 4.0]]]  # not symmetric
    with pytest.raises(ValidationError) as caught:
        client.observe(agent_id(), timestamp=0.0, state=(0, 0, 0, 5), prediction=bad)
    assert caught.value.status == 422 and caught.value.field == "prediction.cov.0"
    assert "symmetric" in str(caught.value)

    with pytest.raises(ValidationError) as caught:
        client.get_agent("not a valid id!")
    assert caught.value.status == 422

    with pytest.raises(ValidationError) as caught:  # out of the model's trained speed range
        client.observe(agent_id(), timestamp=0.0, state=(0, 0, 0, 25.0), prediction=prediction())
    assert caught.value.status == 422 and caught.value.field == "state.speed"


def test_malformed_input_is_refused_before_sending(client: FRTClient) -> None:
    with pytest.raises(ValidationError) as caught:
        client.observe("x", timestamp=0.0, state=(1.0, 2.0, 3.0), prediction=prediction())
    assert caught.value.status is None and caught.value.field == "state"
    with pytest.raises(ValidationError):
        client.collision_check("x", [(0.0, 1.0)])


def test_404_and_409(client: FRTClient) -> None:
    with pytest.raises(NotFoundError) as caught:
        client.get_agent(agent_id())
    assert caught.value.status == 404 and "unknown agent" in str(caught.value.detail)
    with pytest.raises(NotFoundError):
        client.collision_check(agent_id(), [(0.0, 0.0, 0.0)])

    agent = agent_id()
    client.observe(agent, timestamp=5.0, state=(0, 0, 0, 5), prediction=prediction())
    with pytest.raises(ConflictError) as conflict:
        client.observe(agent, timestamp=5.0, state=(0, 0, 0, 5), prediction=prediction())
    assert conflict.value.status == 409 and conflict.value.request_id
    assert client.get_agent(agent).frt_version == 1


def test_413_for_a_body_over_the_limit(client: FRTClient) -> None:
    n = 250_000  # over the collision checks' body limit (FRT_MAX_CHECK_BODY_BYTES)
    points = np.column_stack([np.linspace(0, 3, n), np.zeros(n), np.zeros(n)])
    with pytest.raises(PayloadTooLargeError) as caught:
        client.collision_check(agent_id(), points)
    assert caught.value.status == 413


def test_client_timeout_is_a_deadline_error(live_server: LiveServer) -> None:
    agent = agent_id()
    slow = httpx.Timeout(5.0, read=0.0005)
    with FRTClient(live_server.url) as frt, FRTClient(live_server.url, timeout=slow) as hasty:
        frt.observe(agent, timestamp=0.0, state=(0, 0, 0, 5), prediction=prediction())
        with pytest.raises(DeadlineError) as caught:
            hasty.contours(agent, slices=[0.5, 1.0, 1.5, 2.0, 2.5, 3.0])
    assert caught.value.status is None


def test_401_without_the_token_and_503_without_a_model(
    locked_server: LiveServer, caplog: pytest.LogCaptureFixture
) -> None:
    url = locked_server.url
    for token in (None, "wrong"):
        with FRTClient(url, token=token) as frt, pytest.raises(AuthError) as caught:
            frt.get_agent("anyone")
        assert caught.value.status == 401

    caplog.set_level(logging.INFO, logger="frt_client.retry")
    with FRTClient(url, token=TOKEN, retry=FAST_RETRY) as frt:
        assert frt.health().status == "ok"
        assert frt.ready().ready is False  # 503 with a body: an answer, not an error
        before = request_count(url, "/v1/model", "GET", 503)
        with pytest.raises(UnavailableError) as caught:
            frt.model()  # idempotent: retried 3 times, then reported
        assert caught.value.status == 503 and retries_logged(caplog) == 3
        assert request_count(url, "/v1/model", "GET", 503) - before == 4

        caplog.clear()
        route = "/v1/agents/{agent_id}/observations"
        before = request_count(url, route, "POST", 503)
        with pytest.raises(UnavailableError):
            frt.observe("car", timestamp=0.0, state=(0, 0, 0, 5), prediction=prediction())
        assert retries_logged(caplog) == 0  # an observation that reached the service: never again
        assert request_count(url, route, "POST", 503) - before == 1


def test_stream_handshake_without_the_token_is_an_auth_error(locked_server: LiveServer) -> None:
    with FRTClient(locked_server.url, token="wrong") as frt, pytest.raises(AuthError):
        frt.stream().open()
    with FRTClient(locked_server.url, token=TOKEN) as frt, frt.stream() as stream:
        assert stream.ping() > 0


def test_status_to_exception_table() -> None:
    expected = {
        400: ValidationError, 401: AuthError, 403: AuthError, 404: NotFoundError,
        409: ConflictError, 413: PayloadTooLargeError, 422: ValidationError,
        500: ServerError, 502: ServerError, 503: UnavailableError, 504: DeadlineError,
    }  # fmt: skip
    for status, cls in expected.items():
        error = from_status(status, {"detail": "why", "field": "a.b"})
        assert type(error) is cls and isinstance(error, FRTError)
        assert error.status == status and error.detail == "why" and error.field == "a.b"
    assert type(from_status(418, "teapot")) is FRTError


# ------------------------------------------------------------------------------------- retries


def test_connect_errors_are_retried_then_reported(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="frt_client.retry")
    closed = f"http://127.0.0.1:{free_port()}"
    with FRTClient(closed, retry=FAST_RETRY) as frt:
        with pytest.raises(UnavailableError) as caught:
            frt.health()
        assert caught.value.status is None and retries_logged(caplog) == 3
        caplog.clear()
        with pytest.raises(UnavailableError):  # never sent, so an observation may be retried too
            frt.observe("car", timestamp=0.0, state=(0, 0, 0, 5), prediction=prediction())
        assert retries_logged(caplog) == 3
    caplog.clear()
    with FRTClient(closed, retry=NO_RETRY) as frt, pytest.raises(UnavailableError):
        frt.health()
    assert retries_logged(caplog) == 0


def test_a_service_that_starts_listening_during_the_retries_is_reached(
    analytic_model_path: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="frt_client.retry")
    env = {"FRT_MODEL_PATH": str(analytic_model_path), "FRT_LOG_REQUESTS": "false"}
    server = LiveServer(env, tmp_path / "server.log")  # its port is closed until uvicorn is up
    try:
        patient = RetryPolicy(retries=100, backoff_s=0.05, max_backoff_s=0.2)
        with FRTClient(server.url, retry=patient) as frt:
            assert frt.health().status == "ok"
            assert frt.wait_ready(timeout_s=30).ready
        assert retries_logged(caplog) >= 1
    finally:
        server.stop()


# ------------------------------------------------------------------------------ dependency tier


def test_the_client_distribution_needs_neither_torch_nor_onnxruntime() -> None:
    project = tomllib.loads((ROOT / "client" / "pyproject.toml").read_text())["project"]
    names = {
        re.split(r"[<>=!~\[ ;]", dep, maxsplit=1)[0].lower() for dep in project["dependencies"]
    }
    assert names == {"httpx", "pydantic", "websockets"}
    optional = {
        re.split(r"[<>=!~\[ ;]", dep, maxsplit=1)[0].lower()
        for deps in project.get("optional-dependencies", {}).values()
        for dep in deps
    }
    assert not ({"torch", "onnxruntime", "onnx", "frt-service"} & (names | optional))

    code = (
        "import sys, frt_client; "
        "print(sorted({m.split('.')[0] for m in sys.modules} "
        "& {'torch', 'onnxruntime', 'onnx', 'service', 'models', 'numpy'}))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT / "client", capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
