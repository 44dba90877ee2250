"""Witnessed collisions (``reach.witness``, ``service.flows.witnessed``): the rollouts' positions
against an independent fine integration of the same controls, every witness inside the exact set's
tube at its time, the kernel against a brute-force search, and every collision the service says is
witnessed a collision of the exact set recomputed offline."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from frt_client.models import CollisionCheck

from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.contract import COL
from reach.dynamics import interpolate_bounds
from reach.engine import FRTEngine
from reach.frames import Pose
from reach.witness import FRACTIONS, POSITION_ERROR_M, Witnesses, witnessed, witnesses
from service.runtime.jobs import job_for
from service.runtime.settings import Settings
from tests.fixtures.payloads import observation
from tests.test_api_errors import client_for

#: Settings (v_start, bounds in contract order): a car turning and braking to a stop, a car at
#: the class limits, a pedestrian at its limits, a parked car.
SETTINGS = [
    (6.0, [-0.4, -9.0, -0.2, -6.0, 0.3, -2.0, 0.5, 1.0]),
    (20.0, [-2.0, -10.0, -2.0, -10.0, 2.0, 10.0, 2.0, 10.0]),
    (3.0, [-4.0, -3.0, -4.0, -3.0, 4.0, 3.0, 4.0, 3.0]),
    (0.0, [0.0, -1.0, 0.0, -1.0, 0.0, 0.5, 0.0, 0.5]),
]


def _reference(v_start: float, bounds: list[float], step: float = 1e-4) -> np.ndarray:
    """The same rollouts by the midpoint rule on fine steps, the stop rule applied per step
    (v never below 0): positions [K, N, 2] at the witnesses' times."""
    params = np.zeros(len(COL))
    params[6:] = bounds
    f1, f2 = (
        np.array(f) for f in zip(*[(a, b) for a in FRACTIONS for b in FRACTIONS], strict=True)
    )
    n = round(3.0 / step)
    x = np.zeros((2, len(f1)))
    heading, speed = np.zeros(len(f1)), np.full(len(f1), v_start)
    out = [x.copy()]
    for k in range(n):
        lo1, lo2, hi1, hi2 = interpolate_bounds(params, np.array((k + 0.5) * step))
        u1, u2 = lo1 + f1 * (hi1 - lo1), lo2 + f2 * (hi2 - lo2)
        new_heading = heading + u1 * step
        new_speed = np.maximum(speed + u2 * step, 0.0)
        mid_heading, mid_speed = 0.5 * (heading + new_heading), 0.5 * (speed + new_speed)
        x = x + step * mid_speed * np.stack([np.cos(mid_heading), np.sin(mid_heading)])
        heading, speed = new_heading, new_speed
        out.append(x.copy())
    return np.stack(out, axis=-1).transpose(1, 2, 0)  # [K, N, 2]


@pytest.mark.parametrize("v_start, bounds", SETTINGS[:3])
def test_witness_positions_match_a_fine_independent_integration(
    v_start: float, bounds: list[float]
) -> None:
    found = witnesses(v_start, np.array(bounds))
    reference = _reference(v_start, bounds)
    index = np.round(found.times / 1e-4).astype(int)
    error = np.hypot(*(found.xy - reference[:, index]).transpose(2, 0, 1))
    assert error.max() < POSITION_ERROR_M / 3


#: The shipped model: its sets are certified to hold every trajectory under the bounds, which a
#: witness relies on (the analytic test model's value field cuts without that promise).
SHIPPED = Path(__file__).resolve().parents[1] / "models" / "frt_unicycle.onnx"


@pytest.fixture(scope="module")
def engine() -> FRTEngine:
    return engine_for(ValueModel.load(SHIPPED))


@pytest.mark.parametrize("v_start, bounds", SETTINGS)
@pytest.mark.parametrize("geometry_only", [True, False])
def test_every_witness_position_lies_in_the_exact_sets_tube_at_its_time(
    engine: FRTEngine, geometry_only: bool, v_start: float, bounds: list[float]
) -> None:
    pose = Pose(5.0, -3.0, 0.7)
    builder = FRTEngine() if geometry_only else engine
    exact = builder.exact(pose, v_start, np.array(bounds))
    found = witnesses(v_start, np.array(bounds))
    c, s = np.cos(pose.heading), np.sin(pose.heading)
    local = found.xy.reshape(-1, 2)
    world = np.column_stack(
        [pose.x + c * local[:, 0] - s * local[:, 1], pose.y + s * local[:, 0] + c * local[:, 1]]
    )
    times = np.tile(found.times, found.xy.shape[0])
    assert (exact.clearance(world, times) <= 1e-6).all()


def test_the_kernel_finds_what_a_brute_force_search_finds() -> None:
    rng = np.random.default_rng(3)
    found = Witnesses(np.linspace(0.0, 3.0, 31), rng.normal(0.0, 5.0, (4, 31, 2)))
    points = rng.normal(0.0, 6.0, (400, 2))
    until = rng.uniform(-0.5, 3.5, 400)
    for radius, limit in ((1.5, until), (0.8, None)):
        got = witnessed(found, points, limit, radius)
        reach = radius - POSITION_ERROR_M
        distance = np.hypot(*(points[:, None, None, :] - found.xy[None]).transpose(3, 0, 1, 2))
        times = np.inf if limit is None else limit[:, None, None]
        want = ((distance < reach) & (found.times[None, None, :] <= times)).any(axis=(1, 2))
        assert np.array_equal(got, want) and 0 < want.sum() < len(want)


@pytest.fixture(scope="module")
def client() -> Iterator[TestClient]:
    # Checks with a 1 ms deadline never wait: every answer comes from the conservative set.
    settings = Settings(model_path=SHIPPED, log_requests=False, deadline_wait_fraction=0)
    yield from client_for(settings)


def test_a_witnessed_collision_is_a_collision_of_the_exact_set(
    client: TestClient, engine: FRTEngine, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Checks answered from the conservative sets only (the exact sets kept from them): every
    answer said witnessed collides with the agent's exact set recomputed offline, and a
    trajectory through the agents' paths has some."""
    services = client.app.state.services  # type: ignore[attr-defined]
    monkeypatch.setattr(services, "cached_exact", lambda jobs: [None] * len(jobs))
    monkeypatch.setattr(services, "exact_futures", lambda jobs, timeout_s: [None] * len(jobs))
    rng = np.random.default_rng(8)
    ids = [f"wit-{k}" for k in range(6)]
    for k, agent in enumerate(ids):
        body = observation(1.0, x=10.0 * k, y=0.0, heading=0.0, speed=float(rng.uniform(2, 10)))
        assert client.post(f"/v1/agents/{agent}/observations", json=body).status_code == 200
    t = 1.0 + 0.1 * np.arange(20)
    witnessed_answers, clear = 0, 0
    for lane in np.linspace(-8.0, 8.0, 9):
        xy = np.column_stack([4.0 + 20.0 * (t - 1.0), np.full(len(t), lane)])
        trajectory = [
            {"t": float(ti), "x": float(x), "y": float(y)} for ti, (x, y) in zip(t, xy, strict=True)
        ]
        check = {
            "trajectory": trajectory,
            "agent_ids": ids,
            "mode": "time_indexed",
            "deadline_ms": 1.0,
        }
        for answer in client.post("/v1/collision-check", json=check).json()["results"]:
            assert answer["conservative"]
            state = client.portal.call(services.store.get, answer["agent_id"])  # type: ignore[union-attr]
            job = job_for(state)
            exact = engine.exact(job.pose, job.v_start, job.bounds)
            clearance = exact.clearance(xy, t - state.timestamp) - answer["collision_radius"]
            assert (
                CollisionCheck.model_validate(answer).collision_witnessed
                is answer["collision_witnessed"]
            )
            if answer["collision_witnessed"]:
                assert answer["collision"] and (clearance < 0.0).any(), answer["agent_id"]
                witnessed_answers += 1
            clear += not answer["collision"]
    assert witnessed_answers > 0 and clear > 0


def test_no_collision_is_witnessed_where_the_value_network_cuts_the_set(
    analytic_model_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Where the network cuts, the exact set holds the reachable states only with its calibrated
    probability (the analytic test model's cut holds some of them out): such collisions stay
    unwitnessed."""
    settings = Settings(
        model_path=analytic_model_path, log_requests=False, deadline_wait_fraction=0
    )
    for client in client_for(settings):
        services = client.app.state.services  # type: ignore[attr-defined]
        monkeypatch.setattr(services, "cached_exact", lambda jobs: [None] * len(jobs))
        monkeypatch.setattr(services, "exact_futures", lambda jobs, timeout_s: [None] * len(jobs))
        body = observation(1.0, x=10.0, y=0.0, heading=0.0, speed=6.0)
        assert client.post("/v1/agents/cut/observations", json=body).status_code == 200
        state = client.portal.call(services.store.get, "cut")  # type: ignore[union-attr]
        job = job_for(state)
        assert services.require_engine().cuts(job.v_start, job.bounds)
        t = 1.0 + 0.1 * np.arange(20)
        trajectory = [{"t": float(ti), "x": 4.0 + 20.0 * (ti - 1.0), "y": 0.0} for ti in t]
        check = {"trajectory": trajectory, "mode": "time_indexed", "deadline_ms": 1.0}
        answer = client.post("/v1/agents/cut/collision-check", json=check).json()
        assert answer["conservative"] and answer["collision"]
        assert not answer["collision_witnessed"]
