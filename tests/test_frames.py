"""``POST /v1/frames`` (API.md, "Frames"): one request per frame of many agents, each entry
validated and applied on its own, and the ``verdict`` of per-agent check answers (in-process,
the analytic model)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.runtime.settings import Settings

COV = [[[0.01, 0.0], [0.0, 0.25]]] * 6
MEAN = [[0.0, 0.0]] * 6


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    settings = Settings(model_path=analytic_model_path, log_requests=False, max_agents_per_frame=8)
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        deadline = time.monotonic() + 30
        while c.get("/readyz").status_code != 200:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        yield c


def entry(agent_id: str, x: float = 0.0, **extra) -> dict:
    return {
        "agent_id": agent_id,
        "state": {"x": x, "y": 0.0, "heading": 0.0, "speed": 5.0},
        "prediction": {"dt": 0.5, "mean": MEAN, "cov": COV},
        **extra,
    }


def observation(t: float, x: float = 0.0, **extra) -> dict:
    body = entry("unused", x, **extra)
    body.pop("agent_id")
    return {"timestamp": t, **body}


def test_a_frame_answers_as_the_observations_one_by_one(client: TestClient) -> None:
    action = {"steering_rate": 0.3, "acceleration": -2.0}
    for t, act in ((1.0, None), (1.5, action)):
        extra = {} if act is None else {"observed_action": act}
        frame = client.post(
            "/v1/frames",
            json={"timestamp": t, "agents": [entry(f"f{i}", i, **extra) for i in range(3)]},
        )
        assert frame.status_code == 200, frame.text
        for i in range(3):
            one = client.post(f"/v1/agents/s{i}/observations", json=observation(t, i, **extra))
            assert one.status_code == 200
            got, want = frame.json()["results"][i], one.json()
            assert got["agent_id"] == f"f{i}"
            for key in ("beta", "belief", "control_bounds", "frt_version", "action_scored"):
                assert got[key] == want[key]
    assert frame.json()["applied"] == 3 and frame.json()["rejected"] == 0
    assert client.get("/v1/agents/f2").json()["frt_version"] == 2


def test_a_bad_agent_is_rejected_by_index_and_field_and_the_others_apply(
    client: TestClient,
) -> None:
    assert client.post("/v1/frames", json={"timestamp": 1.0, "agents": [entry("b1")]}).is_success
    before = client.get("/v1/agents/b1").json()
    bad_cov = entry("b1")
    bad_cov["prediction"]["cov"] = [[[1.0, 0.0], [0.0, -1.0]]] * 6  # not positive definite
    agents = [
        entry("b0"),
        bad_cov,
        {"state": entry("x")["state"]},  # no agent_id
        entry("b3", extra_field=1),
        entry("b0"),  # twice in one frame
        entry("bad id!"),
    ]
    r = client.post("/v1/frames", json={"timestamp": 2.0, "agents": agents})
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["applied"] == 1 and out["rejected"] == 5
    results = out["results"]
    assert results[0]["agent_id"] == "b0" and "beta" in results[0]
    fields = {res["index"]: res["error"]["field"] for res in results[1:]}
    assert fields[1].startswith("agents.1.prediction.cov")
    assert fields[2] == "agents.2.agent_id"
    assert fields[3] == "agents.3.extra_field"
    assert fields[4] == "agents.4.agent_id"
    assert fields[5] == "agents.5.agent_id"
    assert all(res["error"]["status"] == 422 for res in results[1:])
    assert client.get("/v1/agents/b1").json() == before  # nothing of the bad one changed
    assert client.get("/v1/agents/b3").status_code == 404


def test_a_stale_agent_is_a_409_entry(client: TestClient) -> None:
    client.post("/v1/frames", json={"timestamp": 5.0, "agents": [entry("st")]})
    r = client.post("/v1/frames", json={"timestamp": 4.0, "agents": [entry("st"), entry("st2")]})
    results = r.json()["results"]
    assert results[0]["error"]["status"] == 409 and results[0]["agent_id"] == "st"
    assert results[1]["agent_id"] == "st2" and "beta" in results[1]


def test_a_frame_beyond_the_limit_is_a_422_naming_agents(client: TestClient) -> None:
    agents = [entry(f"l{i}") for i in range(9)]
    r = client.post("/v1/frames", json={"timestamp": 1.0, "agents": agents})
    assert r.status_code == 422 and r.json()["field"] == "agents"
    assert client.get("/v1/agents/l0").status_code == 404
    assert client.post("/v1/frames", json={"agents": []}).status_code == 422  # no timestamp


def test_the_stream_applies_a_frame(client: TestClient) -> None:
    with client.websocket_connect("/v1/stream") as ws:
        ws.send_json({"id": 1, "op": "frame", "timestamp": 1.0, "agents": [entry("w0")]})
        answer = ws.receive_json()
    assert answer["ok"] and answer["result"]["results"][0]["agent_id"] == "w0"


def test_the_verdict_says_how_good_each_answer_is(client: TestClient) -> None:
    client.post("/v1/agents/v/observations?wait_frt_ms=5000", json=observation(1.0))
    far = [{"x": 500.0, "y": 500.0, "t": 1.0 + 0.1 * k} for k in range(5)]
    near = [{"x": 0.0, "y": 0.0, "t": 1.0 + 0.1 * k} for k in range(5)]
    for trajectory, collision in ((far, False), (near, True)):
        r = client.post("/v1/agents/v/collision-check", json={"trajectory": trajectory}).json()
        assert r["collision"] is collision
        assert r["verdict"] == ("exact" if not r["conservative"] else r["verdict"])
    from service.wire.schemas import answer_verdict

    assert answer_verdict(False, True) == "exact"
    assert answer_verdict(True, False) == "decision_exact"
    assert answer_verdict(True, True) == "conservative"


def test_the_sdk_builds_a_frame_and_reads_its_answer(client: TestClient) -> None:
    from frt_client import FrameRejection, FrameResult, ObservationResult
    from frt_client.calls import frame

    call = frame(
        timestamp=1.0,
        agents=[
            {"agent_id": "k0", "state": (0.0, 0.0, 0.0, 5.0), "prediction": entry("k0")["prediction"]},
            {"agent_id": "k1", "state": (0.0, 0.0, 0.0, 500.0), "prediction": entry("k1")["prediction"]},
        ],
    )  # fmt: skip
    assert (call.method, call.path, call.op, call.idempotent) == (
        "POST",
        "/v1/frames",
        "frame",
        False,
    )
    result = FrameResult.model_validate(client.post(call.path, json=call.json).json())
    assert isinstance(result.results[0], ObservationResult)
    assert isinstance(result.results[1], FrameRejection)
    assert result.rejections()[0].error.field.startswith("agents.1.state.speed")
