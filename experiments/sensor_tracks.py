"""Recorded road users of every class, as ``experiments.av2.Track``: the Argoverse 2 sensor-log
tracks of ``../shared/data/av2_sensor_tracks/tracks.json`` and the pedestrians and cyclists of the
motion-forecasting scenario in ``data/av2/``.

Data: Argoverse 2, © Argo AI, LLC, licensed under CC BY-NC-SA 4.0
(https://creativecommons.org/licenses/by-nc-sa/4.0/; non-commercial, share alike). Tracks, figures
and plots derived from either file carry the same licence.

Sensor tracks (``tracks.json``, its NOTICE.md) give box centres ``x, y`` at sweep indices ``k``
(0.1 s apart, no gaps) and a box yaw that may be off by 180 degrees; they give no velocity. The
state the unicycle needs (paper, "Running example": ``x' = v cos th, y' = v sin th``) is estimated
from the positions:

- velocity: the first derivative of a Savitzky-Golay fit (``SMOOTH_WINDOW`` samples, polynomial of
  degree ``SMOOTH_ORDER``, least squares; at the ends the fit over the first / last window) of
  ``x`` and ``y``; speed is its norm;
- heading: the direction of that velocity where the speed is at least ``HEADING_MIN_SPEED``
  (``th`` is the direction of motion in the model, whatever way the box faces); below it the
  last motion heading is held (before the first motion: the first motion heading). A track that
  never reaches that speed keeps its box yaw (the direction most of its yaws agree with, so a
  flipped box does not turn it). The heading is unwrapped (continuous).

A track's yaw "flips" where the box yaw and the motion heading differ by more than 90 degrees on a
moving sample: :func:`yaw_flips` counts them (the estimate above never uses the yaw there).

The scenario's tracks carry their own velocity and heading (``av2.load_tracks`` reads the
vehicles): :func:`load_scenario` reads them per class (``pedestrian`` and ``cyclist`` object
types, or ``vehicle`` as car) the same way.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from scipy.signal import savgol_filter

from experiments.av2 import DATA_DIR, MIN_TRACK_S, SAMPLE_DT_S, SCENARIO_FILE, Track

ROOT = Path(__file__).resolve().parent.parent
SENSOR_TRACKS = ROOT.parent / "shared" / "data" / "av2_sensor_tracks" / "tracks.json"
SENSOR_ATTRIBUTION = (
    "Data: Argoverse 2 sensor logs adcf7d18, 3bffdcff (av2-api test data) and motion-forecasting "
    "scenario 0a1e6f0a, © Argo AI, LLC, CC BY-NC-SA 4.0 "
    "https://creativecommons.org/licenses/by-nc-sa/4.0/"
)
#: Savitzky-Golay window (samples, 1.1 s at 10 Hz) and polynomial degree of the position fit.
SMOOTH_WINDOW = 11
SMOOTH_ORDER = 2
#: Below this speed (m/s) the velocity's direction is noise: the heading is held.
HEADING_MIN_SPEED = 0.5
#: The scenario's object types per agent class.
SCENARIO_CLASSES: dict[str, str] = {
    "vehicle": "car",
    "cyclist": "cyclist",
    "pedestrian": "pedestrian",
}


@dataclass(frozen=True)
class ClassedTrack:
    """A track, its road-user class (car / cyclist / pedestrian) and where it comes from."""

    track: Track
    agent_class: str
    #: "sensor" (tracks.json) or "scenario" (the motion-forecasting parquet).
    source: str

    @property
    def track_id(self) -> str:
        return self.track.track_id


def estimate_motion(
    x: np.ndarray,
    y: np.ndarray,
    dt: float = SAMPLE_DT_S,
    yaw: np.ndarray | None = None,
    window: int = SMOOTH_WINDOW,
    order: int = SMOOTH_ORDER,
    min_speed: float = HEADING_MIN_SPEED,
) -> tuple[np.ndarray, np.ndarray]:
    """``(heading, speed)`` of positions sampled every ``dt`` s (see the module): the heading
    unwrapped, the speed >= 0. ``yaw`` (the box yaw) is used only if the track never moves."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    n = len(x)
    if n < 2:
        raise ValueError("need at least two samples")
    w = min(window, n if n % 2 else n - 1)
    p = min(order, w - 1)
    if w >= 3:
        vx = savgol_filter(x, w, p, deriv=1, delta=dt)
        vy = savgol_filter(y, w, p, deriv=1, delta=dt)
    else:
        vx, vy = np.gradient(x, dt), np.gradient(y, dt)
    speed = np.hypot(vx, vy)
    moving = np.flatnonzero(speed >= min_speed)
    if len(moving) == 0:
        still = 0.0 if yaw is None else _median_angle(np.asarray(yaw, dtype=float))
        return np.full(n, still), speed
    motion = np.unwrap(np.arctan2(vy[moving], vx[moving]))
    # each sample takes the heading of the last moving sample up to it (the first one before it)
    last = np.clip(np.searchsorted(moving, np.arange(n), side="right") - 1, 0, None)
    return np.unwrap(motion[last]), speed


def _median_angle(angles: np.ndarray) -> float:
    """A representative direction of ``angles`` robust to 180-degree flips of some of them."""
    doubled = np.exp(2j * angles)  # a flip by pi maps to the same point
    axis = 0.5 * float(np.angle(doubled.mean()))
    # of the axis' two directions, the one most yaws agree with
    agree = np.cos(angles - axis)
    return axis if np.sum(agree >= 0) >= np.sum(agree < 0) else axis + math.pi


def yaw_flips(yaw: np.ndarray, heading: np.ndarray, speed: np.ndarray) -> int:
    """Moving samples (speed >= ``HEADING_MIN_SPEED``) whose box yaw is more than 90 degrees from
    the motion heading."""
    moving = np.asarray(speed) >= HEADING_MIN_SPEED
    return int(np.sum(np.cos(np.asarray(yaw)[moving] - np.asarray(heading)[moving]) < 0.0))


def sensor_track_id(log: str, track_uuid: str) -> str:
    """A sensor track's id: its log's first 8 characters and its uuid."""
    return f"{log[:8]}-{track_uuid}"


def load_sensor(
    path: Path = SENSOR_TRACKS, min_s: float = MIN_TRACK_S, classes: Iterable[str] | None = None
) -> list[ClassedTrack]:
    """The sensor tracks of ``path`` lasting at least ``min_s`` (of ``classes``, default every
    class), sorted by id, with heading and speed estimated (see the module)."""
    body = json.loads(Path(path).read_text())
    wanted = None if classes is None else set(classes)
    out = []
    for raw in body["tracks"]:
        if wanted is not None and raw["agent_class"] not in wanted:
            continue
        k = np.asarray(raw["k"], dtype=int)
        if len(k) < 2 or np.any(np.diff(k) != 1):
            raise ValueError(f"track {raw['track_uuid']}: sweeps must be contiguous")
        t = k * SAMPLE_DT_S
        if t[-1] - t[0] < min_s - 1e-9:
            continue
        x, y = np.asarray(raw["x"], dtype=float), np.asarray(raw["y"], dtype=float)
        heading, speed = estimate_motion(x, y, yaw=np.asarray(raw["yaw"], dtype=float))
        track = Track(sensor_track_id(raw["log"], raw["track_uuid"]), t, x, y, heading, speed)
        out.append(ClassedTrack(track, raw["agent_class"], "sensor"))
    return sorted(out, key=lambda c: c.track_id)


def sensor_yaw_flips(path: Path = SENSOR_TRACKS, min_s: float = MIN_TRACK_S) -> dict[str, int]:
    """Per sensor track (id) with any, the moving samples whose box yaw is flipped."""
    body = json.loads(Path(path).read_text())
    flips = {}
    for raw in body["tracks"]:
        if (len(raw["k"]) - 1) * SAMPLE_DT_S < min_s - 1e-9:
            continue
        heading, speed = estimate_motion(raw["x"], raw["y"], yaw=np.asarray(raw["yaw"]))
        n = yaw_flips(np.asarray(raw["yaw"]), heading, speed)
        if n:
            flips[sensor_track_id(raw["log"], raw["track_uuid"])] = n
    return flips


def load_scenario(
    path: Path = DATA_DIR / SCENARIO_FILE,
    min_s: float = MIN_TRACK_S,
    classes: Iterable[str] = ("pedestrian", "cyclist"),
) -> list[ClassedTrack]:
    """The scenario's tracks of agent ``classes`` (object types: ``SCENARIO_CLASSES``) lasting at
    least ``min_s`` without gaps, sorted by id; heading (unwrapped) and speed as recorded, the
    way ``av2.load_tracks`` reads the vehicles."""
    wanted = set(classes)
    table = pq.read_table(
        path,
        columns=["track_id", "object_type", "timestep", "position_x", "position_y", "heading",
                 "velocity_x", "velocity_y"],
    ).to_pydict()  # fmt: skip
    rows: dict[str, list[int]] = {}
    kinds: dict[str, str] = {}
    for i, (tid, kind) in enumerate(zip(table["track_id"], table["object_type"], strict=True)):
        klass = SCENARIO_CLASSES.get(kind)
        if klass in wanted:
            rows.setdefault(tid, []).append(i)
            kinds[tid] = klass
    out = []
    for tid in sorted(rows):
        idx = sorted(rows[tid], key=lambda r: table["timestep"][r])
        steps = np.array([table["timestep"][r] for r in idx])
        if len(steps) < 2 or np.any(np.diff(steps) != 1):
            continue
        col = {k: np.array([table[k][r] for r in idx], dtype=float) for k in
               ("position_x", "position_y", "heading", "velocity_x", "velocity_y")}  # fmt: skip
        track = Track(
            track_id=tid,
            t=steps * SAMPLE_DT_S,
            x=col["position_x"],
            y=col["position_y"],
            heading=np.unwrap(col["heading"]),
            speed=np.hypot(col["velocity_x"], col["velocity_y"]),
        )
        if track.duration_s >= min_s - 1e-9:
            out.append(ClassedTrack(track, kinds[tid], "scenario"))
    return out


def load_all(
    sensor_path: Path = SENSOR_TRACKS,
    scenario_path: Path = DATA_DIR / SCENARIO_FILE,
    min_s: float = MIN_TRACK_S,
) -> list[ClassedTrack]:
    """Every class from both sources: the sensor tracks and the scenario's vehicles, pedestrians
    and cyclists, sorted by id."""
    tracks = load_sensor(sensor_path, min_s) + load_scenario(
        scenario_path, min_s, classes=("car", "pedestrian", "cyclist")
    )
    ids = [c.track_id for c in tracks]
    if len(set(ids)) != len(ids):
        raise ValueError("track ids of the two sources overlap")
    return sorted(tracks, key=lambda c: c.track_id)


def by_class(tracks: Sequence[ClassedTrack]) -> dict[str, list[ClassedTrack]]:
    """The tracks grouped by agent class (each group in the given order)."""
    out: dict[str, list[ClassedTrack]] = {}
    for c in tracks:
        out.setdefault(c.agent_class, []).append(c)
    return out
