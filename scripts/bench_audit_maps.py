"""The coverage audit's own work for agents on a map and off one: ``python scripts/bench_audit_maps.py``.

On the recorded Argoverse 2 scenario in ``data/av2/`` (© Argo AI, LLC, CC BY-NC-SA 4.0,
https://creativecommons.org/licenses/by-nc-sa/4.0/): its vehicles moving at 3-15 m/s for more than
6 s (up to six), each observed at 10 Hz along its track; each observation's position is scored against the versions due
(``AuditLedger``, spacing 0.4 s, the conservative sets of the shipped model's geometry, bounds of
fixed width) and counted, and its own version recorded, as the service does after an answer.
The same runs twice per repeat, alternately: the versions without map terms (an agent without a
map) and with the map and both assumptions (``VersionRoad``: misses per assumption counted).
Prints the thread's CPU per observation in milliseconds. Timing only: nothing is asserted.
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
from reach.frames import Pose  # noqa: E402
from service.runtime.audit import (  # noqa: E402
    AuditLedger,
    RollingCoverage,
    ServedVersion,
    count_audited_many,
    score_many,
)
from service.runtime.maps import MapRegistry, VersionRoad  # noqa: E402
from service.runtime.metrics import Metrics  # noqa: E402
from service.runtime.scheduler import FRTKey  # noqa: E402

MODEL = ROOT / "models" / "frt_unicycle.onnx"
BOUNDS = np.array([-0.2, -2.0, -0.2, -2.0, 0.2, 1.5, 0.2, 1.5])
BOTH = ("drivable_area", "reachable_lanes")


def tracks_observed(engine) -> list[list[tuple[float, float, object]]]:
    """Up to six moving vehicles' positions at 10 Hz, each with its conservative set there."""
    out = []
    for track in av2.load_tracks():
        if sum(3.0 < s < 15.0 for s in track.speed) <= 60 or len(out) == 6:
            continue
        poses = zip(track.x, track.y, track.heading, track.speed, strict=True)
        out.append([
            (float(x), float(y), engine.conservative(
                Pose(float(x), float(y), float(wrap_angle(h))), float(np.clip(v, 0, 15)), BOUNDS))
            for x, y, h, v in poses
        ])  # fmt: skip
    return out


def audit_run(observed: list, registry: MapRegistry | None, metrics: Metrics) -> list[float]:
    """CPU seconds of each observation's audit (scored, counted, its version recorded)."""
    ledger, coverage = AuditLedger(32, 1000, spacing_s=0.4), RollingCoverage(1000)
    entry = None if registry is None else registry.get("austin")
    times = []
    for n, positions in enumerate(observed):
        agent = f"car{n}"
        for k, (x, y, conservative) in enumerate(positions):
            t = 0.1 * k
            start = time.thread_time()
            due = ledger.due(agent, t)
            if due:
                scored = score_many([(x, y, t, due)], lambda key: None)
                count_audited_many(metrics, ledger, coverage, [(agent, scored[0], t)])
            key = FRTKey.of(agent, k + 1, [t])
            road = None if entry is None else VersionRoad(registry, entry, key, BOTH)  # type: ignore[arg-type]
            ledger.record(
                agent, ServedVersion(k + 1, key, t, t + 3.0, 1.5, "car", conservative, road)
            )
            times.append(time.thread_time() - start)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    raw = (av2.DATA_DIR / av2.MAP_FILE).read_bytes()
    registry = MapRegistry(2, 1.0, 2_000_000)
    registry.put("austin", registry.parse(raw), "api", len(raw))
    observed = tracks_observed(engine_for(ValueModel.load(MODEL, threads=1), network=False))
    metrics = Metrics()
    runs: dict[str, list[float]] = {"no map": [], "map": []}
    for _ in range(args.repeat):
        runs["no map"] += audit_run(observed, None, metrics)
        runs["map"] += audit_run(observed, registry, metrics)
    n = sum(len(p) for p in observed)
    print(f"{len(observed)} vehicles, {n} observations at 10 Hz, {args.repeat} repeats; ms of CPU "
          "per observation")  # fmt: skip
    for name, times in runs.items():
        a = np.asarray(times) * 1e3
        print(f"{name:7s} p50 {np.percentile(a, 50):.3f}  p99 {np.percentile(a, 99):.3f}  "
              f"mean {a.mean():.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
