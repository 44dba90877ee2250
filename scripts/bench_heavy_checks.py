"""Checks at the edge of what one request may ask, against their deadline, in-process:
``python scripts/bench_heavy_checks.py [--rounds N] [--mode tube|time_indexed]``.

One app (``TestClient``, the shipped model, exact-set workers as served) observes ten agents of
32 modes (``MAX_MODES``), one of 4 modes and one of one mode, waits for their exact sets, then
sends each case ``--rounds`` times with a 20 ms deadline: an agent of 32 modes, of 4 and of one
along a 1 000-point trajectory crossing their paths, the one-mode agent along 20 points, and the
ten 32-mode agents in one multi-agent check. Prints per case the server's own time
(``Server-Timing``, p50 / p99 / largest, ms) and how many answers were conservative, then the
deadline misses the server counted over the run (``frt_deadline_misses_total``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

COV = [[[0.01, 0.0], [0.0, 0.25]]] * 6
DEADLINE_MS = 20.0


def modes(count: int) -> list[dict[str, Any]]:
    """``count`` modes of constant controls, their weights and controls drawn at random."""
    rng = np.random.default_rng(count)
    return [
        {
            "weight": float(rng.uniform(0.5, 1.5)),
            "mean": [[float(rng.uniform(-1, 1)), float(rng.uniform(-3, 3))]] * 6,
            "cov": COV,
        }
        for _ in range(count)
    ]


def observation(count: int, y: float = 0.0) -> dict[str, Any]:
    """A car at (0, y) heading along x at 5 m/s, predicted with ``count`` modes."""
    if count > 1:
        prediction: dict[str, Any] = {"dt": 0.5, "modes": modes(count)}
    else:
        prediction = {"dt": 0.5, "mean": [[0.0, 0.0]] * 6, "cov": COV}
    state = {"x": 0.0, "y": y, "heading": 0.0, "speed": 5.0}
    return {"timestamp": 1.0, "state": state, "prediction": prediction}


def crossing(points: int) -> list[dict[str, float]]:
    """A robot's trajectory across the humans' paths, over 3 s from t = 1.2."""
    return [
        {"t": 1.2 + 3.0 * k / points, "x": 30.0 - 30.0 * k / points, "y": -5.0 + 10.0 * k / points}
        for k in range(points)
    ]


def cases(mode: str) -> list[tuple[str, str, dict[str, Any]]]:
    """(name, path, body) of each case."""
    long, short = crossing(1000), crossing(20)
    many = {"trajectory": long, "agent_ids": [f"m32-{i}" for i in range(10)]}
    plain = [
        ("32 modes, 1 000 points", "/v1/agents/m32-0/collision-check", {"trajectory": long}),
        ("4 modes, 1 000 points", "/v1/agents/m4/collision-check", {"trajectory": long}),
        ("1 mode, 1 000 points", "/v1/agents/m1/collision-check", {"trajectory": long}),
        ("1 mode, 20 points", "/v1/agents/m1/collision-check", {"trajectory": short}),
        ("ten agents of 32 modes, 1 000 points", "/v1/collision-check", many),
    ]
    common = {"deadline_ms": DEADLINE_MS, "mode": mode}
    return [(name, path, {**body, **common}) for name, path, body in plain]


def measure(client: Any, path: str, body: dict[str, Any], rounds: int) -> tuple[np.ndarray, int]:
    """The server's time of each of ``rounds`` checks (after three to warm), and how many
    answered conservatively."""
    for _ in range(3):
        client.post(path, json=body).raise_for_status()
    times, conservative = [], 0
    for _ in range(rounds):
        response = client.post(path, json=body)
        response.raise_for_status()
        times.append(float(response.headers["server-timing"].split("dur=")[1].split(",")[0]))
        conservative += bool(response.json().get("conservative"))
    return np.array(times), conservative


def deadline_misses(client: Any) -> float:
    for line in client.get("/metrics").text.splitlines():
        if line.startswith("frt_deadline_misses_total"):
            return float(line.split()[-1])
    return 0.0


def main() -> None:
    from fastapi.testclient import TestClient

    from service.api.app import create_app
    from service.runtime.settings import Settings

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=100)
    p.add_argument("--mode", choices=("tube", "time_indexed"), default="tube")
    p.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    args = p.parse_args()
    with TestClient(create_app(Settings(model_path=args.model, log_requests=False))) as client:
        while client.get("/readyz").status_code != 200:
            time.sleep(0.05)
        agents = {f"m32-{i}": observation(32, y=3.0 * i) for i in range(10)}
        agents.update(m4=observation(4), m1=observation(1))
        for agent_id, body in agents.items():
            url = f"/v1/agents/{agent_id}/observations"
            client.post(url, params={"wait_frt_ms": 10_000}, json=body).raise_for_status()
        print(f"{args.rounds} checks a case, deadline {DEADLINE_MS:g} ms, mode {args.mode}")
        for name, path, body in cases(args.mode):
            times, conservative = measure(client, path, body, args.rounds)
            p50, p99 = np.percentile(times, [50, 99])
            print(
                f"{name:38s} {p50:7.2f} / {p99:7.2f} / {times.max():7.2f} ms, "
                f"{conservative} conservative"
            )
        print(f"deadline misses over the run: {deadline_misses(client):g}")


if __name__ == "__main__":
    main()
