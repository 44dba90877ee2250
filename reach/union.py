"""The union of several FRT sets of one human: the set of a multi-modal prediction.

Each member is a set the engine built for one mode's control bounds (``FRTEngine.exact`` or
``FRTEngine.conservative``), all from the same pose; a position is in the union when it is in some
member, so K, every slice, interval and tube of the union is the union of the members'. Each
member contains the reachable set of its mode's bounds, so the union contains the reachable set of
every member's mode: the union of certified sets is certified.

Clearance: where the members measure distances to their drawn tubes (the exact sets), the union
does too, to the union of the members' tubes: outside K that is the minimum of the members'
distances, and inside it is at most that minimum (the depth in the union is at least the depth in
any member). Otherwise (the conservative box sets) it is the minimum of the members' clearances,
which has the same sign everywhere.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from reach.box_tubes import box_tubes_of
from reach.engine import FRTEngine
from reach.frames import Pose
from reach.outer_bound import outer_boxes
from reach.sets import BoxTubeSet, FRTSet


class UnionSet(FRTSet):
    """The union of ``members`` (same pose, slices and horizon)."""

    def __init__(self, members: Sequence[FRTSet]) -> None:
        if not members:
            raise ValueError("a union needs at least one member")
        first = members[0]
        for m in members[1:]:
            same = (m.pose, m.slice_dt, m.horizon_s, m.n_slices)
            if same != (first.pose, first.slice_dt, first.horizon_s, first.n_slices):
                raise ValueError("the members of a union must share pose, slices and horizon")
        super().__init__(
            first.pose,
            first.slice_dt,
            first.horizon_s,
            first.n_slices,
            conservative=any(m.conservative for m in members),
        )
        self.members = tuple(members)
        self.evaluations = sum(m.evaluations for m in members)
        self.clearance_from_tubes = all(m.clearance_from_tubes for m in members)
        self._tubes: dict[int, BaseGeometry] = {}

    def _union(self, parts: list[BaseGeometry]) -> BaseGeometry:
        return parts[0] if len(parts) == 1 else shapely.union_all(parts)

    def tube(self, j: int) -> BaseGeometry:
        cached = self._tubes.get(j)
        if cached is None:
            cached = self._union([m.tube(j) for m in self.members])
            self._tubes[j] = cached
        return cached

    def slice(self, j: int) -> BaseGeometry:
        return self._union([m.slice(j) for m in self.members])

    def interval(self, j: int) -> BaseGeometry:
        return self._union([m.interval(j) for m in self.members])

    def clearance(self, xy_world: np.ndarray, t_rel: np.ndarray | None = None) -> np.ndarray:
        if self.clearance_from_tubes:
            return super().clearance(xy_world, t_rel)
        distances = [np.asarray(m.clearance(xy_world, t_rel)) for m in self.members]
        return np.min(np.stack(distances), axis=0)

    def missing_tubes(self, indices: list[int]) -> list[int]:
        if not self.clearance_from_tubes:
            return []
        return [j for j in dict.fromkeys(indices) if j not in self._tubes]

    def nearest_built_tube(self, j: int) -> int:
        if not self.clearance_from_tubes:
            return j
        built = [k for k in self._tubes if k >= j]
        return min(built) if built else self.n_slices - 1


def box_members(frt: FRTSet) -> list[BoxTubeSet]:
    """The box sets whose least distance at each point is ``frt``'s clearance there: ``frt``
    itself if it is one, a union's members if they all are (it measures by its members), else
    none."""
    if isinstance(frt, BoxTubeSet):
        return [frt]
    if isinstance(frt, UnionSet) and not frt.clearance_from_tubes:
        members = list(frt.members)
        if members and all(isinstance(m, BoxTubeSet) for m in members):
            return members  # type: ignore[return-value]
    return []


def exact_union(engine: FRTEngine, pose: Pose, v_start: float, bounds: np.ndarray) -> UnionSet:
    """The engine's exact set of each row of ``bounds`` [M, 8] (uncut by the notch stages), as one
    union whose whole-horizon tube is drawn (collision checks need it first)."""
    members = [engine.exact(pose, v_start, b, notch_cut=False) for b in np.asarray(bounds)]
    union = UnionSet(members)
    union.tube(union.n_slices - 1)
    return union


def conservative_union(
    engine: FRTEngine, pose: Pose, v_start: float, bounds: np.ndarray
) -> UnionSet:
    """The engine's conservative set of each row of ``bounds`` [M, 8], as one union: it contains
    :func:`exact_union` of the same bounds, member by member."""
    (union,) = conservative_sets(engine, [pose], [v_start], [np.asarray(bounds).reshape(-1, 8)])
    return union  # type: ignore[return-value]


@dataclass(frozen=True)
class SettingRows:
    """Settings whose conservative sets are to be built: their rows of bounds one after the other
    (``bounds`` [R, 8], each row's pose and speed), and per setting whether it is a union of
    rows (bounds given as rows [M, 8]) and how many."""

    poses: list[Pose]
    v_starts: np.ndarray
    bounds: np.ndarray
    unions: list[bool]
    counts: list[int]

    @classmethod
    def of(
        cls, poses: Sequence[Pose], v_starts: Sequence[float], bounds: Sequence[np.ndarray]
    ) -> SettingRows:
        rows = [np.asarray(b, dtype=np.float64) for b in bounds]
        counts = [1 if r.ndim == 1 else len(r) for r in rows]
        return cls(
            poses=[pose for pose, c in zip(poses, counts, strict=True) for _ in range(c)],
            v_starts=np.array([v for v, c in zip(v_starts, counts, strict=True) for _ in range(c)]),
            bounds=np.concatenate([r.reshape(-1, 8) for r in rows]),
            unions=[r.ndim != 1 for r in rows],
            counts=counts,
        )

    def sweeps(self, engine: FRTEngine, rows: slice = slice(None)) -> np.ndarray:
        """The outer bounds' sweep boxes [R, steps, 4] of ``rows`` (every row by default;
        ``outer_boxes``: compiled, free of the GIL, so other threads may run it, each row by
        the same operations whatever the others)."""
        return outer_boxes(
            self.v_starts[rows],
            self.bounds[rows],
            engine.horizon,
            engine.outer_steps,
            8,
            engine.initial_set,
        )

    def sets(self, engine: FRTEngine, sweeps: np.ndarray) -> list[FRTSet]:
        """Each setting's conservative set from its rows' ``sweeps``."""
        tubes = box_tubes_of(engine, self.poses, sweeps)
        out: list[FRTSet] = []
        start = 0
        for union, c in zip(self.unions, self.counts, strict=True):
            members = tubes[start : start + c]
            out.append(UnionSet(members) if union else members[0])
            start += c
        return out


def conservative_sets(
    engine: FRTEngine,
    poses: Sequence[Pose],
    v_starts: Sequence[float],
    bounds: Sequence[np.ndarray],
) -> list[FRTSet]:
    """The conservative set of each setting: for one row of bounds [8] its box tube
    (``FRTEngine.conservative``), for rows [M, 8] the union of theirs (:func:`conservative_union`);
    the outer bounds of every row of every setting propagated together (``reach.box_tubes``)."""
    rows = SettingRows.of(poses, v_starts, bounds)
    return rows.sets(engine, rows.sweeps(engine))
