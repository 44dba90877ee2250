"""Inputs at the edges of what JSON and floats allow: a 4xx naming what is wrong (or a normal
answer where the input is valid), never a 500, a closed stream or an invalid JSON answer; what a
rejected input names changes nothing."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from service.runtime.settings import Settings
from tests.fixtures.payloads import observation, prediction
from tests.test_api_errors import client_for

HUGE_INTEGER = "1" + "0" * 5000  # more digits than Python converts from text
COV = [[[0.01, 0.0], [0.0, 0.25]]] * 6


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    yield from client_for(Settings(model_path=analytic_model_path, log_requests=False))


def post_raw(client: TestClient, path: str, text: str):
    return client.post(path, content=text.encode(), headers={"content-type": "application/json"})


def field_of(response) -> str:
    assert response.status_code == 422, response.text
    return response.json()["field"]


def test_a_subnormal_dt_is_a_prediction_like_any_other(client: TestClient) -> None:
    body = observation(0.0, prediction=prediction(steps=1, dt=1e-310))
    answer = client.post("/v1/agents/tiny-dt/observations", json=body)
    assert answer.status_code == 200, answer.text
    bounds = answer.json()["control_bounds"]
    assert all(bounds[k] <= bounds[k.replace("min", "max")] for k in bounds if "min" in k)
    frame = client.post(
        "/v1/frames",
        json={
            "timestamp": 1.0,
            "agents": [
                {"agent_id": "tiny-dt-2", **{k: v for k, v in body.items() if k != "timestamp"}},
                {"agent_id": "plain", "state": body["state"], "prediction": prediction()},
            ],
        },
    )
    assert frame.status_code == 200, frame.text
    assert frame.json()["applied"] == 2


def test_weights_near_the_largest_float_are_normalised(client: TestClient) -> None:
    modes = [
        {"weight": 1e308, "mean": [[0.0, 0.0]] * 6, "cov": COV},
        {"weight": 1e308, "mean": [[0.0, 1.0]] * 6, "cov": COV},
    ]
    body = observation(0.0, prediction={"dt": 0.5, "modes": modes})
    answer = client.post("/v1/agents/huge-weights/observations", json=body)
    assert answer.status_code == 200, answer.text
    assert [m["weight"] for m in answer.json()["modes"]] == [0.5, 0.5]


def test_unreadable_json_bodies_are_422s_naming_the_body(client: TestClient) -> None:
    body = json.dumps(observation(0.0)).replace('"speed": 5.0', f'"speed": {HUGE_INTEGER}')
    assert field_of(post_raw(client, "/v1/agents/big-int/observations", body)) == "body"
    deep = "[" * 50_000 + "]" * 50_000
    assert field_of(post_raw(client, "/v1/agents/deep/observations", deep)) == "body"
    assert client.get("/v1/agents/big-int").status_code == 404


def test_a_lone_surrogate_in_a_named_key_is_escaped_in_the_422(client: TestClient) -> None:
    body = '{"\\ud800": 1, "drivable_areas": {}}'
    response = client.put(
        "/v1/maps/surrogate", content=body.encode(), headers={"content-type": "application/json"}
    )
    assert response.status_code == 422, response.text
    assert json.loads(response.content)["field"] == "\ud800"
    assert client.get("/v1/maps/surrogate").status_code == 404


def test_a_map_coordinate_too_large_for_a_float_is_named(client: TestClient) -> None:
    ring = f'[{{"x": 0, "y": 0}}, {{"x": 10, "y": 0}}, {{"x": 1{"0" * 400}, "y": 10}}]'
    body = f'{{"drivable_areas": {{"1": {{"area_boundary": {ring}}}}}}}'
    response = client.put(
        "/v1/maps/huge", content=body.encode(), headers={"content-type": "application/json"}
    )
    assert field_of(response) == "drivable_areas.1.area_boundary.2.x"
    assert client.get("/v1/maps/huge").status_code == 404


def test_a_frame_rejects_an_entry_that_is_not_an_object_on_its_own(client: TestClient) -> None:
    entry = {"agent_id": "framed", "state": observation(0.0)["state"], "prediction": prediction()}
    for odd in (42, None, [], "x"):
        answer = client.post("/v1/frames", json={"timestamp": 5.0, "agents": [entry, odd]})
        assert answer.status_code == 200, answer.text
        frame = answer.json()
        assert (frame["applied"], frame["rejected"]) == (1, 1)
        assert frame["results"][1]["error"]["field"] == "agents.1"
        assert client.delete("/v1/agents/framed").status_code == 200


def test_slices_are_decimal_numbers(client: TestClient) -> None:
    assert client.post("/v1/agents/sliced/observations", json=observation(0.0)).status_code == 200
    for text in ("1_0", "\u0661", "nan", "0x1"):
        response = client.get("/v1/agents/sliced/frt", params={"slices": f"1.0,{text}"})
        assert field_of(response) == "slices.1", text
    assert client.get("/v1/agents/sliced/frt", params={"slices": "+1.5,.5,2e0"}).status_code == 200


def test_the_stream_answers_hostile_messages_and_stays_open(client: TestClient) -> None:
    with client.websocket_connect("/v1/stream") as ws:
        ws.send_text(f'{{"id": {HUGE_INTEGER}, "op": "ping"}}')
        assert ws.receive_json()["error"]["status"] == 400
        for message in ('{"id": NaN, "op": "ping"}', '{"id": [1e400], "op": "ping"}'):
            ws.send_text(message)
            answer = json.loads(ws.receive_text(), parse_constant=pytest.fail)
            assert (answer["id"], answer["error"]["field"]) == (None, "id")
        ws.send_text('{"id": "\\ud800", "op": "ping"}')
        assert json.loads(ws.receive_text())["id"] == "\ud800"
        ws.send_text('{"op": "get_agent", "agent_id": "nobody", "\\udc00": 1}')
        assert ws.receive_json()["error"]["field"] == "\udc00"
        for radius in ('"7"', "true", '" 2 "'):
            ws.send_text(f'{{"id": 9, "op": "frt", "agent_id": "a", "collision_radius": {radius}}}')
            assert ws.receive_json()["error"]["field"] == "collision_radius", radius
        ws.send_text('{"id": 10, "op": "ping"}')
        assert ws.receive_json()["ok"] is True
