"""What one collision check measures: its trajectories' points, flattened into one array, or the
discs covering the ego's footprint at each point (``reach.footprint``), and the way back from the
distances of those probes to per-point distances and per-trajectory answers.

Every trajectory of a check, every point and every disc go through the sets' clearance in one
call per agent; per trajectory, the minimum clearance and the first colliding point come from
segment reductions over the flattened rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from reach.batch import trajectory_reductions
from reach.footprint import DiscCover, disc_centres, disc_cover, footprint_distances
from service.wire.batch_body import ColumnBatch, packed_batch
from service.wire.errors import FieldError
from service.wire.limits import RequestLimits, check_length, check_trajectory
from service.wire.schemas import CollisionCheckRequest, TrajectoryColumns, TrajectoryPoint


@dataclass(frozen=True)
class CheckPoints:
    """The points of a check's trajectories, flattened in order (``starts[k]``: trajectory k's
    first row), and what is measured at them: the points, or their footprints' discs."""

    xy: np.ndarray
    times: np.ndarray
    starts: np.ndarray
    cover: DiscCover | None
    batch: bool
    headings: np.ndarray | None = None
    #: The request's field that holds the points (errors about them name it).
    field: str = "trajectory"

    @property
    def n_points(self) -> int:
        return len(self.times)

    @property
    def n_probes(self) -> int:
        """Where distances are measured: the points, or their footprints' discs."""
        return self.n_points * (1 if self.cover is None else self.cover.count)

    @property
    def probe_xy(self) -> np.ndarray:
        """Where distances to the sets are measured: ``[points * discs, 2]``."""
        if self.cover is None:
            return self.xy
        assert self.headings is not None
        return disc_centres(self.xy, self.headings, self.cover)

    @property
    def probe_times(self) -> np.ndarray:
        return self.times if self.cover is None else np.repeat(self.times, self.cover.count)

    def thresholds(self, radii: np.ndarray) -> np.ndarray:
        """The distance to K below which a probe collides, per agent of R_col ``radii``."""
        return radii if self.cover is None else radii + self.cover.radius

    def point_distances(self, probe_distances: np.ndarray) -> np.ndarray:
        """Distances ``[..., points]`` of each point (its footprint: a lower bound) to the set,
        from those of the probes."""
        if self.cover is None:
            return probe_distances
        return footprint_distances(probe_distances, self.cover)


def check_points(request: CollisionCheckRequest, limits: RequestLimits) -> CheckPoints:
    """The points of ``request`` (its ``trajectory`` or its ``trajectories``), checked against the
    server's limits and, with a footprint, for a heading at every point: 422 naming the field."""
    if isinstance(request.trajectories, ColumnBatch):
        return _batch_points(request, request.trajectories, limits)
    if request.packed_trajectories is not None:
        packed = packed_batch(request.packed_trajectories)
        return _batch_points(request, packed, limits, "packed_trajectories")
    if request.trajectories is not None:
        field, parts = "trajectories", list(request.trajectories)
        check_length(field, parts, limits.max_trajectories)
    else:
        field, parts = "trajectory", [request.trajectory]
    columns = [
        _columns(f"{field}.{k}" if request.trajectories else field, p, limits)
        for k, p in enumerate(parts)
    ]
    lengths = np.array([len(c[0]) for c in columns])
    cover = _cover(request, field, int(lengths.sum()), limits)
    headings = None
    if cover is not None:
        headings = np.concatenate(
            [
                _headings(field, k, c, request.trajectories is not None)
                for k, c in enumerate(columns)
            ]
        )
    return CheckPoints(
        xy=np.stack(
            [np.concatenate([c[1] for c in columns]), np.concatenate([c[2] for c in columns])],
            axis=1,
        ),
        times=np.concatenate([c[0] for c in columns]),
        starts=np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.intp),
        cover=cover,
        batch=request.trajectories is not None,
        headings=headings,
        field=field,
    )


def _batch_points(
    request: CollisionCheckRequest,
    batch: ColumnBatch,
    limits: RequestLimits,
    field: str = "trajectories",
) -> CheckPoints:
    """:func:`check_points` of a batch read in bulk: the same checks on its flat columns, in the
    same order, naming the same fields (of ``packed_trajectories``: its ``lengths`` and
    ``heading``)."""
    check_length(field, batch, limits.max_trajectories)
    packed = field == "packed_trajectories"
    too_long = np.flatnonzero(batch.lengths > limits.max_trajectory_points)
    if len(too_long):
        k = int(too_long[0])
        where = f"{field}.lengths.{k}" if packed else f"{field}.{k}"
        check_trajectory(where, batch.t[: batch.lengths[k]], limits)
    cover = _cover(request, field, len(batch.t), limits)
    headings = None
    if cover is not None:
        unheaded = np.flatnonzero(~batch.headed)
        if len(unheaded):
            raise FieldError(
                f"{field}.heading" if packed else f"{field}.{int(unheaded[0])}.heading",
                "a footprint needs a heading at every point",
            )
        headings = batch.heading
    return CheckPoints(
        xy=np.stack([batch.x, batch.y], axis=1),
        times=batch.t,
        starts=batch.starts,
        cover=cover,
        batch=True,
        headings=headings,
        field=field,
    )


def _cover(
    request: CollisionCheckRequest, field: str, total: int, limits: RequestLimits
) -> DiscCover | None:
    """The footprint's disc cover (None without one), once the ``total`` points, with their
    discs, are known to be within what one check may measure."""
    cover = None
    if request.footprint is not None:
        fp = request.footprint
        cover = disc_cover(fp.length, fp.width, fp.rear_axle_to_center)
    probes = total * (1 if cover is None else cover.count)
    if probes > limits.max_check_points:
        raise FieldError(
            field,
            f"{total} points{'' if cover is None else f' x {cover.count} footprint discs'} "
            f"exceed the {limits.max_check_points} one check may measure",
        )
    return cover


Columns = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | list[float | None] | None]


def _columns(field: str, part: Any, limits: RequestLimits) -> Columns:
    """(t, x, y, heading) of one trajectory in either form."""
    check_trajectory(field, part.t if isinstance(part, TrajectoryColumns) else part, limits)
    if isinstance(part, TrajectoryColumns):
        return (
            np.asarray(part.t, dtype=np.float64),
            np.asarray(part.x, dtype=np.float64),
            np.asarray(part.y, dtype=np.float64),
            part.heading,
        )
    points: list[TrajectoryPoint] = part
    return (
        np.array([p.t for p in points], dtype=np.float64),
        np.array([p.x for p in points], dtype=np.float64),
        np.array([p.y for p in points], dtype=np.float64),
        [p.heading for p in points],
    )


def _headings(field: str, k: int, columns: Columns, batch: bool) -> np.ndarray:
    where = f"{field}.{k}" if batch else field
    heading = columns[3]
    if isinstance(heading, np.ndarray):
        return heading
    if heading is None:
        raise FieldError(f"{where}.heading", "a footprint needs a heading at every point")
    missing = [i for i, h in enumerate(heading) if h is None]
    if missing:
        raise FieldError(
            f"{where}.{missing[0]}.heading", "a footprint needs a heading at every point"
        )
    return np.asarray(heading, dtype=np.float64)


@dataclass(frozen=True)
class BatchAnswers:
    """A batch's answers per agent, whether any of its points is in C and its least clearance;
    the answers are the response's ``field``: ``trajectories`` (an entry per trajectory) or
    ``trajectory_columns`` (a list per entry field)."""

    answers: list[Any]
    colliding: list[bool]
    least: np.ndarray
    field: str = "trajectories"


def batch_answers(
    probed: Sequence[np.ndarray],
    points: CheckPoints,
    radii: np.ndarray,
    request: CollisionCheckRequest,
    limit: float,
) -> BatchAnswers:
    """Per agent, per trajectory: ``{collision, first_collision_index, first_collision_time,
    min_clearance}`` (and ``clearance`` per point with ``include_clearance``), as entries or, with
    ``answer_columns``, as columns, from each agent's probe distances to K, the clearances to C
    being those of ``clearance_rows`` (R_col ``radii``, clipped to +-``limit``). Without per-point
    clearances the reductions are made in one compiled pass per agent
    (``reach.batch.trajectory_reductions``, the same arithmetic)."""
    if not len(probed):
        return BatchAnswers([], [], np.zeros(0))
    per_point = None
    if request.include_clearance:
        per_point = _clearances(np.stack(probed), points, radii, limit)
        least = np.minimum.reduceat(per_point, points.starts, axis=1)
        rows = np.arange(points.n_points)
        first = np.minimum.reduceat(
            np.where(per_point < 0.0, rows[None, :], points.n_points), points.starts, axis=1
        )
    else:
        group = 1 if points.cover is None else points.cover.count
        offset = 0.0 if points.cover is None else points.cover.radius
        reduced = [
            trajectory_reductions(d, points.starts, group, offset, float(r), limit)
            for d, r in zip(probed, radii.tolist(), strict=True)
        ]
        least = np.stack([r[0] for r in reduced])
        first = np.stack([r[1] for r in reduced])
    colliding = (first < points.n_points).any(axis=1).tolist()
    if request.answer_columns:
        columns = _columns_of(least, first, points, per_point)
        return BatchAnswers(columns, colliding, least.min(axis=1), "trajectory_columns")
    return BatchAnswers(_entries(least, first, points, per_point), colliding, least.min(axis=1))


def _columns_of(
    least: np.ndarray, first: np.ndarray, points: CheckPoints, per_point: np.ndarray | None
) -> list[dict[str, Any]]:
    """:func:`_entries` as columns: per agent a list per field, item k trajectory k's."""
    starts = points.starts
    ends = np.append(starts[1:], points.n_points)
    hit = first < ends[None, :]
    index, time = _first_collisions(hit, first, points)
    collision, minimum = hit.tolist(), least.tolist()
    answers = []
    for a in range(len(minimum)):
        agent: dict[str, Any] = {
            "collision": collision[a],
            "first_collision_index": index[a],
            "first_collision_time": time[a],
            "min_clearance": minimum[a],
        }
        if per_point is not None:
            values = per_point[a].tolist()
            spans = zip(starts.tolist(), ends.tolist(), strict=True)
            agent["clearance"] = [values[b:e] for b, e in spans]
        answers.append(agent)
    return answers


def _first_collisions(
    hit: np.ndarray, first: np.ndarray, points: CheckPoints
) -> tuple[list[list[int | None]], list[list[float | None]]]:
    """Per agent, per trajectory, the index within it and the time of its first colliding point
    (None for those that do not collide), from the rows ``first`` ([agents, trajectories])
    where ``hit``."""
    agents, count = hit.shape
    index: list[list[int | None]] = [[None] * count for _ in range(agents)]
    time: list[list[float | None]] = [[None] * count for _ in range(agents)]
    # Only the colliding trajectories carry an index and a time: filled in where they are.
    rows, columns = np.nonzero(hit)
    at = first[rows, columns]
    for a, k, i, t in zip(
        rows.tolist(),
        columns.tolist(),
        (at - points.starts[columns]).tolist(),
        points.times[at].tolist(),
        strict=True,
    ):
        index[a][k], time[a][k] = i, t
    return index, time


def _clearances(
    probed: np.ndarray, points: CheckPoints, radii: np.ndarray, limit: float
) -> np.ndarray:
    """Clearances ``[A, points]`` to C of the probe distances ``[A, probes]``, as
    ``service.flows.checks.clearance_rows`` takes them."""
    distance = points.point_distances(probed) - radii[:, None]
    distance = np.where(np.isnan(distance), -limit, distance)
    return np.clip(distance, -limit, limit)


def _entries(
    least: np.ndarray, first: np.ndarray, points: CheckPoints, per_point: np.ndarray | None
) -> list[list[dict[str, Any]]]:
    """The entries per agent from each trajectory's least clearance and its first colliding row
    (``points.n_points`` if none), with each one's clearances from ``per_point`` if given:
    :func:`_columns_of`, one dict per trajectory."""
    answers = []
    for columns in _columns_of(least, first, points, per_point):
        fields = list(columns)
        rows = zip(*columns.values(), strict=True)
        answers.append([dict(zip(fields, row, strict=True)) for row in rows])
    return answers


def check_work(points: CheckPoints, agents: int, limits: RequestLimits) -> None:
    """422 if measuring ``points`` against ``agents`` agents exceeds what one check may do."""
    probes = points.n_probes
    if probes * agents > limits.max_check_work:
        raise FieldError(
            points.field,
            f"{probes} points against {agents} agents exceed the {limits.max_check_work} "
            "point-agent pairs one check may measure: check fewer agents or trajectories",
        )
