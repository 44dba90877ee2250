"""Predictors' native messages as observation pieces: Autoware's and Apollo's, without ROS.

- :func:`from_autoware`: an ``autoware_perception_msgs/PredictedObject`` (predicted paths of
  poses every ``time_step``, each with a ``confidence``).
- :func:`from_apollo`: an Apollo ``prediction.PredictionObstacle`` (trajectories of points with a
  ``relative_time`` and a per-point ``gaussian_info``, each with a ``probability``).

Each takes the message as a plain mapping (the shape of its JSON or YAML dump: ``ros2 topic echo``
for Autoware; protobuf's ``MessageToDict``/``MessageToJson`` for Apollo, snake_case or camelCase
keys) or as the dataclasses below, which mirror the fields that are read, and returns::

    {"agent_id": ..., "state": {"x", "y", "heading", "speed"}, "agent_class": ...,
     "prediction": {"dt", "modes": [{"weight", "mean", "cov"}, ...]}[, "config": {...}]}

which ``observe(timestamp=t, **piece)`` and ``frame(timestamp=t, agents=[piece, ...])`` take
(``agent_id`` only when the message has an id; ``config`` only with ``radius_from_shape``).

**The state.** Position from the message; speed the norm of the velocity; heading the direction of
the velocity when the speed is at least :data:`HEADING_MIN_SPEED` (the unicycle's heading is the
direction of motion), else the object's yaw. Autoware's twist is in the object's frame, so its
direction is added to the pose's yaw.

**The paths.** Each predicted path is moved so that its point at time 0 is the state's position
(a path that starts later gets the state's position as its point at 0), then resampled to the
step ``dt`` (default: the message's own step) on ``0, dt, 2 dt, ...`` up to its last point or
``horizon``, whichever is first, by cubic Hermite interpolation of the positions (each tangent
that of the parabola through the point and its neighbours: at the message's own times the points
are kept as they are, and a path of constant acceleration is reproduced exactly).
Paths with zero probability are dropped; the rest are weighted by their probabilities
(normalised) and the 32 most probable kept. Modes shorter than the longest repeat their last step
(the service holds a prediction's last step to the horizon anyway).

**The controls**: :func:`frt_client.paths.path_controls` (central differences: the state at an
inner point the mean of its two segments' velocities), which meets a smooth path's points to
second order in ``dt``; docs/client.md gives its error on recorded tracks beside the first-order
differences of :func:`frt_client.paths.trajectory_controls` and the command that measures both.

**The covariances.** Autoware's paths carry none: step k gets the rule of
:func:`frt_client.mixtures.from_trajectories` (``diag((sigma_1 s_k)^2, (sigma_2 s_k)^2)``,
``s_k = 1 + growth k``). Apollo's ``gaussian_info`` (``sigma_x``, ``sigma_y``, ``correlation``
of the position, interpolated linearly in time as a covariance matrix) is turned into a
covariance of the controls (:func:`gaussian_controls_cov`): the position covariance grown since
time 0 (per axis ``max(sigma_t^2 - sigma_0^2, 0)``, with the point's correlation) is split along
and across the path's heading at the point, and each part is the spread that a control held
since time 0 would cause at the point's time t: an acceleration error ``a`` moves the point
``a t^2 / 2`` along the path, a heading-rate error ``w`` moves it ``w * int_0^t v(s) s ds``
across (the speed ``v`` floored at :data:`LATERAL_MIN_SPEED`). Step k takes the covariance of
point k + 1, plus ``diag(floor_1^2, floor_2^2)`` so that it is positive definite. A trajectory
whose ``gaussian_info`` is missing or all zero gets the rule above.

**Classes** (:data:`AUTOWARE_CLASSES`, :data:`APOLLO_CLASSES`, or a mapping of your own as
``classes``): the most probable Autoware label; Apollo's ``type`` (a motorcyclist ``sub_type``
overrides ``BICYCLE``). Motorcycles are served as cars: they reach speeds and accelerations
beyond the service's cyclist class's range and limits. Unknown labels are cars, the service's
default class.

Pure Python (no ROS, no numpy needed); invalid input raises
:class:`~frt_client.errors.ValidationError` with ``field`` the dotted path of the culprit in the
message (``trajectory.1.trajectory_point.3.relative_time``).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from frt_client.errors import ValidationError
from frt_client.inputs import plain
from frt_client.mixtures import MAX_MODES, from_mixture
from frt_client.paths import path_controls, path_states, wrap

#: The service's horizon T (s): later points of a path are not used.
HORIZON_S = 3.0
#: Below this speed (m/s) the velocity's direction is noise: the object's yaw is its heading.
HEADING_MIN_SPEED = 0.5
#: The speed (m/s) below which a heading-rate error is taken to move a point as at this speed.
LATERAL_MIN_SPEED = 0.5
#: Default standard deviations (rad/s, m/s²) of the first step, and their growth per step, for
#: paths without covariance: the defaults of :func:`frt_client.mixtures.from_trajectories`.
DEFAULT_SIGMA = (0.1, 0.5)
DEFAULT_GROWTH = 0.25
#: Standard deviations (rad/s, m/s²) added to every covariance made from ``gaussian_info``.
DEFAULT_FLOOR = (0.02, 0.05)

#: ``autoware_perception_msgs/ObjectClassification`` labels.
AUTOWARE_LABELS: dict[int, str] = {
    0: "UNKNOWN",
    1: "CAR",
    2: "TRUCK",
    3: "BUS",
    4: "TRAILER",
    5: "MOTORCYCLE",
    6: "BICYCLE",
    7: "PEDESTRIAN",
}
#: Autoware label -> the service's agent class.
AUTOWARE_CLASSES: dict[str, str] = {
    "UNKNOWN": "car",
    "CAR": "car",
    "TRUCK": "car",
    "BUS": "car",
    "TRAILER": "car",
    "MOTORCYCLE": "car",
    "BICYCLE": "cyclist",
    "PEDESTRIAN": "pedestrian",
}
#: Apollo ``PerceptionObstacle.Type`` values.
APOLLO_TYPES: dict[int, str] = {
    0: "UNKNOWN",
    1: "UNKNOWN_MOVABLE",
    2: "UNKNOWN_UNMOVABLE",
    3: "PEDESTRIAN",
    4: "BICYCLE",
    5: "VEHICLE",
}
#: Apollo type -> the service's agent class (``ST_MOTORCYCLIST`` is looked up as a type too).
APOLLO_CLASSES: dict[str, str] = {
    "UNKNOWN": "car",
    "UNKNOWN_MOVABLE": "car",
    "UNKNOWN_UNMOVABLE": "car",
    "PEDESTRIAN": "pedestrian",
    "BICYCLE": "cyclist",
    "VEHICLE": "car",
    "ST_MOTORCYCLIST": "car",
}
#: Apollo ``PerceptionObstacle.SubType`` of a motorcyclist (the other sub-types are not read).
APOLLO_MOTORCYCLIST = (8, "ST_MOTORCYCLIST")
#: Autoware ``Shape.type`` values.
AUTOWARE_SHAPES: dict[int, str] = {0: "BOUNDING_BOX", 1: "CYLINDER", 2: "POLYGON"}


# ------------------------------------------------------------------ the messages, as dataclasses


@dataclass
class Vector3:
    """``geometry_msgs/Point`` or ``Vector3`` (Apollo: ``common.Point3D``)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass
class Quaternion:
    """``geometry_msgs/Quaternion``."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0

    @classmethod
    def from_yaw(cls, yaw: float) -> Quaternion:
        """The rotation by ``yaw`` (rad) about +z."""
        return cls(0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw))


@dataclass
class Pose:
    """``geometry_msgs/Pose``."""

    position: Vector3 = field(default_factory=Vector3)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseWithCovariance:
    """``geometry_msgs/PoseWithCovariance`` (the covariance is not read)."""

    pose: Pose = field(default_factory=Pose)
    covariance: list[float] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Twist:
    """``geometry_msgs/Twist``: in the object's frame (``linear.x`` forward)."""

    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class TwistWithCovariance:
    """``geometry_msgs/TwistWithCovariance`` (the covariance is not read)."""

    twist: Twist = field(default_factory=Twist)
    covariance: list[float] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class PredictedPath:
    """``autoware_perception_msgs/PredictedPath``: poses at ``0, time_step, 2 time_step, ...``
    (``time_step`` in seconds; a ``{sec, nanosec}`` mapping is accepted where a dict is)."""

    path: list[Pose] = field(default_factory=list)
    time_step: float = 0.1
    confidence: float = 1.0


@dataclass
class PredictedObjectKinematics:
    """``autoware_perception_msgs/PredictedObjectKinematics`` (acceleration is not read)."""

    initial_pose_with_covariance: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    initial_twist_with_covariance: TwistWithCovariance = field(default_factory=TwistWithCovariance)
    predicted_paths: list[PredictedPath] = field(default_factory=list)


@dataclass
class ObjectClassification:
    """``autoware_perception_msgs/ObjectClassification``: ``label`` a number or its name."""

    label: int | str = 0
    probability: float = 1.0


@dataclass
class Polygon:
    """``geometry_msgs/Polygon``."""

    points: list[Vector3] = field(default_factory=list)


@dataclass
class Shape:
    """``autoware_perception_msgs/Shape``: ``dimensions`` x = length, y = width (a cylinder's x
    its diameter); ``footprint`` the polygon in the object's frame."""

    type: int | str = 0
    footprint: Polygon = field(default_factory=Polygon)
    dimensions: Vector3 = field(default_factory=Vector3)


@dataclass
class PredictedObject:
    """``autoware_perception_msgs/PredictedObject``: ``object_id`` the UUID's 16 bytes, or text."""

    object_id: list[int] | str | None = None
    existence_probability: float = 1.0
    classification: list[ObjectClassification] = field(default_factory=list)
    kinematics: PredictedObjectKinematics = field(default_factory=PredictedObjectKinematics)
    shape: Shape = field(default_factory=Shape)


@dataclass
class PathPoint:
    """Apollo ``common.PathPoint`` (only x, y and theta)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    theta: float = 0.0


@dataclass
class GaussianInfo:
    """Apollo ``common.GaussianInfo``: the position's standard deviations (m) and correlation;
    the ellipse fields are not read."""

    sigma_x: float = 0.0
    sigma_y: float = 0.0
    correlation: float = 0.0
    area_probability: float = 0.0
    ellipse_a: float = 0.0
    ellipse_b: float = 0.0
    theta_a: float = 0.0


@dataclass
class ApolloTrajectoryPoint:
    """Apollo ``common.TrajectoryPoint`` (``v`` and ``a`` are not read: positions are)."""

    path_point: PathPoint = field(default_factory=PathPoint)
    v: float = 0.0
    a: float = 0.0
    relative_time: float = 0.0
    gaussian_info: GaussianInfo | None = None


@dataclass
class ApolloTrajectory:
    """Apollo ``prediction.Trajectory``."""

    probability: float = 1.0
    trajectory_point: list[ApolloTrajectoryPoint] = field(default_factory=list)


@dataclass
class PerceptionObstacle:
    """Apollo ``perception.PerceptionObstacle``: ``theta`` and ``velocity`` in the world frame,
    ``type`` and ``sub_type`` numbers or names."""

    id: int | str | None = None
    position: Vector3 = field(default_factory=Vector3)
    theta: float = 0.0
    velocity: Vector3 = field(default_factory=Vector3)
    length: float = 0.0
    width: float = 0.0
    type: int | str = 0
    sub_type: int | str = 0


@dataclass
class PredictionObstacle:
    """Apollo ``prediction.PredictionObstacle``."""

    perception_obstacle: PerceptionObstacle = field(default_factory=PerceptionObstacle)
    trajectory: list[ApolloTrajectory] = field(default_factory=list)
    timestamp: float = 0.0


# ------------------------------------------------------------------ reading a message


def _message(value: Any) -> Any:
    """A dataclass, pydantic model, mapping or sequence as plain dicts and lists."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = dataclasses.asdict(value)
    return plain(value)


def _camel(name: str) -> str:
    head, *rest = name.split("_")
    return head + "".join(part.title() for part in rest)


def _get(node: Any, key: str, where: str, default: Any = ...) -> Any:
    """``node[key]`` (or its camelCase spelling); ``default`` if absent, else an error naming it."""
    name = f"{where}.{key}" if where else key
    if not isinstance(node, Mapping):
        raise ValidationError(f"{where or 'message'}: expected a mapping", field=where or None)
    value = node.get(key)
    if value is None:
        value = node.get(_camel(key))
    if value is None:
        if default is ...:
            raise ValidationError(f"{name}: missing", field=name)
        return default
    return value


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValidationError(f"{where}: expected a finite number, got {value!r}", field=where)
    return float(value)


def _num(node: Any, key: str, where: str, default: Any = ...) -> float:
    name = f"{where}.{key}" if where else key
    return _number(_get(node, key, where, default), name)


def _list(node: Any, key: str, where: str) -> list[Any]:
    name = f"{where}.{key}" if where else key
    value = _get(node, key, where, [])
    if not isinstance(value, list):
        raise ValidationError(f"{name}: expected a list", field=name)
    return value


def _yaw(orientation: Any, where: str) -> float:
    """The yaw of a quaternion mapping (or of a mapping with ``yaw``)."""
    if isinstance(orientation, Mapping) and "yaw" in orientation:
        return _num(orientation, "yaw", where)
    x, y, z = (_num(orientation, k, where, 0.0) for k in ("x", "y", "z"))
    w = _num(orientation, "w", where, 1.0)
    if x * x + y * y + z * z + w * w < 1e-12:
        raise ValidationError(f"{where}: a zero quaternion has no yaw", field=where)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _seconds(value: Any, where: str) -> float:
    """A duration: seconds, ``{sec, nanosec}`` (ROS 2), ``{secs, nsecs}`` (ROS 1) or ``"0.5s"``."""
    if isinstance(value, str) and value.endswith("s"):
        try:
            return _number(float(value[:-1]), where)
        except ValueError:
            pass
    if isinstance(value, Mapping):
        sec = _number(value.get("sec", value.get("secs", 0)), f"{where}.sec")
        nano = _number(value.get("nanosec", value.get("nsecs", 0)), f"{where}.nanosec")
        return sec + 1e-9 * nano
    return _number(value, where)


def _state(x: float, y: float, yaw: float, vx: float, vy: float) -> dict[str, float]:
    """The unicycle state from a position, a yaw and a world-frame velocity (see the module)."""
    speed = math.hypot(vx, vy)
    heading = math.atan2(vy, vx) if speed >= HEADING_MIN_SPEED else yaw
    return {"x": x, "y": y, "heading": wrap(heading), "speed": speed}


# ------------------------------------------------------------------ the method


def _tangents(times: Sequence[float], points: Sequence[complex]) -> list[complex]:
    """The derivative at each point of the parabola through it and its two neighbours (at the
    ends, through the first or last three points; a two-point path: its chord)."""
    n = len(points)
    if n == 2:
        chord = (points[1] - points[0]) / (times[1] - times[0])
        return [chord, chord]
    out = []
    for i in range(n):
        j = min(max(i, 1), n - 2)  # the middle of the three points used
        h0, h1 = times[j] - times[j - 1], times[j + 1] - times[j]
        d0 = (points[j] - points[j - 1]) / h0
        d1 = (points[j + 1] - points[j]) / h1
        middle = (d0 * h1 + d1 * h0) / (h0 + h1)
        curvature = 2.0 * (d1 - d0) / (h0 + h1)  # the parabola's second derivative
        out.append(middle + curvature * (times[i] - times[j]))
    return out


def resample(
    times: Sequence[float],
    positions: Sequence[Sequence[float]],
    dt: float,
    horizon: float = HORIZON_S,
) -> list[list[float]]:
    """A path's points at ``0, dt, 2 dt, ...`` up to ``min(times[-1], horizon)``.

    ``times`` (s) start at 0 and increase; ``positions`` are the path's ``(x, y)`` at them. Cubic
    Hermite interpolation with the tangents of :func:`_tangents`: exact at the given times and
    for paths of constant acceleration.
    """
    end = min(times[-1], horizon)
    steps = math.floor(end / dt + 1e-9)
    pts = [complex(x, y) for x, y in positions]
    if len(pts) == 1:
        return [[pts[0].real, pts[0].imag]]
    tangents = _tangents(times, pts)
    out, i = [], 0
    for k in range(steps + 1):
        t = min(k * dt, times[-1])
        while i < len(times) - 2 and times[i + 1] < t:
            i += 1
        h = times[i + 1] - times[i]
        s = (t - times[i]) / h
        s2, s3 = s * s, s * s * s
        p = (
            (2 * s3 - 3 * s2 + 1) * pts[i]
            + (s3 - 2 * s2 + s) * h * tangents[i]
            + (-2 * s3 + 3 * s2) * pts[i + 1]
            + (s3 - s2) * h * tangents[i + 1]
        )
        out.append([p.real, p.imag])
    return out


# ------------------------------------------------------------------ covariances


def grown_covs(steps: int, sigma: Sequence[float], growth: float) -> list[list[list[float]]]:
    """The covariance rule of :func:`frt_client.mixtures.from_trajectories` for ``steps`` steps:
    ``diag((sigma_1 s_k)^2, (sigma_2 s_k)^2)``, ``s_k = 1 + growth k``."""
    s1, s2 = sigma
    out = []
    for k in range(steps):
        scale = 1.0 + growth * k
        out.append([[(s1 * scale) ** 2, 0.0], [0.0, (s2 * scale) ** 2]])
    return out


def _lateral_levers(times: Sequence[float], speeds: Sequence[float]) -> list[float]:
    """``int_0^t v(s) s ds`` at each time, ``v`` linear between the points and at least
    :data:`LATERAL_MIN_SPEED` (Simpson's rule, exact for it)."""
    out, total = [0.0], 0.0
    for i in range(1, len(times)):
        t0, t1 = times[i - 1], times[i]
        v0, v1 = (max(v, LATERAL_MIN_SPEED) for v in (speeds[i - 1], speeds[i]))
        tm, vm = 0.5 * (t0 + t1), 0.5 * (v0 + v1)
        total += (t1 - t0) / 6.0 * (v0 * t0 + 4.0 * vm * tm + v1 * t1)
        out.append(total)
    return out


def gaussian_controls_cov(
    times: Sequence[float],
    position_covs: Sequence[Sequence[Sequence[float]]],
    headings: Sequence[float],
    speeds: Sequence[float],
    floor: Sequence[float] = DEFAULT_FLOOR,
) -> list[list[list[float]]]:
    """Covariances of the controls, one per step, from the position covariances at the points.

    ``times`` are the points' times (s, the first 0); ``position_covs`` their 2x2 covariances of
    (x, y) (m²); ``headings`` and ``speeds`` the path's state at them (:func:`path_controls`'s).
    Step k (to point k + 1 at time t) gets, from the covariance grown since time 0 (per axis
    ``max(var_t - var_0, 0)``, the point's correlation) rotated to (across, along) the heading,
    ``diag(1 / b, 2 / t^2) G diag(1 / b, 2 / t^2) + diag(floor_1^2, floor_2^2)`` with
    ``b = int_0^t v(s) s ds``: the spread of a heading-rate and an acceleration error held since
    time 0 that moves the point as much.
    """
    levers = _lateral_levers(times, speeds)
    (xx0, _), (_, yy0) = position_covs[0]
    f1, f2 = floor
    out = []
    for k in range(1, len(times)):
        (xx, xy), (_, yy) = position_covs[k]
        gx, gy = max(xx - xx0, 0.0), max(yy - yy0, 0.0)
        rho = xy / math.sqrt(xx * yy) if xx > 0 and yy > 0 else 0.0
        gxy = rho * math.sqrt(gx * gy)
        c, s = math.cos(headings[k]), math.sin(headings[k])
        along = c * c * gx + 2 * c * s * gxy + s * s * gy
        across = s * s * gx - 2 * c * s * gxy + c * c * gy
        mixed = -s * c * gx + (c * c - s * s) * gxy + s * c * gy
        a, b = 0.5 * times[k] ** 2, levers[k]
        out.append(
            [
                [across / (b * b) + f1 * f1, mixed / (a * b)],
                [mixed / (a * b), along / (a * a) + f2 * f2],
            ]
        )
    return out


# ------------------------------------------------------------------ one observation


@dataclass
class _Path:
    """One predicted path as read: its times from 0 (s), world positions, probability, position
    covariances (or ``None``), and its own step (s)."""

    where: str
    times: list[float]
    positions: list[list[float]]
    probability: float
    step: float
    covs: list[list[list[float]]] | None = None


@dataclass(frozen=True)
class _Options:
    """How the paths become modes: the arguments of :func:`from_autoware` and
    :func:`from_apollo`."""

    dt: float | None
    horizon: float
    sigma: tuple[float, float]
    growth: float
    floor: tuple[float, float]
    max_modes: int


def _check_times(times: list[float], where: str) -> None:
    if not times:
        raise ValidationError(f"{where}: a path needs points", field=where)
    if times[0] < 0 or any(b <= a for a, b in itertools.pairwise(times)):
        raise ValidationError(f"{where}: times must start at 0 or later and increase", field=where)


def _interpolate_covs(
    times: Sequence[float], covs: Sequence[Sequence[Sequence[float]]], grid: Sequence[float]
) -> list[list[list[float]]]:
    """The covariance matrices at ``grid``, linear in time between ``times`` (held at the ends)."""
    out, i = [], 0
    for t in grid:
        if t <= times[0] or len(times) == 1:
            out.append([list(r) for r in covs[0]])
            continue
        while i < len(times) - 2 and times[i + 1] < t:
            i += 1
        w = min(max((t - times[i]) / (times[i + 1] - times[i]), 0.0), 1.0)
        out.append(
            [[(1 - w) * covs[i][r][c] + w * covs[i + 1][r][c] for c in range(2)] for r in range(2)]
        )
    return out


def _mode(
    path: _Path, start: dict[str, float], dt: float, options: _Options
) -> tuple[list[list[float]], list[list[list[float]]]]:
    """One path's (means, covs) on the grid of ``dt`` from the state ``start``."""
    times, positions, covs = list(path.times), [list(p) for p in path.positions], path.covs
    x, y = start["x"], start["y"]
    if times[0] <= 1e-6:
        ox, oy = positions[0]
        positions = [[px - ox + x, py - oy + y] for px, py in positions]
        times[0] = 0.0
    else:
        times.insert(0, 0.0)
        positions.insert(0, [x, y])
        if covs is not None:
            covs = [covs[0], *covs]
    points = resample(times, positions, dt, options.horizon)
    if len(points) < 2:
        raise ValidationError(
            f"{path.where}: the path ends before its first step of {dt} s", field=path.where
        )
    means = path_controls(points, dt, start["heading"], start["speed"])
    if covs is None:
        return means, grown_covs(len(means), options.sigma, options.growth)
    grid = [k * dt for k in range(len(points))]
    headings, speeds = path_states(points, dt, start["heading"], start["speed"])
    position_covs = _interpolate_covs(times, covs, grid)
    return means, gaussian_controls_cov(grid, position_covs, headings, speeds, options.floor)


def _observation(
    agent_id: str | None,
    start: dict[str, float],
    agent_class: str,
    paths: list[_Path],
    options: _Options,
    radius: float | None,
    where: str,
) -> dict[str, Any]:
    """The observation piece (see the module) of the paths of positive probability."""
    kept = [p for p in paths if p.probability > 0]
    if not kept:
        raise ValidationError(f"{where}: no path with a positive probability", field=where)
    dt = options.dt
    if dt is None:
        best = max(kept, key=lambda p: p.probability)
        if not math.isfinite(best.step):
            raise ValidationError(
                f"{best.where}: one point gives no step; pass dt", field=best.where
            )
        dt = best.step
    if not (isinstance(dt, int | float) and math.isfinite(dt) and dt > 0):
        raise ValidationError(f"dt must be a positive number, got {dt!r}", field="dt")
    modes = [_mode(p, start, float(dt), options) for p in kept]
    steps = max(len(means) for means, _ in modes)
    for means, covs in modes:  # the shorter ones hold their last step
        means += [list(means[-1]) for _ in range(steps - len(means))]
        covs += [[list(r) for r in covs[-1]] for _ in range(steps - len(covs))]
    prediction = from_mixture(
        [math.log(p.probability) for p in kept],
        [means for means, _ in modes],
        [covs for _, covs in modes],
        float(dt),
        options.max_modes,
    )
    piece: dict[str, Any] = {}
    if agent_id is not None:
        piece["agent_id"] = agent_id
    piece.update(state=start, agent_class=agent_class, prediction=prediction)
    if radius is not None:
        piece["config"] = {"collision_radius": radius}
    return piece


def _probability(value: Any, where: str) -> float:
    p = _number(value, where)
    if p < 0:
        raise ValidationError(f"{where}: a probability is not negative, got {p!r}", field=where)
    return p


def _label(value: Any, names: Mapping[int, str], where: str) -> str:
    if isinstance(value, str):
        return value.upper()
    if isinstance(value, int) and not isinstance(value, bool):
        return names.get(value, "UNKNOWN")
    raise ValidationError(f"{where}: expected a number or a name, got {value!r}", field=where)


def _class_of(name: str, classes: Mapping[str, str]) -> str:
    return classes.get(name, classes.get("UNKNOWN", "car"))


def shape_radius(length: float, width: float) -> float:
    """The radius (m) of the circle around a ``length`` x ``width`` box centred on the object: a
    collision radius that holds the whole box wherever the centre is."""
    return 0.5 * math.hypot(length, width)


# ------------------------------------------------------------------ Autoware


def _autoware_id(value: Any) -> str | None:
    if value is None:
        return None
    if isinstance(value, Mapping):
        value = value.get("uuid")
    if isinstance(value, list) and all(isinstance(b, int) and 0 <= b < 256 for b in value):
        return bytes(value).hex() if value else None
    if isinstance(value, str | int) and not isinstance(value, bool):
        return str(value)
    raise ValidationError("object_id: expected the UUID's bytes or text", field="object_id")


def _autoware_class(obj: Mapping[str, Any], classes: Mapping[str, str]) -> str:
    best, best_p = "UNKNOWN", -math.inf
    for i, entry in enumerate(_list(obj, "classification", "")):
        where = f"classification.{i}"
        p = _probability(_get(entry, "probability", where, 1.0), f"{where}.probability")
        label = _label(_get(entry, "label", where), AUTOWARE_LABELS, f"{where}.label")
        if p > best_p:
            best, best_p = label, p
    return _class_of(best, classes)


def _autoware_radius(obj: Mapping[str, Any]) -> float:
    shape = _get(obj, "shape", "")
    kind = _label(_get(shape, "type", "shape", 0), AUTOWARE_SHAPES, "shape.type")
    if kind == "POLYGON":
        where = "shape.footprint.points"
        points = _list(_get(shape, "footprint", "shape"), "points", "shape.footprint")
        radii = [
            math.hypot(_num(p, "x", f"{where}.{i}"), _num(p, "y", f"{where}.{i}"))
            for i, p in enumerate(points)
        ]
        if radii and max(radii) > 0:
            return max(radii)
        raise ValidationError(f"{where}: no points away from the centre", field=where)
    dims = _get(shape, "dimensions", "shape")
    length = _num(dims, "x", "shape.dimensions")
    width = _num(dims, "y", "shape.dimensions", 0.0)
    if length <= 0:
        raise ValidationError("shape.dimensions.x: must be > 0", field="shape.dimensions.x")
    return 0.5 * length if kind == "CYLINDER" else shape_radius(length, width)


def _autoware_state(kinematics: Any) -> dict[str, float]:
    where = "kinematics.initial_pose_with_covariance"
    pose = _get(_get(kinematics, "initial_pose_with_covariance", "kinematics"), "pose", where)
    position = _get(pose, "position", f"{where}.pose")
    yaw = _yaw(_get(pose, "orientation", f"{where}.pose"), f"{where}.pose.orientation")
    twist_at = "kinematics.initial_twist_with_covariance"
    twist = _get(_get(kinematics, "initial_twist_with_covariance", "kinematics", {}), "twist",
                 twist_at, {})  # fmt: skip
    linear = _get(twist, "linear", f"{twist_at}.twist", {})
    vx = _num(linear, "x", f"{twist_at}.twist.linear", 0.0)
    vy = _num(linear, "y", f"{twist_at}.twist.linear", 0.0)
    c, s = math.cos(yaw), math.sin(yaw)
    x = _num(position, "x", f"{where}.pose.position")
    y = _num(position, "y", f"{where}.pose.position")
    return _state(x, y, yaw, c * vx - s * vy, s * vx + c * vy)


def _autoware_paths(kinematics: Any) -> list[_Path]:
    out = []
    for i, raw in enumerate(_list(kinematics, "predicted_paths", "kinematics")):
        where = f"kinematics.predicted_paths.{i}"
        step = _seconds(_get(raw, "time_step", where), f"{where}.time_step")
        if step <= 0:
            raise ValidationError(f"{where}.time_step: must be > 0", field=f"{where}.time_step")
        positions = []
        for k, pose in enumerate(_list(raw, "path", where)):
            at = f"{where}.path.{k}.position"
            position = _get(pose, "position", f"{where}.path.{k}")
            positions.append([_num(position, "x", at), _num(position, "y", at)])
        if not positions:
            raise ValidationError(f"{where}.path: no poses", field=f"{where}.path")
        probability = _probability(_get(raw, "confidence", where, 1.0), f"{where}.confidence")
        times = [k * step for k in range(len(positions))]
        out.append(_Path(where, times, positions, probability, step))
    return out


def from_autoware(
    obj: Any,
    *,
    dt: float | None = None,
    horizon: float = HORIZON_S,
    sigma: tuple[float, float] = DEFAULT_SIGMA,
    growth: float = DEFAULT_GROWTH,
    classes: Mapping[str, str] = AUTOWARE_CLASSES,
    radius_from_shape: bool = False,
    max_modes: int = MAX_MODES,
) -> dict[str, Any]:
    """An Autoware ``PredictedObject`` as an observation piece (see the module).

    Args:
        obj: the message, as a mapping or a :class:`PredictedObject`.
        dt: the prediction's step (s); default the most confident path's ``time_step``.
        horizon: the last time (s) of the paths that is used.
        sigma, growth: the covariance rule (:func:`grown_covs`).
        classes: label name -> agent class.
        radius_from_shape: add ``config.collision_radius`` from ``shape``: the circle around the
            box (:func:`shape_radius`), the cylinder or the footprint polygon.
        max_modes: keep the most confident this many paths.
    """
    msg = _message(obj)
    kinematics = _get(msg, "kinematics", "")
    return _observation(
        _autoware_id(_get(msg, "object_id", "", None)),
        _autoware_state(kinematics),
        _autoware_class(msg, classes),
        _autoware_paths(kinematics),
        _Options(dt, horizon, sigma, growth, DEFAULT_FLOOR, max_modes),
        _autoware_radius(msg) if radius_from_shape else None,
        "kinematics.predicted_paths",
    )


# ------------------------------------------------------------------ Apollo


def _apollo_cov(info: Any, where: str) -> list[list[float]] | None:
    if info is None:
        return None
    sx = _num(info, "sigma_x", where, 0.0)
    sy = _num(info, "sigma_y", where, 0.0)
    rho = _num(info, "correlation", where, 0.0)
    if sx < 0 or sy < 0 or abs(rho) > 1:
        raise ValidationError(f"{where}: sigmas must be >= 0 and |correlation| <= 1", field=where)
    return [[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]


def _apollo_path(raw: Any, where: str, use_gaussian: bool) -> _Path:
    times, positions, covs = [], [], []
    for k, point in enumerate(_list(raw, "trajectory_point", where)):
        at = f"{where}.trajectory_point.{k}"
        path_point = _get(point, "path_point", at)
        positions.append([_num(path_point, "x", f"{at}.path_point"),
                          _num(path_point, "y", f"{at}.path_point")])  # fmt: skip
        times.append(_num(point, "relative_time", at, 0.0))
        covs.append(_apollo_cov(_get(point, "gaussian_info", at, None), f"{at}.gaussian_info"))
    _check_times(times, f"{where}.trajectory_point")
    probability = _probability(_get(raw, "probability", where, 1.0), f"{where}.probability")
    gaps = sorted(b - a for a, b in itertools.pairwise(times))
    step = gaps[len(gaps) // 2] if gaps else math.nan  # the median spacing
    informed = use_gaussian and any(c is not None and (c[0][0] > 0 or c[1][1] > 0) for c in covs)
    zero = [[0.0, 0.0], [0.0, 0.0]]
    path_covs = [c if c is not None else zero for c in covs] if informed else None
    return _Path(where, times, positions, probability, step, path_covs)


def from_apollo(
    obstacle: Any,
    *,
    dt: float | None = None,
    horizon: float = HORIZON_S,
    use_gaussian: bool = True,
    floor: tuple[float, float] = DEFAULT_FLOOR,
    sigma: tuple[float, float] = DEFAULT_SIGMA,
    growth: float = DEFAULT_GROWTH,
    classes: Mapping[str, str] = APOLLO_CLASSES,
    radius_from_shape: bool = False,
    max_modes: int = MAX_MODES,
) -> dict[str, Any]:
    """An Apollo ``PredictionObstacle`` as an observation piece (see the module).

    Args:
        obstacle: the message, as a mapping or a :class:`PredictionObstacle`.
        dt: the prediction's step (s); default the median step of the most probable trajectory.
        horizon: the last time (s) of the trajectories that is used.
        use_gaussian: covariances from ``gaussian_info`` (:func:`gaussian_controls_cov`, plus
            ``floor``); without it, or for a trajectory without it, the rule of ``sigma`` and
            ``growth`` (:func:`grown_covs`).
        classes: type name -> agent class.
        radius_from_shape: add ``config.collision_radius``: the circle around the
            ``length`` x ``width`` box (:func:`shape_radius`).
        max_modes: keep the most probable this many trajectories.
    """
    msg = _message(obstacle)
    where = "perception_obstacle"
    obs = _get(msg, "perception_obstacle", "")
    position = _get(obs, "position", where)
    velocity = _get(obs, "velocity", where, {})
    start = _state(
        _num(position, "x", f"{where}.position"),
        _num(position, "y", f"{where}.position"),
        _num(obs, "theta", where, 0.0),
        _num(velocity, "x", f"{where}.velocity", 0.0),
        _num(velocity, "y", f"{where}.velocity", 0.0),
    )
    kind = _label(_get(obs, "type", where, 0), APOLLO_TYPES, f"{where}.type")
    if _get(obs, "sub_type", where, 0) in APOLLO_MOTORCYCLIST:
        kind = "ST_MOTORCYCLIST"
    radius = None
    if radius_from_shape:
        length, width = _num(obs, "length", where, 0.0), _num(obs, "width", where, 0.0)
        if length <= 0 or width < 0:
            raise ValidationError(f"{where}.length: must be > 0", field=f"{where}.length")
        radius = shape_radius(length, width)
    paths = [
        _apollo_path(raw, f"trajectory.{i}", use_gaussian)
        for i, raw in enumerate(_list(msg, "trajectory", ""))
    ]
    object_id = _get(obs, "id", where, None)
    return _observation(
        None if object_id is None else str(object_id),
        start,
        _class_of(kind, classes),
        paths,
        _Options(dt, horizon, sigma, growth, floor, max_modes),
        radius,
        "trajectory",
    )
