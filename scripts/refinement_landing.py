"""How often a background refinement (the notch cut) is served at all.

``python scripts/refinement_landing.py --agents 5 --hz 2 --seconds 15`` starts the service with the
shipped model, observes that many agents whose predictor is unsure of the steering (so each of
their sets may turn round and is refined) at ``--hz`` each for ``--seconds``, and prints the
server's ``frt_refinements_total`` by stage of the notch cut and outcome: landed on the agent's
current set (served), stale (it landed once a later version had come: checks ask for that one),
dropped before it ran, wasted or failed. A refinement is only worth its cost while its version is current; this says how often
that is, for a number of agents and an observation rate.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))

from bench import WIDE_STEERING_VAR, observation, running_service  # noqa: E402

OUTCOMES = ("landed", "stale", "dropped", "wasted", "failed", "skipped")


async def observe(url: str, agents: int, hz: float, seconds: float) -> None:
    """Every agent observed at ``hz`` for ``seconds`` (the first observations at once, the rest
    with random phases), over one client."""
    rng = np.random.default_rng(0)
    limits = httpx.Limits(max_connections=agents + 5)
    async with httpx.AsyncClient(base_url=url, timeout=5, limits=limits) as client:

        async def post(a: int, k: int) -> None:
            body = observation(k / hz, rng, k == 0, 10.0 * a, steering_var=WIDE_STEERING_VAR)
            (await client.post(f"/v1/agents/w{a}/observations", json=body)).raise_for_status()

        for a in range(agents):
            await post(a, 0)
        start = time.monotonic()

        async def observer(a: int) -> None:
            k = 1
            await asyncio.sleep(rng.uniform(0, 1 / hz))
            while time.monotonic() - start < seconds:
                await post(a, k)
                k += 1
                await asyncio.sleep(1 / hz)

        await asyncio.gather(*(observer(a) for a in range(agents)))
        await asyncio.sleep(1.0)  # the last refinements finish


def refinement_counts(url: str) -> dict[str, dict[str, int]]:
    """The server's ``frt_refinements_total`` by stage and outcome, from ``/metrics``."""
    counts: dict[str, dict[str, int]] = {}
    for line in httpx.get(f"{url}/metrics", timeout=10).text.splitlines():
        if line.startswith("frt_refinements_total{"):
            outcome = line.split('outcome="')[1].split('"')[0]
            stage = line.split('stage="')[1].split('"')[0]
            counts.setdefault(stage, dict.fromkeys(OUTCOMES, 0))[outcome] = int(
                float(line.rsplit(" ", 1)[1])
            )
    return dict(sorted(counts.items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    parser.add_argument("--agents", type=int, default=5)
    parser.add_argument("--hz", type=float, default=2.0)
    parser.add_argument("--seconds", type=float, default=15.0)
    args = parser.parse_args()
    with running_service(args.model.resolve()) as url:
        asyncio.run(observe(url, args.agents, args.hz, args.seconds))
        counts = refinement_counts(url)
    print(json.dumps({"agents": args.agents, "hz": args.hz, "seconds": args.seconds, **counts}))
    for stage, by_outcome in counts.items():
        total = sum(by_outcome.values())
        served = by_outcome["landed"] / total if total else float("nan")
        print(
            f"stage {stage}: served (landed on the current set) {by_outcome['landed']} of "
            f"{total} ({served:.0%})"
        )


if __name__ == "__main__":
    main()
