"""The coverage audit and adaptive gamma (docs/coverage.md), in-process with the analytic model.

The audit's distances are checked against an independent path to the same sets: a time-indexed
collision check with ``collision_radius = 0`` sent before the observation, whose clearance is the
distance to K at that point's time.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.flows.adaptive_gamma import GAMMA_MAX, GAMMA_MIN, next_state, served_gamma
from service.runtime.settings import Settings

NARROW = [[[0.01, 0.0], [0.0, 0.01]]] * 6
STRAIGHT = [[0.0, 0.0]] * 6
CONFIDENCE_OFF = 0.999999


def _client(model: Path, **settings: object) -> Iterator[TestClient]:
    app = create_app(
        Settings(model_path=model, log_requests=False, frt_executor="thread", **settings)
    )
    with TestClient(app, raise_server_exceptions=False) as c:
        deadline = time.monotonic() + 30
        while c.get("/readyz").status_code != 200:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        yield c


@pytest.fixture
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    yield from _client(analytic_model_path)


def observe(client: TestClient, agent: str, t: float, x: float, y: float, **extra) -> dict:
    body = {
        "timestamp": t,
        "state": {"x": x, "y": y, "heading": 0.0, "speed": 5.0},
        "prediction": {"dt": 0.5, "mean": STRAIGHT, "cov": NARROW},
        **extra,
    }
    r = client.post(f"/v1/agents/{agent}/observations?wait_frt_ms=5000", json=body)
    assert r.status_code == 200, r.text
    return r.json()


def distance_to_k(client: TestClient, agent: str, t: float, x: float, y: float) -> float:
    """The current version's distance to K at (x, y) and time t, from a time-indexed check."""
    r = client.post(
        f"/v1/agents/{agent}/collision-check",
        json={
            "trajectory": [{"t": t, "x": x, "y": y}],
            "mode": "time_indexed",
            "collision_radius": 0.0,
            "deadline_ms": 10_000,
        },
    )
    assert r.status_code == 200, r.text
    assert r.json()["conservative"] is False
    return float(r.json()["clearance"][0])


def audit_metrics(client: TestClient) -> dict[str, float]:
    """Sums of the audit's counters by series and set label, and the coverage gauges."""
    out: dict[str, float] = {}
    for line in client.get("/metrics").text.splitlines():
        if line.startswith("frt_audit") and not line.startswith("#"):
            name, value = line.rsplit(" ", 1)
            if "_created" in name:
                continue
            series = name.split("{")[0]
            part = 'set="C"' if 'set="C"' in name else 'set="K"' if 'set="K"' in name else ""
            key = f"{series}{{{part}}}" if part else series
            out[key] = out.get(key, 0.0) + float(value)
    return out


def test_audit_counts_a_scripted_hit_and_miss_exactly(client: TestClient) -> None:
    radius = 1.5
    hit, miss = (0.5, 2.5, 0.0), (1.0, 5.0, 20.0)  # (t, x, y): on the predicted path; far off
    observe(client, "scripted", 0.0, 0.0, 0.0, config={"collision_radius": radius})
    d1_hit = distance_to_k(client, "scripted", *hit)
    d1_miss = distance_to_k(client, "scripted", *miss)
    assert d1_hit <= 0.0 < d1_miss

    observe(client, "scripted", *hit)
    audit = client.get("/v1/agents/scripted").json()["audit"]
    assert (audit["audited"], audit["missed_k"], audit["missed_c"]) == (1, 0, 0)
    assert audit["last_miss"] is None and audit["coverage_c"] == 1.0

    d2_miss = distance_to_k(client, "scripted", *miss)
    observe(client, "scripted", *miss)  # against version 1 (t0 = 0) and version 2 (t0 = 0.5)
    agent = client.get("/v1/agents/scripted").json()
    audit = agent["audit"]
    assert (audit["audited"], audit["missed_k"], audit["missed_c"]) == (3, 2, 2)
    # The checks drew the tubes the audit needs: every position was scored on the exact sets.
    assert audit["exact"] == 3
    last = audit["last_miss"]
    worst = max(d1_miss, d2_miss)
    assert last["timestamp"] == 1.0
    assert last["frt_version"] == (1 if d1_miss >= d2_miss else 2)
    assert last["distance_outside_k_m"] == pytest.approx(worst, abs=1e-9)
    assert last["distance_outside_c_m"] == pytest.approx(worst - radius, abs=1e-9)
    assert last["source"] == "exact"
    assert audit["coverage_c"] == pytest.approx(1 / 3)
    assert agent["gamma_effective"] == agent["config"]["gamma"] and audit["gamma_state"] is None

    metrics = audit_metrics(client)
    assert metrics["frt_audit_positions_total"] == 3
    assert metrics['frt_audit_misses_total{set="K"}'] == 2
    assert metrics['frt_audit_misses_total{set="C"}'] == 2
    assert metrics['frt_audit_coverage{set="C"}'] == pytest.approx(1 / 3)


def test_audit_scores_only_versions_whose_horizon_covers_the_time(client: TestClient) -> None:
    for t in (0.0, 0.5, 1.0):
        observe(client, "horizon", t, 5.0 * t, 0.0)
    assert client.get("/v1/agents/horizon").json()["audit"]["audited"] == 1 + 2
    observe(client, "horizon", 3.4, 17.0, 0.0)  # covered by versions 2 (to 3.5) and 3 (to 4.0)
    assert client.get("/v1/agents/horizon").json()["audit"]["audited"] == 3 + 2
    observe(client, "horizon", 9.0, 45.0, 0.0)  # nobody's horizon reaches 9 s
    audit = client.get("/v1/agents/horizon").json()["audit"]
    assert audit["audited"] == 5 and audit["missed_c"] == 0


def test_a_new_life_of_an_agent_is_not_scored_against_the_old_one(client: TestClient) -> None:
    observe(client, "again", 0.0, 0.0, 0.0)
    assert client.delete("/v1/agents/again").status_code == 200
    observe(client, "again", 0.5, 50.0, 50.0)  # far from the old set: would be a miss
    observe(client, "again", 1.0, 52.5, 50.0)
    audit = client.get("/v1/agents/again").json()["audit"]
    assert (audit["audited"], audit["missed_c"]) == (1, 0)


def test_multi_modal_cyclist_is_audited_against_its_union_set(client: TestClient) -> None:
    """A two-mode cyclist: its sets are the union of the modes' (the check's distances, taken as
    ground truth, are to the same union); the class sets the collision radius and labels the
    metrics."""
    before = client.get("/metrics").text.count('agent_class="cyclist"')
    modes = {"modes": [{"weight": 0.5, "mean": STRAIGHT, "cov": NARROW},
                       {"weight": 0.5, "mean": [[0.8, 0.5]] * 6, "cov": NARROW}]}  # fmt: skip

    def send(t: float, x: float, y: float) -> None:
        body = {
            "timestamp": t,
            "state": {"x": x, "y": y, "heading": 0.0, "speed": 4.0},
            "prediction": {"dt": 0.5, **modes},
            "agent_class": "cyclist",
        }
        r = client.post("/v1/agents/bike/observations?wait_frt_ms=5000", json=body)
        assert r.status_code == 200, r.text

    hit, miss = (1.5, 6.0, 0.0), (2.0, 0.0, -30.0)
    send(0.0, 0.0, 0.0)
    assert distance_to_k(client, "bike", *hit) <= 0.0
    d1 = distance_to_k(client, "bike", *miss)
    send(*hit)
    d2 = distance_to_k(client, "bike", *miss)
    send(*miss)
    agent = client.get("/v1/agents/bike").json()
    audit = agent["audit"]
    assert (audit["audited"], audit["missed_k"], audit["missed_c"]) == (1 + 2, 2, 2)
    radius = agent["config"]["collision_radius"]
    assert radius != 1.5  # the cyclist's own
    last = audit["last_miss"]
    assert last["distance_outside_k_m"] == pytest.approx(max(d1, d2), abs=1e-9)
    assert last["distance_outside_c_m"] == pytest.approx(max(d1, d2) - radius, abs=1e-9)
    assert client.get("/metrics").text.count('agent_class="cyclist"') > before


def test_audit_off(analytic_model_path: Path) -> None:
    for c in _client(analytic_model_path, audit=False):
        observe(c, "quiet", 0.0, 0.0, 0.0)
        observe(c, "quiet", 0.5, 5.0, 30.0)
        assert c.get("/v1/agents/quiet").json()["audit"] is None
        assert "frt_audit_positions_total" not in audit_metrics(c)


# ------------------------------------------------------------------------------ adaptive gamma


def test_rule_moves_gamma_up_on_misses_and_down_slowly_on_hits() -> None:
    g = 0.075
    up = next_state(g, audited=1, missed=1, target=0.99, step=0.02)
    down = next_state(g, audited=1, missed=0, target=0.99, step=0.02)
    assert up == pytest.approx(g + 0.02 * 0.99) and down == pytest.approx(g - 0.02 * 0.01)
    assert next_state(GAMMA_MIN, 100, 0, 0.99, 0.5) == GAMMA_MIN
    assert served_gamma(5.0) == GAMMA_MAX and served_gamma(-1.0) == GAMMA_MIN


def test_rule_bound_holds_on_any_sequence() -> None:
    """Gibbs & Candès's bound, misses/T <= a + (g_T - g_1) / (eta T), on adversarial streams:
    misses exactly when gamma is low, in bursts, and at random."""
    rng = np.random.default_rng(0)
    ticks = itertools.count()
    streams = {
        "adversarial": lambda g: bool(g < 0.6),
        "bursts": lambda g: next(ticks) % 50 < 10,
        "random": lambda g: bool(rng.random() < 0.3),
    }
    target, step = 0.95, 0.03
    for miss in streams.values():
        g = g1 = 0.075
        misses = 0
        for _ in range(5000):
            m = miss(served_gamma(g))
            misses += m
            g = next_state(g, 1, int(m), target, step)
        assert misses / 5000 <= (1 - target) + (g - g1) / (step * 5000) + 1e-12


def human_track(n: int, seed: int, sd: float) -> list[tuple[float, float, float, float]]:
    """A car at 5 m/s steering at a rate drawn from N(0, sd^2) every 0.5 s: (t, x, y, heading)."""
    rng = np.random.default_rng(seed)
    x = y = h = 0.0
    out = []
    for k in range(n):
        out.append((0.5 * k, x, y, h))
        u1 = rng.normal(0.0, sd)
        for _ in range(50):
            x, y, h = x + 5.0 * math.cos(h) * 0.01, y + 5.0 * math.sin(h) * 0.01, h + u1 * 0.01
    return out


def run_stream(
    client: TestClient, agent: str, config: dict, n: int = 250, gammas: list | None = None
) -> dict:
    """Observe the stream with a narrow straight-ahead predictor; the agent's final view (and,
    into ``gammas``, its ``gamma_effective`` every 10 observations)."""
    for k, (t, x, y, h) in enumerate(human_track(n, seed=1, sd=0.4)):
        if gammas is not None and k % 10 == 0:
            gammas.append(client.get(f"/v1/agents/{agent}").json()["gamma_effective"] if k else 0)
        body = {
            "timestamp": t,
            "state": {"x": x, "y": y, "heading": (h + math.pi) % (2 * math.pi) - math.pi,
                      "speed": 5.0},
            "prediction": {"dt": 0.5, "mean": STRAIGHT, "cov": NARROW},
            "config": {"beta_low": CONFIDENCE_OFF, **config} if k == 0 else None,
        }  # fmt: skip
        r = client.post(f"/v1/agents/{agent}/observations", json=body)
        assert r.status_code == 200, r.text
    return client.get(f"/v1/agents/{agent}").json()


def test_adaptive_gamma_holds_its_target_where_the_humans_leave_the_narrow_set(
    client: TestClient,
) -> None:
    target, step, gamma = 0.9, 0.05, 0.075
    fixed = run_stream(client, "fixed", {"gamma": gamma})["audit"]
    assert fixed["coverage_c"] < target - 0.02, "the stream must leave the fixed narrow set"

    served: list[float] = []
    agent = run_stream(
        client,
        "adaptive",
        {"gamma": gamma, "coverage_target": target, "coverage_step": step},
        gammas=served,
    )
    audit = agent["audit"]
    n, g_final = audit["audited"], audit["gamma_state"]
    assert agent["config"]["coverage_target"] == target
    assert agent["gamma_effective"] == pytest.approx(min(g_final, GAMMA_MAX))
    assert max(served) > 0.3, "misses must have raised gamma"
    # The guarantee, exactly (Gibbs & Candès): miss rate <= 1 - target + (g_T - g_1) / (eta T),
    # and g stayed bounded, so the target holds up to a small finite-sample term.
    assert audit["missed_c"] / n <= (1 - target) + (g_final - gamma) / (step * n) + 1e-12
    assert g_final < 1.5
    assert audit["coverage_c"] >= target - 0.01


def test_sdk_reads_the_audit_and_sets_a_coverage_target(live_server) -> None:
    from frt_client import Audit, FRTClient

    prediction = {"dt": 0.5, "mean": STRAIGHT, "cov": NARROW}
    with FRTClient(live_server.url) as sdk:
        sdk.observe("sdk-audit", timestamp=0.0, state=(0.0, 0.0, 0.0, 5.0),
                    prediction=prediction, config={"coverage_target": 0.95})  # fmt: skip
        sdk.observe("sdk-audit", timestamp=0.5, state=(0.0, 40.0, 0.0, 5.0), prediction=prediction)
        agent = sdk.get_agent("sdk-audit")
        sdk.delete_agent("sdk-audit")
    assert isinstance(agent.audit, Audit)
    assert (agent.audit.audited, agent.audit.missed_c) == (1, 1)
    assert agent.audit.last_miss is not None and agent.audit.last_miss.distance_outside_c_m > 30
    assert agent.config.coverage_target == 0.95
    # One miss at target 0.95: gamma rose from the default by step * target.
    assert agent.gamma_effective == pytest.approx(0.075 + agent.config.coverage_step * 0.95)


def test_ledger_keeps_only_versions_that_can_still_cover_and_forgets_idle_agents() -> None:
    from service.runtime.audit import AuditLedger, ServedVersion
    from service.runtime.scheduler import FRTKey

    now = [0.0]
    ledger = AuditLedger(max_versions=4, max_agents=2, ttl_s=10.0, clock=lambda: now[0])

    def served(agent: str, version: int, t0: float) -> ServedVersion:
        key = FRTKey.of(agent, version, [t0])
        return ServedVersion(version, key, t0, t0 + 3.0, 1.5, "car", None)  # type: ignore[arg-type]

    for v, t0 in enumerate((0.0, 1.0, 2.0, 3.0, 3.5), start=1):
        ledger.record("a", served("a", v, t0))
    # At most 4 kept; at 3.6 the horizons of versions 2 (to 4.0) .. 5 cover it.
    assert [v.version for v in ledger.due("a", 3.6)] == [2, 3, 4, 5]
    ledger.record("a", served("a", 6, 5.5))  # versions 2 (to 4.0) and 3 (to 5.0) have ended
    assert [v.version for v in ledger.due("a", 5.6)] == [4, 5, 6]
    ledger.record("a", served("a", 1, 9.0))  # version 1 again: a new life starts afresh
    assert [v.version for v in ledger.due("a", 9.5)] == [1]
    ledger.record("b", served("b", 1, 0.0))
    ledger.record("c", served("c", 1, 0.0))  # over the cap of 2: "a", least recent, goes
    assert ledger.due("a", 9.5) == [] and len(ledger) == 2
    now[0] = 11.0
    ledger.record("d", served("d", 1, 0.0))  # "b" and "c" idle for more than the TTL
    assert len(ledger) == 1 and ledger.due("d", 1.0) != []


def test_ledger_scores_each_version_at_positions_spaced_apart() -> None:
    from service.runtime.audit import AuditLedger, ServedVersion
    from service.runtime.scheduler import FRTKey

    ledger = AuditLedger(max_versions=32, max_agents=4, spacing_s=0.4)
    for v in range(1, 4):  # versions at 0.0, 0.1, 0.2
        t0 = (v - 1) / 10
        key = FRTKey.of("a", v, [t0])
        ledger.record("a", ServedVersion(v, key, t0, t0 + 3.0, 1.5, "car", None))  # type: ignore[arg-type]
    due = [[s.version for s in ledger.due("a", k / 10)] for k in range(1, 12)]  # 0.1 .. 1.1 s
    # Each version at the first position after it, then at each one at least 0.4 s after the
    # last it was scored at (positions on a 0.1 s grid: every fourth).
    assert due == [[1], [2], [3], [], [1], [2], [3], [], [1], [2], [3]]
    unspaced = AuditLedger(max_versions=32, max_agents=4)
    unspaced.record("a", ServedVersion(1, FRTKey.of("a", 1, [0.0]), 0.0, 3.0, 1.5, "car", None))  # type: ignore[arg-type]
    assert all(len(unspaced.due("a", k / 10)) == 1 for k in range(1, 31))


def test_a_frames_positions_are_scored_together_as_each_set_measures_them() -> None:
    """``score_many``: every (position, version) pair's distance is the version's set's own
    ``clearance`` at that time, bit for bit, for box sets and unions of them together."""
    from reach.engine import FRTEngine
    from reach.frames import Pose
    from reach.union import conservative_sets
    from service.runtime.audit import ServedVersion, score_many
    from service.runtime.scheduler import FRTKey

    engine = FRTEngine()
    rng = np.random.default_rng(11)
    positions = []
    for a in range(12):
        poses = [Pose(*rng.uniform(-20, 20, 2), rng.uniform(-3, 3)) for _ in range(8)]
        row = np.array([-0.3, -2, -0.3, -2, 0.3, 1, 0.3, 1]) * rng.uniform(0.2, 2)
        bounds = [row if a % 3 else np.stack([row, 0.5 * row + 0.1]) for _ in poses]
        sets = conservative_sets(engine, poses, rng.uniform(0, 12, len(poses)), bounds)
        versions = [
            ServedVersion(
                k + 1, FRTKey.of(f"a{a}", k + 1, (k,)), 0.2 * k, 0.2 * k + 3, 1.5, "car", s
            )
            for k, s in enumerate(sets)
        ]
        positions.append((*rng.uniform(-30, 30, 2).tolist(), 1.55, versions))
    scored = score_many(positions, lambda _key: None)
    for (x, y, t, versions), got in zip(positions, scored, strict=True):
        for v, s in zip(versions, got, strict=True):
            want = v.conservative.clearance(np.array([[x, y]]), np.array([t - v.t0]))[0]
            assert s.distance_to_k == want and s.version == v.version and not s.exact


def test_rolling_coverage_is_the_share_inside_over_the_last_window_positions() -> None:
    from service.runtime.audit import RollingCoverage, Scored

    rng = np.random.default_rng(3)
    rolling, every = RollingCoverage(50), []
    for size in rng.integers(0, 80, size=30):
        batch = [
            Scored(1, 0.5, float(d), 1.5, False, "car") for d in rng.normal(0.0, 1.5, size=size)
        ]
        every += batch
        found = rolling.add(batch)
        window = every[-50:]
        expected = (
            (
                sum(s.distance_to_k <= 0.0 for s in window) / len(window),
                sum(s.distance_to_k <= 1.5 for s in window) / len(window),
            )
            if window
            else (1.0, 1.0)
        )
        assert found == expected
