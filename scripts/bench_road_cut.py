"""Time of cutting sets by the road: ``python scripts/bench_road_cut.py``.

On the recorded Argoverse 2 scenario in ``data/av2/`` (© Argo AI, LLC, CC BY-NC-SA 4.0,
https://creativecommons.org/licenses/by-nc-sa/4.0/): every vehicle observation of the replay
(``experiments.av2``: tracks of at least 4 s, every 0.5 s while 3 s of future remain, speed in the
model's range) gets the exact set of fixed-width bounds around its constant turn rate (the shipped
model's geometry, no network); then, ``--repeat`` times each:

- ``world``: ``RoadMap.cut`` of the whole-horizon tube K in the world frame (K ∩ R);
- ``set``: a ``CutSet`` made (R read and moved into the human frame once) and its whole-horizon
  tube cut (with the components that cannot be reached on the road dropped);
- ``set_all``: then every tube, slice and interval of that set cut;
- ``lanes``: the set cut to the drivable area and the lanes it can reach (``lane_cut``: the start
  lanes found, the lane graph followed within the set's box, the region read and moved into the
  human frame) and its whole-horizon tube cut, for the sets the lane assumption applies to;
  ``lanes_warm``: the same after the first repeat, when the region of every set of reachable
  lanes has been built (the first repeat builds each on its first use, as a server does once
  per set of lanes while it keeps it);
- ``on_road`` and ``start``: an observation's tests of the two assumptions at the set's pose (the
  pose on R; the lanes holding it within 30° of its heading).

Prints p50 / p99 / max in milliseconds of wall time and of the thread's CPU time (on a shared
machine the wall time's tail is mostly other processes' turns). Timing only: nothing is asserted.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from experiments import av2  # noqa: E402
from models.runtime import ValueModel  # noqa: E402
from models.value_fields import engine_for  # noqa: E402
from reach.dynamics import wrap_angle  # noqa: E402
from reach.frames import Pose, to_world_frame  # noqa: E402
from reach.lanes import HEADING_TOLERANCE, VEHICLE_LANE_TYPES  # noqa: E402
from reach.road_cut import CutSet, lane_cut  # noqa: E402
from reach.road_map import RoadMap  # noqa: E402

MODEL = ROOT / "models" / "frt_unicycle.onnx"


def bounds_for(omega: float) -> np.ndarray:
    """u1 within omega ± 0.2 rad/s, u2 within [-2, 1.5] m/s², constant over the horizon."""
    u1 = float(np.clip(omega, -1.8, 1.8))
    return np.array([u1 - 0.2, -2.0, u1 - 0.2, -2.0, u1 + 0.2, 1.5, u1 + 0.2, 1.5])


def sets(engine, v_max: float) -> list:
    """The exact set of every vehicle observation of the replay."""
    out = []
    for track in av2.load_tracks():
        for i in track.observation_indices():
            if not 0.0 <= track.speed[i] <= v_max:
                continue
            pose = Pose(float(track.x[i]), float(track.y[i]), float(wrap_angle(track.heading[i])))
            omega, _ = track.action(i)
            out.append(engine.exact(pose, float(track.speed[i]), bounds_for(omega)))
    return out


def stats_ms(samples: list[float]) -> str:
    a = np.asarray(samples) * 1e3
    return f"p50 {np.percentile(a, 50):7.3f}  p99 {np.percentile(a, 99):7.3f}  max {a.max():7.3f}"


class Clock:
    """Wall and thread CPU seconds of timed sections, by name."""

    def __init__(self) -> None:
        self.wall: dict[str, list[float]] = {}
        self.cpu: dict[str, list[float]] = {}
        self.started = (0.0, 0.0)

    def start(self) -> None:
        self.started = (time.perf_counter(), time.thread_time())

    def stop(self, *names: str) -> None:
        wall, cpu = time.perf_counter() - self.started[0], time.thread_time() - self.started[1]
        for name in names:
            self.wall.setdefault(name, []).append(wall)
            self.cpu.setdefault(name, []).append(cpu)


def test_assumptions(clock: Clock, road: RoadMap, pose: Pose, margin: float) -> None:
    """Time an observation's tests of the assumptions at ``pose`` (``service.flows.road``'s)."""
    clock.start()
    road.on_road(pose.x, pose.y, margin)
    clock.stop("on_road")
    clock.start()
    graph = road.lane_graph
    index = graph.index(margin, road.region(margin))
    graph.start(index, (pose.x, pose.y), pose.heading, VEHICLE_LANE_TYPES, HEADING_TOLERANCE)
    clock.stop("start")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--margin", type=float, default=1.0, help="R = D ⊕ margin (m)")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    road = RoadMap.load(av2.DATA_DIR / av2.MAP_FILE)
    road.region(args.margin)
    model = ValueModel.load(MODEL, threads=1)
    engine = engine_for(model, network=False)
    exact = sets(engine, float(model.card.ranges["v_start"][1]))
    for frt in exact:
        frt.draw_tubes()
        for j in range(frt.n_slices):
            frt.slice(j), frt.interval(j)
    clock = Clock()
    for repeat in range(args.repeat):
        for frt in exact:
            world = to_world_frame(frt.tube(frt.n_slices - 1), frt.pose)
            clock.start()
            road.cut(world, args.margin)
            clock.stop("world")
            clock.start()
            cut = CutSet(frt, road, args.margin)
            cut.tube(cut.n_slices - 1)
            clock.stop("set")
            clock.start()
            for j in range(cut.n_slices):
                cut.tube(j), cut.slice(j), cut.interval(j)
            clock.stop("set_all")
            clock.start()
            lanes = lane_cut(frt, road, args.margin)
            if lanes is not None:
                lanes.tube(lanes.n_slices - 1)
                clock.stop("lanes", *(("lanes_warm",) if repeat else ()))
            test_assumptions(clock, road, frt.pose, args.margin)
    print(f"{len(exact)} vehicle sets of the recorded scenario, margin {args.margin} m, "
          f"{args.repeat} repeats; milliseconds")  # fmt: skip
    for name in clock.wall:
        print(f"{name:10s} wall {stats_ms(clock.wall[name])}   cpu {stats_ms(clock.cpu[name])}")


if __name__ == "__main__":
    main()
