"""``make demo``: the service on 127.0.0.1 and a replay of recorded traffic into it, for the viewer.

Starts ``uvicorn service.api.app:app`` (the shipped model unless ``--model``), then replays the
Argoverse 2 scenario in ``data/av2/`` (or ``../shared/data/av2/``) through the client SDK at real
time, looping: every vehicle track is observed every 0.5 s with the constant velocity and turn
rate predictor of ``experiments/av2.py`` (its covariance fitted on all tracks), the action taken
over the last 0.5 s scored against it. The recording car's own track (``AV``) is the planner: at
each tick its recorded next 3 s are checked against every agent (``time_indexed``), which the
viewer draws. The scenario's map archive is loaded at start-up and named by every car, so their
sets are cut to the road and the viewer draws the map (``--no-map``: neither). Prints the viewer's
URL; Ctrl-C stops the replay and the server. ``--screenshot PATH`` instead runs the replay until
the sets are drawn, saves the page as seen by headless Chromium (``scripts/headless_chromium.py``)
and stops.

Data: Argoverse 2 (scenario 0a1e6f0a), © Argo AI, LLC, CC BY-NC-SA 4.0
(https://creativecommons.org/licenses/by-nc-sa/4.0/), see ``data/av2/NOTICE.md``; the screenshot
carries the same licence.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from frt_client import FRTClient, FRTError  # noqa: E402

from experiments.av2 import (  # noqa: E402
    ATTRIBUTION,
    MAP_FILE,
    OBS_EVERY,
    SAMPLE_DT_S,
    SCENARIO_FILE,
    Track,
    cvtr_mean,
    fit_sigma,
    load_tracks,
    prediction,
)
from reach.dynamics import wrap_angle  # noqa: E402

DATA_DIRS = (ROOT / "data" / "av2", ROOT.parent / "shared" / "data" / "av2")
DEFAULT_MODEL = ROOT / "models" / "frt_unicycle.onnx"
STEP_S = OBS_EVERY * SAMPLE_DT_S  # one observation per track every 0.5 s
PLANNER_TRACK = "AV"  # the recording car: its own future is the planner's trajectory
PLAN_S = 3.0
#: The scenario's map archive, loaded at start-up (``FRT_MAP``) and named by every car.
MAP_ID = "av2-scenario"
#: Tracks shorter than this are left out (a first observation needs 0.5 s of history).
MIN_TRACK_S = 1.0


@dataclass(frozen=True)
class Observation:
    agent_id: str
    index: int  # the track's sample
    t: float  # seconds from the scenario's start
    state: tuple[float, float, float, float]
    action: tuple[float, float]


def data_dir(given: Path | None) -> Path:
    for candidate in (given,) if given else DATA_DIRS:
        if (candidate / SCENARIO_FILE).is_file():
            return candidate
    raise SystemExit(f"no {SCENARIO_FILE} in {', '.join(str(d) for d in DATA_DIRS)}")


def schedule(tracks: list[Track], v_max: float) -> dict[int, list[Observation]]:
    """The observations of every tick (0.5 s apart), with speeds the model covers."""
    ticks: dict[int, list[Observation]] = {}
    for track in tracks:
        for i in range(OBS_EVERY, len(track.t)):
            tick = round(track.t[i] / STEP_S, 6)
            if tick != int(tick) or not 0.0 <= track.speed[i] <= v_max:
                continue
            state = (
                float(track.x[i]),
                float(track.y[i]),
                float(wrap_angle(track.heading[i])),
                float(track.speed[i]),
            )
            ticks.setdefault(int(tick), []).append(
                Observation(f"av2-{track.track_id}", i, float(track.t[i]), state, track.action(i))
            )
    return ticks


class Replay:
    """Observes the scheduled tracks at real time, loop after loop, until stopped."""

    def __init__(
        self, client: FRTClient, tracks: list[Track], v_max: float, map_id: str | None
    ) -> None:
        self.client = client
        self.map_id = map_id
        self.planner = next((t for t in tracks if t.track_id == PLANNER_TRACK), None)
        tracks = [t for t in tracks if t.track_id != PLANNER_TRACK]
        self.sigma = fit_sigma([t for t in tracks if t.observation_indices()])
        self.tracks = {f"av2-{t.track_id}": t for t in tracks}
        self.ticks = schedule(tracks, v_max)
        self.last_tick = max(self.ticks)
        self.loop_s = (self.last_tick + 2) * STEP_S  # the clock keeps increasing across loops
        self.stop = threading.Event()
        self.observed = 0
        self.checks = 0
        self.errors = 0
        self.loops = 0

    def _observe(self, obs: Observation, clock: float, previous: set[str]) -> None:
        track = self.tracks[obs.agent_id]
        try:
            self.client.observe(
                obs.agent_id,
                timestamp=clock + obs.t,
                state=obs.state,
                prediction=prediction(cvtr_mean(track, obs.index), self.sigma),
                observed_action=obs.action if obs.agent_id in previous else None,
                map_id=self.map_id,
            )
            self.observed += 1
        except FRTError as exc:
            self.errors += 1
            print(f"observation of {obs.agent_id} failed: {exc}", file=sys.stderr)

    def _check_plan(self, tick: int, clock: float) -> None:
        """The planner's recorded next 3 s from this tick, against every agent."""
        track = self.planner
        if track is None:
            return
        future = (track.t >= tick * STEP_S - 1e-9) & (track.t <= tick * STEP_S + PLAN_S + 1e-9)
        if future.sum() < 2:
            return
        path = [(clock + t, x, y) for t, x, y in
                zip(track.t[future], track.x[future], track.y[future], strict=True)]  # fmt: skip
        try:
            self.client.collision_check_many(path, mode="time_indexed")
            self.checks += 1
        except FRTError as exc:
            self.errors += 1
            print(f"the planner's check failed: {exc}", file=sys.stderr)

    def run(self) -> None:
        start = time.monotonic()
        previous: set[str] = set()
        while not self.stop.is_set():
            clock = self.loops * self.loop_s
            for tick in range(self.last_tick + 2):
                due = start + (clock + tick * STEP_S)
                if self.stop.wait(max(0.0, due - time.monotonic())):
                    return
                now = self.ticks.get(tick, [])
                for obs in now:
                    self._observe(obs, clock, previous)
                if now:
                    self._check_plan(tick, clock)
                current = {o.agent_id for o in now}
                for gone in previous - current:  # the track ended: its sets go with it
                    with contextlib.suppress(FRTError):
                        self.client.delete_agent(gone)
                previous = current
            self.loops += 1

    def forget_all(self) -> None:
        for agent_id in self.tracks:
            with contextlib.suppress(FRTError):
                self.client.delete_agent(agent_id)


@contextlib.contextmanager
def server(model: Path, host: str, port: int, log: Path, map_path: Path | None) -> Iterator[str]:
    """uvicorn in its own session (Ctrl-C reaches this script only, which then stops it), with
    ``map_path`` loaded at start-up as map ``MAP_ID`` where given."""
    env = {**os.environ, "FRT_MODEL_PATH": str(model), "FRT_LOG_REQUESTS": "false"}
    if map_path is not None:
        env.update(FRT_MAP=str(map_path), FRT_MAP_ID=MAP_ID)
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [
                sys.executable, "-m", "uvicorn", "service.api.app:app", "--host", host,
                "--port", str(port), "--log-level", "warning", "--no-access-log",
            ],
            cwd=ROOT, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
        )  # fmt: skip
        try:
            yield f"http://{host}:{port}"
        finally:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _chromium() -> ModuleType:
    path = Path(__file__).resolve().parent / "headless_chromium.py"
    spec = importlib.util.spec_from_file_location("frt_headless_chromium", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def screenshot(
    url: str, out: Path, agent_id: str | None, wait_s: float, scale: float = 8.0
) -> dict:
    """The viewer after ``wait_s`` of replay, ``agent_id`` (or the fastest agent) selected and
    centred at ``scale`` pixels per metre, saved as PNG at ``out``."""
    chromium = _chromium()
    with chromium.launch(chromium.find_chromium(install=True), 1400, 820) as page:
        page.navigate(f"{url}/viewer")
        page.wait_for("window.frtViewer && window.frtViewer.snapshot().connected")
        time.sleep(wait_s)
        agents = page.evaluate("window.frtViewer.snapshot().agents")
        if agent_id not in agents:  # the fastest car on the map instead
            agent_id = max(agents, key=lambda a: agents[a]["state"]["speed"])
        page.evaluate(f"window.frtViewer.select({agent_id!r})")
        pose = agents[agent_id]["state"]
        ahead = 1.5 * pose["speed"]  # the middle of its 3 s tube
        cx = pose["x"] + ahead * math.cos(pose["heading"])
        cy = pose["y"] + ahead * math.sin(pose["heading"])
        page.evaluate(f"window.frtViewer.setView({cx}, {cy}, {scale})")
        page.wait_for(
            "(s => Object.keys(s.agents).length > 0 && "
            "Object.values(s.agents).every(a => a.drawnVersion > 0))(window.frtViewer.snapshot())",
            timeout_s=30.0,
        )
        time.sleep(1.0)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(page.screenshot())
        if page.errors:
            raise SystemExit(f"the page reported errors: {page.errors}")
        return page.evaluate("window.frtViewer.snapshot().stats")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    parser.add_argument("--data", type=Path, default=None, help="folder of the AV2 scenario")
    parser.add_argument("--log", type=Path, default=Path("/tmp/frt-demo-server.log"))
    parser.add_argument(
        "--no-map", action="store_true", help="replay without the scenario's map (sets uncut)"
    )
    parser.add_argument("--screenshot", type=Path, default=None, help="save the page and stop")
    parser.add_argument("--screenshot-after", type=float, default=5.0, help="seconds of replay")
    parser.add_argument("--select", default=None, help="agent to select in the screenshot")
    parser.add_argument("--scale", type=float, default=8.0, help="screenshot's pixels per metre")
    args = parser.parse_args(argv)
    # Ctrl-C and SIGTERM both end the replay and then the server (even where a shell started
    # this script with SIGINT ignored, as it does for a background job).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.default_int_handler)

    data = data_dir(args.data)
    tracks = load_tracks(data / SCENARIO_FILE, min_s=MIN_TRACK_S)
    map_path = None if args.no_map else (data / MAP_FILE).resolve()
    with (
        server(args.model.resolve(), args.host, args.port, args.log, map_path) as url,
        FRTClient(url, timeout=30.0) as client,
    ):
        try:
            client.wait_ready(timeout_s=120.0)
        except FRTError as exc:
            raise SystemExit(f"the service did not get ready ({exc}); see {args.log}") from None
        v_max = float(client.model().ranges.get("v_start", [0.0, math.inf])[1])
        replay = Replay(client, tracks, v_max, None if map_path is None else MAP_ID)
        worker = threading.Thread(target=replay.run, name="replay", daemon=True)
        worker.start()
        print(f"viewer: {url}/viewer", flush=True)
        print(f"replaying {len(replay.tracks)} vehicle tracks and the recording car's plan, "
              f"{replay.loop_s:.1f} s a loop; "
              f"{ATTRIBUTION}", flush=True)  # fmt: skip
        try:
            if args.screenshot is not None:
                stats = screenshot(
                    url, args.screenshot, args.select, args.screenshot_after, args.scale
                )
                print(f"saved {args.screenshot}; page draw p50 {stats['drawMsP50']} ms")
            else:
                while worker.is_alive():
                    worker.join(timeout=5.0)
                    print(f"\rloop {replay.loops + 1}, {replay.observed} observations, "
                          f"{replay.checks} planner checks, {replay.errors} errors", end="",
                          flush=True)  # fmt: skip
        except KeyboardInterrupt:
            print("\nstopping", flush=True)
        finally:
            replay.stop.set()
            worker.join(timeout=10.0)
            replay.forget_all()
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:  # before the replay started: the server is stopped already
        sys.exit(130)
