"""Errors in-process (TestClient): 422 naming the field, 404, 409, 413, 401, 503, never a 500."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.runtime.settings import Settings
from tests.conftest import READY_TIMEOUT_S
from tests.fixtures.payloads import NARROW_BOUNDS, observation

LIMITS = {"max_prediction_steps": 8, "max_trajectory_points": 5, "max_agents_per_check": 3}


def client_for(settings: Settings, ready: bool = True) -> Iterator[TestClient]:
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        if ready:
            deadline = time.monotonic() + READY_TIMEOUT_S
            while client.get("/readyz").status_code != 200:
                assert time.monotonic() < deadline, client.get("/readyz").json()
                time.sleep(0.02)
        yield client


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    settings = Settings(
        model_path=analytic_model_path, log_requests=False, max_body_bytes=20_000, **LIMITS
    )
    yield from client_for(settings)


def field_of(response) -> str:
    assert response.status_code == 422, response.text
    body = response.json()
    assert isinstance(body["detail"], list) and body["detail"][0]["msg"]
    return body["field"]


def test_missing_and_malformed_fields_are_named(client: TestClient) -> None:
    r = client.post("/v1/agents/a/observations", json={"timestamp": 1.0})
    assert field_of(r) == "state"
    body = observation(1.0)
    body["state"]["speed"] = -1.0
    assert field_of(client.post("/v1/agents/a/observations", json=body)) == "state.speed"
    body = observation(1.0, colour="red")
    assert field_of(client.post("/v1/agents/a/observations", json=body)) == "colour"
    r = client.post(
        "/v1/agents/a/observations",
        content=b'{"timestamp": NaN}',
        headers={"content-type": "application/json"},
    )
    assert field_of(r) == "timestamp"
    # The body as a whole: malformed JSON (located by a character offset), null, a list, nothing.
    for content in (b"{", b'{"timestamp": 1.0,', b"null", b"[]", b""):
        r = client.post(
            "/v1/agents/a/observations",
            content=content,
            headers={"content-type": "application/json"},
        )
        assert field_of(r) == "body", content
    assert (
        "at character"
        in client.post(
            "/v1/agents/a/observations", content=b"{", headers={"content-type": "application/json"}
        ).json()["detail"][0]["msg"]
    )


def test_numbers_sent_as_strings_or_booleans_are_refused(client: TestClient) -> None:
    """Strict numbers: "1" and true are not read as 1.0 (a typo'd client must hear of it)."""
    for path, value in ((("state", "x"), "1"), (("state", "speed"), True), (("timestamp",), "5")):
        body = observation(1.0)
        target = body
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
        r = client.post("/v1/agents/strict/observations", json=body)
        assert field_of(r) == ".".join(path)
    body = observation(1.0)
    body["prediction"]["mean"][0][0] = True
    r = client.post("/v1/agents/strict/observations", json=body)
    assert field_of(r) == "prediction.mean.0.0"
    body = observation(1.0)
    body["state"]["x"] = 3  # an integer is a number
    assert client.post("/v1/agents/strict/observations", json=body).status_code == 200


def test_prediction_errors_name_the_step(client: TestClient) -> None:
    body = observation(1.0)
    body["prediction"]["cov"][1] = [[1.0, 2.0], [2.0, 1.0]]  # symmetric, not positive definite
    assert field_of(client.post("/v1/agents/a/observations", json=body)) == "prediction.cov.1"
    body = observation(1.0)
    body["prediction"]["cov"][2] = [[1.0, 0.5], [0.0, 1.0]]
    assert field_of(client.post("/v1/agents/a/observations", json=body)) == "prediction.cov.2"
    body = observation(1.0)
    body["prediction"]["cov"].pop()
    assert field_of(client.post("/v1/agents/a/observations", json=body)) == "prediction.cov"
    body = observation(1.0)
    body["prediction"]["mean"][0] = [0.0]
    assert field_of(client.post("/v1/agents/a/observations", json=body)) == "prediction.mean.0"


def test_settings_limit_array_lengths(client: TestClient) -> None:
    body = observation(1.0)
    body["prediction"]["mean"] *= 2  # 12 steps > 8
    body["prediction"]["cov"] *= 2
    assert field_of(client.post("/v1/agents/a/observations", json=body)) == "prediction.mean"
    assert client.post("/v1/agents/b/observations", json=observation(1.0)).status_code == 200
    check = {"trajectory": [{"t": 1.0, "x": 0.0, "y": float(i)} for i in range(6)]}
    assert field_of(client.post("/v1/agents/b/collision-check", json=check)) == "trajectory"
    many = {"agent_ids": ["a", "b", "c", "d"], "trajectory": check["trajectory"][:1]}
    assert field_of(client.post("/v1/collision-check", json=many)) == "agent_ids"


def test_out_of_trained_range_is_a_named_422(client: TestClient) -> None:
    r = client.post("/v1/agents/fast/observations", json=observation(1.0, speed=25.0))
    assert field_of(r) == "state.speed"
    assert "range [0, 20]" in r.json()["detail"][0]["msg"]
    assert client.get("/v1/agents/fast").status_code == 404  # nothing stored
    frt = {"state": {"x": 0, "y": 0, "heading": 0, "speed": 5}, "control_bounds": NARROW_BOUNDS}
    frt["control_bounds"] = {**NARROW_BOUNDS, "u2_max_end": 11.0}
    assert field_of(client.post("/v1/frt", json=frt)) == "control_bounds.u2_max_end"


def test_stateless_needs_exactly_one_source_of_bounds(client: TestClient) -> None:
    state = {"x": 0, "y": 0, "heading": 0, "speed": 5}
    assert field_of(client.post("/v1/frt", json={"state": state})) == "control_bounds"
    pred = observation(0.0)["prediction"]
    assert field_of(client.post("/v1/frt", json={"state": state, "prediction": pred})) == "beta"
    both = {"state": state, "prediction": pred, "beta": 1.0, "control_bounds": NARROW_BOUNDS}
    assert field_of(client.post("/v1/frt", json=both)) == "prediction"
    # beta is a confidence in (0, 1]: beta_high = 1 (API.md); above it the covariance would shrink.
    beyond = {"state": state, "prediction": pred, "beta": 5.0}
    assert field_of(client.post("/v1/frt", json=beyond)) == "beta"
    for name, value in (("beta", 0.5), ("gamma", 0.1), ("bounds_fit", "endpoints")):
        ignored = {"state": state, "control_bounds": NARROW_BOUNDS, name: value}
        assert field_of(client.post("/v1/frt", json=ignored)) == name
    inverted = {**NARROW_BOUNDS, "u1_min_start": 1.0}
    r = client.post("/v1/frt", json={"state": state, "control_bounds": inverted})
    assert field_of(r) == "control_bounds"


def test_contour_query_errors(client: TestClient) -> None:
    client.post("/v1/agents/c/observations", json=observation(1.0))
    assert field_of(client.get("/v1/agents/c/frt", params={"slices": "1,x"})) == "slices.1"
    assert field_of(client.get("/v1/agents/c/frt", params={"slices": "4.0"})) == "slices.0"
    assert field_of(client.get("/v1/agents/c/frt", params={"include": "K,Z"})) == "include"
    # Numbers float() reads but the schema refuses (a 500 once): named, not crashed.
    for text, field in (("nan", "slices.0"), ("1,inf", "slices.1"), ("-inf", "slices.0")):
        assert field_of(client.get("/v1/agents/c/frt", params={"slices": text})) == field
    assert field_of(client.get("/v1/agents/c/frt", params={"slices": "1e400"})) == "slices.0"
    r = client.get("/v1/agents/c/frt", params={"slices": "1.5", "include": "C"})
    assert r.status_code == 200


def test_query_parameters_are_neither_unknown_nor_repeated(client: TestClient) -> None:
    client.post("/v1/agents/q/observations", json=observation(1.0))
    # A list parameter's repeats add to it: the same contours as the comma-separated list.
    together = client.get("/v1/agents/q/frt", params={"slices": "1.0,2.0", "include": "C"})
    repeated = client.get("/v1/agents/q/frt", params=[("slices", "1.0"), ("slices", "2.0"),
                                                      ("include", "C")])  # fmt: skip
    assert together.status_code == repeated.status_code == 200
    assert repeated.json() == together.json() and len(repeated.json()["slices"]) == 2
    r = client.get("/v1/agents/q/frt", params=[("include", "K"), ("include", "C")])
    assert r.status_code == 200 and set(r.json()["tube"]) == {"K", "C"}
    assert field_of(client.get("/v1/agents/q/frt", params={"include": ""})) == "include"
    # A single-valued parameter given twice, or one the route does not take: named, not dropped.
    twice = [("tube", "false"), ("tube", "true")]
    assert field_of(client.get("/v1/agents/q/frt", params=twice)) == "tube"
    waits = [("wait_frt_ms", "1"), ("wait_frt_ms", "2")]
    assert field_of(client.get("/v1/agents/q", params=waits)) == "wait_frt_ms"
    assert field_of(client.get("/v1/agents/q/frt", params={"slice": "1.0"})) == "slice"
    r = client.post("/v1/agents/q/observations", params={"wait": "5"}, json=observation(2.0))
    assert field_of(r) == "wait"
    assert client.get("/v1/agents/q").json()["timestamp"] == 1.0  # refused before any change
    assert field_of(client.get("/v1/model", params={"verbose": "1"})) == "verbose"
    long = ",".join(["1.0"] * 1100)
    assert field_of(client.get("/v1/agents/q/frt", params={"slices": long})) == "slices"


def test_unknown_agents_are_404(client: TestClient) -> None:
    check = {"trajectory": [{"t": 1.0, "x": 0.0, "y": 0.0}]}
    assert client.get("/v1/agents/nobody").status_code == 404
    assert client.delete("/v1/agents/nobody").status_code == 404
    assert client.get("/v1/agents/nobody/frt").status_code == 404
    r = client.post("/v1/agents/nobody/collision-check", json=check)
    assert r.status_code == 404 and "nobody" in r.json()["detail"]
    assert client.get("/v1/agents/bad%20id").status_code == 422


def test_stale_timestamps_are_409(client: TestClient) -> None:
    assert client.post("/v1/agents/t/observations", json=observation(2.0)).status_code == 200
    assert client.post("/v1/agents/t/observations", json=observation(2.0)).status_code == 409


def test_oversized_bodies_are_413_by_length_and_by_count(client: TestClient) -> None:
    big = b'{"timestamp": 1, "pad": "' + b"x" * 30_000 + b'"}'
    r = client.post(
        "/v1/agents/a/observations", content=big, headers={"content-type": "application/json"}
    )
    assert r.status_code == 413

    def chunks() -> Iterator[bytes]:  # no Content-Length: the middleware must count
        yield b'{"timestamp": 1, "pad": "'
        for _ in range(30):
            yield b"x" * 1000
        yield b'"}'

    r = client.post(
        "/v1/agents/a/observations", content=chunks(), headers={"content-type": "application/json"}
    )
    assert r.status_code == 413
    assert "larger than" in r.json()["detail"]


def test_unexpected_errors_are_json_500s_not_crashes(client: TestClient, monkeypatch) -> None:
    services = client.app.state.services  # type: ignore[attr-defined]

    async def broken(agent_id: str):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(services.store, "get", broken)
    r = client.get("/v1/agents/a")
    assert r.status_code == 500
    assert r.json()["detail"] == "internal server error" and "x-request-id" in r.headers


def test_websocket_survives_malformed_messages(client: TestClient) -> None:
    with client.websocket_connect("/v1/stream") as ws:
        ws.send_bytes(b"\xff\xfe")
        assert ws.receive_json()["error"]["status"] == 400
        ws.send_text('{"id": 1, "op": "observe"}')
        assert ws.receive_json()["error"] == {
            "status": 422,
            "detail": [{"loc": ["agent_id"], "msg": "agent_id is required for this op",
                        "type": "value_error"}],
            "field": "agent_id",
        }  # fmt: skip
        ws.send_text('{"id": 2, "op": "get_agent", "agent_id": "x y"}')
        assert ws.receive_json()["error"]["field"] == "agent_id"
        ws.send_text('{"id": 3, "op": "frt", "agent_id": "c", "collision_radius": -1}')
        assert ws.receive_json()["error"]["field"] == "collision_radius"
        ws.send_text('{"id": 4, "op": "get_agent", "agent_id": "nobody"}')
        assert ws.receive_json()["error"]["status"] == 404
        ws.send_text("x" * 30_000)
        assert ws.receive_json()["error"]["status"] == 413
        ws.send_text('{"id": 5, "op": "ping"}')
        assert ws.receive_json()["ok"] is True


def test_auth_in_process(analytic_model_path: Path) -> None:
    settings = Settings(model_path=analytic_model_path, log_requests=False, auth_token="tok")
    for client in client_for(settings):
        assert client.get("/v1/model").status_code == 401
        assert client.get("/v1/model", headers={"Authorization": "Basic tok"}).status_code == 401
        assert client.get("/v1/model", headers={"Authorization": "Bearer tok"}).status_code == 200
        assert client.get("/metrics").status_code == 200
        with client.websocket_connect("/v1/stream?token=tok") as ws:
            ws.send_text('{"op": "ping"}')
            assert ws.receive_json()["ok"] is True


def test_no_model_means_503_on_model_routes(tmp_path: Path) -> None:
    settings = Settings(model_path=tmp_path / "none.onnx", log_requests=False)
    for client in client_for(settings, ready=False):
        deadline = time.monotonic() + 10
        while "loading" in (client.get("/readyz").json()["detail"] or ""):
            assert time.monotonic() < deadline
            time.sleep(0.02)
        r = client.get("/readyz")
        assert r.status_code == 503 and "not found" in r.json()["detail"]
        assert client.get("/healthz").status_code == 200
        r = client.post("/v1/frt", json={"state": {"x": 0, "y": 0, "heading": 0, "speed": 1},
                                          "control_bounds": NARROW_BOUNDS})  # fmt: skip
        assert r.status_code == 503 and r.headers["retry-after"] == "1"
        with client.websocket_connect("/v1/stream") as ws:
            ws.send_text('{"id": 1, "op": "get_agent", "agent_id": "a"}')
            assert ws.receive_json()["error"]["status"] in (404, 503)


def test_beta_high_other_than_one_is_refused_not_ignored() -> None:
    """The filter's top hypothesis is fixed at 1: a setting that would be ignored must not start."""
    from pydantic import ValidationError

    from service.runtime.settings import Settings

    assert Settings(beta_high=1).beta_high == 1.0
    with pytest.raises(ValidationError, match="beta_high"):
        Settings(beta_high=0.9)
