"""Batch checks against single checks, side by side: ``make bench-batch``.

Starts the service (uvicorn, one worker) with the shipped model, observes ``--agents`` cars and
waits for their exact sets, then alternates, ``--rounds`` times:

- one batch: ``--trajectories`` candidate trajectories of ``--points`` points each (a fan of
  constant-curvature paths, time-indexed, as a sampling planner draws them) against every agent in
  one ``POST /v1/collision-check``, in each of ``--forms``: ``sdk``, what the SDK sends (the
  trajectories as ``packed_trajectories``, the answers asked for as columns), and ``columns``, the
  trajectories as columns of JSON numbers answered by an entry per trajectory (the default form,
  which an earlier revision also takes);
- the same, each point carrying the ego's footprint (4.8 x 1.9 m);
- the same candidates as single checks (one trajectory against every agent per request), one after
  another over one keep-alive connection.

Prints the medians and p99 of the batch at the client and at the server (``Server-Timing``), the
time of the whole series of single checks, and their ratio; writes ``results/bench_batch.json``.
The rows of the ``sdk`` form are ``batch`` and ``fp``, those of the ``columns`` form
``batch_columns`` and ``fp_columns``.

``--pause S`` leaves each service idle S seconds before each batch, as a planner checking at
10 Hz leaves it (``--pause 0.1``); back to back (0, the default) the service's caches and cores
stay warm from one batch to the next, which a planner's cycle does not give them.

``--kinds batch`` sends only the plain batches (``fp`` only those with footprints); ``--profile
PATH`` samples this tree's service with py-spy during the rounds (py-spy's raw format: one stack a
line with its count of samples) and prints the share of the requests' samples each phase of a
batch takes (:data:`PHASES`; the response body's write to the socket, after ``Server-Timing`` is
taken, left out; run it with ``--single-series 0``, or single checks count too).

``--baseline REV`` starts a second service from the files of git revision ``REV`` beside this
tree's and sends every request of a round to both in turn, so that the two are measured side by
side under the same load (on a shared machine the p99 moves between runs by more than a change
may move it); the baseline is sent the ``--baseline-forms`` (default ``columns``).
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import sys
import time
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from frt_client.inputs import packed_trajectories  # noqa: E402

from scripts.bench import server_seconds, service_at, stats  # noqa: E402
from scripts.bench_frames import tree_of  # noqa: E402

FOOTPRINT = {"length": 4.8, "width": 1.9, "rear_axle_to_center": 1.4}
#: A batch's phases for ``--profile``: a sample counts for the first whose frames one names.
PHASES = (
    ("reading the body", ("parse_batch_check", "routes/json_body.py")),
    ("the ring kernel", ("trajectory_surrogates (reach/packed_rings",)),
    ("tubes of the points' times", ("tubes_of (", "_fit_tubes_to_deadline", "_note_tube_demand")),
    ("the answers per trajectory", ("batch_answers",)),
    ("the rest of the answers", ("_respond_all",)),
    ("the answers' JSON", ("ModelJSONResponse.render",)),
    ("recording the check for the viewer", ("RecentChecks.record",)),
)


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


#: The row of each kind of batch in each form (see the module docstring).
ROWS = {
    ("batch", "sdk"): "batch",
    ("fp", "sdk"): "fp",
    ("batch", "columns"): "batch_columns",
    ("fp", "columns"): "fp_columns",
}


def batch_body(batch: np.ndarray, form: str) -> dict:
    """The trajectories of a check (``[M, N, 3 or 4]`` rows) as the SDK sends them and asks for
    the answers (``sdk``), or as columns answered by entries (``columns``)."""
    if form == "sdk":
        return {"packed_trajectories": packed_trajectories(batch), "answer_columns": True}
    return {"trajectories": as_columns(batch, batch.shape[-1] == 4)}


def entries_of(result: dict) -> list[dict]:
    """An agent's answers per trajectory, from either form."""
    if "trajectories" in result:
        return result["trajectories"]
    columns = result["trajectory_columns"]
    return [dict(zip(columns, row, strict=True)) for row in zip(*columns.values(), strict=True)]


@dataclass
class Target:
    """One service under test, the forms it is sent, its request bodies and what was measured
    on it."""

    name: str
    client: httpx.Client
    forms: tuple[str, ...] = ("sdk", "columns")
    bodies: dict[str, bytes] = field(default_factory=dict)
    singles: list[bytes] = field(default_factory=list)
    rows: dict[str, list[float]] = field(default_factory=dict)
    series: list[float] = field(default_factory=list)
    verdicts: dict[str, int] = field(default_factory=dict)
    hits: int = 0


def prepare(target: Target, args: argparse.Namespace) -> None:
    """Observe the agents (their exact sets ready), build the bodies, warm the service."""
    rng = np.random.default_rng(0)
    batch = candidates(args.trajectories, args.points)
    agents = [f"bench-batch-{k}" for k in range(args.agents)]
    for k, agent in enumerate(agents):
        target.client.post(
            f"/v1/agents/{agent}/observations",
            params={"wait_frt_ms": 10_000},
            json=observation(rng, k),
        ).raise_for_status()
    common = {"agent_ids": agents, "mode": "time_indexed", "deadline_ms": 1000}
    for (kind, form), row in ROWS.items():
        if kind not in args.kinds.split(",") or form not in target.forms:
            continue
        if kind == "batch":
            body = {**common, **batch_body(batch[..., :3], form)}
        else:
            body = {**common, **batch_body(batch, form), "footprint": FOOTPRINT}
        target.bodies[row] = json.dumps(body).encode()
        target.rows.update({row: [], f"{row}_server": []})
    target.singles = [
        json.dumps(
            {**common, "trajectory": [dict(zip("txy", p[:3], strict=True)) for p in path.tolist()]}
        ).encode()
        for path in batch
    ]
    for body in (*target.bodies.values(), target.singles[0]):  # warm: tubes drawn, caches filled
        timed_post(target.client, body)


def one_round(target: Target, singles: bool, pause_s: float = 0.0) -> None:
    """One batch and one batch with footprints (and, if ``singles``, the series of single
    checks) on ``target``, each batch sent ``pause_s`` after the last answer."""
    for name, body in target.bodies.items():
        time.sleep(pause_s)
        elapsed, server, answer = timed_post(target.client, body)
        target.rows[name].append(elapsed)
        target.rows[f"{name}_server"].append(server)
        for result in answer["results"]:
            target.verdicts[result["verdict"]] = target.verdicts.get(result["verdict"], 0) + 1
        if name.startswith("batch"):
            target.hits = sum(t["collision"] for r in answer["results"] for t in entries_of(r))
    if singles:
        t0 = time.perf_counter()
        for body in target.singles:
            timed_post(target.client, body)
        target.series.append(time.perf_counter() - t0)


def summary(target: Target) -> dict:
    results: dict = {name: stats(samples) for name, samples in target.rows.items() if samples}
    results["verdicts"] = target.verdicts
    results["trajectory_agent_pairs_colliding"] = target.hits
    if target.series:
        results["singles_series"] = stats(target.series)
    batch = next((k for k in ("batch", "batch_columns") if k in results), None)
    if target.series and batch is not None:
        results["singles_over_batch_p50_ratio"] = (
            results["singles_series"]["p50_ms"] / results[batch]["p50_ms"]
        )
    return results


def run(targets: list[Target], args: argparse.Namespace, pid: int) -> dict:
    """Every round on every target in turn (the first, of process ``pid``, sampled by py-spy
    with ``--profile``); the results per target."""
    for target in targets:
        prepare(target, args)
    spy = None
    if args.profile:
        spy = subprocess.Popen(
            [str(Path(sys.executable).parent / "py-spy"), "record", "-p", str(pid),
             "-o", str(args.profile), "-f", "raw", "-r", "200", "--nonblocking"],
        )  # fmt: skip
    for r in range(args.rounds):
        for target in targets:
            one_round(target, singles=r < args.single_series, pause_s=args.pause)
    if spy is not None:
        spy.send_signal(signal.SIGINT)
        spy.wait(timeout=60)
        print_shares(args.profile)
    return {target.name: summary(target) for target in targets}


def print_shares(path: Path) -> None:
    """The share of the requests' samples in ``path`` (py-spy raw) each of :data:`PHASES` takes."""
    counts = dict.fromkeys([name for name, _ in PHASES] + ["ASGI, middleware, the rest"], 0)
    total = 0
    for line in path.read_text().splitlines():
        stack, _, samples = line.rpartition(" ")
        if "run_asgi" not in stack or "RequestResponseCycle.send" in stack:
            continue
        total += int(samples)
        phase = next((n for n, keys in PHASES if any(k in stack for k in keys)), None)
        counts[phase or "ASGI, middleware, the rest"] += int(samples)
    print(f"where a request's time goes ({total} samples):")
    for name, count in sorted(counts.items(), key=lambda item: -item[1]):
        print(f"  {100.0 * count / max(total, 1):5.1f} %  {name}")


def print_table(results: dict, args: argparse.Namespace) -> None:
    label = f"{args.trajectories} x {args.points} points against {args.agents} agents"
    print(f"batch checks: {label}, {args.rounds} rounds; p50 / p99 [ms]")
    names = list(results)
    print(f"{'measure':44s}" + "".join(f"{name:>24s}" for name in names))
    for key, text in (
        ("batch", "one batch request (SDK form), client"),
        ("batch_server", "one batch request (SDK form), server"),
        ("fp", "one batch with footprints (SDK form), client"),
        ("fp_server", "one batch with footprints (SDK form), server"),
        ("batch_columns", "one batch request (columns), client"),
        ("batch_columns_server", "one batch request (columns), server"),
        ("fp_columns", "one batch with footprints (columns), client"),
        ("fp_columns_server", "one batch with footprints (columns), server"),
        ("singles_series", f"{args.trajectories} single checks in a row, client"),
    ):
        if not any(key in results[n] for n in names):
            continue
        cells = [
            f"{results[n][key]['p50_ms']:.2f} / {results[n][key]['p99_ms']:.2f}"
            if key in results[n]
            else "-"
            for n in names
        ]
        print(f"{text:44s}" + "".join(f"{cell:>24s}" for cell in cells))
    for name in names:
        ratio = results[name].get("singles_over_batch_p50_ratio", math.nan)
        print(f"{name}: single checks / batch (p50, same run) {ratio:.0f}x, "
              f"per-agent verdicts {results[name]['verdicts']}")  # fmt: skip


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
    parser.add_argument("--kinds", default="batch,fp", help="batch, fp or both (comma-separated)")
    parser.add_argument(
        "--pause", type=float, default=0.0, help="idle seconds before each batch (0: back to back)"
    )
    parser.add_argument("--forms", default="sdk,columns", help="sdk, columns or both")
    parser.add_argument("--baseline-forms", default="columns", help="the baseline's forms")
    parser.add_argument("--profile", type=Path, help="py-spy this tree's service (raw stacks)")
    parser.add_argument("--baseline", help="a git revision to measure side by side")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "bench_batch.json")
    args = parser.parse_args()
    with ExitStack() as stack:
        trees = [("working tree", ROOT)]
        if args.baseline:
            trees.append((f"baseline {args.baseline}", stack.enter_context(tree_of(args.baseline))))
        targets, pids = [], []
        for name, root in trees:
            url, pid = stack.enter_context(service_at(root, args.model.resolve()))
            client = stack.enter_context(httpx.Client(base_url=url, timeout=60))
            forms = args.forms if root == ROOT else args.baseline_forms
            targets.append(Target(name, client, tuple(forms.split(","))))
            pids.append(pid)
        results = run(targets, args, pids[0])
    print_table(results, args)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    out = results["working tree"] if len(results) == 1 else results
    args.out.write_text(json.dumps(out, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
