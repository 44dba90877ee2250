"""Demand-driven exact sets: checks mark the agents whose exact sets change planners' answers
(service.runtime.demand, service.flows.checks), and answers are counted by verdict."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from service.runtime.settings import Settings
from tests.fixtures.payloads import observation
from tests.test_api_errors import client_for


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    yield from client_for(Settings(model_path=analytic_model_path, log_requests=False))


def _verdicts(client: TestClient) -> dict[str, float]:
    out = {}
    for line in client.get("/metrics").text.splitlines():
        if line.startswith("frt_check_verdicts_total{"):
            name = line.split('verdict="')[1].split('"')[0]
            out[name] = float(line.rsplit(" ", 1)[1])
    return out


def test_a_check_near_an_agent_demands_its_exact_sets_and_a_far_one_does_not(
    client: TestClient,
) -> None:
    for agent, y in (("near", 0.0), ("far", 400.0)):
        answer = client.post(
            f"/v1/agents/{agent}/observations",
            params={"wait_frt_ms": 5000},
            json=observation(1.0, y=y),
        )
        assert answer.json()["frt_ready"]
    before = _verdicts(client)
    # Along the near car's lane, 5-25 m ahead of it: through its set, 400 m from the far one's.
    trajectory = [{"t": 1.0 + 0.1 * i, "x": 5.0 + i, "y": 0.0} for i in range(20)]
    answer = client.post(
        "/v1/collision-check",
        json={"trajectory": trajectory, "agent_ids": ["near", "far"], "deadline_ms": 5000},
    ).json()
    verdicts = {r["agent_id"]: r["verdict"] for r in answer["results"]}
    assert verdicts == {"near": "exact", "far": "exact"}
    demand = client.app.state.services.demand  # type: ignore[attr-defined]
    assert demand.wants("near") and not demand.wants("far")
    assert client.app.state.services.scheduler.demand is demand  # type: ignore[attr-defined]
    after = _verdicts(client)
    assert after.get("exact", 0.0) == before.get("exact", 0.0) + 2


def test_a_check_within_the_margin_demands_and_one_beyond_it_does_not(
    client: TestClient,
) -> None:
    client.post(
        "/v1/agents/edge/observations",
        params={"wait_frt_ms": 5000},
        json=observation(1.0, y=-100.0, speed=0.0),
    )
    services = client.app.state.services  # type: ignore[attr-defined]
    margin = services.settings.exact_demand_margin_m

    def clearance_at(y: float) -> float:
        body = {"trajectory": [{"t": 1.5, "x": 0.0, "y": y}], "deadline_ms": 5000}
        return client.post("/v1/agents/edge/collision-check", json=body).json()["clearance"][0]

    # A parked car's C is a disc-like set around it: walk outwards until clear by margin + 1 m.
    services.demand.forget("edge")
    y = -100.0
    while clearance_at(y) < margin + 1.0:
        y += 0.5
    services.demand.forget("edge")
    assert clearance_at(y) >= margin and not services.demand.wants("edge")
    y_inside = y
    while clearance_at(y_inside) >= margin - 0.5:
        y_inside -= 0.25
    assert services.demand.wants("edge")


def test_an_answer_near_a_set_demands_it_whichever_set_answered() -> None:
    """A trajectory clear of an agent's conservative set by less than the margin is likely to
    meet it at the next check: the agent is demanded then (its clearance is a lower bound of the
    exact set's), as for an exact answer below the margin; one clear by more is not."""
    import numpy as np

    from service.flows.checks import _note_demand
    from service.runtime.demand import ExactDemand
    from service.runtime.metrics import Metrics
    from service.wire.schemas import CollisionCheckResponse

    margin = Settings().exact_demand_margin_m

    def answer(agent_id: str, conservative: bool, collision: bool) -> CollisionCheckResponse:
        return CollisionCheckResponse.model_construct(
            agent_id=agent_id, conservative=conservative, collision=collision
        )

    class _Services:
        settings = Settings()
        metrics = Metrics()
        demand = ExactDemand(hold_s=60.0, size=16)

    results = [
        answer("clear-near", True, False),  # decision-exact, just clear of the conservative set
        answer("clear-far", True, False),
        answer("exact-near", False, False),
        answer("exact-far", False, False),
        answer("meets", True, True),  # conservative: its exact set decides
        answer("exact-meets", False, True),
    ]
    least = np.array([margin - 0.5, margin + 0.5, margin - 0.5, margin + 0.5, -1.0, -0.5])
    services = _Services()
    _note_demand(services, results, least, batch=False)  # type: ignore[arg-type]
    batch = [answer("batch-meets", False, True)]  # some candidate of many collides
    _note_demand(services, batch, np.array([-0.5]), batch=True)  # type: ignore[arg-type]
    results += batch
    wanted = {r.agent_id for r in results if services.demand.wants(r.agent_id)}
    assert wanted == {"clear-near", "exact-near", "meets", "exact-meets", "batch-meets"}
    # The trajectory met these two sets: their next sets go before the other demanded agents'.
    assert {r.agent_id for r in results if services.demand.met(r.agent_id)} == {
        "meets",
        "exact-meets",
    }
