"""Every decision-exact verdict is the exact set's (API.md, "Frames": a set containing the exact one
that the trajectory clears), checked on answers the service gave before its exact sets were ready:
each agent's exact set is recomputed offline by an engine of its own from the agent's stored state,
and every decision-exact answer's trajectories must clear it too."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.engine import FRTEngine
from service.runtime.jobs import job_for
from service.runtime.settings import Settings
from tests.fixtures.payloads import observation
from tests.test_api_errors import client_for

AGENTS = 12


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    # Checks with a 1 ms deadline never wait: every answer comes from the conservative set.
    settings = Settings(
        model_path=analytic_model_path, log_requests=False, deadline_wait_fraction=0
    )
    yield from client_for(settings)


@pytest.fixture(scope="module")
def offline_engine(analytic_model_path: Path) -> FRTEngine:
    return engine_for(ValueModel.load(analytic_model_path))


def random_trajectories(rng: np.random.Generator, count: int) -> list[dict]:
    out = []
    for _ in range(count):
        start = rng.uniform([-40.0, -40.0], [60.0, 40.0])
        heading, speed = rng.uniform(-np.pi, np.pi), rng.uniform(0.0, 15.0)
        t = 1.0 + 0.1 * np.arange(20)
        x = start[0] + speed * (t - 1.0) * np.cos(heading)
        y = start[1] + speed * (t - 1.0) * np.sin(heading)
        out.append({"t": t.tolist(), "x": x.tolist(), "y": y.tolist()})
    return out


def test_decision_exact_verdicts_hold_for_the_exact_sets_recomputed_offline(
    client: TestClient, offline_engine: FRTEngine
) -> None:
    rng = np.random.default_rng(11)
    ids = [f"de-{k}" for k in range(AGENTS)]
    for agent in ids:
        body = observation(
            1.0,
            x=float(rng.uniform(-20, 40)),
            y=float(rng.uniform(-20, 20)),
            heading=float(rng.uniform(-np.pi, np.pi)),
            speed=float(rng.uniform(0.0, 12.0)),
        )
        assert client.post(f"/v1/agents/{agent}/observations", json=body).status_code == 200
    trajectories = random_trajectories(rng, 60)
    answers = client.post(
        "/v1/collision-check",
        json={
            "trajectories": trajectories,
            "agent_ids": ids,
            "mode": "time_indexed",
            "deadline_ms": 1.0,
        },
    ).json()["results"]
    services = client.app.state.services  # type: ignore[attr-defined]
    decided = 0
    for answer in answers:
        if answer["verdict"] != "decision_exact":
            continue
        state = client.portal.call(services.store.get, answer["agent_id"])  # type: ignore[union-attr]
        job = job_for(state)
        exact = offline_engine.exact(job.pose, job.v_start, job.bounds)
        for trajectory, verdict in zip(trajectories, answer["trajectories"], strict=True):
            xy = np.column_stack([trajectory["x"], trajectory["y"]])
            t_rel = np.asarray(trajectory["t"]) - state.timestamp
            clearance = exact.clearance(xy, t_rel) - answer["collision_radius"]
            assert not verdict["collision"]
            assert (clearance >= 0.0).all(), answer["agent_id"]
            # The conservative clearance is a lower bound of the exact one.
            assert verdict["min_clearance"] <= clearance.min() + 1e-9
        decided += 1
    assert answers and all(a["conservative"] for a in answers)
    assert 0 < decided < len(answers)  # some are clear, some are met (verdict conservative)
