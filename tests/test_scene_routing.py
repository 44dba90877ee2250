"""Requests routed by scene (docs/deploy.md, "Scenes"): every request carrying one ``X-FRT-Scene``
goes to one replica, which computes each of the scene's sets once; a replica's death moves its
scenes to another, which reads their agents from Redis and answers them again.

In-process (fast): ``X-FRT-Replica`` names the answering replica; ``frt_exact_sets`` tells a set
computed for a version the replica stored itself (``observed``) from one it read from the store
(``read``: another replica's, or rebuilt), and two apps sharing one Redis show both; the SDK sends
the scene on every request and in the stream's handshake.

On loopback (slow): redis-server, three replicas and nginx running docker/nginx.conf (as
tests/test_scale_out.py starts them). Three scenes of four agents each send one frame per 100 ms
(``POST /v1/frames``) and then check all their agents (``POST /v1/collision-check``), through nginx
with their scene's header. After ``STEADY_S`` the replica of the first scene gets SIGKILL. The test
asserts that each scene is answered by one replica (the ``X-FRT-Replica`` of every answer) and no
set was computed twice (no ``read`` set on any replica before the kill); that the killed replica's
scenes are answered by one survivor each from the next request after at most one frame period's
failed requests, its other scenes staying where they were; that no observation was lost or repeated (every agent's
version, timestamp and beta are the driver's own count and filter, every answer carried them);
and that every error was a request in flight to the killed replica. It prints the figures.
"""

from __future__ import annotations

import asyncio
import math
import random
import re
import shutil
import signal
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient
from frt_client import AsyncFRTClient, FRTClient
from frt_client.wire import SCENE_HEADER, headers

from service.api.app import create_app
from service.flows.confidence import Belief, hypotheses, prior_belief, update_belief
from service.runtime.settings import Settings
from tests.fixtures.analytic_model import write_model
from tests.test_redis_store import RedisServer, require_commands
from tests.test_scale_out import (
    BETA_LOW,
    EPSILON,
    Nginx,
    Replica,
    percentile,
    read_access_log,
    replica_env,
)

SCENES = ("scene-a", "scene-b", "scene-c")
AGENTS_PER_SCENE = 4
PERIOD_S = 0.1  # one frame per scene per period (10 Hz), then one check of the scene's agents
STEADY_S = 6.0  # before the kill
AFTER_KILL_S = 6.0
CHECK_DEADLINE_MS = 50.0
_EXACT_SETS = re.compile(r'^frt_exact_sets_total\{origin="(\w+)"\} (\S+)$', re.MULTILINE)


def exact_sets(metrics_text: str) -> Counter[str]:
    """``frt_exact_sets_total`` by origin, from a ``/metrics`` page."""
    return Counter({m[1]: int(float(m[2])) for m in _EXACT_SETS.finditer(metrics_text)})


# ----------------------------------------------------------------------------- in-process


COV = [[[0.01, 0.0], [0.0, 0.25]]] * 6
MEAN = [[0.0, 0.0]] * 6


def observation(t: float) -> dict[str, Any]:
    return {
        "timestamp": t,
        "state": {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 5.0},
        "prediction": {"dt": 0.5, "mean": MEAN, "cov": COV},
    }


def ready(client: TestClient) -> TestClient:
    deadline = time.monotonic() + 60
    while client.get("/readyz").status_code != 200:
        assert time.monotonic() < deadline, "not ready"
        time.sleep(0.05)
    return client


@pytest.fixture
def redis_server(tmp_path: Path) -> Iterator[RedisServer]:
    server = RedisServer(tmp_path)
    server.start()
    yield server
    server.kill(signal.SIGTERM)


def test_replica_header_and_sets_by_origin_across_two_replicas(
    analytic_model_path: Path, redis_server: RedisServer
) -> None:
    def settings(replica: str | None) -> Settings:
        return Settings(
            model_path=analytic_model_path,
            store_url=redis_server.url,
            replica_id=replica,
            frt_executor="thread",
            frt_workers=1,
            log_requests=False,
        )

    with (
        TestClient(create_app(settings("r-1"))) as first,
        TestClient(create_app(settings("r-2"))) as second,
        TestClient(create_app(settings(None))) as unnamed,
    ):
        ready(first), ready(second), ready(unnamed)
        answer = first.post("/v1/agents/o1/observations?wait_frt_ms=5000", json=observation(1.0))
        assert answer.status_code == 200 and answer.json()["frt_ready"]
        assert answer.headers["x-frt-replica"] == "r-1"
        assert first.get("/healthz").headers["x-frt-replica"] == "r-1"
        assert "x-frt-replica" not in unnamed.get("/healthz").headers
        # The other replica reads the agent from Redis and computes its set itself: "read".
        view = second.get("/v1/agents/o1?wait_frt_ms=5000")
        assert view.json()["frt_ready"] and view.headers["x-frt-replica"] == "r-2"
        # Asked again of the replica that stored it: found, not computed again.
        assert first.get("/v1/agents/o1?wait_frt_ms=5000").json()["frt_ready"]
        assert exact_sets(first.get("/metrics").text) == {"observed": 1}
        assert exact_sets(second.get("/metrics").text) == {"read": 1}
        # The next version, stored by the second replica: its set is "observed" there.
        nxt = second.post("/v1/agents/o1/observations?wait_frt_ms=5000", json=observation(2.0))
        assert nxt.json()["frt_version"] == 2 and nxt.json()["frt_ready"]
        assert exact_sets(second.get("/metrics").text) == {"read": 1, "observed": 1}
        first.delete("/v1/agents/o1")


def test_the_sdk_sends_the_scene_on_every_request_and_stream() -> None:
    with FRTClient(scene="crossing-4") as frt:
        assert frt._http.headers[SCENE_HEADER] == "crossing-4"
        assert frt.stream()._headers[SCENE_HEADER] == "crossing-4"
    with FRTClient() as frt:
        assert SCENE_HEADER not in frt._http.headers and not frt.stream()._headers
    frt_async = AsyncFRTClient(scene="crossing-4", token="t")
    assert frt_async._http.headers[SCENE_HEADER] == "crossing-4"
    assert frt_async.stream()._headers == {"Authorization": "Bearer t", SCENE_HEADER: "crossing-4"}
    asyncio.run(frt_async.aclose())
    for bad in ("", "   ", "x" * 129, "naïve", "a\nb"):
        with pytest.raises(ValueError, match="scene"):
            headers(None, scene=bad)


# ----------------------------------------------------------------------------- the topology


@dataclass
class Cluster:
    redis: RedisServer
    replicas: dict[str, Replica]  # by FRT_REPLICA_ID
    nginx: Nginx


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[Cluster]:
    require_commands("redis-server", "nginx")
    model = write_model(tmp_path / "model")
    redis = RedisServer(tmp_path / "redis")
    redis.directory.mkdir()
    redis.start()
    env = replica_env(redis.url, model)
    replicas: dict[str, Replica] = {}
    nginx: Nginx | None = None
    try:
        for i in range(3):
            name = f"replica-{i}"
            replicas[name] = Replica({**env, "FRT_REPLICA_ID": name}, tmp_path / f"{name}.log")
        for replica in replicas.values():
            replica.wait_ready()
        nginx = Nginx([r.address for r in replicas.values()])
        yield Cluster(redis, replicas, nginx)
    finally:
        if nginx is not None:
            nginx.cleanup()
        for replica in replicas.values():
            replica.stop()
        redis.kill(signal.SIGTERM)


# ----------------------------------------------------------------------------- the driver


@dataclass
class Human:
    """One agent of a scene; keeps the driver's own filter (the reference)."""

    agent_id: str
    lane: float
    rng: random.Random
    belief: Belief = field(default_factory=lambda: prior_belief(hypotheses(BETA_LOW)))
    sent: int = 0  # observations acknowledged: the agent's FRT version
    timestamp: float | None = None
    prediction: dict[str, Any] | None = None
    x: float = 0.0

    def entry(self) -> dict[str, Any]:
        """This agent's entry of the next frame: half its actions near the prediction, half far,
        so that beta moves every step and a lost or repeated observation shows."""
        rng = self.rng
        mean = [[round(rng.gauss(0, 0.05), 3), round(rng.gauss(0, 0.5), 3)] for _ in range(6)]
        var = (round(rng.uniform(0.01, 0.04), 3), round(rng.uniform(0.1, 0.5), 3))
        body: dict[str, Any] = {
            "agent_id": self.agent_id,
            "state": {"x": self.x, "y": self.lane, "heading": 0.0, "speed": 5.0},
            "prediction": {"dt": 0.5, "mean": mean, "cov": [[[var[0], 0], [0, var[1]]]] * 6},
        }
        if self.prediction is not None:
            prev = self.prediction["mean"][0]
            if rng.random() < 0.5:
                action = [prev[0] + rng.gauss(0, 0.02), prev[1] + rng.gauss(0, 0.1)]
            else:
                action = [rng.choice([-1, 1]) * 0.6, rng.choice([-1, 1]) * 3.0]
            body["observed_action"] = {
                "steering_rate": round(action[0], 4),
                "acceleration": round(action[1], 4),
            }
        return body

    def acknowledge(self, entry: dict[str, Any], timestamp: float) -> None:
        """The server has stored this entry: advance the reference exactly as the service does."""
        action = entry.get("observed_action")
        belief = Belief.from_dict(self.belief.to_dict())  # the store's JSON round trip
        if action is not None and self.prediction is not None:
            first = (self.prediction["mean"][0], self.prediction["cov"][0])
            belief = update_belief(
                belief, [action["steering_rate"], action["acceleration"]], *first, EPSILON
            )
        self.belief = Belief.from_dict(belief.to_dict())
        self.prediction = entry["prediction"]
        self.timestamp = timestamp
        self.sent += 1
        self.x += 0.5


@dataclass
class Record:
    scene: str
    op: str
    start: float  # wall clock, comparable with nginx's $msec
    end: float
    status: int | None  # None: no HTTP answer
    replica: str | None
    request_id: str | None


@dataclass
class Events:
    victim: str = ""
    kill_at: float = math.inf
    dead_at: float = math.inf
    before_kill: dict[str, Counter[str]] = field(default_factory=dict)
    versions_before_kill: int = 0
    after: dict[str, Counter[str]] = field(default_factory=dict)
    #: Every agent as the server holds it at the end (read through nginx).
    finals: dict[str, Any] = field(default_factory=dict)


class Driver:
    def __init__(self) -> None:
        self.records: list[Record] = []
        self.wrong: list[str] = []
        self.applied_despite_error = 0

    async def request(
        self, client: httpx.AsyncClient, scene: str, op: str, method: str, path: str, body: Any
    ) -> httpx.Response | None:
        start = time.time()
        try:
            response = await client.request(method, path, json=body)
        except httpx.TransportError:
            self.records.append(Record(scene, op, start, time.time(), None, None, None))
            return None
        self.records.append(
            Record(
                scene,
                op,
                start,
                time.time(),
                response.status_code,
                response.headers.get("x-frt-replica"),
                response.headers.get("x-request-id"),
            )
        )
        return response

    async def until_answered(
        self, client: httpx.AsyncClient, scene: str, op: str, method: str, path: str, body: Any
    ) -> tuple[httpx.Response | None, bool]:
        """Resend on no answer or a 502/503/504 (at once the first time, then after 20 ms);
        the answer and whether an attempt failed."""
        failed = False
        for attempt in range(100):
            response = await self.request(client, scene, op, method, path, body)
            if response is not None and response.status_code not in (502, 503, 504):
                return response, failed
            failed = True
            await asyncio.sleep(0.0 if attempt == 0 else 0.02)
        self.wrong.append(f"{scene}: {op} never answered")
        return None, failed

    async def frame(
        self, client: httpx.AsyncClient, scene: str, humans: list[Human], timestamp: float
    ) -> None:
        entries = [h.entry() for h in humans]
        body = {"timestamp": timestamp, "agents": entries}
        response, failed = await self.until_answered(
            client, scene, "frame", "POST", "/v1/frames", body
        )
        if response is None:
            return
        if response.status_code != 200:
            self.wrong.append(f"{scene}: frame {response.status_code} {response.text[:200]}")
            return
        for human, entry, result in zip(humans, entries, response.json()["results"], strict=True):
            if "error" in result:
                if result["error"]["status"] == 409 and failed:
                    # An attempt that failed was applied before its answer was lost: confirm
                    # the server holds exactly this observation.
                    await self.confirm(client, scene, human, timestamp)
                    human.acknowledge(entry, timestamp)
                    self.applied_despite_error += 1
                else:
                    self.wrong.append(f"{scene}: {human.agent_id} rejected: {result['error']}")
                continue
            human.acknowledge(entry, timestamp)
            if (result["frt_version"], result["beta"]) != (human.sent, human.belief.beta):
                self.wrong.append(f"{human.agent_id}: frame answer {result} != v{human.sent}")

    async def confirm(
        self, client: httpx.AsyncClient, scene: str, human: Human, timestamp: float
    ) -> None:
        path = f"/v1/agents/{human.agent_id}"
        got, _ = await self.until_answered(client, scene, "get", "GET", path, None)
        data = got.json() if got is not None else {}
        if (data.get("timestamp"), data.get("frt_version")) != (timestamp, human.sent + 1):
            self.wrong.append(f"{human.agent_id}: 409 after an error, but the server has {data}")

    async def check(self, client: httpx.AsyncClient, scene: str, humans: list[Human]) -> None:
        body = {
            "agent_ids": [h.agent_id for h in humans],
            "trajectory": [{"t": humans[0].timestamp or 0.0, "x": -50.0, "y": 500.0}],
            "mode": "tube",
            "deadline_ms": CHECK_DEADLINE_MS,
        }
        response, _ = await self.until_answered(
            client, scene, "check", "POST", "/v1/collision-check", body
        )
        if response is None or response.status_code != 200:
            self.wrong.append(f"{scene}: check {response and response.status_code}")
            return
        answers = {r["agent_id"]: r for r in response.json()["results"]}
        for h in humans:
            got = answers.get(h.agent_id, {})
            if (got.get("frt_version"), got.get("beta")) != (h.sent, h.belief.beta):
                self.wrong.append(f"{h.agent_id}: check answered {got} (expected v{h.sent})")

    async def scene(
        self, url: str, scene: str, humans: list[Human], t0: float, stop_at: float
    ) -> None:
        """One frame per period at timestamps 1.0, 1.1, ... (none skipped: a late frame is sent
        late), each followed by a check of the scene's agents."""
        async with httpx.AsyncClient(
            base_url=url, headers=headers(None, scene=scene), timeout=10.0
        ) as client:
            k = 0
            while t0 + k * PERIOD_S < stop_at:
                await asyncio.sleep(max(0.0, t0 + k * PERIOD_S - time.time()))
                await self.frame(client, scene, humans, round(1.0 + PERIOD_S * k, 3))
                await self.check(client, scene, humans)
                k += 1


async def scrape(replicas: dict[str, Replica]) -> dict[str, Counter[str]]:
    async with httpx.AsyncClient(timeout=5.0) as client:
        pages = {n: await client.get(f"http://{r.address}/metrics") for n, r in replicas.items()}
    return {name: exact_sets(page.text) for name, page in pages.items()}


def replicas_of(records: list[Record], scene: str, start: float, end: float) -> Counter[str]:
    """Which replicas answered ``scene``'s requests that started in [start, end)."""
    return Counter(
        r.replica or "?"
        for r in records
        if r.scene == scene and start <= r.start < end and r.status == 200
    )


async def chaos(
    cluster: Cluster, driver: Driver, events: Events, humans: dict[str, list[Human]], t0: float
) -> None:
    await asyncio.sleep(max(0.0, t0 + STEADY_S - time.time()))
    steady = replicas_of(driver.records, SCENES[0], t0, math.inf)
    events.victim = steady.most_common(1)[0][0]
    events.before_kill = await scrape(cluster.replicas)
    events.versions_before_kill = sum(h.sent for group in humans.values() for h in group)
    events.kill_at = time.time()
    victim = cluster.replicas[events.victim]
    victim.proc.send_signal(signal.SIGKILL)
    await asyncio.to_thread(victim.proc.wait)
    events.dead_at = time.time()


async def drive(cluster: Cluster) -> tuple[Driver, Events, dict[str, list[Human]], float]:
    driver, events = Driver(), Events()
    rng = random.Random(36)
    humans = {
        scene: [
            Human(f"{scene}-h{i}", lane=10.0 * i, rng=random.Random(rng.random()))
            for i in range(AGENTS_PER_SCENE)
        ]
        for scene in SCENES
    }
    t0 = time.time()
    stop_at = t0 + STEADY_S + AFTER_KILL_S
    url = cluster.nginx.url
    await asyncio.gather(
        chaos(cluster, driver, events, humans, t0),
        *(driver.scene(url, s, humans[s], t0 + 0.03 * i, stop_at) for i, s in enumerate(SCENES)),
    )
    survivors = {n: r for n, r in cluster.replicas.items() if n != events.victim}
    events.after = await scrape(survivors)
    async with httpx.AsyncClient(base_url=url, timeout=10.0) as client:
        for scene, group in humans.items():
            for h in group:
                path = f"/v1/agents/{h.agent_id}"
                got = await client.get(path, headers=headers(None, scene=scene))
                events.finals[h.agent_id] = got.json()
    return driver, events, humans, t0


# ----------------------------------------------------------------------------- the test


def failover(driver: Driver, events: Events, scene: str) -> tuple[float, float, str]:
    """(when the scene saw the kill, when it was answered again, by whom): seen at the end of
    its first failed request, or else at the start of its first request after the kill (nginx
    meets the dead replica there and passes it on)."""
    mine = [r for r in driver.records if r.scene == scene and r.end >= events.kill_at]
    failed = [r.end for r in mine if r.status is None or r.status >= 500]
    started = [r.start for r in mine if r.start >= events.kill_at]
    seen = min(failed + started)
    answered = min(
        (r for r in mine if r.status == 200 and r.replica != events.victim and r.end >= seen),
        key=lambda r: r.end,
    )
    return seen, answered.end, answered.replica or "?"


def figures(driver: Driver, events: Events, humans: dict[str, list[Human]], t0: float) -> str:
    rows = [f"replica SIGKILL at +{events.kill_at - t0:.2f} s: {events.victim}"]
    for scene in SCENES:
        before = replicas_of(driver.records, scene, t0, events.kill_at)
        after = replicas_of(driver.records, scene, events.dead_at, math.inf)
        lat = {
            op: [
                1000 * (r.end - r.start) for r in driver.records if r.scene == scene and r.op == op
            ]
            for op in ("frame", "check")
        }
        rows.append(
            f"{scene}: answered by {dict(before)} before the kill, {dict(after)} after; "
            f"frame p50/p99 {percentile(lat['frame'], 50):.1f}/{percentile(lat['frame'], 99):.1f}"
            f" ms, check {percentile(lat['check'], 50):.1f}/{percentile(lat['check'], 99):.1f} ms"
        )
        if before and events.victim in before:
            seen, answered, by = failover(driver, events, scene)
            rows.append(
                f"  kill seen at +{1000 * (seen - events.kill_at):.1f} ms, answered again by "
                f"{by} {1000 * (answered - seen):.1f} ms later"
            )
    versions = sum(h.sent for group in humans.values() for h in group)
    sets_before = sum(events.before_kill.values(), Counter())
    sets_after = sum(events.after.values(), Counter())
    errors = sum(1 for r in driver.records if r.status is None or r.status >= 500)
    rows.append(
        f"before the kill: {events.versions_before_kill} versions stored, exact sets computed "
        f"{dict(sets_before)} (per replica {events.before_kill}); survivors at the end: "
        f"{dict(sets_after)}; {versions} versions in all; {len(driver.records)} requests, "
        f"{errors} failed and resent, {driver.applied_despite_error} frame entries applied "
        f"whose answer was lost"
    )
    return "\n".join(rows)


@pytest.mark.slow
@pytest.mark.timeout(150)
def test_each_scene_goes_to_one_replica_and_survives_its_death(
    cluster: Cluster, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    driver, events, humans, t0 = asyncio.run(drive(cluster))
    cluster.nginx.stop()  # flushes the access log
    log = read_access_log(Path(shutil.copy(cluster.nginx.access_log, tmp_path / "access.log")))
    report = figures(driver, events, humans, t0)
    with capsys.disabled():
        print("\n" + report)

    assert not driver.wrong, "wrong answers:\n" + "\n".join(driver.wrong[:20])
    addresses = {name: r.address for name, r in cluster.replicas.items()}

    # Before the kill each scene was answered by one replica, and no set was computed twice: no
    # replica computed a set for a version it had not stored itself.
    homes = {}
    for scene in SCENES:
        before = replicas_of(driver.records, scene, t0, events.kill_at)
        assert len(before) == 1, f"{scene} answered by {before}"
        homes[scene] = next(iter(before))
    sets = sum(events.before_kill.values(), Counter())
    assert sets["read"] == 0, events.before_kill
    assert 0 < sets["observed"] <= events.versions_before_kill + len(SCENES) * AGENTS_PER_SCENE

    # After the kill: the victim's scenes each went to one survivor, from the next frame on; the
    # other scenes stayed where they were. A survivor computed at most
    # one set per moved agent that it had not stored itself (its current version, rebuilt).
    moved = [s for s in SCENES if homes[s] == events.victim]
    for scene in SCENES:
        after = replicas_of(driver.records, scene, events.dead_at, math.inf)
        assert len(after) == 1 and events.victim not in after, f"{scene} after: {after}"
        if scene not in moved:
            assert set(after) == {homes[scene]}, f"{scene} moved: {after}"
            continue
        # In requests, not seconds (a shared machine's timings are figures, printed above): at
        # most the frame and the check of one period failed (in flight to the dead replica, or
        # sent on nginx's kept-alive connection to it), and the scene's next request after them
        # was answered by a survivor.
        seen, _, _ = failover(driver, events, scene)
        mine = [r for r in driver.records if r.scene == scene and r.end >= events.kill_at]
        failed = [r for r in mine if r.status is None or r.status >= 500]
        assert len(failed) <= 2, (scene, failed)
        after = max([seen, *(r.end for r in failed)])
        first = min((r for r in mine if r.start >= after), key=lambda r: r.start)
        assert first.status == 200 and first.replica not in (None, events.victim), (scene, first)
    rebuilt = sum(c["read"] for c in events.after.values())
    assert rebuilt <= len(moved) * AGENTS_PER_SCENE, events.after

    # Nothing lost or repeated: every agent holds one version per frame, the last frame's
    # timestamp and the driver's own beta.
    for group in humans.values():
        assert len({h.sent for h in group}) == 1, [h.sent for h in group]
        assert group[0].sent >= 0.5 * (STEADY_S + AFTER_KILL_S) / PERIOD_S
        for h in group:
            got = events.finals[h.agent_id]
            want = (h.sent, h.timestamp, h.belief.beta)
            assert (got["frt_version"], got["timestamp"], got["beta"]) == want, got

    # Every error was a request in flight to the killed replica at its death.
    for r in driver.records:
        if r.status is not None and r.status < 500:
            continue
        line = log.get(r.request_id or "")
        in_flight = r.start <= events.dead_at + 0.002 and r.end >= events.kill_at - 0.002
        to_victim = line is None or line.upstreams == [addresses[events.victim]]
        assert in_flight and to_victim and r.status in (None, 502), (r, line)
