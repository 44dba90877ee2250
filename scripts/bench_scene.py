"""A whole scene on one event loop, in-process: ``python scripts/bench_scene.py``.

One process builds the service's engine (``Services``, the shipped model, exact sets in worker
processes as served) and drives, on its own event loop, what a scene sends a replica: every
``1 / --hz`` seconds one frame of ``--agents`` agents (``scripts/bench_frames.py``'s scene:
cars, pedestrians and three-mode cars, ``service.flows.frames.apply_frame``), and ``--planners``
planners each checking a 20-point, 2 s time-indexed trajectory against every agent at ``--hz``
(``service.flows.checks.check_agents_at_once``, deadline ``--deadline-ms``). The frames' bodies
are made before the clock starts and read as ``POST /v1/frames`` reads them (typed in one pass,
``service.wire.frame_body.parse_frame``), inside each frame's time. Without HTTP and without a
load harness beside it, what is measured is the event loop's own scheduling: how long a check
waits behind frames and their audit, from the tick it was due at to its answer. The share of answers exact or decision-exact
is printed with, beside it, the share whose verdict is known: those and the conservative
collisions a reached position witnesses (``collision_witnessed``).

``--phase-sweep`` gives the planners a period 3 % longer than the frames' so that, over the run,
their checks come at every phase of the frame period; each check's answers are then counted by
its phase (the time since the frame's tick, in tenths of the period): the conservative answers,
the collisions and the exact answers per check, and the checks' latency from their tick. It shows
whether the conservative answers wait on a frame just applied or on sets that do not keep up.
Every run also prints how long the exact sets took from submission to ready, by their priority
(``frt_exact_ready_seconds``: met, demanded, background).

``--baseline REV`` runs the same scene, in a second process started after this one, on the tree of
git revision ``REV`` (``git archive`` into a temporary directory); both print one line each and
``--out`` keeps both. With ``--turns N`` both trees run in processes of their own, in turns, N
times each (on a shared machine runs one after the other meet its load at different moments).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel

ROOT = Path(__file__).resolve().parent.parent
SOURCE = Path(os.environ.get("FRT_BENCH_SOURCE", ROOT))
sys.path.insert(0, str(SOURCE))
sys.path.insert(1, str(ROOT))

TRAJECTORY_POINTS = 20
TRAJECTORY_DT = 0.1
PLANNER_SPEED = 8.0
M = TypeVar("M", bound=BaseModel)
#: ``--phase-sweep``: the planners' period this much longer than the frames'.
PHASE_SWEEP_STRETCH = 0.03


def quantile_ms(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return 1e3 * ordered[min(len(ordered) - 1, int(q * len(ordered)))] if ordered else float("nan")


def frame_bodies(args: argparse.Namespace) -> list[bytes]:
    """Every frame's JSON body, made before the clock starts: the scene's simulation is not the
    service's work."""
    from scripts.bench_frames import Scene

    scene, bodies = Scene(args.agents, "agent", 1), []
    for k in range(int(args.duration * args.hz) + 1):
        t = k / args.hz
        agents = [{"agent_id": a, **e} for a, e in scene.step(t)]
        bodies.append(json.dumps({"timestamp": t, "agents": agents}).encode())
    return bodies


def read_frame(body: bytes, model: type[M]) -> M:
    """A frame's body read as ``POST /v1/frames`` reads it: typed in one pass where the tree
    has that path (``service.wire.frame_body.parse_frame``), else by ``model``."""
    try:
        from service.wire.frame_body import parse_frame
    except ImportError:
        return model.model_validate_json(body)
    typed = parse_frame(body, model)
    return typed if typed is not None else model.model_validate_json(body)


async def drive(args: argparse.Namespace) -> dict[str, Any]:
    """The scene for ``args.duration`` seconds: frame and check latencies, check verdicts."""
    from service.flows import checks, frames
    from service.runtime.services import Services
    from service.runtime.settings import Settings
    from service.wire.schemas import FrameRequest, MultiCollisionCheckRequest

    services = Services.build(Settings(model_path=args.model, log_requests=False))
    await services.start()
    while services.engine is None:
        await asyncio.sleep(0.1)
    bodies = frame_bodies(args)
    t0 = time.monotonic()
    frame_s: list[float] = []
    check_s: list[float] = []
    verdicts: dict[str, int] = {}
    witnessed: list[str] = []  # the agents of conservative collisions said witnessed
    phases: list[dict[str, float]] = []  # per check: its phase in the frame period, its answers

    async def framer() -> None:
        for k, body in enumerate(bodies):
            await asyncio.sleep(max(0.0, t0 + k / args.hz - time.monotonic()))
            if time.monotonic() - t0 >= args.duration:
                return
            started = time.perf_counter()
            await frames.apply_frame(services, read_frame(body, FrameRequest))
            frame_s.append(time.perf_counter() - started)

    period = (1.0 + PHASE_SWEEP_STRETCH if args.phase_sweep else 1.0) / args.hz

    async def planner(lane: float) -> None:
        await asyncio.sleep(args.warm + random.uniform(0.0, 1.0 / args.hz))
        start, k = time.monotonic(), 0
        while time.monotonic() - t0 < args.duration:
            due = start + k * period
            await asyncio.sleep(max(0.0, due - time.monotonic()))
            k += 1
            t = time.monotonic() - t0
            x0 = -60.0 + (PLANNER_SPEED * t) % 120.0
            step = PLANNER_SPEED * TRAJECTORY_DT
            points = [
                {"t": t + j * TRAJECTORY_DT, "x": x0 + step * j, "y": lane}
                for j in range(TRAJECTORY_POINTS)
            ]
            request = MultiCollisionCheckRequest.model_validate(
                {"trajectory": points, "mode": "time_indexed", "deadline_ms": args.deadline_ms}
            )
            answer = await checks.check_agents_at_once(services, request, time.perf_counter())
            answer.model_dump_json()
            check_s.append(time.monotonic() - due)
            phases.append(checked_at_phase((due - t0) * args.hz % 1.0, check_s[-1], answer.results))
            for result in answer.results:
                verdicts[result.verdict] = verdicts.get(result.verdict, 0) + 1
                if result.verdict == "conservative" and getattr(
                    result, "collision_witnessed", False
                ):
                    witnessed.append(result.agent_id)

    lanes = [-20.0 + 40.0 * i / max(args.planners - 1, 1) for i in range(args.planners)]
    loop_cpu, process_cpu = time.thread_time(), time.process_time()
    await asyncio.gather(framer(), *(planner(lane) for lane in lanes))
    elapsed = time.monotonic() - t0
    busy = (time.thread_time() - loop_cpu) / elapsed, (time.process_time() - process_cpu) / elapsed
    ready = exact_ready(services.metrics.registry)
    await services.stop()
    result = summary(frame_s, check_s, verdicts, args.deadline_ms, len(witnessed))
    if args.phase_sweep:
        result["by_phase"] = by_phase(phases)
    return {**result, "cpu_per_s": busy, **({"exact_ready": ready} if ready else {})}


def exact_ready(registry: Any) -> dict[str, dict[str, float]]:
    """Per priority (met, demanded, background), the exact sets made ready and their mean and
    median time from submission to ready (the median as the upper edge of its histogram
    bucket), from ``frt_exact_ready_seconds`` where the tree has it."""
    buckets: dict[str, list[tuple[float, float]]] = {}
    sums: dict[str, float] = {}
    for family in registry.collect():
        if family.name != "frt_exact_ready_seconds":
            continue
        for sample in family.samples:
            priority = sample.labels.get("priority")
            if sample.name.endswith("_bucket"):
                edge = float(sample.labels["le"])
                buckets.setdefault(priority, []).append((edge, sample.value))
            elif sample.name.endswith("_sum"):
                sums[priority] = sample.value
    out = {}
    for priority, cumulative in buckets.items():
        cumulative.sort()
        count = cumulative[-1][1]
        if not count:
            continue
        median = next(edge for edge, seen in cumulative if seen >= count / 2)
        out[priority] = {
            "sets": count,
            "mean_ms": round(1e3 * sums[priority] / count, 1),
            "median_ms_at_most": 1e3 * median,
        }
    return out


def checked_at_phase(phase: float, latency_s: float, results: list[Any]) -> dict[str, float]:
    """One check of all agents at ``phase`` (0..1) of the frame period: its latency from its
    tick, its conservative, colliding and exact answers."""
    return {
        "phase": phase,
        "latency_ms": 1e3 * latency_s,
        "conservative": sum(r.verdict == "conservative" for r in results),
        "collisions": sum(bool(r.collision) for r in results),
        "exact": sum(r.verdict == "exact" for r in results),
    }


def by_phase(checks: list[dict[str, float]], bins: int = 10) -> list[dict[str, Any]]:
    """Per tenth of the frame period: the checks due in it, their answers per check and their
    latency from their tick (p50 and largest)."""
    rows = []
    for b in range(bins):
        inside = [c for c in checks if int(c["phase"] * bins) == b]
        if not inside:
            continue
        latency = [c["latency_ms"] for c in inside]
        rows.append(
            {
                "phase": [b / bins, (b + 1) / bins],
                "checks": len(inside),
                **{
                    f"{kind}_per_check": round(sum(c[kind] for c in inside) / len(inside), 3)
                    for kind in ("conservative", "collisions", "exact")
                },
                "latency_ms_p50_max": [
                    round(quantile_ms([v / 1e3 for v in latency], 0.5), 1),
                    round(max(latency), 1),
                ],
            }
        )
    return rows


def summary(
    frame_s: list[float],
    check_s: list[float],
    verdicts: dict[str, int],
    deadline_ms: float,
    witnessed: int,
) -> dict[str, Any]:
    answers = sum(verdicts.values())
    settled = verdicts.get("exact", 0) + verdicts.get("decision_exact", 0)
    return {
        "frames": len(frame_s),
        "frame_ms": {q: quantile_ms(frame_s, float(q)) for q in ("0.5", "0.99")},
        "checks": len(check_s),
        "check_from_tick_ms": {q: quantile_ms(check_s, float(q)) for q in ("0.5", "0.9", "0.99")},
        "checks_over_deadline": sum(s * 1e3 > deadline_ms for s in check_s),
        "verdicts": verdicts,
        "exact_or_decision_exact": settled / answers if answers else None,
        # A conservative collision a reached position witnesses has the exact set's verdict.
        "witnessed": witnessed,
        "verdict_known": (settled + witnessed) / answers if answers else None,
    }


def line(name: str, result: dict[str, Any]) -> str:
    f, c = result["frame_ms"], result["check_from_tick_ms"]
    share = result["exact_or_decision_exact"]
    return (
        f"{name}: {result['frames']} frames, p50/p99 {f['0.5']:.1f}/{f['0.99']:.1f} ms; "
        f"{result['checks']} check-alls from their tick p50/p90/p99 "
        f"{c['0.5']:.1f}/{c['0.9']:.1f}/{c['0.99']:.1f} ms, "
        f"{result['checks_over_deadline']} over the deadline; exact or decision-exact "
        f"{100 * share:.2f} % ({100 * result.get('verdict_known', share):.2f} % with the "
        "witnessed collisions); CPU s per s: the event loop's thread "
        f"{result['cpu_per_s'][0]:.2f}, the process {result['cpu_per_s'][1]:.2f}"
        if share is not None
        else "no answers"
    )


def phase_line(row: dict[str, Any]) -> str:
    lo, hi = (round(100 * p) for p in row["phase"])
    p50, largest = row["latency_ms_p50_max"]
    return (
        f"  phase {lo:3d}-{hi:3d} % of the period: {row['checks']} checks; per check "
        f"{row['conservative_per_check']:.2f} conservative, {row['collisions_per_check']:.2f} "
        f"colliding, {row['exact_per_check']:.2f} exact; from the tick p50 {p50:.1f} ms, "
        f"largest {largest:.1f} ms"
    )


def baseline(revision: str, argv: list[str]) -> dict[str, Any]:
    """This script run on the tree of ``revision`` (a temporary ``git archive``)."""
    from scripts.bench_frames import tree_of

    with tree_of(revision) as tree:
        return run_on(tree, argv)


def run_on(tree: Path, argv: list[str]) -> dict[str, Any]:
    """This script's scene run in a process of its own on the checkout ``tree``."""
    done = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), *argv, "--json"],
        env=dict(os.environ, FRT_BENCH_SOURCE=str(tree)),
        cwd=ROOT,
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def in_turns(revision: str, turns: int, argv: list[str]) -> dict[str, Any]:
    """The scene on this tree and on ``revision``'s, each in a process of its own, in turns
    (the revision first), ``turns`` times each: runs one after the other on a shared machine
    meet its load at different moments, and alternating spreads that over both."""
    from scripts.bench_frames import tree_of

    results: dict[str, Any] = {}
    with tree_of(revision) as tree:
        for k in range(turns):
            for name, source in ((f"baseline {revision}", tree), ("working tree", SOURCE)):
                results[f"{name}, turn {k + 1}"] = run_on(source, argv)
                print(line(f"{name}, turn {k + 1}", results[f"{name}, turn {k + 1}"]), flush=True)
    return results


def parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    p.add_argument("--agents", type=int, default=100)
    p.add_argument("--planners", type=int, default=2)
    p.add_argument("--hz", type=float, default=10.0)
    p.add_argument("--deadline-ms", type=float, default=20.0)
    p.add_argument("--duration", type=float, default=20.0, help="seconds of scene")
    p.add_argument("--warm", type=float, default=1.0, help="seconds before the planners start")
    p.add_argument("--baseline", help="a git revision to run the same scene on afterwards")
    p.add_argument(
        "--phase-sweep",
        action="store_true",
        help="planners 3 %% slower than the frames; answers counted by phase of the frame period",
    )
    p.add_argument("--out", type=Path)
    p.add_argument("--json", action="store_true", help="print the result as one JSON line")
    p.add_argument(
        "--turns",
        type=int,
        default=0,
        help="with --baseline: run both trees this many times each, in turns",
    )
    return p.parse_args(argv)


def without(argv: list[str], options: tuple[str, ...]) -> list[str]:
    """``argv`` without ``options`` and their values (``--opt value`` or ``--opt=value``)."""
    out: list[str] = []
    skip = False
    for arg in argv:
        if skip:
            skip = False
        elif arg in options:
            skip = True
        elif not arg.startswith(tuple(f"{o}=" for o in options)):
            out.append(arg)
    return out


def main(argv: list[str]) -> None:
    args = parse(argv)
    if args.baseline and args.turns:
        results = in_turns(
            args.baseline, args.turns, without(argv, ("--baseline", "--turns", "--out"))
        )
        if args.out:
            args.out.write_text(json.dumps(results, indent=2) + "\n")
        return
    result = asyncio.run(drive(args))
    if args.json:
        print(json.dumps(result))
        return
    results = {"working tree": result}
    if args.baseline:
        forwarded = [a for a in argv if not a.startswith("--baseline") and a != args.baseline]
        results[f"baseline {args.baseline}"] = baseline(args.baseline, forwarded)
    for name, found in results.items():
        print(line(name, found))
        for row in found.get("by_phase", []):
            print(phase_line(row))
        for priority, ready in found.get("exact_ready", {}).items():
            print(
                f"  exact sets, {priority}: {ready['sets']:.0f}, submitted to ready mean "
                f"{ready['mean_ms']:.1f} ms, median at most {ready['median_ms_at_most']:g} ms"
            )
    if args.out:
        args.out.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main(sys.argv[1:])
