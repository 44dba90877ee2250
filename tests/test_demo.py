"""scripts/demo.py (``make demo``): the Argoverse 2 replay's schedule, and a few seconds of it
against a live server."""

from __future__ import annotations

import importlib.util
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import httpx
import numpy as np
import pyarrow.parquet as pq
import pytest
from frt_client import FRTClient

from tests.conftest import LiveServer

ROOT = Path(__file__).resolve().parent.parent


def load_demo() -> ModuleType:
    spec = importlib.util.spec_from_file_location("frt_demo_script", ROOT / "scripts" / "demo.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


demo = load_demo()


@pytest.fixture(scope="module")
def tracks() -> list:
    path = demo.data_dir(None) / demo.SCENARIO_FILE
    return demo.load_tracks(path, min_s=demo.MIN_TRACK_S)


def test_schedule_observes_the_recorded_rows_every_half_second(tracks: list) -> None:
    ticks = demo.schedule(tracks, v_max=10.0)
    rows = pq.read_table(
        demo.data_dir(None) / demo.SCENARIO_FILE,
        columns=["track_id", "timestep", "position_x", "position_y", "velocity_x", "velocity_y"],
    ).to_pydict()
    recorded = {
        (f"av2-{tid}", step): (x, y, float(np.hypot(vx, vy)))
        for tid, step, x, y, vx, vy in zip(*rows.values(), strict=True)
    }
    seen: dict[str, float] = {}
    for tick in sorted(ticks):
        for obs in ticks[tick]:
            assert obs.t == pytest.approx(tick * 0.5)
            assert obs.agent_id not in seen or seen[obs.agent_id] < obs.t
            seen[obs.agent_id] = obs.t
            x, y, speed = recorded[(obs.agent_id, round(obs.t / 0.1))]
            assert obs.state[:2] == pytest.approx((x, y)) and obs.state[3] == pytest.approx(speed)
            assert 0.0 <= obs.state[3] <= 10.0  # only speeds the model covers
    assert len(seen) >= 20


def test_replay_feeds_the_service_and_forgets_its_agents(
    start_server: Callable[..., LiveServer], tracks: list
) -> None:
    archive = demo.data_dir(None) / demo.MAP_FILE
    server = start_server(map=str(archive), map_id=demo.MAP_ID)
    with FRTClient(server.url, timeout=20.0) as client:
        replay = demo.Replay(client, tracks, v_max=20.0, map_id=demo.MAP_ID)
        worker = threading.Thread(target=replay.run, daemon=True)
        worker.start()
        time.sleep(1.6)  # ticks 0-3 at real time (0, 0.5, 1.0, 1.5 s)
        replay.stop.set()
        worker.join(timeout=10)
        assert not worker.is_alive() and replay.errors == 0
        expected = sum(len(replay.ticks.get(k, [])) for k in range(3))  # surely done
        assert expected > 0 and replay.observed >= expected
        assert replay.planner is not None and replay.checks >= 1  # the recording car's plan
        assert f"av2-{demo.PLANNER_TRACK}" not in replay.tracks
        with httpx.Client(base_url=server.url) as http:
            first = replay.ticks[min(replay.ticks)][0].agent_id
            agent = http.get(f"/v1/agents/{first}").json()
            assert agent["frt_version"] >= 1 and agent["map_id"] == demo.MAP_ID
            replay.forget_all()
            assert http.get(f"/v1/agents/{first}").status_code == 404
