"""The main flows through a real uvicorn process serving the analytic model.

The analytic model's set at time t is a disc of radius 0.5 + w t centred (v_start t, 0) ahead of the
human (tests/fixtures/analytic_model.py), which gives every answer here an independent ground truth.
"""

from __future__ import annotations

import json
import math
import time
import uuid
from concurrent.futures import ThreadPoolExecutor

import httpx
import numpy as np
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from tests.conftest import LiveServer, _free_port
from tests.fixtures.analytic_model import growth_rate
from tests.fixtures.payloads import (
    NARROW_BOUNDS,
    ahead,
    observation,
    tube_front,
    tube_tolerance,
)

pytestmark = pytest.mark.slow


def new_agent() -> str:
    return f"h-{uuid.uuid4().hex[:8]}"


def wait_exact(http: httpx.Client, agent: str, timeout_s: float = 10.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        body = http.get(f"/v1/agents/{agent}").json()
        if body["frt_ready"]:
            return body
        time.sleep(0.02)
    raise TimeoutError("exact FRT never became ready")


def test_health_ready_and_model_card(http: httpx.Client) -> None:
    assert http.get("/healthz").json() == {"status": "ok"}
    assert http.get("/readyz").json()["ready"] is True
    card = http.get("/v1/model").json()
    assert card["name"] == "analytic-disc" and card["semantics"] == "set"
    assert card["delta"] == 0.0 and card["ranges"]["v_start"] == [0.0, 20.0]
    assert card["card"]["sha256"]


def test_observation_flow_updates_beta_and_versions(http: httpx.Client) -> None:
    agent = new_agent()
    first = http.post(f"/v1/agents/{agent}/observations", json=observation(10.0))
    assert first.status_code == 200, first.text
    body = first.json()
    assert body["frt_version"] == 1 and body["action_scored"] is False
    assert body["belief"] == pytest.approx({"beta_low": 0.5, "beta_high": 0.5})
    assert set(body["control_bounds"]) == set(NARROW_BOUNDS)

    # An action far from the prediction (mean 0, sd 0.1 / 0.5) moves the belief to beta_low.
    second = http.post(
        f"/v1/agents/{agent}/observations", json=observation(10.5, action=(1.5, 4.0))
    ).json()
    assert second["frt_version"] == 2 and second["action_scored"] is True
    assert second["belief"]["beta_low"] > 0.9
    assert second["beta"] < body["beta"]
    # Lower confidence widens the bounds.
    assert second["control_bounds"]["u1_max_start"] > body["control_bounds"]["u1_max_start"]

    agent_view = http.get(f"/v1/agents/{agent}").json()
    assert agent_view["frt_version"] == 2 and agent_view["timestamp"] == 10.5
    assert agent_view["beta"] == pytest.approx(second["beta"])
    assert agent_view["config"]["collision_radius"] == 1.5
    assert agent_view["hypotheses"] == pytest.approx({"beta_low": 0.03, "beta_high": 1.0})


def test_get_agent_can_wait_for_the_exact_set(http: httpx.Client) -> None:
    """``wait_frt_ms`` answers once the exact FRT of the current version is ready: one request
    instead of polling (the bench's observation -> ready measure)."""
    agent = new_agent()
    version = http.post(f"/v1/agents/{agent}/observations", json=observation(3.0)).json()
    body = http.get(f"/v1/agents/{agent}", params={"wait_frt_ms": 10_000}).json()
    assert body["frt_ready"] is True and body["frt_version"] == version["frt_version"]
    assert http.get(f"/v1/agents/{agent}", params={"wait_frt_ms": -1}).status_code == 422


def test_observation_can_wait_for_its_exact_set(http: httpx.Client) -> None:
    """``wait_frt_ms`` on the observation: the answer leaves once the new version's exact FRT is
    computed (one request instead of the observation and a waiting GET)."""
    agent = new_agent()
    first = http.post(
        f"/v1/agents/{agent}/observations", json=observation(1.0), params={"wait_frt_ms": 10_000}
    ).json()
    assert first["frt_version"] == 1 and first["frt_ready"] is True
    second = http.post(
        f"/v1/agents/{agent}/observations",
        json=observation(2.0, action=(0.0, 0.0)),
        params={"wait_frt_ms": 10_000},
    ).json()
    assert second["frt_version"] == 2 and second["frt_ready"] is True
    view = http.get(f"/v1/agents/{agent}").json()  # no wait: the set is there already
    assert view["frt_version"] == 2 and view["frt_ready"] is True
    bad = http.post(
        f"/v1/agents/{agent}/observations", json=observation(3.0), params={"wait_frt_ms": -1}
    )
    assert bad.status_code == 422 and "wait_frt_ms" in bad.text
    assert http.get(f"/v1/agents/{agent}").json()["frt_version"] == 2  # nothing stored


def test_stale_timestamp_is_409_and_keeps_state(http: httpx.Client) -> None:
    agent = new_agent()
    assert http.post(f"/v1/agents/{agent}/observations", json=observation(5.0)).status_code == 200
    for stale in (5.0, 4.0):
        r = http.post(f"/v1/agents/{agent}/observations", json=observation(stale))
        assert r.status_code == 409 and "stale" in r.json()["detail"]
    assert http.get(f"/v1/agents/{agent}").json()["frt_version"] == 1


def test_concurrent_observations_of_one_agent_lose_no_update(live_server: LiveServer) -> None:
    """Racing observations: each is either applied (and counted in the version) or refused as
    stale (409, when a later timestamp won the race); the final state is the latest accepted."""
    agent = new_agent()
    timestamps = [float(t) for t in range(1, 25)]

    def send(t: float) -> int:
        with httpx.Client(base_url=live_server.url, timeout=10.0) as client:
            body = observation(t, action=(0.1, 0.2))
            return client.post(f"/v1/agents/{agent}/observations", json=body).status_code

    with ThreadPoolExecutor(8) as pool:
        statuses = dict(zip(timestamps, pool.map(send, timestamps), strict=True))
    assert set(statuses.values()) <= {200, 409}
    accepted = [t for t, status in statuses.items() if status == 200]
    with httpx.Client(base_url=live_server.url, timeout=10.0) as client:
        view = client.get(f"/v1/agents/{agent}").json()
    assert view["frt_version"] == len(accepted)
    assert view["timestamp"] == max(accepted)


def test_per_agent_config_is_echoed_and_used(http: httpx.Client) -> None:
    agent = new_agent()
    config = {"collision_radius": 0.5, "gamma": 0.5, "bounds_fit": "endpoints"}
    r = http.post(f"/v1/agents/{agent}/observations", json=observation(1.0, config=config))
    assert r.status_code == 200, r.text
    view = http.get(f"/v1/agents/{agent}").json()
    assert view["config"]["collision_radius"] == 0.5 and view["config"]["gamma"] == 0.5
    assert view["config"]["bounds_fit"] == "endpoints" and view["config"]["beta_low"] == 0.03
    # Omitted config fields keep the agent's values.
    http.post(f"/v1/agents/{agent}/observations", json=observation(2.0, config={"epsilon": 0.2}))
    view = http.get(f"/v1/agents/{agent}").json()
    assert view["config"]["collision_radius"] == 0.5 and view["config"]["epsilon"] == 0.2
    check = http.post(
        f"/v1/agents/{agent}/collision-check",
        json={"trajectory": [{"t": 2.0, "x": 100.0, "y": 100.0}]},
    ).json()
    assert check["collision_radius"] == 0.5


def test_collision_check_against_the_analytic_disc(http: httpx.Client) -> None:
    agent = new_agent()
    x0, y0, heading, speed = 10.0, -4.0, 0.7, 5.0
    obs = observation(100.0, x=x0, y=y0, heading=heading, speed=speed)
    bounds = http.post(f"/v1/agents/{agent}/observations", json=obs).json()["control_bounds"]
    wait_exact(http, agent)
    front = tube_front(speed, bounds)
    centre_2s = ahead(x0, y0, heading, speed * 2.0)
    far = ahead(x0, y0, heading, front + 10.0)
    points = [
        {"t": 100.0, "x": x0, "y": y0},  # the human itself, at t = 0
        {"t": 102.0, **centre_2s},  # the disc's centre at t = 2
        {"t": 102.5, **far},  # 10 m beyond the tube's front
    ]
    r = http.post(
        f"/v1/agents/{agent}/collision-check",
        json={"trajectory": points, "mode": "tube", "deadline_ms": 1000},
    )
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["conservative"] is False and body["frt_version"] == 1
    assert body["collision"] is True and body["first_collision_index"] == 0
    assert body["first_collision_time"] == 100.0
    clearance = body["clearance"]
    assert clearance[0] < 0 and clearance[1] < 0
    expected = 10.0 - 1.5
    assert expected - tube_tolerance(speed, bounds) <= clearance[2] <= expected + 1e-6
    assert body["horizon_end"] == pytest.approx(103.0)


def test_responses_say_how_long_the_server_took(http: httpx.Client) -> None:
    """Server-Timing lets a planner split its round trip into the service's part and the trip's."""
    agent = new_agent()
    http.post(f"/v1/agents/{agent}/observations", json=observation(1.0))
    for request in (
        lambda: http.get("/healthz"),
        lambda: http.post(
            f"/v1/agents/{agent}/collision-check",
            json={"trajectory": [{"t": 1.5, "x": 3.0, "y": 0.0}], "deadline_ms": 1000},
        ),
        lambda: http.get("/v1/agents/nobody"),
    ):
        t0 = time.perf_counter()
        r = request()
        round_trip_ms = (time.perf_counter() - t0) * 1000.0
        name, duration = r.headers["server-timing"].split(";dur=")
        assert name == "app"
        assert 0.0 < float(duration) < round_trip_ms


def test_time_indexed_mode_uses_the_tube_up_to_t(http: httpx.Client) -> None:
    agent = new_agent()
    speed = 5.0
    bounds = http.post(
        f"/v1/agents/{agent}/observations", json=observation(0.0, speed=speed)
    ).json()["control_bounds"]
    wait_exact(http, agent)
    w = growth_rate(bounds)
    # 12 m ahead: reached only after ~(12 - 0.5 - 1.5) / (v + w) s, so clear at t = 0.5, hit at 3.
    point = ahead(0.0, 0.0, 0.0, 12.0)
    trajectory = [{"t": 0.5, **point}, {"t": 3.0, **point}, {"t": 0.0, "x": 0.0, "y": 0.0}]
    body = http.post(
        f"/v1/agents/{agent}/collision-check",
        json={"trajectory": trajectory, "mode": "time_indexed", "deadline_ms": 1000},
    ).json()
    assert body["conservative"] is False
    clear_at_half = 12.0 - (speed * 0.5 + 0.5 + w * 0.5) - 1.5
    assert body["clearance"][0] == pytest.approx(clear_at_half, abs=tube_tolerance(speed, bounds))
    assert body["clearance"][0] > 0 and body["clearance"][1] < 0
    assert body["clearance"][2] < 0  # the human's own position is inside C at t = 0
    assert body["first_collision_index"] == 1 and body["first_collision_time"] == 3.0
    tube = http.post(
        f"/v1/agents/{agent}/collision-check", json={"trajectory": trajectory, "mode": "tube"}
    ).json()
    assert tube["clearance"][0] < 0  # the whole-horizon tube is less forgiving


def fallback_then_exact(http: httpx.Client) -> tuple[dict, dict]:
    """One check before the exact set can be ready (deadline 1 us), one after it is.

    On a quiet machine the fixture model's exact set can be ready before the first check
    arrives; a few fresh agents are tried before giving up on observing the fallback."""
    for _ in range(10):
        fast, exact = _fallback_then_exact(http)
        if fast["conservative"]:
            return fast, exact
    pytest.skip("the exact set was always ready before the first check: no fallback to observe")


def _fallback_then_exact(http: httpx.Client) -> tuple[dict, dict]:
    agent = new_agent()
    obs = observation(0.0, x=3.0, y=2.0, heading=-0.4, speed=6.0)
    http.post(f"/v1/agents/{agent}/observations", json=obs)
    rng = np.random.default_rng(1)
    points = [
        {"t": float(t), "x": float(x), "y": float(y)}
        for t, x, y in zip(
            rng.uniform(0, 3, 200), rng.uniform(-10, 30, 200), rng.uniform(-20, 15, 200),
            strict=True,
        )
    ]  # fmt: skip
    request = {"trajectory": points, "mode": "time_indexed", "deadline_ms": 0.001}
    start = time.perf_counter()
    fast = http.post(f"/v1/agents/{agent}/collision-check", json=request)
    elapsed = time.perf_counter() - start
    assert fast.status_code == 200, fast.text
    assert elapsed < 2.0, f"a check that may not wait took {elapsed:.3f} s"
    wait_exact(http, agent)
    # Time to draw the tubes the time-indexed points need (a 1 us deadline would not allow it).
    exact = http.post(f"/v1/agents/{agent}/collision-check", json={**request, "deadline_ms": 1000})
    assert exact.status_code == 200, exact.text
    return fast.json(), exact.json()


def conservative_answers(http: httpx.Client, reason: str) -> float:
    """``frt_conservative_answers_total{reason=...}`` from /metrics (0 before the first)."""
    prefix = f'frt_conservative_answers_total{{reason="{reason}"}} '
    lines = [line for line in http.get("/metrics").text.splitlines() if line.startswith(prefix)]
    return float(lines[0].split()[-1]) if lines else 0.0


def test_tubes_not_drawn_in_time_give_a_conservative_answer_then_an_exact_one(
    start_server,
) -> None:
    """With the workers drawing no tubes (``FRT_FRT_DRAW_TUBES=false``), a time-indexed check on a
    fresh exact set whose deadline leaves no time to draw the tubes up to each point's time (29 of
    them) but enough to answer one agent is answered against later tubes (which contain them) and
    says so; the missing tubes are drawn between requests, and the same check is then exact."""
    server = start_server(frt_draw_tubes="false")
    with httpx.Client(base_url=server.url, timeout=10.0) as http:
        _tubes_drawn_between_requests(http)


def _tubes_drawn_between_requests(http: httpx.Client) -> None:
    points = [{"t": 0.1 * k, "x": 3.0 + 0.6 * k, "y": 2.5} for k in range(1, 30)]
    # A deadline short enough that the tubes cannot all be drawn within it, long enough to answer
    # one agent: on a busy machine answering takes longer (the answer is then conservative for
    # want of time, "no_time"), so fresh agents are tried with longer deadlines.
    for deadline_ms in (10.0, 15.0, 20.0, 30.0, 45.0):
        agent = new_agent()
        obs = observation(0.0, x=3.0, y=2.0, speed=6.0)
        http.post(f"/v1/agents/{agent}/observations", json=obs)
        wait_exact(http, agent)
        hurried = {"trajectory": points, "mode": "time_indexed", "deadline_ms": deadline_ms}
        tubes_before = conservative_answers(http, "tubes")
        first = http.post(f"/v1/agents/{agent}/collision-check", json=hurried).json()
        if conservative_answers(http, "tubes") == tubes_before + 1:  # /metrics says why
            break
    else:
        pytest.fail("no check was answered against later tubes for want of time to draw its own")
    assert first["conservative"] is True
    deadline = time.monotonic() + 10
    while True:  # the tubes are drawn between requests
        later = http.post(f"/v1/agents/{agent}/collision-check", json=hurried).json()
        if not later["conservative"] or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    assert later["conservative"] is False
    assert later["frt_version"] == first["frt_version"]
    # The conservative answer is never less safe than the exact one.
    assert all(f <= e + 1e-6 for f, e in zip(first["clearance"], later["clearance"], strict=True))
    assert any(f < e - 1e-3 for f, e in zip(first["clearance"], later["clearance"], strict=True))


def test_a_late_exact_set_gives_a_conservative_answer_in_time(http: httpx.Client) -> None:
    """On a quiet machine the fixture model's set can be ready before the first check arrives (the
    answer is then conservative for want of time to measure it, ``no_time``): a few fresh agents are
    tried until one's first check finds its set not ready."""
    for _ in range(10):
        not_ready_before = conservative_answers(http, "not_ready")
        fast, exact = _fallback_then_exact(http)
        if conservative_answers(http, "not_ready") > not_ready_before:
            break
    else:
        pytest.skip("the exact set was always ready before the first check: nothing late to see")
    assert fast["conservative"] is True, "a set not ready was not said to be conservative"
    assert exact["conservative"] is False, "the exact set was ready but not used"
    assert fast["frt_version"] == exact["frt_version"] == 1
    assert sum(c < 0 for c in exact["clearance"]) > 0  # some points do collide
    # Whatever the exact set calls a collision, the conservative one does too.
    assert all(f < 0 for f, e in zip(fast["clearance"], exact["clearance"], strict=True) if e < 0)


def test_the_fallback_set_contains_the_exact_set(http: httpx.Client) -> None:
    """Containment: every point is at most as far from the conservative set as from the exact."""
    fast, exact = fallback_then_exact(http)
    assert fast["conservative"] is True and exact["conservative"] is False
    assert np.all(np.array(fast["clearance"]) <= np.array(exact["clearance"]) + 1e-6)


def test_multi_agent_check_answers_per_agent(http: httpx.Client) -> None:
    near, far = new_agent(), new_agent()
    http.post(f"/v1/agents/{near}/observations", json=observation(0.0, x=0.0, y=0.0))
    http.post(f"/v1/agents/{far}/observations", json=observation(0.0, x=500.0, y=500.0))
    missing = new_agent()
    body = http.post(
        "/v1/collision-check",
        json={
            "agent_ids": [near, far, missing, near],
            "trajectory": [{"t": 0.1, "x": 0.0, "y": 0.0}],
        },
    ).json()
    assert [r["agent_id"] for r in body["results"]] == [near, far]
    assert body["missing"] == [missing]
    assert body["results"][0]["collision"] is True and body["results"][1]["collision"] is False
    assert body["collision"] is True


def test_contours_are_geojson_in_the_world_frame(http: httpx.Client) -> None:
    agent = new_agent()
    x0, y0, speed = 50.0, 20.0, 4.0
    obs = observation(7.0, x=x0, y=y0, heading=math.pi / 2, speed=speed)
    http.post(f"/v1/agents/{agent}/observations", json=obs)
    r = http.get(f"/v1/agents/{agent}/frt", params={"slices": "1.0,2.0,3.0", "include": "K,C"})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["conservative"] is False and body["frt_version"] == 1
    assert body["tube"]["K"]["type"] in ("Polygon", "MultiPolygon")
    assert [s["t"] for s in body["slices"]] == [1.0, 2.0, 3.0]
    assert [s["time"] for s in body["slices"]] == [8.0, 9.0, 10.0]
    # Heading +y: the slice at t = 2 is a disc around (x0, y0 + 2 v).
    ring = np.array(body["slices"][1]["K"]["coordinates"][0])
    centre = ring[:-1].mean(axis=0)
    assert centre == pytest.approx([x0, y0 + 2 * speed], abs=0.3)
    c_ring = np.array(body["slices"][1]["C"]["coordinates"][0])
    assert np.ptp(c_ring[:, 0]) == pytest.approx(np.ptp(ring[:, 0]) + 3.0, abs=0.3)
    only_k = http.get(f"/v1/agents/{agent}/frt", params={"include": "K", "tube": "false"}).json()
    assert only_k["tube"] is None and only_k["slices"] == []


def test_stateless_frt_with_bounds_and_with_prediction(http: httpx.Client) -> None:
    state = {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 5.0}
    front = tube_front(5.0, NARROW_BOUNDS)
    trajectory = [{"t": 0.0, "x": 0.0, "y": 0.0}, {"t": 3.0, "x": front + 10.0, "y": 0.0}]
    body = {"state": state, "control_bounds": NARROW_BOUNDS, "trajectory": trajectory}
    r = http.post("/v1/frt", json=body)
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["conservative"] is False and out["contours"] is None
    assert out["collision"]["collision"] is True
    assert out["collision"]["clearance"][1] == pytest.approx(
        8.5, abs=tube_tolerance(5.0, NARROW_BOUNDS)
    )
    assert out["control_bounds"] == pytest.approx(NARROW_BOUNDS)

    with_prediction = {
        "state": state,
        "prediction": observation(0.0)["prediction"],
        "beta": 1.0,
        "contours": {"slices": [1.5], "include": ["C"]},
    }
    out = http.post("/v1/frt", json=with_prediction).json()
    assert out["beta"] == 1.0 and out["collision"] is None
    assert out["contours"]["tube"]["K"] is None and out["contours"]["tube"]["C"]
    assert out["contours"]["slices"][0]["t"] == 1.5


def test_delete_forgets_the_agent(http: httpx.Client) -> None:
    agent = new_agent()
    http.post(f"/v1/agents/{agent}/observations", json=observation(1.0))
    assert http.delete(f"/v1/agents/{agent}").json() == {"agent_id": agent, "deleted": True}
    assert http.get(f"/v1/agents/{agent}").status_code == 404
    assert http.delete(f"/v1/agents/{agent}").status_code == 404
    check = {"trajectory": [{"t": 1.0, "x": 0.0, "y": 0.0}]}
    assert http.post(f"/v1/agents/{agent}/collision-check", json=check).status_code == 404
    # A new agent under the same id starts again at version 1 with the new state.
    r = http.post(f"/v1/agents/{agent}/observations", json=observation(0.5, x=300.0))
    assert r.json()["frt_version"] == 1
    far = http.post(f"/v1/agents/{agent}/collision-check", json=check).json()
    assert far["collision"] is False


def test_metrics_show_routes_frt_times_cache_and_agents(http: httpx.Client) -> None:
    agent = new_agent()
    http.post(f"/v1/agents/{agent}/observations", json=observation(1.0))
    wait_exact(http, agent)
    http.post(
        f"/v1/agents/{agent}/collision-check", json={"trajectory": [{"t": 1, "x": 0, "y": 0}]}
    )
    text = http.get("/metrics").text
    assert 'route="/v1/agents/{agent_id}/collision-check"' in text
    assert 'frt_compute_seconds_count{kind="exact"}' in text
    for phase in ("queued", "transfer"):  # where an exact set's time goes besides computing it
        count = next(
            line for line in text.splitlines()
            if line.startswith(f'frt_exact_phase_seconds_count{{phase="{phase}"}}')
        )  # fmt: skip
        assert float(count.split()[1]) >= 1
    assert 'frt_cache_lookups_total{result="hit"}' in text
    agents_line = next(line for line in text.splitlines() if line.startswith("frt_agents "))
    assert float(agents_line.split()[1]) >= 1


def test_websocket_stream(live_server: LiveServer) -> None:
    agent = new_agent()
    with connect(f"{live_server.ws_url}/v1/stream") as ws:

        def call(message: dict | str) -> dict:
            ws.send(message if isinstance(message, str) else json.dumps(message))
            return json.loads(ws.recv(timeout=10))

        ok = call({"id": 1, "op": "observe", "agent_id": agent, **observation(1.0)})
        assert ok["id"] == 1 and ok["ok"] is True and ok["result"]["frt_version"] == 1
        check = call(
            {
                "id": "c",
                "op": "collision_check",
                "agent_id": agent,
                "trajectory": [{"t": 1.0, "x": 0.0, "y": 0.0}],
            }
        )
        assert check["ok"] is True and check["result"]["collision"] is True
        assert call({"id": 2, "op": "get_agent", "agent_id": agent})["result"]["agent_id"] == agent
        frt = call({"id": 3, "op": "frt", "agent_id": agent, "slices": [1.0], "include": ["K"]})
        assert frt["ok"] is True and frt["result"]["slices"][0]["K"]["type"]
        stale = call({"id": 4, "op": "observe", "agent_id": agent, **observation(0.5)})
        assert stale["ok"] is False and stale["error"]["status"] == 409
        # Malformed messages get an error answer and the socket stays open.
        assert call("not json")["error"]["status"] == 400
        assert call("[1, 2]")["error"]["status"] == 400
        assert call({"id": 5, "op": "fly"})["error"]["field"] == "op"
        bad = call({"id": 6, "op": "observe", "agent_id": agent, "timestamp": "soon"})
        assert bad["ok"] is False and bad["error"]["status"] == 422
        assert bad["error"]["field"] == "timestamp"
        assert call({"id": 7, "op": "ping"}) == {"id": 7, "ok": True, "result": {"pong": True}}
        # Ops without a body refuse fields they do not know, as HTTP bodies do.
        for op in ("get_agent", "delete_agent", "ping"):
            extra = call({"id": 8, "op": op, "agent_id": agent, "wait_frt_ms": 5})
            assert extra["error"]["status"] == 422 and extra["error"]["field"] in (
                "agent_id",
                "wait_frt_ms",
            )
        assert call({"id": 9, "op": "get_agent", "agent_id": agent})["ok"] is True


def test_auth_token_guards_v1_only(start_server) -> None:
    server = start_server(auth_token="s3cret")
    with httpx.Client(base_url=server.url, timeout=10.0) as client:
        assert client.get("/healthz").status_code == 200
        assert client.get("/readyz").status_code == 200
        r = client.get("/v1/model")
        assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
        wrong = {"Authorization": "Bearer nope"}
        assert client.get("/v1/model", headers=wrong).status_code == 401
        # Checked before the body: even a malformed body gets the 401.
        r = client.post("/v1/agents/a/observations", content=b"{", headers=wrong)
        assert r.status_code == 401
        good = {"Authorization": "Bearer s3cret"}
        assert client.get("/v1/model", headers=good).status_code == 200
    with connect(f"{server.ws_url}/v1/stream?token=s3cret") as ws:
        ws.send(json.dumps({"id": 1, "op": "ping"}))
        assert json.loads(ws.recv(timeout=10))["ok"] is True
    with pytest.raises(InvalidStatus) as refused:
        connect(f"{server.ws_url}/v1/stream")
    assert refused.value.response.status_code == 403


def test_without_a_model_the_service_lives_but_is_not_ready(start_server, tmp_path) -> None:
    server = start_server(ready=False, model_path=str(tmp_path / "missing.onnx"))
    with httpx.Client(base_url=server.url, timeout=10.0) as client:
        assert client.get("/healthz").status_code == 200
        ready = client.get("/readyz")
        assert ready.status_code == 503 and ready.json()["ready"] is False
        assert client.get("/v1/model").status_code == 503
        r = client.post("/v1/agents/a/observations", json=observation(1.0))
        assert r.status_code == 503


def test_an_unreachable_store_makes_the_service_not_ready(start_server) -> None:
    """The model loads, but the Redis store does not answer: not ready, and the detail says why."""
    server = start_server(ready=False, store_url=f"redis://127.0.0.1:{_free_port()}/0")
    with httpx.Client(base_url=server.url, timeout=10.0) as client:
        assert client.get("/healthz").status_code == 200
        deadline = time.monotonic() + 30.0
        while True:
            ready = client.get("/readyz")
            if ready.json()["detail"] == "agent store unreachable" or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert ready.status_code == 503, ready.json()
        assert ready.json() == {
            "ready": False,
            "model": ready.json()["model"],
            "detail": "agent store unreachable",
            "active": ready.json()["active"],
        }
        assert ready.json()["model"] is not None
        assert ready.json()["active"]["geometry"][0] == "outer_bound"
