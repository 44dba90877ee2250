"""Frames of many agents at the server: ``python scripts/bench_frames.py``.

Starts the service (uvicorn, the shipped model, as ``scripts/bench.py`` does) and, with
``--baseline REV``, a second one from the tree of git revision ``REV`` (``git archive`` into a
temporary directory, the same interpreter and model), and drives both from this process in one
run:

1. frames: every ``1 / --hz`` seconds one ``POST /v1/frames`` of ``--agents`` agents observed at
   that instant (cars, pedestrians and cars with three-mode predictions, moving by the extended
   unicycle; each frame's prediction a predictor's six 0.5 s steps whose spread grows with the
   step, as ``experiments/predictor.py`` makes them; the observed action the average controls
   since the last frame, sometimes a swerve the prediction did not foresee);
2. the same agents' observations one by one: ``--agents`` ``POST /v1/agents/{id}/observations``
   per instant, one in flight, at the same pace where they fit in it.

The services take turns in blocks of ``--block`` instants (the others idle meanwhile), so that
one's load does not land in the other's figures while a drift of the machine's load reaches both.

Prints per service the server's time (``Server-Timing``) per frame and, for the one-by-one
observations, their sum per instant, as p50 / p99 / max, and writes them to ``--out``. With
``--profile PATH`` the working tree's service is sampled by py-spy during its frames (a
speedscope file at PATH).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from scripts.bench import server_seconds, service_at, stats  # noqa: E402

#: The predictor's steps (experiments/predictor.py: 0.5 s steps over the 3 s horizon) and its
#: first-step standard deviations, growing by ``SD_GROWTH`` per step.
PRED_DT = 0.5
PRED_STEPS = 6
CAR_SD = (0.2, 0.5)
PEDESTRIAN_SD = (0.4, 0.3)
SD_GROWTH = 0.3
#: Of every ten agents: this many pedestrians, and this many cars with three-mode predictions.
PEDESTRIANS_PER_TEN = 2
MIXTURES_PER_TEN = 1


@dataclass
class Agent:
    """One simulated road user: extended unicycle state and a smooth control law, now and then
    a swerve its predictor does not foresee."""

    agent_id: str
    pedestrian: bool
    modes: int
    x: float
    y: float
    heading: float
    speed: float
    steer_amp: float
    phase: float
    v_target: float
    rng: np.random.Generator
    swerve_until: float = -1.0
    swerve: float = 0.0

    def nominal(self, t: float) -> tuple[float, float]:
        u1 = self.steer_amp * math.sin(0.5 * t + self.phase)
        u2 = max(-2.0, min(2.0, 0.8 * (self.v_target - self.speed)))
        return u1, u2

    def advance(self, t0: float, t1: float, step: float = 0.02) -> tuple[float, float]:
        """Integrate from t0 to t1; the average controls taken (the observed action)."""
        if self.rng.random() < 0.02:
            self.swerve_until = t0 + self.rng.uniform(0.3, 1.0)
            self.swerve = float(self.rng.choice((-1.0, 1.0)) * self.rng.uniform(0.5, 1.2))
        t, total1, total2 = t0, 0.0, 0.0
        while t < t1 - 1e-12:
            h = min(step, t1 - t)
            u1, u2 = self.nominal(t)
            u1 = self.swerve if t < self.swerve_until else u1
            u2 = 0.0 if self.speed <= 0.0 and u2 < 0.0 else u2
            self.x += h * self.speed * math.cos(self.heading)
            self.y += h * self.speed * math.sin(self.heading)
            self.heading = math.remainder(self.heading + h * u1, math.tau)
            self.speed = max(self.speed + h * u2, 0.0)
            total1, total2 = total1 + h * u1, total2 + h * u2
            t += h
        return total1 / (t1 - t0), total2 / (t1 - t0)

    def gaussian(self, u1: float, u2: float) -> dict[str, Any]:
        sd = PEDESTRIAN_SD if self.pedestrian else CAR_SD
        growth = [1.0 + SD_GROWTH * k for k in range(PRED_STEPS)]
        return {
            "mean": [[u1, u2] for _ in range(PRED_STEPS)],
            "cov": [[[(sd[0] * g) ** 2, 0.0], [0.0, (sd[1] * g) ** 2]] for g in growth],
        }

    def prediction(self, t: float) -> dict[str, Any]:
        """Constant nominal controls (one Gaussian), or keep / turn left / turn right."""
        u1, u2 = self.nominal(t)
        if self.modes == 1:
            return {"dt": PRED_DT, **self.gaussian(u1, u2)}
        turns = ((0.6, u1), (0.2, u1 + 0.3), (0.2, u1 - 0.3))[: self.modes]
        return {"dt": PRED_DT, "modes": [{"weight": w, **self.gaussian(s, u2)} for w, s in turns]}

    def state(self) -> dict[str, float]:
        return {"x": self.x, "y": self.y, "heading": self.heading, "speed": self.speed}

    def entry(self, t: float, action: tuple[float, float] | None) -> dict[str, Any]:
        """The agent's observation at ``t`` without the timestamp."""
        body: dict[str, Any] = {
            "state": self.state(),
            "prediction": self.prediction(t),
            "observed_action": None
            if action is None
            else {"steering_rate": action[0], "acceleration": action[1]},
        }
        if self.pedestrian:
            body["agent_class"] = "pedestrian"
        return body


def make_agents(count: int, prefix: str, seed: int) -> list[Agent]:
    rng = np.random.default_rng(seed)
    agents = []
    for i in range(count):
        pedestrian = i % 10 < PEDESTRIANS_PER_TEN
        mixture = not pedestrian and i % 10 < PEDESTRIANS_PER_TEN + MIXTURES_PER_TEN
        angle = math.tau * i / count
        top = 1.8 if pedestrian else 14.0
        agents.append(
            Agent(
                agent_id=f"{prefix}-{i}",
                pedestrian=pedestrian,
                modes=3 if mixture else 1,
                x=40.0 * math.cos(angle),
                y=40.0 * math.sin(angle),
                heading=float(rng.uniform(-math.pi, math.pi)),
                speed=float(rng.uniform(0.5, top)),
                steer_amp=float(rng.uniform(0.02, 0.3)),
                phase=float(rng.uniform(0.0, math.tau)),
                v_target=float(rng.uniform(0.5, top)),
                rng=np.random.default_rng(rng.integers(1 << 32)),
            )
        )
    return agents


class Scene:
    """The agents one service is sent: their clock and what they did since the last instant."""

    def __init__(self, count: int, prefix: str, seed: int) -> None:
        self.agents = make_agents(count, prefix, seed)
        self.t: float | None = None

    def step(self, t: float) -> list[tuple[str, dict[str, Any]]]:
        """Every agent's observation at ``t`` (moved from the last instant)."""
        previous, self.t = self.t, t
        out = []
        for agent in self.agents:
            action = None if previous is None else agent.advance(previous, t)
            out.append((agent.agent_id, agent.entry(t, action)))
        return out


@contextmanager
def tree_of(revision: str) -> Iterator[Path]:
    """The files of git ``revision`` in a temporary directory (the repository is not touched)."""
    directory = Path(tempfile.mkdtemp(prefix="frt-baseline-"))
    try:
        archive = subprocess.run(
            ["git", "archive", "--format=tar", revision],
            cwd=ROOT,
            check=True,
            capture_output=True,
        ).stdout
        subprocess.run(["tar", "-x", "-C", str(directory)], input=archive, check=True)
        yield directory
    finally:
        shutil.rmtree(directory, ignore_errors=True)


@dataclass
class Target:
    """One service under test and what was measured on it."""

    name: str
    client: httpx.Client
    frame_scene: Scene
    single_scene: Scene
    frame_s: list[float]
    single_sum_s: list[float]
    single_s: list[float]
    rejected: int = 0


def send_frame(target: Target, t: float) -> None:
    entries = target.frame_scene.step(t)
    body = {"timestamp": t, "agents": [{"agent_id": a, **e} for a, e in entries]}
    r = target.client.post("/v1/frames", json=body)
    r.raise_for_status()
    target.rejected += r.json()["rejected"]
    target.frame_s.append(server_seconds(r))


def send_singles(target: Target, t: float) -> None:
    total = 0.0
    for agent_id, entry in target.single_scene.step(t):
        r = target.client.post(
            f"/v1/agents/{agent_id}/observations", json={"timestamp": t, **entry}
        )
        if r.status_code != 200:
            target.rejected += 1
            continue
        total += server_seconds(r)
        target.single_s.append(server_seconds(r))
    target.single_sum_s.append(total)


def paced(n: int, hz: float, t0: float) -> Iterator[float]:
    """``n`` instants ``1 / hz`` apart on the wall clock (late ones at once), from time ``t0``."""
    start = time.monotonic()
    for k in range(n):
        at = start + k / hz
        time.sleep(max(0.0, at - time.monotonic()))
        yield t0 + k / hz


def run(
    targets: list[Target], instants: int, hz: float, warm: int, block: int, frames: bool
) -> None:
    """Frames (or the observations one by one) at ``hz``: ``block`` instants to one target, then
    the same instants to the next (each measured while the other services are idle: one's load
    does not land in the other's figures), and so on; the ``warm`` first instants are not
    measured."""
    send = send_frame if frames else send_singles
    done = 0
    while done < instants + warm:
        n = min(block, instants + warm - done)
        for target in targets:
            for t in paced(n, hz, 1.0 + done / hz):
                send(target, t)
        done += n
    for target in targets:
        if frames:
            del target.frame_s[:warm]
        else:
            del (
                target.single_sum_s[:warm],
                target.single_s[: warm * len(target.single_scene.agents)],
            )


def summary(target: Target, agents: int) -> dict[str, Any]:
    return {
        "frame_at_server": stats(target.frame_s),
        "one_by_one_sum_at_server": stats(target.single_sum_s),
        "one_observation_at_server": stats(target.single_s),
        "agents": agents,
        "rejected": target.rejected,
    }


def print_table(results: dict[str, dict[str, Any]], agents: int) -> None:
    rows = [
        (f"frame of {agents} agents", "frame_at_server"),
        (f"{agents} observations one by one (sum)", "one_by_one_sum_at_server"),
        ("one observation", "one_observation_at_server"),
    ]
    names = list(results)
    print(f"{'at the server, p50 / p99 / max [ms]':44s}" + "".join(f"{n:>28s}" for n in names))
    for label, key in rows:
        cells = [results[n][key] for n in names]
        print(
            f"{label:44s}"
            + "".join(
                f"{c['p50_ms']:>10.2f} /{c['p99_ms']:>7.2f} /{c['max_ms']:>7.2f}" for c in cells
            )
        )
    for n in names:
        if results[n]["rejected"]:
            print(f"{n}: {results[n]['rejected']} agents rejected")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    parser.add_argument("--agents", type=int, default=100)
    parser.add_argument("--hz", type=float, default=10.0)
    parser.add_argument("--frames", type=int, default=300, help="measured frames per service")
    parser.add_argument("--singles", type=int, default=40, help="measured instants one by one")
    parser.add_argument("--warm", type=int, default=10, help="unmeasured instants first")
    parser.add_argument("--block", type=int, default=25, help="instants to one service in a row")
    parser.add_argument("--baseline", help="a git revision to measure side by side")
    parser.add_argument("--profile", type=Path, help="py-spy the working tree's service")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "bench_frames.json")
    args = parser.parse_args()
    settings = {"max_agents_per_frame": str(max(args.agents, 256))}
    with ExitStack() as stack:
        trees = [("working tree", ROOT)]
        if args.baseline:
            trees.append((f"baseline {args.baseline}", stack.enter_context(tree_of(args.baseline))))
        targets, pids = [], []
        for i, (name, root) in enumerate(trees):
            url, pid = stack.enter_context(service_at(root, args.model.resolve(), **settings))
            client = stack.enter_context(httpx.Client(base_url=url, timeout=30.0))
            scenes = (Scene(args.agents, f"f{i}", 1), Scene(args.agents, f"s{i}", 1))
            targets.append(Target(name, client, *scenes, [], [], []))
            pids.append(pid)
        if args.profile:
            spy = subprocess.Popen(
                [str(Path(sys.executable).parent / "py-spy"), "record", "-p", str(pids[0]),
                 "-o", str(args.profile), "-f", "speedscope", "-r", "200", "--nonblocking"],
            )  # fmt: skip
        run(targets, args.frames, args.hz, args.warm, args.block, frames=True)
        if args.profile:
            spy.send_signal(signal.SIGINT)
            spy.wait(timeout=60)
        run(targets, args.singles, args.hz, args.warm, args.block, frames=False)
    results = {t.name: summary(t, args.agents) for t in targets}
    print_table(results, args.agents)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
