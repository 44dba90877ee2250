"""Latency benchmark of the FRT service: ``make bench`` (``python scripts/bench.py``).

Starts the service (uvicorn, one worker) on a free loopback port with the shipped model and drives
it with httpx from this process. Prints medians and p99 for:

1. a collision check of a 20-point trajectory against one agent, warm (exact set cached);
2. observation -> new FRT ready (a new prediction and a new beta; timed until GET agent reports
   the exact set of the new version computed: one ``GET /v1/agents/{id}?wait_frt_ms=...``, which
   the server answers as soon as that set is ready. Earlier versions polled GET agent every 2 ms;
   each poll is a request the server answers on the same 2 cores, so polling measured its own
   load too); alternating with the same through one request (the observation with
   ``?wait_frt_ms=``);
   and the same through one request for an agent whose predictor is unsure of the steering (its
   steering bounds near +-1 rad/s: it may turn round, so with ``FRT_FRT_NOTCH_CUT``, the default,
   the service refines its sets in the background, in stages), and from the observation until that
   refinement's first stage is served (``frt_refinement_stage: 1``), and, observed 1.5 s apart
   (the fine stage is skipped when it would land after the next observation), until its last is;
   polled every 2 ms; the bench passes the caller's ``FRT_*`` environment to the service;
3. contours for one agent (tube + 3 slices), on a fresh FRT version each time; then multi-modal
   agents: observation -> new FRT ready through one request with 1 and with 6 modes (the set the
   union of the 6 modes' tubes), and the warm 20-point time-indexed check of the 6-mode agent
   (``--modes-only``: these rows and the single-mode warm check alone);
4. sustained: 50 agents observed at 2 Hz while a planner (a process of its own) checks all of
   them at 10 Hz with one multi-agent request per round; a round misses its deadline when its
   end-to-end time exceeds the request's ``deadline_ms`` (20 ms); run twice, the planner
   sending its checks over HTTP, then over the WebSocket stream (``--planner-transport``);
5. the HTTP floor: GET /healthz through the same client, server and middleware (what a request
   costs with no work in the route), next to the warm check;
6. the exact set alone, in-process, for a moving, a parked and a wide-bound car (for the moving car
   also with the tubes make load's time-indexed checks need drawn, as a worker sends it, and with
   the projection network evaluated at every lattice node, i.e. without
   ``reach.refine``; for the wide one also cut to the speed-coupled partition, the service's
   background refinement of such sets, ``FRTEngine.exact(notch_cut=True)``, by its first stage
   and by its last, ``reach.engine.NOTCH_STAGES``);
7. serialising a 50-agent collision answer in-process, the way the service does
   (``service.api.routes.model_json``) and the way FastAPI does for a returned model (validated again
   against ``response_model``, then ``jsonable_encoder`` and ``json.dumps``), alternately;
8. the coverage audit's cost on the observation (``--audit-only``: these rows alone): two services
   side by side, the audit on and off (``FRT_AUDIT=0``), each observing one car at 10 Hz (so
   every observation is scored against the 30 earlier versions its 3 s horizon covers) with a
   planner's 20-point time-indexed check after each observation (so the two latest versions'
   exact sets have their tubes drawn and are scored exactly), the two services' requests
   alternating; and, on the audit's service, a car with adaptive gamma (``coverage_target``),
   whose observations are audited before they are answered (the others' after); the
   observation's latency at the client and at the server (``Server-Timing``); and the audit's
   own work for one observation against 30 versions, in-process;
9. the load mix: ``make load``'s defaults (``scripts/load.py``: 2 planners checking all of 10
   humans at 10 Hz with 20-point time-indexed trajectories, each human observed at 5 Hz) for
   ``--load-seconds``: a check-all round end to end, the share of per-agent answers from exact
   sets and the late rounds, at the client and at the server;

and, side by side in the same run, the naive approach: building the set by evaluating the full
network on a dense grid for every query (no cache, no distilled projection).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from scripts.exact_cost import LOAD_MIX_TUBES  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def service_at(root: Path, model: Path, **settings: str) -> Iterator[tuple[str, int]]:
    """The service of the tree at ``root`` on a free loopback port, ready: (url, pid). The
    settings are ``FRT_*`` variables beside the caller's environment."""
    port = free_port()
    env = dict(os.environ, FRT_MODEL_PATH=str(model), FRT_LOG_REQUESTS="false")
    env.update({f"FRT_{k.upper()}": v for k, v in settings.items()})
    command = [sys.executable, "-m", "uvicorn", "service.api.app:app", "--port", str(port)]
    proc = subprocess.Popen([*command, "--log-level", "warning"], cwd=root, env=env)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            try:
                if httpx.get(f"{url}/readyz", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        else:
            raise RuntimeError(f"the service at {root} did not become ready")
        yield url, proc.pid
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@contextmanager
def running_service(model: Path, **settings: str) -> Iterator[str]:
    """This tree's service (:func:`service_at`): its url."""
    with service_at(ROOT, model, **settings) as (url, _):
        yield url


def prediction(rng: np.random.Generator, steps: int = 6, steering_var: float = 0.01) -> dict:
    mean = [[float(rng.normal(0, 0.05)), float(rng.normal(0, 0.3))] for _ in range(steps)]
    cov = [[[steering_var, 0.0], [0.0, 0.25]] for _ in range(steps)]
    return {"dt": 0.5, "mean": mean, "cov": cov}


#: A predictor unsure of the steering: the agent's steering bounds come out near +-1 rad/s, so it
#: may turn round within the horizon (and the service refines its sets by the notch cut).
WIDE_STEERING_VAR = 50.0


def observation(
    t: float, rng: np.random.Generator, first: bool, x: float = 0.0, steering_var: float = 0.01
) -> dict:
    body = {
        "timestamp": t,
        "state": {"x": x, "y": 0.0, "heading": 0.0, "speed": float(rng.uniform(5, 12))},
        "prediction": prediction(rng, steering_var=steering_var),
        "observed_action": None
        if first
        else {"steering_rate": float(rng.normal(0, 0.1)), "acceleration": float(rng.normal(0, 1))},
    }
    return body


def trajectory(t0: float, n: int = 20) -> list[dict]:
    return [{"t": t0 + 0.1 * i, "x": 40.0 - 2.0 * i, "y": -3.0} for i in range(n)]


def stats(samples_s: list[float]) -> dict[str, float]:
    a = np.array(samples_s) * 1e3
    return {
        "n": len(a),
        "p50_ms": float(np.percentile(a, 50)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(a.max()),
    }


def bench_collision(client: httpx.Client, n: int) -> dict:
    rng = np.random.default_rng(0)
    client.post(
        "/v1/agents/bench-cc/observations", json=observation(0.0, rng, True)
    ).raise_for_status()
    body = {"trajectory": trajectory(0.1), "mode": "time_indexed", "deadline_ms": 1000}
    client.post("/v1/agents/bench-cc/collision-check", json=body).raise_for_status()  # warm
    body["deadline_ms"] = 5
    times, conservative = [], 0
    for _ in range(n):
        t0 = time.perf_counter()
        r = client.post("/v1/agents/bench-cc/collision-check", json=body)
        times.append(time.perf_counter() - t0)
        conservative += r.json()["conservative"]
    return {**stats(times), "conservative": conservative}


def bench_http_floor(client: httpx.Client, n: int) -> dict:
    """GET /healthz: the same client, server and middleware with no work in the route. What a
    check costs beyond it is the check's own; on this machine httpx alone spends ~1.4 ms of CPU
    per request, most of this floor."""
    for _ in range(20):
        client.get("/healthz").raise_for_status()
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        client.get("/healthz")
        times.append(time.perf_counter() - t0)
    return stats(times)


#: How far apart the bench observes the wide agent while it times the refinement's last stage: a
#: version that lives this long gets it (``RefinementQueue.lands_in_time``).
FINE_PERIOD_S = 1.5


def observe_until_ready(client: httpx.Client, agent: str, body: dict) -> float:
    """Seconds from sending an observation with ``?wait_frt_ms=`` (answered once its version's
    exact set is computed) to the exact set being ready."""
    t0 = time.perf_counter()
    r = client.post(f"/v1/agents/{agent}/observations", json=body, params={"wait_frt_ms": 1000})
    r.raise_for_status()
    while not r.json()["frt_ready"]:  # only after a 1 s wait: counted in full
        r = client.get(f"/v1/agents/{agent}", params={"wait_frt_ms": 1000})
    return time.perf_counter() - t0


def bench_observe_to_ready(client: httpx.Client, n: int) -> dict[str, dict]:
    """Observation -> exact FRT ready, two ways, alternating on two agents: the observation then a
    waiting ``GET /v1/agents/{id}?wait_frt_ms=``, and the observation alone with ``?wait_frt_ms=``
    (answered once its version's exact set is computed)."""
    rng = np.random.default_rng(1)
    two, one = [], []
    client.post("/v1/agents/bench-obs/observations", json=observation(0.0, rng, True))
    client.post("/v1/agents/bench-obs1/observations", json=observation(0.0, rng, True))
    for i in range(1, n + 1):
        t0 = time.perf_counter()
        r = client.post("/v1/agents/bench-obs/observations", json=observation(float(i), rng, False))
        r.raise_for_status()
        version = r.json()["frt_version"]
        while True:  # the server answers once the exact set of this version is computed
            agent = client.get("/v1/agents/bench-obs", params={"wait_frt_ms": 1000}).json()
            if agent["frt_ready"] and agent["frt_version"] == version:
                break
        two.append(time.perf_counter() - t0)

        one.append(observe_until_ready(client, "bench-obs1", observation(float(i), rng, False)))
    return {
        "observation_to_frt_ready": stats(two),
        "observation_to_frt_ready_one_request": stats(one),
    }


def mixture(rng: np.random.Generator, n_modes: int) -> dict:
    """A prediction of ``n_modes`` equally weighted modes, their mean steering spread over
    [-0.4, 0.4] rad/s (distinct sets, none containing another)."""
    modes = []
    for m, u1 in enumerate(np.linspace(-0.4, 0.4, n_modes) if n_modes > 1 else [0.0]):
        single = prediction(rng)
        single["mean"] = [[float(u1), u2 + 0.1 * m] for _, u2 in single["mean"]]
        modes.append({"weight": 1.0, "mean": single["mean"], "cov": single["cov"]})
    return {"dt": 0.5, "modes": modes}


def mixture_observation(t: float, rng: np.random.Generator, n_modes: int) -> dict:
    """An observation with an ``n_modes`` mixture and no scored action: every mode keeps its
    weight, so the served set is the union of all ``n_modes`` tubes."""
    body = observation(t, rng, True)
    body["prediction"] = mixture(rng, n_modes)
    return body


def bench_modes(client: httpx.Client, n: int, n_checks: int) -> dict[str, dict]:
    """Multi-modal agents: observation -> exact set ready with 1 and 6 modes (one request with
    ``?wait_frt_ms=``), and the warm 20-point time-indexed check of a 6-mode agent."""
    rng = np.random.default_rng(5)
    out: dict[str, dict] = {}
    for n_modes in (1, 6):
        agent = f"bench-modes{n_modes}"
        client.post(
            f"/v1/agents/{agent}/observations", json=mixture_observation(0.0, rng, n_modes)
        ).raise_for_status()
        times = [
            observe_until_ready(client, agent, mixture_observation(float(i), rng, n_modes))
            for i in range(1, n + 1)
        ]
        out[f"observation_to_frt_ready_{n_modes}_mode{'s' if n_modes > 1 else ''}"] = stats(times)
    agent = "bench-modes6"
    body = {"trajectory": trajectory(float(n) + 0.1), "mode": "time_indexed", "deadline_ms": 1000}
    client.post(f"/v1/agents/{agent}/collision-check", json=body).raise_for_status()  # warm
    body["deadline_ms"] = 5
    times, conservative = [], 0
    for _ in range(n_checks):
        t0 = time.perf_counter()
        r = client.post(f"/v1/agents/{agent}/collision-check", json=body)
        times.append(time.perf_counter() - t0)
        conservative += r.json()["conservative"]
    out["collision_check_20pt_warm_6_modes"] = {**stats(times), "conservative": conservative}
    for n_modes in (1, 6):
        client.delete(f"/v1/agents/bench-modes{n_modes}").raise_for_status()
    return out


def bench_observe_to_ready_wide(client: httpx.Client, n: int, n_fine: int = 15) -> dict[str, dict]:
    """The same through one request for an agent whose predictor is unsure of the steering
    (WIDE_STEERING_VAR): its sets may turn round, so the service also refines them in the
    background (FRT_FRT_NOTCH_CUT), in stages. Then, polling ``GET /v1/agents/{id}`` every 2 ms,
    until the first stage is served (``frt_refinement_stage``: what a planner gets at any
    observation rate), ``n`` times back to back; and ``n_fine`` times, observed FINE_PERIOD_S
    apart (the fine stage is skipped when it would land after the agent's next observation), until
    the last stage is (``frt_refinement: done`` at the last stage)."""
    from reach.notch import NOTCH_STAGES

    rng = np.random.default_rng(2)
    wide = WIDE_STEERING_VAR
    client.post("/v1/agents/bench-wide/observations", json=observation(0.0, rng, True, 0.0, wide))

    def refined_until(stage: int, t0: float) -> float | None:
        """Seconds from ``t0`` until the agent's set has had ``stage`` stages (None if its
        refinement ends before)."""
        while True:
            agent = client.get("/v1/agents/bench-wide").json()
            if (agent.get("frt_refinement_stage") or 0) >= stage:
                return time.perf_counter() - t0
            if agent["frt_refinement"] != "pending":
                return None
            time.sleep(0.002)

    ready, first, fine = [], [], []
    t0 = time.perf_counter()
    for i in range(1, n + n_fine + 1):
        if i > n:
            time.sleep(max(FINE_PERIOD_S - (time.perf_counter() - t0), 0.0))
        t0 = time.perf_counter()
        body = observation(float(i), rng, False, 0.0, wide)
        seconds = observe_until_ready(client, "bench-wide", body)
        if i <= n:
            ready.append(seconds)
            if (took := refined_until(1, t0)) is not None:
                first.append(took)
        elif (took := refined_until(len(NOTCH_STAGES), t0)) is not None:
            fine.append(took)
    out = {"observation_to_frt_ready_wide_steering": stats(ready)}
    if first:
        out["observation_to_frt_first_cut_wide_steering"] = stats(first)
    if fine:
        out["observation_to_frt_refined_wide_steering"] = stats(fine)
    return out


def bench_contours(client: httpx.Client, n: int) -> dict:
    rng = np.random.default_rng(2)
    times = []
    client.post("/v1/agents/bench-frt/observations", json=observation(0.0, rng, True))
    for i in range(1, n + 1):
        client.post("/v1/agents/bench-frt/observations", json=observation(float(i), rng, False))
        t0 = time.perf_counter()
        r = client.get(
            "/v1/agents/bench-frt/frt", params={"slices": "1.0,2.0,3.0", "include": "K,C"}
        )
        times.append(time.perf_counter() - t0)
        r.raise_for_status()
    return stats(times)


async def _rounds(
    send: Callable[[int, dict], Awaitable[Any]],
    parse: Callable[[Any], tuple[dict | None, float | None]],
    start_at: float,
    seconds: float,
    deadline_ms: float,
) -> dict:
    """A planner's rounds at 10 Hz from ``start_at`` (time.time()) for ``seconds``: each sends a
    check of all agents (``send(k, body)``), timed up to its answer; ``parse`` gives the answer's
    result (None if it failed) and the server's own time, if the transport says it."""
    check_times: list[float] = []
    server_times: list[float] = []
    misses = conservative = errors = 0
    await asyncio.sleep(max(0.0, start_at - time.time()))
    start = time.monotonic()
    k = 0
    while time.monotonic() - start < seconds:
        t0 = time.perf_counter()
        body = {"trajectory": trajectory(1.0), "mode": "tube", "deadline_ms": deadline_ms}
        raw = await send(k, body)
        dt = time.perf_counter() - t0
        check_times.append(dt)
        result, server_s = parse(raw)
        if server_s is not None:
            server_times.append(server_s)
        if result is None:
            errors += 1
        else:
            conservative += result["conservative"]
        misses += dt * 1e3 > deadline_ms
        k += 1
        await asyncio.sleep(max(0.0, 0.1 - dt))
    return {
        "check_times": check_times,
        "server_times": server_times,
        "misses": misses,
        "conservative": conservative,
        "errors": errors,
    }


async def _planner(url: str, start_at: float, seconds: float, deadline_ms: float) -> dict:
    """Check all agents at 10 Hz with one multi-agent request each (API.md: POST
    /v1/collision-check); the server's own time from each response's Server-Timing.

    Like a planner starting up (the SDK's ``wait_ready``), it waits for ``/readyz`` before its
    first round: that opens the connection, which the WebSocket planner opens before its rounds
    too. Without it the first round paid the TCP connect and httpx's first-request set-up (34-45
    ms end to end, measured) and was the one late round of most runs."""
    async with httpx.AsyncClient(base_url=url, timeout=5) as client:
        (await client.get("/readyz")).raise_for_status()

        def parse(r: httpx.Response) -> tuple[dict | None, float]:
            return (r.json() if r.status_code == 200 else None), server_seconds(r)

        return await _rounds(
            lambda _k, body: client.post("/v1/collision-check", json=body),
            parse,
            start_at,
            seconds,
            deadline_ms,
        )


async def _planner_ws(url: str, start_at: float, seconds: float, deadline_ms: float) -> dict:
    """The same planner over the WebSocket stream (``WS /v1/stream``, op ``collision_check``): one
    socket, no HTTP request per round. The stream has no Server-Timing, so only end to end."""
    import websockets

    async with websockets.connect(url.replace("http://", "ws://") + "/v1/stream") as stream:

        async def send(k: int, body: dict) -> str:
            await stream.send(json.dumps({"id": k, "op": "collision_check", **body}))
            return await stream.recv()

        def parse(text: str) -> tuple[dict | None, None]:
            message = json.loads(text)
            return (message["result"] if message["ok"] else None), None

        return await _rounds(send, parse, start_at, seconds, deadline_ms)


def server_seconds(response: httpx.Response) -> float:
    """The server's own time for a request, from its ``Server-Timing: app;dur=<ms>`` header."""
    return float(response.headers["server-timing"].split("dur=")[1]) / 1000.0


def _planner_process(
    url: str, start_at: float, seconds: float, deadline_ms: float, transport: str, conn
) -> None:
    """The planner in a process of its own (spawned): a planner and the perception feeding the
    observations are different programs; in one event loop the observers' 100 requests/s delayed
    the planner's own sends and reads, which the service's latency does not include."""
    planner = {"http": _planner, "ws": _planner_ws}[transport]
    conn.send(asyncio.run(planner(url, start_at, seconds, deadline_ms)))
    conn.close()


async def bench_sustained(
    url: str, agents: int, seconds: float, headers: dict, transport: str = "http"
) -> dict:
    """``agents`` agents observed at 2 Hz (one asyncio client, a keep-alive connection per
    observer) while a planner in another process checks all of them at 10 Hz, over HTTP or the
    WebSocket stream (``transport``); a check-all round misses its deadline when its end-to-end
    time exceeds ``deadline_ms``."""
    import multiprocessing

    rng = np.random.default_rng(3)
    obs_times: list[float] = []
    errors = 0
    deadline_ms = 20.0
    limits = httpx.Limits(max_connections=agents + 10, max_keepalive_connections=agents + 10)
    async with httpx.AsyncClient(base_url=url, timeout=5, headers=headers, limits=limits) as client:
        for a in range(agents):
            await client.post(
                f"/v1/agents/s{a}/observations", json=observation(0.0, rng, True, 10.0 * a)
            )
        context = multiprocessing.get_context("spawn")
        receive, send = context.Pipe(duplex=False)
        start_at = time.time() + 3.0  # the spawned planner imports httpx and numpy first
        planner = context.Process(
            target=_planner_process, args=(url, start_at, seconds, deadline_ms, transport, send)
        )
        planner.start()
        await asyncio.sleep(max(0.0, start_at - time.time()))
        start = time.monotonic()

        async def observer(a: int) -> None:
            nonlocal errors
            k = 1
            await asyncio.sleep(rng.uniform(0, 0.5))
            while time.monotonic() - start < seconds:
                t0 = time.perf_counter()
                r = await client.post(
                    f"/v1/agents/s{a}/observations",
                    json=observation(float(k), rng, False, 10.0 * a),
                )
                obs_times.append(time.perf_counter() - t0)
                errors += r.status_code != 200
                k += 1
                await asyncio.sleep(0.5)

        await asyncio.gather(*(observer(a) for a in range(agents)))
        if not await asyncio.to_thread(receive.poll, 60.0):
            planner.kill()
            raise RuntimeError("the planner process sent no result")
        checks = receive.recv()
        planner.join(timeout=10)
        for a in range(agents):  # the next case's planner checks every known agent
            await client.delete(f"/v1/agents/s{a}")
    split = {}
    if checks["server_times"]:
        # The same rounds from the server's Server-Timing (arrival to response start) and the rest
        # of each round trip: the client's sending and reading, the network, the OS's scheduling.
        split = {
            "check_all_server": stats(checks["server_times"]),
            "check_all_trip": stats(np.subtract(checks["check_times"], checks["server_times"])),
        }
    return {
        "agents": agents,
        "seconds": seconds,
        "planner_transport": transport,
        "check_all": stats(checks["check_times"]),
        **split,
        "observe": stats(obs_times),
        "deadline_ms": deadline_ms,
        "deadline_misses_end_to_end": checks["misses"],
        "conservative_answers": checks["conservative"],
        "errors": errors + checks["errors"],
    }


def sustained_run(url: str, seconds: float, transport: str) -> dict:
    """One sustained case, with the server's own counts of late answers and of the sets the
    per-agent answers came from over the run (from ``/metrics`` before and after)."""
    before = server_counters(url)
    sustained = asyncio.run(bench_sustained(url, 50, seconds, {}, transport))
    after = server_counters(url)
    sustained["deadline_misses_server_side"] = after.pop("deadline_misses") - before.pop(
        "deadline_misses"
    )
    sustained["agent_answers"] = {
        source: count - before.get(source, 0) for source, count in after.items()
    }
    return sustained


def run_summary(sustained: dict) -> dict:
    """What one sustained run says about deadlines, for comparing runs."""
    return {
        "rounds": sustained["check_all"]["n"],
        "deadline_misses_end_to_end": sustained["deadline_misses_end_to_end"],
        "deadline_misses_server_side": sustained["deadline_misses_server_side"],
        "check_all_p99_ms": round(sustained["check_all"]["p99_ms"], 2),
        "check_all_max_ms": round(sustained["check_all"]["max_ms"], 2),
    }


def server_counters(url: str) -> dict[str, int]:
    """The server's counts so far, from one read of ``/metrics``: ``deadline_misses`` (collision
    checks it answered after their deadline, from their arrival: the end-to-end count adds the trip
    and the client's own delays) and, per set the per-agent answers came from, ``exact`` and
    ``conservative``."""
    counts = {"deadline_misses": -1}
    for line in httpx.get(f"{url}/metrics", timeout=10).text.splitlines():
        if line.startswith("frt_deadline_misses_total"):
            counts["deadline_misses"] = int(float(line.split()[-1]))
        elif line.startswith("frt_collision_checks_total{"):
            source = line.split('source="')[1].split('"')[0]
            counts[source] = int(float(line.split()[-1]))
    return counts


def bench_load_mix(url: str, model: Path, seconds: float) -> dict:
    """``make load``'s mix at its defaults (scripts/load.py: 2 planners checking all of 10 humans
    at 10 Hz with 20-point time-indexed trajectories, each human observed at 5 Hz) for
    ``seconds``: a check-all round end to end, the share of per-agent answers from exact sets,
    late rounds at the client and at the server."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "load.json"
        subprocess.run(
            [sys.executable, str(ROOT / "scripts" / "load.py"), "--url", url,
             "--duration", str(seconds), "--model", str(model), "--out", str(out)],
            check=False, capture_output=True, timeout=seconds + 300,
        )  # fmt: skip
        load = json.loads(out.read_text())
    check = load["operations"]["check"]
    deadline = load["deadline"]
    return {
        "seconds": seconds,
        "n": check["count"],
        "p50_ms": check["p50_ms"],
        "p99_ms": check["p99_ms"],
        "exact_share": deadline["exact_share"],
        "answers": deadline["answers"],
        "late_end_to_end": deadline["client_over_deadline"],
        "late_server_side": deadline["server_misses"],
        "errors": load["errors"],
        "fallback_area_ratio": load["fallback_area_ratio"],
    }


def bench_naive(model: Path, n: int) -> dict:
    """The naive approach: per query, the set from the full network on a dense grid, no cache."""
    from models.runtime import ValueModel
    from models.value_fields import engine_for
    from reach.frames import Pose

    vm = ValueModel.load(model, threads=1)
    naive = engine_for(vm, stencil=True)
    bounds = np.array([-0.15, -1.5, -0.15, -1.5, 0.15, 1.5, 0.15, 1.5])
    points = np.array([[p["x"], p["y"]] for p in trajectory(0.1)])
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        frt = naive.exact(Pose(0.0, 0.0, 0.0), 8.0, bounds)
        frt.clearance(points, np.linspace(0.1, 2.0, len(points)))
        times.append(time.perf_counter() - t0)
    return stats(times)


#: Exact-set cases timed in-process (v_start, bounds in contract order): a parked car used to take
#: tens of seconds here (GEOS unions of near-identical slices).
EXACT_CASES = {
    "exact_set_in_process_moving_8mps": (8.0, [-0.15, -1.5, -0.15, -1.5, 0.15, 1.5, 0.15, 1.5]),
    "exact_set_in_process_parked": (0.0, [-0.05, -0.2, -0.05, -0.2, 0.05, 0.2, 0.05, 0.2]),
    "exact_set_in_process_parked_zero_bounds": (0.0, [0.0] * 8),
    # urban_wide of the evaluation: it can turn round, so the service refines it by the notch cut.
    "exact_set_in_process_wide": (8.0, [-1.2, -6.0, -1.2, -6.0, 1.2, 6.0, 1.2, 6.0]),
}


def fifty_agent_answer():
    """A 50-agent answer to a 20-point check, as the service builds it (``model_construct``)."""
    from service.wire.schemas import CollisionCheckResponse, MultiCollisionCheckResponse

    rng = np.random.default_rng(0)
    results = [
        CollisionCheckResponse.model_construct(
            collision=False,
            first_collision_index=None,
            first_collision_time=None,
            clearance=rng.uniform(0.0, 80.0, 20).tolist(),
            agent_id=f"agent-{i}",
            mode="tube",
            collision_radius=1.5,
            beta=float(rng.uniform()),
            frt_version=3,
            conservative=False,
            horizon_end=1003.0,
        )
        for i in range(50)
    ]
    return MultiCollisionCheckResponse.model_construct(
        collision=False, conservative=False, results=results, missing=[]
    )


def bench_serialisation(n: int) -> dict[str, dict]:
    """Body bytes of a 50-agent answer: the service's ModelJSONResponse against FastAPI's path for
    a returned model, alternately, with a check that both give the same JSON."""
    from fastapi.routing import serialize_response
    from fastapi.utils import create_model_field
    from starlette.responses import JSONResponse

    from service.api.routes.model_json import ModelJSONResponse
    from service.wire.schemas import MultiCollisionCheckResponse

    answer = fifty_agent_answer()
    field = create_model_field(
        name="response", type_=MultiCollisionCheckResponse, mode="serialization"
    )

    async def fastapi_body() -> bytes:
        content = await serialize_response(field=field, response_content=answer, is_coroutine=True)
        return JSONResponse(content).body

    async def run() -> dict[str, list[float]]:
        times: dict[str, list[float]] = {"fastapi": [], "model_json": []}
        if json.loads(await fastapi_body()) != json.loads(ModelJSONResponse(answer).body):
            raise SystemExit("serialise_50_agents: the two paths give different JSON")
        for _ in range(n):
            t0 = time.perf_counter()
            await fastapi_body()
            times["fastapi"].append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            ModelJSONResponse(answer)
            times["model_json"].append(time.perf_counter() - t0)
        return times

    times = asyncio.run(run())
    return {
        "serialise_50_agents_model_json": stats(times["model_json"]),
        "serialise_50_agents_fastapi_default": stats(times["fastapi"]),
    }


def bench_exact_in_process(model: Path, n: int) -> dict[str, dict]:
    """FRTEngine.exact alone (no HTTP, no queue): what an observation costs the worker; and the
    moving car's set (with the load mix's tubes) written and read as bytes, its trip back."""
    from models.runtime import ValueModel
    from models.value_fields import engine_for, network_decision
    from reach.engine import FRTEngine
    from reach.frames import Pose
    from reach.set_bytes import set_from_bytes, set_to_bytes

    value_model = ValueModel.load(model, threads=1)
    # As the service builds it: with the network only where the card says it cuts (FRT_NETWORK).
    network, _ = network_decision(value_model.card, "auto")
    engine = engine_for(value_model, network=network)
    # The same set with the network evaluated (FRT_NETWORK=on), coarse-to-fine and at every node
    # (reach.refine off), interleaved with the served engine's runs so that all see one machine.
    with_network = engine_for(value_model, network=True)
    full = engine_for(value_model, network=True, refine=False)
    # The same set also cut to the speed-coupled partition (the service's background refinement).
    notched = engine_for(value_model, network=network, notch_cut=True)
    out = {}
    for name, (v_start, bounds) in EXACT_CASES.items():
        b = np.array(bounds)

        def run(
            e: FRTEngine,
            stage: int | None = None,
            v: float = v_start,
            b: np.ndarray = b,
            tubes: int = -1,
        ) -> Callable[[], object]:
            return lambda: e.exact(Pose(0.0, 0.0, 0.0), v, b, notch_stage=stage, tubes_upto=tubes)

        variants = {name: run(engine)}
        if "moving" in name:  # as a worker sends it for make load's 2 s time-indexed checks
            variants[f"{name}_with_load_mix_tubes"] = run(engine, tubes=LOAD_MIX_TUBES)
            # ... and its trip back to the server: written and read as the pipe pool sends it.
            sent = run(engine, tubes=LOAD_MIX_TUBES)()
            variants[f"{name}_sent_back_as_bytes"] = lambda s=sent: set_from_bytes(set_to_bytes(s))
        if not network:
            variants[f"{name}_with_network"] = run(with_network)
        if "moving" in name:
            variants[f"{name}_with_network_every_node"] = run(full)
        if "wide" in name:  # each stage of the refinement (NOTCH_STAGES), the last as before
            variants[f"{name}_notch_cut_stage_1"] = run(notched, 1)
            variants[f"{name}_notch_cut"] = run(notched)
        times: dict[str, list[float]] = {key: [] for key in variants}
        for compute in variants.values():
            compute()  # warm-up
        for _ in range(n):
            for key, compute in variants.items():
                t0 = time.perf_counter()
                compute()
                times[key].append(time.perf_counter() - t0)
        out.update({key: stats(values) for key, values in times.items()})
    return out


def audit_observation(t: float, rng: np.random.Generator, first: bool) -> dict:
    """A car at 8 m/s along +x observed at time ``t`` (where the straight prediction puts it,
    give or take a tracker's 0.2 m), with a fresh straight-ahead prediction."""
    body = observation(t, rng, first)
    body["state"].update(x=8.0 * t, y=float(rng.normal(0, 0.2)), speed=8.0)
    return body


def bench_audit(model: Path, n: int, rate_hz: float = 10.0) -> dict[str, dict]:
    """The observation with the audit on and off, side by side (module docstring, item 8)."""
    rng = np.random.default_rng(8)
    times: dict[str, dict[str, list[float]]] = {
        k: {"client": [], "server": []} for k in ("on", "off", "adaptive")
    }
    audited: dict[str, int] = {}
    with (
        running_service(model) as on_url,
        running_service(model, audit="0") as off_url,
        httpx.Client(base_url=on_url, timeout=10) as on,
        httpx.Client(base_url=off_url, timeout=10) as off,
    ):
        clients = {"on": on, "off": off, "adaptive": on}
        agents = {"on": "bench-audit", "off": "bench-audit", "adaptive": "bench-audit-adaptive"}
        warm_up = round(3.0 * rate_hz) + 5  # the ledger full: 30 versions cover each time
        for i in range(warm_up + n):
            t = i / rate_hz
            body = audit_observation(t, rng, i == 0)
            order = ("on", "off", "adaptive") if i % 2 == 0 else ("off", "on", "adaptive")
            for key in order:
                client, agent = clients[key], agents[key]
                if key == "adaptive" and i == 0:
                    body = {**body, "config": {"coverage_target": 0.99}}
                start = time.perf_counter()
                r = client.post(f"/v1/agents/{agent}/observations", json=body)
                elapsed = time.perf_counter() - start
                r.raise_for_status()
                if i >= warm_up:
                    times[key]["client"].append(elapsed)
                    times[key]["server"].append(server_seconds(r))
                check = {"trajectory": trajectory(t + 0.1), "mode": "time_indexed",
                         "deadline_ms": 20}  # fmt: skip
                client.post(f"/v1/agents/{agent}/collision-check", json=check)
            time.sleep(max(1.0 / rate_hz - 0.02, 0.02))  # the exact sets land meanwhile
        agent = on.get("/v1/agents/bench-audit").json()
        audit = agent["audit"]
        audited = {"audited": audit["audited"], "exact": audit["exact"]}
        assert off.get("/v1/agents/bench-audit").json()["audit"] is None
    out = {
        f"observation_audit_{key}_{side}": stats(values)
        for key, sides in times.items()
        for side, values in sides.items()
    }
    out["audit_positions"] = audited  # type: ignore[assignment]
    return out


def bench_audit_in_process(model: Path, n: int, versions: int = 30) -> dict[str, dict]:
    """The audit's own work for one observation, in-process: a position scored against
    ``versions`` earlier versions' conservative sets (a 3 s horizon at 10 Hz; what
    ``Services.audit_later`` does after the answer, and an adaptive agent's observation before)."""
    from models.runtime import ValueModel
    from models.value_fields import engine_for, network_decision
    from reach.frames import Pose
    from service.runtime.audit import ServedVersion, fold, score
    from service.runtime.scheduler import FRTKey

    value_model = ValueModel.load(model)
    engine = engine_for(value_model, network=network_decision(value_model.card, "auto")[0])
    bounds = np.array([-0.1, -1.0, -0.1, -1.0, 0.1, 1.0, 0.1, 1.0])
    served = [
        ServedVersion(k + 1, FRTKey.of("a", k + 1, [float(k)]), 0.1 * k, 0.1 * k + 3.0, 1.5,
                      "car", engine.conservative(Pose(0.8 * k, 0.0, 0.0), 8.0, bounds))
        for k in range(versions)
    ]  # fmt: skip
    t = 0.1 * versions
    times = []
    for i in range(n + 5):
        start = time.perf_counter()
        fold(None, score(8.0 * t, 0.1, t, served, lambda key: None), t)
        if i >= 5:
            times.append(time.perf_counter() - start)
    return {f"audit_score_{versions}_versions_in_process": stats(times)}


def print_audit(results: dict) -> None:
    for side in ("client", "server"):
        off = results.get(f"observation_audit_off_{side}")
        for key in ("on", "adaptive"):
            on = results.get(f"observation_audit_{key}_{side}")
            if on and off:
                print(
                    f"audit cost on the observation, {key} - off ({side}): p50 "
                    f"{on['p50_ms'] - off['p50_ms']:+.3f} ms, p99 "
                    f"{on['p99_ms'] - off['p99_ms']:+.3f} ms (same run)"
                )
    if "audit_positions" in results:
        a = results["audit_positions"]
        print(f"audited positions: {a['audited']}, of which scored on exact sets: {a['exact']}")


#: Where each planner transport's sustained case goes in the results.
SUSTAINED_KEYS = {"http": "sustained_50_agents", "ws": "sustained_50_agents_ws"}


def print_sustained(s: dict, transport: str, width: int) -> None:
    label = "sustained: check all 50 @10 Hz" + (" over WS" if transport == "ws" else "")
    print(
        f"{label:{width}s}  {s['check_all']['p50_ms']:9.2f} "
        f"{s['check_all']['p99_ms']:9.2f}  misses={s['deadline_misses_end_to_end']} of "
        f"{s['check_all']['n']} (server side {s['deadline_misses_server_side']}) "
        f"conservative={s['conservative_answers']} errors={s['errors']}"
    )
    if "check_all_server" in s:
        print(
            f"{'  of which at the server (Server-Timing)':{width}s}  "
            f"{s['check_all_server']['p50_ms']:9.2f} {s['check_all_server']['p99_ms']:9.2f}"
        )
        print(
            f"{'  of which the trip and the client':{width}s}  "
            f"{s['check_all_trip']['p50_ms']:9.2f} {s['check_all_trip']['p99_ms']:9.2f}"
        )
    answers = s["agent_answers"]
    exact_share = answers.get("exact", 0) / max(sum(answers.values()), 1)
    print(f"  per-agent answers from the exact set: {exact_share:.1%} of {sum(answers.values())}")


def print_table(results: dict) -> int:
    """Print every timed row; the width of the name column."""
    width = max(len(k) for k in results)
    print(f"{'measure':{width}s}  {'p50 [ms]':>9s} {'p99 [ms]':>9s}")
    for name, r in results.items():
        if isinstance(r, dict) and "p50_ms" in r:
            print(f"{name:{width}s}  {r['p50_ms']:9.2f} {r['p99_ms']:9.2f}")
    return width


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    parser.add_argument("--checks", type=int, default=500)
    parser.add_argument("--observations", type=int, default=60)
    parser.add_argument("--sustained-seconds", type=float, default=20.0)
    parser.add_argument("--naive", type=int, default=10)
    parser.add_argument(
        "--load-seconds",
        type=float,
        default=30.0,
        help="seconds of make load's mix (scripts/load.py at its defaults); 0: not run",
    )
    parser.add_argument(
        "--sustained-only",
        action="store_true",
        help="run only the sustained case (for comparing revisions run after run)",
    )
    parser.add_argument(
        "--planner-transport",
        choices=("http", "ws", "both"),
        default="both",
        help="how the sustained case's planner sends its checks (the observers always use "
        "HTTP); both: one sustained run each, HTTP first",
    )
    parser.add_argument(
        "--sustained-runs",
        type=int,
        default=1,
        help="run the sustained case this many times per transport (one server), to count how "
        "often a round is late rather than quote one run; the first run's full figures are kept",
    )
    parser.add_argument(
        "--modes-only",
        action="store_true",
        help="run only the multi-modal rows and the single-mode rows beside them",
    )
    parser.add_argument(
        "--audit-only",
        action="store_true",
        help="run only the coverage audit's side-by-side rows (audit on and off)",
    )
    parser.add_argument("--audit-observations", type=int, default=300)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    if args.out is None:
        name = "bench_audit.json" if args.audit_only else "bench.json"
        args.out = ROOT / "results" / name
    results: dict = {}
    if args.audit_only:
        results.update(bench_audit(args.model.resolve(), args.audit_observations))
        results.update(bench_audit_in_process(args.model.resolve(), args.audit_observations))
        print_table(results)
        print_audit(results)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=2))
        print(f"wrote {args.out}")
        return
    with running_service(args.model.resolve()) as url:
        if args.modes_only:
            with httpx.Client(base_url=url, timeout=10) as client:
                results["collision_check_20pt_warm"] = bench_collision(client, args.checks)
                results.update(bench_modes(client, args.observations, args.checks))
                client.delete("/v1/agents/bench-cc").raise_for_status()
            args.sustained_runs = 0
        elif not args.sustained_only:
            with httpx.Client(base_url=url, timeout=10) as client:
                results["collision_check_20pt_warm"] = bench_collision(client, args.checks)
                results["http_floor_get_healthz"] = bench_http_floor(client, args.checks)
                results.update(bench_observe_to_ready(client, args.observations))
                results.update(bench_observe_to_ready_wide(client, args.observations))
                results["contours_tube_plus_3_slices"] = bench_contours(client, args.observations)
                results.update(bench_modes(client, args.observations, args.checks))
                # The planner checks every known agent: the sustained case's 50 and no others.
                for agent in ("bench-cc", "bench-obs", "bench-obs1", "bench-wide", "bench-frt"):
                    client.delete(f"/v1/agents/{agent}").raise_for_status()
        transports = (
            ("http", "ws") if args.planner_transport == "both" else (args.planner_transport,)
        )
        runs: dict[str, list[dict]] = {transport: [] for transport in transports}
        for _ in range(args.sustained_runs):
            for transport in transports:
                sustained = sustained_run(url, args.sustained_seconds, transport)
                runs[transport].append(run_summary(sustained))
                results.setdefault(SUSTAINED_KEYS[transport], sustained)
        if args.sustained_runs > 1:
            results["sustained_runs"] = runs
        if not (args.sustained_only or args.modes_only) and args.load_seconds > 0:
            results["load_mix_check_all_10"] = bench_load_mix(
                url, args.model.resolve(), args.load_seconds
            )
    if not (args.sustained_only or args.modes_only):
        results.update(bench_audit(args.model.resolve(), args.audit_observations))
        results.update(bench_audit_in_process(args.model.resolve(), args.audit_observations))
        results.update(bench_exact_in_process(args.model.resolve(), args.observations))
        results.update(bench_serialisation(args.checks))
        results["naive_dense_grid_per_query"] = bench_naive(args.model.resolve(), args.naive)
        warm = results["collision_check_20pt_warm"]["p50_ms"]
        naive = results["naive_dense_grid_per_query"]["p50_ms"]
        results["naive_over_engine_p50_ratio"] = naive / warm if warm > 0 else math.inf
    width = print_table(results)
    print_audit(results)
    for transport, key in SUSTAINED_KEYS.items():
        if key in results:
            print_sustained(results[key], transport, width)
    if "load_mix_check_all_10" in results:
        mix = results["load_mix_check_all_10"]
        print(
            f"load mix (make load's defaults, {mix['seconds']:g} s): exact answers "
            f"{100 * (mix['exact_share'] or 0):.1f} % of {mix['answers']}, late rounds "
            f"{mix['late_end_to_end']} end to end (at the server {mix['late_server_side']}) of "
            f"{mix['n']}, errors {mix['errors']}"
        )
    for transport, summaries in results.get("sustained_runs", {}).items():
        late = [r["deadline_misses_end_to_end"] for r in summaries]
        server = [r["deadline_misses_server_side"] for r in summaries]
        print(
            f"sustained over {transport}, {len(summaries)} runs: late rounds end to end {late} "
            f"(at the server {server}) of {[r['rounds'] for r in summaries]}"
        )
    if "naive_over_engine_p50_ratio" in results:
        ratio = results["naive_over_engine_p50_ratio"]
        print(f"naive / engine (p50, same run): {ratio:.0f}x")
    for name in EXACT_CASES:
        served, evaluated = results.get(name), results.get(f"{name}_with_network")
        if served and evaluated:
            saving = evaluated["p50_ms"] - served["p50_ms"]
            print(
                f"{name}: the network skipped saves {saving:.2f} ms at the median "
                f"({evaluated['p50_ms'] / served['p50_ms']:.2f}x, same run)"
            )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
