"""Batch checks against single checks, side by side: ``make bench-batch``.

Starts the service (uvicorn, one worker) with the shipped model, observes ``--agents`` cars and
waits for their exact sets, then alternates, ``--rounds`` times:

- one batch: ``--trajectories`` candidate trajectories of ``--points`` points each (a fan of
  constant-curvature paths, time-indexed, as a sampling planner draws them) against every agent in
  one ``POST /v1/collision-check``, the trajectories as columns (what the SDK sends);
- the same, each point carrying the ego's footprint (4.8 x 1.9 m);
- the same candidates as single checks (one trajectory against every agent per request), one after
  another over one keep-alive connection.

Prints the medians and p99 of the batch at the client and at the server (``Server-Timing``), the
time of the whole series of single checks, and their ratio; writes ``results/bench_batch.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from scripts.bench import running_service, server_seconds, stats  # noqa: E402

FOOTPRINT = {"length": 4.8, "width": 1.9, "rear_axle_to_center": 1.4}


def observation(rng: np.random.Generator, k: int) -> dict:
    """A car ``k`` of a column of traffic ahead of and beside the ego."""
    return {
        "timestamp": 0.0,
        "state": {
            "x": 15.0 + 12.0 * (k // 2),
            "y": -3.5 if k % 2 else 3.5,
            "heading": math.pi if k % 2 else 0.0,
            "speed": float(rng.uniform(4.0, 10.0)),
        },
        "prediction": {
            "dt": 0.5,
            "mean": [[0.0, float(rng.normal(0.0, 0.3))]] * 6,
            "cov": [[[0.01, 0.0], [0.0, 0.25]]] * 6,
        },
    }


def candidates(count: int, points: int, dt: float = 0.1) -> np.ndarray:
    """``[count, points, 4]`` rows (t, x, y, heading): arcs of the ego from the origin at speeds
    4..12 m/s and curvatures -0.08..0.08 1/m."""
    speeds = np.repeat(np.linspace(4.0, 12.0, math.ceil(count / 25)), 25)[:count]
    curvatures = np.tile(np.linspace(-0.08, 0.08, 25), math.ceil(count / 25))[:count]
    t = dt * np.arange(1, points + 1)
    heading = curvatures[:, None] * speeds[:, None] * t[None, :]
    safe = np.where(np.abs(curvatures) < 1e-9, 1.0, curvatures)[:, None]
    straight = np.abs(curvatures)[:, None] < 1e-9
    x = np.where(straight, speeds[:, None] * t, np.sin(heading) / safe)
    y = np.where(straight, 0.0, (1.0 - np.cos(heading)) / safe)
    return np.stack([np.broadcast_to(t, x.shape), x, y, heading], axis=-1)


def as_columns(batch: np.ndarray, with_heading: bool) -> list[dict]:
    keys = ("t", "x", "y", "heading") if with_heading else ("t", "x", "y")
    return [{key: path[:, i].tolist() for i, key in enumerate(keys)} for path in batch]


def timed_post(client: httpx.Client, body: bytes) -> tuple[float, float, dict]:
    t0 = time.perf_counter()
    response = client.post(
        "/v1/collision-check", content=body, headers={"content-type": "application/json"}
    )
    elapsed = time.perf_counter() - t0
    response.raise_for_status()
    return elapsed, server_seconds(response), response.json()


def run(url: str, args: argparse.Namespace) -> dict:
    rng = np.random.default_rng(0)
    batch = candidates(args.trajectories, args.points)
    with httpx.Client(base_url=url, timeout=60) as client:
        agents = [f"bench-batch-{k}" for k in range(args.agents)]
        for k, agent in enumerate(agents):
            client.post(
                f"/v1/agents/{agent}/observations",
                params={"wait_frt_ms": 10_000},
                json=observation(rng, k),
            ).raise_for_status()
        common = {"agent_ids": agents, "mode": "time_indexed", "deadline_ms": 1000}
        plain = json.dumps({**common, "trajectories": as_columns(batch, False)}).encode()
        boxed = json.dumps(
            {**common, "trajectories": as_columns(batch, True), "footprint": FOOTPRINT}
        ).encode()
        singles = [
            json.dumps(
                {
                    **common,
                    "trajectory": [dict(zip("txy", p[:3], strict=True)) for p in path.tolist()],
                }
            ).encode()
            for path in batch
        ]
        for body in (plain, boxed, singles[0]):  # warm: tubes drawn, caches filled
            timed_post(client, body)
        rows: dict[str, list[float]] = {k: [] for k in ("batch", "batch_server", "fp", "fp_server")}
        series, verdicts, hits = [], {}, 0
        for _ in range(args.rounds):
            for name, body in (("batch", plain), ("fp", boxed)):
                elapsed, server, answer = timed_post(client, body)
                rows[name].append(elapsed)
                rows[f"{name}_server"].append(server)
                for result in answer["results"]:
                    verdicts[result["verdict"]] = verdicts.get(result["verdict"], 0) + 1
                if name == "batch":
                    hits = sum(t["collision"] for r in answer["results"] for t in r["trajectories"])
            if len(series) < args.single_series:
                t0 = time.perf_counter()
                for body in singles:
                    timed_post(client, body)
                series.append(time.perf_counter() - t0)
    results = {name: stats(samples) for name, samples in rows.items()}
    results["singles_series"] = stats(series)
    results["verdicts"] = verdicts
    results["trajectory_agent_pairs_colliding"] = hits
    results["singles_over_batch_p50_ratio"] = (
        results["singles_series"]["p50_ms"] / results["batch"]["p50_ms"]
    )
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    parser.add_argument("--agents", type=int, default=10)
    parser.add_argument("--trajectories", type=int, default=500)
    parser.add_argument("--points", type=int, default=30)
    parser.add_argument("--rounds", type=int, default=200)
    parser.add_argument(
        "--single-series", type=int, default=5, help="series of single checks, one per round"
    )
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "bench_batch.json")
    args = parser.parse_args()
    with running_service(args.model.resolve()) as url:
        results = run(url, args)
    label = f"{args.trajectories} x {args.points} points against {args.agents} agents"
    print(f"batch checks: {label}, {args.rounds} rounds")
    print(f"{'measure':44s} {'p50 [ms]':>9s} {'p99 [ms]':>9s}")
    for name, text in (
        ("batch", "one batch request, client"),
        ("batch_server", "one batch request, server"),
        ("fp", "one batch request with footprints, client"),
        ("fp_server", "one batch request with footprints, server"),
        ("singles_series", f"{args.trajectories} single checks in a row, client"),
    ):
        print(f"{text:44s} {results[name]['p50_ms']:9.2f} {results[name]['p99_ms']:9.2f}")
    print(f"single checks / batch (p50, same run): {results['singles_over_batch_p50_ratio']:.0f}x")
    print(f"per-agent verdicts: {results['verdicts']}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
