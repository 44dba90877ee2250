"""Time-indexed checks answer from the exact set once it is ready: a real server, the shipped model.

A time-indexed check compares each point at time t with the tube up to t. The agent's first such
check draws those tubes on the event loop (within its budget) and names them; the worker that
computes each later version draws them before sending it back (``service.runtime.tube_demand``),
so its checks answer ``conservative: false`` without drawing any on the event loop. The independent
reference is the conservative set (boxes, ``reach.outer_bound``), which contains the exact one: no
point may be farther from it than from the exact tube, and the whole-horizon tube never leaves a
point clearer than the tube up to the point's time.
"""

from __future__ import annotations

import time
import uuid
from pathlib import Path

import httpx
import pytest

from tests.conftest import LiveServer

pytestmark = pytest.mark.slow

SHIPPED = Path(__file__).resolve().parents[1] / "models" / "frt_unicycle.onnx"
#: 30 points over the 3 s horizon, 0.1 s apart, standing 18 m ahead of the human.
POINTS = 30


@pytest.fixture(scope="module")
def shipped_server(start_server) -> LiveServer:
    return start_server(model_path=str(SHIPPED))


def observation(t: float, x: float, speed: float) -> dict:
    steps = 6
    return {
        "timestamp": t,
        "state": {"x": x, "y": 0.0, "heading": 0.0, "speed": speed},
        "prediction": {
            "dt": 0.5,
            "mean": [[0.0, 0.2]] * steps,
            "cov": [[[0.04, 0.0], [0.0, 0.5]]] * steps,
        },
    }


def trajectory(t0: float, x0: float) -> list[dict]:
    return [{"t": t0 + 0.1 * k, "x": x0 + 18.0, "y": 1.0} for k in range(1, POINTS + 1)]


def event_loop_tubes(http: httpx.Client) -> float:
    for line in http.get("/metrics").text.splitlines():
        if line.startswith("frt_event_loop_tubes_total "):
            return float(line.split()[-1])
    return 0.0


def check(
    http: httpx.Client, agent: str, points: list[dict], mode: str, deadline_ms: float = 5000
) -> dict:
    # A long deadline: what is asserted is where the tubes come from, not how fast a busy
    # machine answers.
    response = http.post(
        f"/v1/agents/{agent}/collision-check",
        json={"trajectory": points, "mode": mode, "deadline_ms": deadline_ms},
    )
    assert response.status_code == 200, response.text
    return response.json()


def test_a_time_indexed_check_of_a_ready_set_is_exact(shipped_server: LiveServer) -> None:
    agent = f"h-{uuid.uuid4().hex[:8]}"
    with httpx.Client(base_url=shipped_server.url, timeout=30.0) as http:
        for version, t in enumerate((10.0, 10.5), start=1):
            x = 8.0 * (t - 10.0)
            answer = http.post(
                f"/v1/agents/{agent}/observations?wait_frt_ms=10000",
                json=observation(t, x, speed=8.0),
            ).json()
            assert answer["frt_version"] == version and answer["frt_ready"] is True
            drawn_before = event_loop_tubes(http)
            points = trajectory(t, x)
            timed = check(http, agent, points, "time_indexed")
            assert timed["conservative"] is False, "the exact set was ready: answer from it"
            assert timed["frt_version"] == version
            if version == 1:  # no check had named the tubes: drawn on the event loop
                assert event_loop_tubes(http) > drawn_before
            else:  # named by the first check: drawn by the worker
                assert event_loop_tubes(http) == drawn_before, "tubes drawn on the event loop"
            whole = check(http, agent, points, "tube")
            assert whole["conservative"] is False
            # Tubes grow with time: the whole tube is never farther than the tube up to t.
            assert all(
                w <= c + 1e-6 for w, c in zip(whole["clearance"], timed["clearance"], strict=True)
            )
            assert any(
                w < c - 0.5 for w, c in zip(whole["clearance"], timed["clearance"], strict=True)
            )
            conservative = check(http, agent, points, "time_indexed")
            assert conservative["clearance"] == timed["clearance"]  # the same set, answered again


def test_a_first_time_indexed_check_draws_its_tubes_when_they_fit_its_deadline(
    shipped_server: LiveServer,
) -> None:
    """The server times tubes at start-up, so a new agent's first time-indexed check plans with
    what they cost here: at a 200 ms deadline (a wait of 120 ms) its 30 tubes fit, where the first
    guess (2 ms each, plus four deviations) would not."""
    agent = f"h-{uuid.uuid4().hex[:8]}"
    with httpx.Client(base_url=shipped_server.url, timeout=30.0) as http:
        answer = http.post(
            f"/v1/agents/{agent}/observations?wait_frt_ms=10000",
            json=observation(20.0, 0.0, speed=8.0),
        ).json()
        assert answer["frt_ready"] is True
        first = check(http, agent, trajectory(20.0, 0.0), "time_indexed", deadline_ms=200)
        assert first["conservative"] is False


TURNING = {
    "u1_min_start": -0.8, "u2_min_start": -1.0, "u1_min_end": -0.8, "u2_min_end": -1.0,
    "u1_max_start": 0.8, "u2_max_start": 1.0, "u1_max_end": 0.8, "u2_max_end": 1.0,
}  # fmt: skip


def tube_area(body: dict) -> float:
    from shapely.geometry import shape

    return shape(body["contours"]["tube"]["K"]).area


def test_the_stateless_frt_says_when_it_answers_from_the_uncut_set(
    shipped_server: LiveServer,
) -> None:
    """A car that may turn round within the horizon: the first answer is the exact set before the
    notch cut (stage 0, refinement pending); asked again, the refined set, never larger."""
    request = {
        "state": {"x": 1.0, "y": -2.0, "heading": 0.3, "speed": 3.0},
        "control_bounds": TURNING,
        "contours": {"slices": [], "include": ["K"]},
    }
    with httpx.Client(base_url=shipped_server.url, timeout=30.0) as http:
        first = http.post("/v1/frt", json=request).json()
        assert first["conservative"] is False
        assert first["refinement_stage"] == 0 and first["refinement"] == "pending"
        later = first
        for _ in range(200):
            later = http.post("/v1/frt", json=request).json()
            if later["refinement_stage"] > 0:
                break
            time.sleep(0.05)
        assert later["refinement_stage"] > 0, "the refinement never landed"
        assert later["refinement"] in ("pending", "done")
        assert tube_area(later) <= tube_area(first) + 1e-9
