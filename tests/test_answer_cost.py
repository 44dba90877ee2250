"""Answering within the deadline: cost estimates, and exact sets answered conservatively when there
is no time left to measure them (service.runtime.answer_cost, service.flows.checks)."""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from service.runtime.answer_cost import SPREAD, AnswerCosts, CostEstimate, work_units
from service.runtime.settings import Settings
from tests.fixtures.payloads import observation
from tests.test_api_errors import client_for


def test_an_estimate_allows_for_the_spread_of_what_it_saw() -> None:
    estimate = CostEstimate()
    assert estimate.upper_s(50) == 0.0  # nothing measured: no reason to hold back
    for seconds in (0.010, 0.030) * 20:  # 50 agents at 0.2 or 0.6 ms each
        estimate.record(seconds, 50)
    per_agent = estimate.upper_s(1)
    assert 0.2e-3 < estimate.mean_s < 0.6e-3
    assert per_agent > 0.6e-3  # above the slowest it saw: mean + SPREAD deviations
    assert math.isclose(estimate.upper_s(50), 50 * per_agent)
    assert math.isclose(per_agent, estimate.mean_s + SPREAD * estimate.deviation_s)
    estimate.record(1.0, 0)  # no agents: nothing to learn
    assert math.isclose(estimate.upper_s(1), per_agent)


def _costs(exact_s: float, conservative_s: float, response_s: float) -> AnswerCosts:
    return AnswerCosts(
        exact=CostEstimate(exact_s, 0.0, True),
        conservative=CostEstimate(conservative_s, 0.0, True),
        response=CostEstimate(response_s, 0.0, True),
    )


def test_as_many_exact_answers_as_fit() -> None:
    costs = _costs(exact_s=1e-3, conservative_s=0.1e-3, response_s=0.05e-3)
    # 50 agents of one unit, 40 with exact sets: all conservative costs 7.5 ms, each exact one
    # 0.9 ms more.
    ones = [1.0] * 40
    assert math.isclose(costs.upper_s(0, 50, 50), 7.5e-3)
    for seconds in (0.0, 7.0e-3, 7.5e-3 + 0.89e-3, 7.5e-3 + 0.91e-3, 0.02, 1.0):
        k = costs.exact_agents_within(seconds, ones, 50, 50)
        assert 0 <= k <= 40
        assert k == 0 or costs.upper_s(k, 50 - k, 50) <= seconds + 1e-12
        assert k == 40 or costs.upper_s(k + 1, 49 - k, 50) > seconds
    assert costs.exact_agents_within(1.0, ones, 50, 50) == 40
    assert costs.exact_agents_within(7.0e-3, ones, 50, 50) == 0
    cheaper = _costs(exact_s=0.1e-3, conservative_s=0.2e-3, response_s=0.0)
    assert cheaper.exact_agents_within(0.011, ones, 50, 50) == 40
    # Past the deadline's reserve either way: conservative answers would take longer still.
    assert cheaper.exact_agents_within(0.005, ones, 50, 50) == 40
    assert cheaper.exact_agents_within(0.0, ones, 50, 50) == 40


def test_heavy_agents_count_by_their_work() -> None:
    """An agent of many modes checked at many probes weighs its members times its probes: the
    exact answers that fit stop before it, though lighter agents after it would fit."""
    assert work_units(20) == 1.0
    assert work_units(1000, members=32) == 32 * 1020 / 40
    costs = _costs(exact_s=1e-3, conservative_s=0.1e-3, response_s=0.0)
    heavy = work_units(1000, members=32)
    units = [1.0, 1.0, heavy, 1.0]
    total = sum(units)
    seconds = total * 0.1e-3 + 3 * 0.9e-3 + 1e-6  # room for three light exact answers
    assert costs.exact_agents_within(seconds, units, total, 4.0) == 2
    assert costs.exact_agents_within(seconds + heavy * 0.9e-3, units, total, 4.0) == 4


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    yield from client_for(Settings(model_path=analytic_model_path, log_requests=False))


def test_an_exact_set_too_slow_to_answer_from_is_answered_conservatively(
    client: TestClient,
) -> None:
    client.post("/v1/agents/slow/observations", params={"wait_frt_ms": 5000}, json=observation(1.0))
    check = {
        "trajectory": [{"t": 1.0 + 0.1 * i, "x": 2.0 + i, "y": 0.5} for i in range(10)],
        "deadline_ms": 20.0,
    }
    quick = client.post("/v1/agents/slow/collision-check", json=check).json()
    assert quick["conservative"] is False  # the exact set is ready and cheap to answer from
    before = _conservative_answers(client)
    costs: AnswerCosts = client.app.state.services.answer_costs  # type: ignore[attr-defined]
    learned = costs.exact
    costs.exact = CostEstimate(mean_s=1.0, deviation_s=0.0, measured=True)  # a second per agent
    try:
        slow = client.post("/v1/agents/slow/collision-check", json=check).json()
        ample = client.post(
            "/v1/agents/slow/collision-check", json={**check, "deadline_ms": 5000.0}
        ).json()
    finally:
        costs.exact = learned
    assert slow["conservative"] is True and slow["frt_version"] == quick["frt_version"]
    after = _conservative_answers(client)
    assert after.get("no_time", 0.0) == before.get("no_time", 0.0) + 1  # and says why, once
    assert after.get("not_ready", 0.0) == before.get("not_ready", 0.0)
    # The conservative set contains the exact one: never less safe, point by point.
    assert all(c <= q + 1e-9 for c, q in zip(slow["clearance"], quick["clearance"], strict=True))
    assert slow["collision"] or not quick["collision"]
    assert ample["conservative"] is False and ample["clearance"] == quick["clearance"]


def _conservative_answers(client: TestClient) -> dict[str, float]:
    """``frt_conservative_answers_total`` by reason, from /metrics."""
    out = {}
    for line in client.get("/metrics").text.splitlines():
        if line.startswith("frt_conservative_answers_total{"):
            reason = line.split('reason="')[1].split('"')[0]
            out[reason] = float(line.rsplit(" ", 1)[1])
    return out


def test_a_late_check_is_counted_and_logged_with_where_its_time_went(
    client: TestClient, caplog: pytest.LogCaptureFixture
) -> None:
    """A deadline no answer can meet (1 us): the check still answers, /metrics counts the miss,
    and one warning names the deadline, the elapsed time and each phase, which add up to it."""
    client.post("/v1/agents/late/observations", params={"wait_frt_ms": 5000}, json=observation(1.0))
    check = {"trajectory": [{"t": 1.5, "x": 2.0, "y": 0.5}], "deadline_ms": 0.001}
    before = _deadline_misses(client)
    with caplog.at_level(logging.WARNING, logger="frt.checks"):
        answer = client.post("/v1/agents/late/collision-check", json=check)
    assert answer.status_code == 200
    assert _deadline_misses(client) == before + 1
    (record,) = [r for r in caplog.records if r.name == "frt.checks"]
    assert record.deadline_ms == 0.001 and record.elapsed_ms > 0.001
    phases = ("before_ms", "wait_ms", "boxes_ms", "sets_ms", "response_ms")
    assert all(getattr(record, p) >= 0 for p in phases)
    assert sum(getattr(record, p) for p in phases) == pytest.approx(record.elapsed_ms, abs=0.01)
    assert record.agents == 1


def _deadline_misses(client: TestClient) -> float:
    lines = client.get("/metrics").text.splitlines()
    return next(
        float(x.rsplit(" ", 1)[1]) for x in lines if x.startswith("frt_deadline_misses_total")
    )


def test_an_estimate_too_high_to_answer_exactly_comes_down(client: TestClient) -> None:
    """A check that answers every agent conservatively for want of time measures, once answered,
    what the exact answer would have cost: an estimate once too high (a cold first answer, a pause
    under load) comes down, and checks answer from the exact set again."""
    client.post("/v1/agents/cold/observations", params={"wait_frt_ms": 5000}, json=observation(1.0))
    check = {"trajectory": [{"t": 1.0 + 0.1 * i, "x": 2.0 + i, "y": 0.5} for i in range(10)]}
    # The first answer measures the exact answer's cost; a deadline a busy machine cannot miss.
    first = client.post("/v1/agents/cold/collision-check", json={**check, "deadline_ms": 1000.0})
    assert first.json()["conservative"] is False
    check["deadline_ms"] = 20.0
    costs: AnswerCosts = client.app.state.services.answer_costs  # type: ignore[attr-defined]
    learned = costs.exact
    costs.exact = CostEstimate(mean_s=0.05, deviation_s=0.0, measured=True)  # 50 ms per agent
    try:
        answers = [
            client.post("/v1/agents/cold/collision-check", json=check).json()["conservative"]
            for _ in range(60)
        ]
        assert answers[0] is True  # the estimate says the exact answer cannot make 20 ms
        # Measured since: it can (one late answer on a busy machine is not a failure to learn).
        assert False in answers[-10:]
        assert costs.exact.mean_s < 0.01
    finally:
        costs.exact = learned


def test_a_batch_check_learns_its_own_cost_and_leaves_single_checks_theirs(
    client: TestClient,
) -> None:
    client.post(
        "/v1/agents/batch/observations", params={"wait_frt_ms": 5000}, json=observation(1.0)
    )
    single = {"trajectory": [{"t": 1.0 + 0.1 * i, "x": 2.0 + i, "y": 0.5} for i in range(10)]}
    assert client.post("/v1/agents/batch/collision-check", json=single).status_code == 200
    services = client.app.state.services  # type: ignore[attr-defined]
    singles = CostEstimate(**vars(services.answer_costs.exact))
    batch = {
        "trajectories": [
            {
                "t": [1.0 + 0.1 * i for i in range(30)],
                "x": [k + i for i in range(30)],
                "y": [0.5] * 30,
            }
            for k in range(200)
        ],
        "deadline_ms": 5000.0,
    }
    answer = client.post("/v1/agents/batch/collision-check", json=batch).json()
    assert answer["verdict"] == "exact" and len(answer["trajectories"]) == 200
    assert services.batch_answer_costs.exact.measured
    assert vars(services.answer_costs.exact) == vars(singles)


def test_left_out_exact_answers_are_measured_in_a_share_of_the_time() -> None:
    """Measuring a left-out exact answer holds the loop as long as that answer would have: the
    next may start only once nine times as long again has passed (REMEASURE_SHARE 0.1)."""
    costs = AnswerCosts()
    assert costs.remeasure_after == -math.inf  # the first may start at once
    costs.remeasured(10.0, 10.002)  # one of 2 ms
    assert math.isclose(costs.remeasure_after, 10.002 + 9 * 0.002)
    costs.remeasured(20.0, 20.0001)  # a light one: the next soon after
    assert math.isclose(costs.remeasure_after, 20.0001 + 9 * 0.0001)
