"""The event loop's CPU per frame and per check of all agents, in-process:
``python scripts/bench_loop_cpu.py [--src DIR]``.

One process builds the service's engine (``Services``, the shipped model, exact sets in worker
processes) and, one after another on its event loop, applies ``scripts/bench_frames.py``'s
scene of ``--agents`` agents frame by frame (``service.flows.frames.apply_frame``, the body
read first as ``POST /v1/frames`` reads it) and after each frame two planners' checks of every
agent (20-point time-indexed trajectories, ``check_agents_at_once``, answers dumped to JSON),
with a pause between them for the audit and the workers. What is timed is the thread's CPU
(``time.thread_time``) of each parse, frame and check: it moves less than a latency with other
processes' load on the machine, though on a shared host it still drifts from run to run (by a
third at times), so two trees are compared in turns, several of them.
Prints one JSON line of medians and 90th percentiles in ms.

``--src DIR`` runs another checkout of the project (e.g. ``git worktree add DIR REV``) with
this venv.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def quantiles_ms(values: list[float]) -> list[float]:
    ordered = sorted(values)
    return [
        round(1e3 * statistics.median(ordered), 2),
        round(1e3 * ordered[int(0.9 * len(ordered))], 2),
    ]


async def measure(args: argparse.Namespace) -> dict[str, Any]:
    from scripts import bench_scene
    from service.flows import checks, frames
    from service.runtime.services import Services
    from service.runtime.settings import Settings
    from service.wire.schemas import FrameRequest, MultiCollisionCheckRequest

    scene = bench_scene.parse(["--duration", str(args.frames / 10.0), "--agents", str(args.agents)])
    services = Services.build(Settings(model_path=scene.model, log_requests=False))
    await services.start()
    while services.engine is None:
        await asyncio.sleep(0.1)
    parse_s, frame_s, check_s = [], [], []
    for k, body in enumerate(bench_scene.frame_bodies(scene)):
        started = time.thread_time()
        request = bench_scene.read_frame(body, FrameRequest)
        parsed = time.thread_time()
        await frames.apply_frame(services, request)
        applied = time.thread_time()
        await asyncio.sleep(0.03)  # the frame's audit and the workers
        if k >= args.warm:
            parse_s.append(parsed - started)
            frame_s.append(applied - parsed)
        t = k / 10.0
        for lane in (-20.0, 20.0):
            x0 = -60.0 + (bench_scene.PLANNER_SPEED * t) % 120.0
            points = [{"t": t + 0.1 * j, "x": x0 + 0.8 * j, "y": lane} for j in range(20)]
            check = MultiCollisionCheckRequest.model_validate(
                {"trajectory": points, "mode": "time_indexed", "deadline_ms": 20}
            )
            started = time.thread_time()
            answer = await checks.check_agents_at_once(services, check, time.perf_counter())
            answer.model_dump_json()
            if k >= args.warm:
                check_s.append(time.thread_time() - started)
        await asyncio.sleep(0.02)
    await services.stop()
    return {
        "source": str(args.src),
        "parse_ms_p50_p90": quantiles_ms(parse_s),
        "frame_ms_p50_p90": quantiles_ms(frame_s),
        "check_ms_p50_p90": quantiles_ms(check_s),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--src", type=Path, default=ROOT, help="the checkout to measure")
    p.add_argument("--agents", type=int, default=100)
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--warm", type=int, default=10, help="frames not measured first")
    args = p.parse_args()
    sys.path.insert(0, str(args.src.resolve()))
    sys.path.insert(1, str(ROOT))
    print(json.dumps(asyncio.run(measure(args))))


if __name__ == "__main__":
    main()
