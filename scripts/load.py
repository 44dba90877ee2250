"""Load test: N planners checking M simulated humans against a local FRT service, for a while.

Each human drives an extended unicycle (x' = v cos θ, y' = v sin θ, θ' = u1, v' = u2) with smooth
controls; one in five turns erratically now and then, so its confidence β falls and recovers. A
perception task per human posts an observation at ``--obs-hz``: the state, the action actually taken
since the previous observation (its average controls), and a constant-control prediction over the
3 s horizon. Each planner checks its 2 s, 20-point trajectory against all M humans in one call at
``--check-hz``. Every task paces itself on a fixed schedule and never has more than one request in
flight, so the offered load is bounded; the run stops by itself after ``--duration`` seconds.

With ``--scenes S`` the humans are split into S scenes (``scene-0``, ...), each with its own
``--planners`` planners checking only that scene's humans, and every request of a scene carries
``X-FRT-Scene`` (``FRTClient(scene=...)``): behind nginx each scene goes to one replica. With
``--frames`` a scene's humans are observed together: one ``POST /v1/frames`` per period, every
human of the scene in it (``FRTClient.frame``), instead of one observation per human.

At the end it verifies, for every human, that the service holds exactly the β the harness computes
from what it sent (with the service's own filter, ``service.flows.confidence``), the FRT version equal to
the number of observations accepted, and the last timestamp sent; and each observation's answer
must carry the β and version expected at that moment. A lost or reordered update shows. It prints throughput and p50/p95/p99/max latency per operation, errors and deadline misses,
writes a JSON summary (``--out``, default results/load.json) and a latency plot beside it (.png).
Exit status: 0 clean, 1 errors or lost updates, 2 refused arguments or service not ready.

    python scripts/load.py --url http://127.0.0.1:8000 --duration 60 --planners 2 --humans 10
    python scripts/load.py --frames --scenes 5 --planners 1 --humans 50 --obs-hz 10
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import random
import re
import sys
import time
import uuid
from collections.abc import Callable, Coroutine, Iterator
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from frt_client import NO_RETRY, AsyncFRTClient, FRTError  # noqa: E402
from frt_client.models import FrameRejection  # noqa: E402

from service.flows.confidence import Belief, hypotheses, prior_belief, update_belief  # noqa: E402

LOCAL_HOSTS = {"127.0.0.1", "localhost", "::1"}
MAX_DURATION_S = 600.0
MAX_PLANNERS = 32
MAX_HUMANS = 256
MAX_SCENES = 32
OBS_HZ = (2.0, 10.0)
CHECK_HZ = (10.0, 20.0)
#: The prediction: constant controls over the horizon, HORIZON_STEPS steps of PRED_DT seconds.
PRED_DT = 0.25
HORIZON_STEPS = 12
PRED_SD = (0.1, 0.5)  # rad/s, m/s²
#: Chance per 20 ms integration step that an erratic driver starts a swerve (about one per 5 s).
SWERVE_CHANCE = 0.004
#: A planner's trajectory: TRAJ_POINTS points TRAJ_DT apart, starting now.
TRAJ_POINTS = 20
TRAJ_DT = 0.1
#: Two β values "equal" when they differ by at most this (both are float64 from the same code).
BETA_TOLERANCE = 1e-9


# ------------------------------------------------------------------------------------ arguments


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--url", default="http://127.0.0.1:8000", help="service URL (loopback only)")
    p.add_argument("--duration", type=float, default=60.0, help=f"seconds (<= {MAX_DURATION_S:g})")
    p.add_argument("--planners", type=int, default=2, help=f"planners (1..{MAX_PLANNERS})")
    p.add_argument("--humans", type=int, default=10, help=f"simulated humans (1..{MAX_HUMANS})")
    p.add_argument("--obs-hz", type=float, default=5.0, help="observations per human per second")
    p.add_argument("--check-hz", type=float, default=10.0, help="checks per planner per second")
    p.add_argument(
        "--scenes", type=int, default=1, help=f"scenes the humans are split into (1..{MAX_SCENES}), "
        "each with --planners planners of its own and its X-FRT-Scene header (none for 1)"
    )  # fmt: skip
    p.add_argument(
        "--frames", action="store_true", help="observe a scene's humans together: one POST "
        "/v1/frames per period with every human of the scene"
    )  # fmt: skip
    p.add_argument("--deadline-ms", type=float, default=20.0, help="deadline of each check")
    p.add_argument("--timeout", type=float, default=2.0, help="client timeout per request, s")
    p.add_argument("--transport", choices=("http", "ws"), default="http")
    p.add_argument("--token", default=None, help="bearer token, if the service has one")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=ROOT / "results" / "load.json")
    p.add_argument("--keep-agents", action="store_true", help="do not delete the run's agents")
    p.add_argument(
        "--model",
        type=Path,
        default=ROOT / "models" / "frt_unicycle.onnx",
        help="the served model, to measure the fallback's area against the exact set's "
        "on the humans' last states (in this process)",
    )
    return p.parse_args(argv)


def refusal(args: argparse.Namespace) -> str | None:
    """Why these arguments are refused, or None."""
    parts = urlsplit(args.url)
    if parts.scheme not in ("http", "https") or parts.hostname not in LOCAL_HOSTS:
        return f"--url must be http://127.0.0.1:<port> or localhost, not {args.url!r}"
    if not 0 < args.duration <= MAX_DURATION_S:
        return f"--duration must be in (0, {MAX_DURATION_S:g}] s"
    if not 1 <= args.planners <= MAX_PLANNERS or not 1 <= args.humans <= MAX_HUMANS:
        return f"--planners must be 1..{MAX_PLANNERS} and --humans 1..{MAX_HUMANS}"
    if not 1 <= args.scenes <= min(MAX_SCENES, args.humans):
        return f"--scenes must be 1..{MAX_SCENES} and at most --humans"
    if args.scenes * args.planners > MAX_PLANNERS:
        return f"--scenes x --planners must be at most {MAX_PLANNERS}"
    if not OBS_HZ[0] <= args.obs_hz <= OBS_HZ[1]:
        return f"--obs-hz must be in [{OBS_HZ[0]:g}, {OBS_HZ[1]:g}]"
    if not CHECK_HZ[0] <= args.check_hz <= CHECK_HZ[1]:
        return f"--check-hz must be in [{CHECK_HZ[0]:g}, {CHECK_HZ[1]:g}]"
    if not 0 < args.deadline_ms <= 1000 or not 0 < args.timeout <= 30:
        return "--deadline-ms must be in (0, 1000] and --timeout in (0, 30]"
    return None


# ------------------------------------------------------------------------------------ the humans


@dataclass
class Human:
    """One simulated driver: extended unicycle state and a smooth (sometimes erratic) control law."""

    agent_id: str
    x: float
    y: float
    heading: float
    speed: float
    v_target: float
    v_max: float
    steer_amp: float
    steer_freq: float
    phase: float
    erratic: bool
    rng: random.Random
    swerve_until: float = -1.0
    swerve: float = 0.0

    def nominal(self, t: float) -> tuple[float, float]:
        """The smooth control law: a slow weave, and speed held near a target."""
        u1 = self.steer_amp * math.sin(self.steer_freq * t + self.phase)
        u2 = max(-3.0, min(3.0, 0.8 * (self.v_target - self.speed)))
        return u1, u2

    def controls(self, t: float) -> tuple[float, float]:
        """The controls actually applied: nominal, except during an erratic driver's swerves."""
        if self.erratic and t >= self.swerve_until and self.rng.random() < SWERVE_CHANCE:
            self.swerve_until = t + self.rng.uniform(0.3, 1.0)
            self.swerve = self.rng.choice((-1.0, 1.0)) * self.rng.uniform(0.8, 1.8)
        u1, u2 = self.nominal(t)
        return (self.swerve if t < self.swerve_until else u1), u2

    def advance(self, t0: float, t1: float, step: float = 0.02) -> tuple[float, float]:
        """Integrate from t0 to t1; returns the average controls taken (the observed action)."""
        t, total1, total2 = t0, 0.0, 0.0
        while t < t1 - 1e-12:
            h = min(step, t1 - t)
            u1, u2 = self.controls(t)
            if self.speed <= 0.0 and u2 < 0.0:
                u2 = 0.0  # a stopped car stays stopped: no reversing
            self.x += h * self.speed * math.cos(self.heading)
            self.y += h * self.speed * math.sin(self.heading)
            self.heading = math.remainder(self.heading + h * u1, math.tau)
            self.speed = min(max(self.speed + h * u2, 0.0), self.v_max)
            total1, total2 = total1 + h * u1, total2 + h * u2
            t += h
        span = max(t1 - t0, 1e-9)
        return total1 / span, total2 / span

    def prediction(self, t: float) -> dict[str, Any]:
        """A constant-control predictor of the smooth law: it does not foresee swerves."""
        u1, u2 = self.nominal(t)
        cov = [[PRED_SD[0] ** 2, 0.0], [0.0, PRED_SD[1] ** 2]]
        return {
            "dt": PRED_DT,
            "mean": [[u1, u2] for _ in range(HORIZON_STEPS)],
            "cov": [[list(row) for row in cov] for _ in range(HORIZON_STEPS)],
        }


def make_humans(count: int, run_id: str, v_max: float, rng: random.Random) -> list[Human]:
    humans = []
    for i in range(count):
        angle = math.tau * i / count
        top = max(2.5, min(15.0, v_max - 2.0))
        humans.append(
            Human(
                agent_id=f"load-{run_id}-h{i}",
                x=30.0 * math.cos(angle),
                y=30.0 * math.sin(angle),
                heading=rng.uniform(-math.pi, math.pi),
                speed=rng.uniform(2.0, top),
                v_target=rng.uniform(2.0, top),
                v_max=max(top + 1.0, 3.0),
                steer_amp=rng.uniform(0.02, 0.3),
                steer_freq=rng.uniform(0.2, 1.0),
                phase=rng.uniform(0.0, math.tau),
                erratic=(i % 5 == 4),
                rng=random.Random(rng.random()),
            )
        )
    return humans


# ------------------------------------------------------------------------------ the expectation


@dataclass
class Expected:
    """What the service should hold for one human, recomputed from what was sent."""

    belief: Belief | None = None
    first_step: tuple[list[float], list[list[float]]] | None = None
    accepted: int = 0
    timestamp: float | None = None
    #: An observation whose fate is unknown (timeout, dropped connection): no verdict possible.
    uncertain: bool = False
    beta_low: float | None = None
    epsilon: float | None = None
    #: Answers whose beta or version differed from the expectation at that moment.
    answers_off: int = 0
    lowest_beta: float = 1.0

    def check_answer(self, beta: float, frt_version: int) -> None:
        """Compare one observation's answer with the expectation just updated."""
        assert self.belief is not None
        if abs(beta - self.belief.beta) > BETA_TOLERANCE or frt_version != self.accepted:
            self.answers_off += 1
        self.lowest_beta = min(self.lowest_beta, beta)

    def accept(
        self, action: tuple[float, float] | None, prediction: dict[str, Any], timestamp: float
    ) -> None:
        """Apply one accepted observation exactly as the service does (service.flows.agents.observe)."""
        assert self.beta_low is not None and self.epsilon is not None
        if self.belief is None:
            self.belief = prior_belief(hypotheses(self.beta_low))
        if action is not None and self.first_step is not None:
            mean, cov = self.first_step
            self.belief = update_belief(self.belief, list(action), mean, cov, self.epsilon)
        self.first_step = (prediction["mean"][0], prediction["cov"][0])
        self.accepted += 1
        self.timestamp = timestamp


# ---------------------------------------------------------------------------------- measurement


@dataclass
class Stats:
    """Latencies and outcomes per operation."""

    latencies: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    errors: dict[str, dict[str, int]] = field(default_factory=dict)
    error_samples: list[str] = field(default_factory=list)
    over_deadline: int = 0
    conservative: int = 0
    answers: int = 0  # per-agent answers of all checks
    #: Per-agent answers by verdict: exact, decision_exact, conservative (API.md, "Frames").
    verdicts: dict[str, int] = field(default_factory=dict)
    skipped_ticks: int = 0

    def record(self, op: str, at: float, seconds: float) -> None:
        self.latencies.setdefault(op, []).append((at, seconds))

    def error(self, op: str, exc: Exception) -> None:
        status = getattr(exc, "status", None)
        kind = f"{type(exc).__name__}:{status}" if status else type(exc).__name__
        per_op = self.errors.setdefault(op, {})
        per_op[kind] = per_op.get(kind, 0) + 1
        if len(self.error_samples) < 10:
            self.error_samples.append(f"{op}: {kind}: {exc}")

    def error_count(self) -> int:
        return sum(sum(kinds.values()) for kinds in self.errors.values())


def ticks(start: float, hz: float, end: float, stats: Stats) -> Iterator[float]:
    """Scheduled times start, start + 1/hz, ... before end; a task that falls behind skips slots
    (counted) rather than bursting to catch up."""
    period, k = 1.0 / hz, 0
    while True:
        at = start + k * period
        now = time.monotonic()
        if at < now - period:
            missed = int((now - at) / period)
            stats.skipped_ticks += missed
            k += missed
            continue
        if at >= end:
            return
        yield at
        k += 1


async def sleep_until(at: float) -> None:
    delay = at - time.monotonic()
    if delay > 0:
        await asyncio.sleep(delay)


# ------------------------------------------------------------------------------------ the tasks


async def perceive(
    ops: Any, human: Human, expected: Expected, clock0: float, end: float, hz: float, stats: Stats
) -> None:
    """Observe one human at ``hz`` until ``end`` (one request in flight at a time)."""
    last_t: float | None = None
    for at in ticks(clock0 + random.uniform(0, 1.0 / hz), hz, end, stats):
        await sleep_until(at)
        t = time.monotonic() - clock0
        action = None if last_t is None else human.advance(last_t, t)
        prediction = human.prediction(t)
        state = (human.x, human.y, human.heading, human.speed)
        started = time.perf_counter()
        try:
            answer = await ops.observe(
                human.agent_id,
                timestamp=t,
                state=state,
                prediction=prediction,
                observed_action=action,
            )
        except FRTError as exc:
            stats.error("observe", exc)
            if exc.status is None or (exc.status >= 500 and exc.status != 503):
                expected.uncertain = True  # it may or may not have been applied
        else:
            stats.record("observe", t, time.perf_counter() - started)
            expected.accept(action, prediction, t)
            if not expected.uncertain:
                expected.check_answer(answer.beta, answer.frt_version)
        last_t = t


async def perceive_frames(
    ops: Any,
    humans: list[Human],
    expectations: dict[str, Expected],
    clock0: float,
    end: float,
    hz: float,
    stats: Stats,
) -> None:
    """Observe a scene's ``humans`` together at ``hz`` until ``end``: one frame per period with
    every one of them (one request in flight at a time)."""
    last_t: float | None = None
    for at in ticks(clock0 + random.uniform(0, 1.0 / hz), hz, end, stats):
        await sleep_until(at)
        t = time.monotonic() - clock0
        entries = []
        for human in humans:
            entries.append(
                {
                    "agent_id": human.agent_id,
                    "observed_action": None if last_t is None else human.advance(last_t, t),
                    "prediction": human.prediction(t),
                    "state": (human.x, human.y, human.heading, human.speed),
                }
            )
        started = time.perf_counter()
        try:
            answer = await ops.frame(timestamp=t, agents=entries)
        except FRTError as exc:
            stats.error("frame", exc)
            if exc.status is None or (exc.status >= 500 and exc.status != 503):
                for human in humans:  # each may or may not have been applied
                    expectations[human.agent_id].uncertain = True
        else:
            stats.record("frame", t, time.perf_counter() - started)
            for entry, result in zip(entries, answer.results, strict=True):
                expected = expectations[entry["agent_id"]]
                if isinstance(result, FrameRejection):
                    error = FRTError(result.error.detail, status=result.error.status)
                    stats.error("frame", error)
                    continue
                expected.accept(entry["observed_action"], entry["prediction"], t)
                if not expected.uncertain:
                    expected.check_answer(result.beta, result.frt_version)
        last_t = t


async def plan(
    ops: Any,
    index: int,
    agent_ids: list[str],
    clock0: float,
    end: float,
    args: argparse.Namespace,
    stats: Stats,
) -> None:
    """Check one robot's trajectory against every human at ``args.check_hz`` until ``end``."""
    lane = -20.0 + 40.0 * index / max(args.planners - 1, 1)
    for at in ticks(clock0 + random.uniform(0, 1.0 / args.check_hz), args.check_hz, end, stats):
        await sleep_until(at)
        t = time.monotonic() - clock0
        x0 = -60.0 + (8.0 * t) % 120.0
        trajectory = [(t + k * TRAJ_DT, x0 + 8.0 * k * TRAJ_DT, lane) for k in range(TRAJ_POINTS)]
        started = time.perf_counter()
        try:
            answer = await ops.collision_check_many(
                trajectory, agent_ids, mode="time_indexed", deadline_ms=args.deadline_ms
            )
        except FRTError as exc:
            stats.error("check", exc)
            continue
        seconds = time.perf_counter() - started
        stats.record("check", t, seconds)
        stats.conservative += sum(1 for r in answer.results if r.conservative)
        stats.answers += len(answer.results)
        for result in answer.results:
            verdict = result.verdict or ("conservative" if result.conservative else "exact")
            stats.verdicts[verdict] = stats.verdicts.get(verdict, 0) + 1
        if seconds * 1000.0 > args.deadline_ms:
            stats.over_deadline += 1


# ------------------------------------------------------------------------------ the server side


def fallback_area(model: Path, agents: list[Any]) -> dict[str, float | int | None]:
    """Mean ratio of the conservative set's whole-horizon area to the exact set's, of K and C,
    over the humans' last states (``scripts/fallback_cost.py``; computed here, off the clock)."""
    from reach.frames import Pose
    from scripts.fallback_cost import BOUND_NAMES, area_ratio, mean_ratio, served_engine

    if not agents or not model.is_file():
        return {"k": None, "c": None, "agents": 0}
    engine = served_engine(model)
    ratios = []
    for agent in agents:
        state = agent.state
        bounds = [getattr(agent.control_bounds, name) for name in BOUND_NAMES]
        pose = Pose(state["x"], state["y"], state["heading"])
        radius = agent.config.collision_radius if agent.config is not None else 1.5
        ratios.append(area_ratio(engine, pose, state["speed"], bounds, radius))
    mean = mean_ratio(ratios)
    return {"k": mean.k, "c": mean.c, "agents": len(ratios)}


async def server_counters(url: str) -> dict[str, float]:
    """Deadline misses and conservative answers as the service counts them (/metrics)."""
    wanted = {
        "frt_deadline_misses_total": "deadline_misses",
        'frt_collision_checks_total{source="conservative"}': "conservative",
        'frt_collision_checks_total{source="exact"}': "exact",
    }
    try:
        async with httpx.AsyncClient(timeout=5.0) as http:
            text = (await http.get(f"{url}/metrics")).text
    except httpx.HTTPError:
        return {}
    found: dict[str, float] = {}
    for line in text.splitlines():
        match = re.match(r"^(\S+?)\s+(\S+)$", line)
        if match and match.group(1) in wanted:
            found[wanted[match.group(1)]] = float(match.group(2))
    return found


async def verify(
    client: AsyncFRTClient, humans: list[Human], expectations: dict[str, Expected]
) -> dict[str, Any]:
    """Compare every agent on the service with what the harness expects."""
    mismatches, unverifiable, max_diff = [], [], 0.0
    for human in humans:
        want = expectations[human.agent_id]
        if want.uncertain:
            unverifiable.append(human.agent_id)
            continue
        if want.accepted == 0:
            continue
        try:
            have = await client.get_agent(human.agent_id)
        except FRTError as exc:
            mismatches.append({"agent_id": human.agent_id, "error": str(exc)})
            continue
        assert want.belief is not None
        diff = abs(have.beta - want.belief.beta)
        max_diff = max(max_diff, diff)
        if (
            diff > BETA_TOLERANCE
            or have.frt_version != want.accepted
            or have.timestamp != want.timestamp
        ):
            mismatches.append(
                {
                    "agent_id": human.agent_id,
                    "beta": have.beta,
                    "expected_beta": want.belief.beta,
                    "frt_version": have.frt_version,
                    "expected_frt_version": want.accepted,
                    "timestamp": have.timestamp,
                    "expected_timestamp": want.timestamp,
                }
            )
    betas = [e.belief.beta for e in expectations.values() if e.belief is not None]
    return {
        "agents": len(humans),
        "verified": len(humans) - len(unverifiable),
        "lost_updates": len(mismatches),
        "answers_off": sum(e.answers_off for e in expectations.values()),
        "lowest_beta_answered": min(e.lowest_beta for e in expectations.values()),
        "unverifiable": unverifiable,
        "mismatches": mismatches[:20],
        "max_beta_diff": max_diff,
        "beta_range": [min(betas), max(betas)] if betas else None,
    }


async def settle_config(
    client: AsyncFRTClient, humans: list[Human], expectations: dict[str, Expected]
) -> None:
    """Create every agent with one observation and read back its effective filter settings, so
    the reference computation uses exactly the server's beta_low and epsilon."""
    for human in humans:
        prediction = human.prediction(0.0)
        state = (human.x, human.y, human.heading, human.speed)
        await client.observe(human.agent_id, timestamp=-1.0, state=state, prediction=prediction)
        view = await client.get_agent(human.agent_id)
        assert view.config is not None, "the service must echo the agent's config"
        want = expectations[human.agent_id]
        want.beta_low, want.epsilon = view.config.beta_low, view.config.epsilon
        want.accept(None, prediction, -1.0)


# ---------------------------------------------------------------------------------- the summary


def summarise(stats: Stats, elapsed: float) -> dict[str, dict[str, float]]:
    table = {}
    for op, samples in sorted(stats.latencies.items()):
        ms = np.array([s for _, s in samples]) * 1000.0
        table[op] = {
            "count": int(ms.size),
            "errors": sum(stats.errors.get(op, {}).values()),
            "throughput_per_s": ms.size / elapsed,
            "p50_ms": float(np.percentile(ms, 50)),
            "p95_ms": float(np.percentile(ms, 95)),
            "p99_ms": float(np.percentile(ms, 99)),
            "max_ms": float(ms.max()),
            "mean_ms": float(ms.mean()),
        }
    for op, kinds in stats.errors.items():
        table.setdefault(op, {"count": 0, "errors": sum(kinds.values())})
    return table


def print_report(summary: dict[str, Any]) -> None:
    cfg = summary["config"]
    print(
        f"\nFRT load test: {cfg['planners']} planners x {cfg['humans']} humans, "
        f"obs {cfg['obs_hz']:g} Hz/human, checks {cfg['check_hz']:g} Hz/planner "
        f"({cfg['transport']}), {summary['elapsed_s']:.1f} s against {cfg['url']}"
        + (f", {cfg['scenes']} scenes" if cfg["scenes"] > 1 else "")
        + (", observed in frames" if cfg["frames"] else "")
    )
    header = f"{'op':<9}{'count':>8}{'err':>6}{'req/s':>9}{'p50 ms':>9}{'p95 ms':>9}"
    print(header + f"{'p99 ms':>9}{'max ms':>9}")
    for op, row in summary["operations"].items():
        if row.get("count"):
            print(
                f"{op:<9}{row['count']:>8}{row['errors']:>6}{row['throughput_per_s']:>9.1f}"
                f"{row['p50_ms']:>9.2f}{row['p95_ms']:>9.2f}{row['p99_ms']:>9.2f}"
                f"{row['max_ms']:>9.2f}"
            )
        else:
            print(f"{op:<9}{0:>8}{row['errors']:>6}")
    d = summary["deadline"]
    print(
        f"errors: {summary['errors']}   checks over {d['deadline_ms']:g} ms (client-side): "
        f"{d['client_over_deadline']}   server deadline misses: {d['server_misses']}   "
        f"conservative answers: {d['conservative_answers']}   skipped ticks: "
        f"{summary['skipped_ticks']}"
    )
    share, area = d["exact_share"], summary["fallback_area_ratio"]
    if share is not None:
        print(
            f"exact answers: {d['answers'] - d['conservative_answers']} of {d['answers']} "
            f"per-agent answers ({100.0 * share:.1f} %); by verdict {d['verdicts']}, exact or "
            f"decision-exact {100.0 * d['decision_exact_share']:.1f} %"
        )
    if area["k"] is not None:
        print(
            f"fallback area / exact area (whole tube, mean over the humans' last states): "
            f"K {area['k']:.2f}x, C {area['c']:.2f}x"
        )
    v = summary["verification"]
    print(
        f"beta check: {v['verified']}/{v['agents']} agents verified, lost or reordered updates: "
        f"{v['lost_updates']}, answers off: {v['answers_off']}, max |beta - expected| = "
        f"{v['max_beta_diff']:.2e} (lowest beta answered {v['lowest_beta_answered']:.3f})"
        + (f", unverifiable: {len(v['unverifiable'])}" if v["unverifiable"] else "")
    )
    for sample in summary["error_samples"]:
        print(f"  {sample}")


def plot(stats: Stats, summary: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.5))
    for op, samples in sorted(stats.latencies.items()):
        at = np.array([a for a, _ in samples])
        ms = np.array([s for _, s in samples]) * 1000.0
        left.scatter(at, ms, s=3, alpha=0.5, label=op)
        ordered = np.sort(ms)
        right.plot(ordered, np.arange(1, ordered.size + 1) / ordered.size, label=op)
    deadline = summary["deadline"]["deadline_ms"]
    for ax in (left, right):
        ax.grid(True, alpha=0.3)
        ax.legend()
    left.axhline(deadline, color="red", lw=0.8, ls="--")
    right.axvline(deadline, color="red", lw=0.8, ls="--", label="check deadline")
    left.set(xlabel="time since start [s]", ylabel="latency [ms]", yscale="log")
    right.set(xlabel="latency [ms]", ylabel="fraction of requests", xscale="log")
    cfg = summary["config"]
    fig.suptitle(
        f"{cfg['planners']} planners x {cfg['humans']} humans, obs {cfg['obs_hz']:g} Hz, "
        f"checks {cfg['check_hz']:g} Hz, {cfg['transport']}"
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------------ the run


def client_for(args: argparse.Namespace, scene: str | None = None) -> AsyncFRTClient:
    return AsyncFRTClient(
        args.url,
        token=args.token,
        scene=scene,
        timeout=httpx.Timeout(args.timeout, connect=2.0),
        retry=NO_RETRY,  # a load test reports failures, it does not hide them
        limits=httpx.Limits(
            max_connections=args.planners + args.humans + 4,
            max_keepalive_connections=args.planners + args.humans + 4,
            keepalive_expiry=2.0,  # below uvicorn's 5 s keep-alive: no close/reuse race
        ),
    )


def scene_names(args: argparse.Namespace) -> list[str | None]:
    """The scenes' X-FRT-Scene values (None: one scene, no header)."""
    return [f"scene-{i}" for i in range(args.scenes)] if args.scenes > 1 else [None]


async def drive(
    args: argparse.Namespace,
    clients: list[AsyncFRTClient],
    scenes: list[list[Human]],
    expectations: dict[str, Expected],
    stats: Stats,
) -> float:
    """Every scene's perception (per human, or one frame per period) and planners until the
    run's end, through the scene's client; the seconds it took."""
    sessions: list[Any] = []

    def ops_of(client: AsyncFRTClient) -> Any:
        if args.transport != "ws":
            return client
        sessions.append(client.stream(timeout=args.timeout))
        return sessions[-1]

    # Each task's operations first (a stream each, with --transport ws), then the schedule.
    starts: list[Callable[[float, float], Coroutine[Any, Any, None]]] = []
    for client, group in zip(clients, scenes, strict=True):
        pace = {"hz": args.obs_hz, "stats": stats}
        if args.frames:
            starts.append(partial(perceive_frames, ops_of(client), group, expectations, **pace))
        else:
            starts += [
                partial(perceive, ops_of(client), h, expectations[h.agent_id], **pace)
                for h in group
            ]
        ids = [h.agent_id for h in group]
        starts += [
            partial(plan, ops_of(client), i, ids, args=args, stats=stats)
            for i in range(args.planners)
        ]
    try:
        await asyncio.gather(*(s.open() for s in sessions))
        clock0 = time.monotonic()
        tasks = [start(clock0, clock0 + args.duration) for start in starts]
        await asyncio.wait_for(asyncio.gather(*tasks), timeout=args.duration + 30.0)
    finally:
        for session in sessions:
            await session.close()
    return time.monotonic() - clock0


async def run(args: argparse.Namespace) -> tuple[dict[str, Any], Stats]:
    rng = random.Random(args.seed)
    random.seed(args.seed)
    run_id = uuid.uuid4().hex[:8]
    async with contextlib.AsyncExitStack() as stack:
        clients = [
            await stack.enter_async_context(client_for(args, scene)) for scene in scene_names(args)
        ]
        client = clients[0]
        await client.wait_ready(timeout_s=30.0)
        card = await client.model()
        v_max = card.ranges.get("v_start", [0.0, 20.0])[1]
        humans = make_humans(args.humans, run_id, v_max, rng)
        scenes = [humans[i :: len(clients)] for i in range(len(clients))]
        expectations = {h.agent_id: Expected() for h in humans}
        for scene_client, group in zip(clients, scenes, strict=True):
            await settle_config(scene_client, group, expectations)
        agent_ids = [h.agent_id for h in humans]
        before = await server_counters(args.url)
        stats = Stats()
        elapsed = await drive(args, clients, scenes, expectations, stats)

        after = await server_counters(args.url)
        verification = await verify(client, humans, expectations)
        finals = []
        for human in humans:
            with contextlib.suppress(FRTError):
                finals.append(await client.get_agent(human.agent_id))
        area = fallback_area(args.model, finals)
        if not args.keep_agents:
            for agent in agent_ids:
                with contextlib.suppress(FRTError):
                    await client.delete_agent(agent)

    def delta(key: str) -> float | None:
        return after[key] - before.get(key, 0.0) if key in after else None

    errors = stats.error_count()
    summary = {
        "config": {
            "url": args.url, "duration_s": args.duration, "planners": args.planners,
            "humans": args.humans, "obs_hz": args.obs_hz, "check_hz": args.check_hz,
            "scenes": args.scenes, "frames": args.frames,
            "deadline_ms": args.deadline_ms, "timeout_s": args.timeout,
            "transport": args.transport, "seed": args.seed, "model": card.name,
            "trajectory_points": TRAJ_POINTS, "prediction_steps": HORIZON_STEPS,
        },
        "elapsed_s": elapsed,
        "operations": summarise(stats, elapsed),
        "errors": errors,
        "errors_by_op": stats.errors,
        "error_samples": stats.error_samples,
        "deadline": {
            "deadline_ms": args.deadline_ms,
            "client_over_deadline": stats.over_deadline,
            "server_misses": delta("deadline_misses"),
            "conservative_answers": stats.conservative,
            "server_conservative": delta("conservative"),
            "server_exact": delta("exact"),
            "answers": stats.answers,
            "exact_share": 1.0 - stats.conservative / stats.answers if stats.answers else None,
            "verdicts": stats.verdicts,
            "decision_exact_share": (
                (stats.verdicts.get("exact", 0) + stats.verdicts.get("decision_exact", 0))
                / stats.answers
                if stats.answers
                else None
            ),
        },
        "fallback_area_ratio": area,
        #: Observations the service stored during the run (each a new version of its agent).
        "versions_stored": sum(e.accepted for e in expectations.values()) - len(humans),
        "skipped_ticks": stats.skipped_ticks,
        "verification": verification,
        "ok": errors == 0
        and verification["lost_updates"] == 0
        and verification["answers_off"] == 0,
        "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }  # fmt: skip
    return summary, stats


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    why = refusal(args)
    if why:
        print(f"load.py: refused: {why}", file=sys.stderr)
        return 2
    try:
        summary, stats = asyncio.run(run(args))
    except FRTError as exc:
        print(f"load.py: service not usable: {exc}", file=sys.stderr)
        return 2
    print_report(summary)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=2) + "\n")
    png = args.out.with_suffix(".png")
    plot(stats, summary, png)
    print(f"wrote {args.out} and {png}")
    return 0 if summary["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
