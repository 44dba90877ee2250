"""A set cut by the road: the assumption "the human stays on the drivable area", and with it
"the human keeps to the lanes it can reach" (``reach.lanes``), one cut for any such region.

The assumption: the human's position stays in R = (D ⊕ margin) ∪ (the plane outside the map's
extent) over the whole horizon (``reach.road_map``). The certified statement becomes: every set
served holds every position that a trajectory of the dynamics under the bounds *which keeps to R*
reaches. Cut from an inner set that holds every trajectory's positions:

* tube j: a trajectory keeping to R stays, over [0, s_j], inside tube_j ∩ R, and its path there is
  connected and starts in the initial set (slice 0); so its positions lie in the connected
  components of tube_j ∩ R that meet slice_0 ∩ R, and the cut tube keeps only those (a component
  of R that the set reaches only across the off-road is dropped: the oncoming carriageway beyond a
  kerb, a parallel street behind a building). Components touching along an edge or at a point are
  one component; a part where they only touch is kept as a thin polygon (1 µm);
* slice j (the set at s_j) and interval j (over [s_(j-1), s_j]): the inner one ∩ the cut tube j,
  which holds every such position at or before s_j.

Each cut set is inside its inner set. Where the human's observed position is not in R, the
assumption is already broken: the caller serves the inner set (``RoadMap.on_road``).

The same cut holds for any region a trajectory respecting an assumption keeps its position in:
:func:`lane_cut` cuts to R ∩ L, L the region of the lanes the human can reach from the lanes
holding it (``reach.lanes``), and answers None where that assumption does not apply (no lane of
its direction holds the human): the caller serves the set cut to R alone, or uncut off R.

The assumption ``speed_limit`` (``reach.speed_limit``) cuts each tube j to a disc of radius
ρ(s_j) about the observed position, alone or with a region (:func:`assumption_cut`,
``CutSet(inner, region, discs=...)``): a trajectory keeping both stays in region ∩ disc_j over
[0, s_j], so the components of tube_j ∩ region ∩ disc_j meeting the start hold its positions.

R is read once per set, in the human frame, around the bounding box of the inner set's whole
horizon (its outer bound's boxes where it has them); a geometry reaching past that box rebuilds it
around both, so nothing is cut for want of map.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry, BaseMultipartGeometry

from reach.contract import INITIAL_SET, U2_LIMIT
from reach.frames import Pose, covers_box
from reach.lanes import (
    DRIVABLE_AREA,
    HEADING_TOLERANCE,
    REACHABLE_LANES,
    VEHICLE_LANE_TYPES,
    LaneRegion,
)
from reach.road_map import DrivableRegion, RoadMap, cut_to, region_in_frame, world_box
from reach.sets import BoxTubeSet, FRTSet
from reach.speed_limit import DEFAULT_FACTOR, SPEED_LIMIT, ReachDiscs, reach_radii

__all__ = [
    "DRIVABLE_AREA",
    "SPEED_LIMIT",
    "CutSet",
    "assumption_cut",
    "connected_to",
    "extent",
    "lane_cut",
    "observation_box",
    "speed_discs",
]

#: Lower-dimensional parts of a cut (where a set and R only touch) are kept grown by this (m).
THIN_PART_M = 1e-6
#: R is read this far (m) around the box it is read for, so small overshoots do not rebuild it.
REGION_PAD_M = 5.0


def extent(frt: FRTSet) -> tuple[float, float, float, float]:
    """A box (x0, y0, x1, y1) in the human frame holding the set's whole-horizon tube: its outer
    bound's boxes where it has them (a box set, an exact set's ``outer``, a union's members),
    else the tube's bounds."""
    boxes = _boxes(frt)
    if boxes is not None:
        lo, hi = boxes.min(axis=0).tolist(), boxes.max(axis=0).tolist()
        return (lo[0], lo[2], hi[1], hi[3])
    return tuple(float(v) for v in frt.tube(frt.n_slices - 1).bounds)  # type: ignore[return-value]


def padded_extent(frt: FRTSet) -> tuple[float, float, float, float]:
    """:func:`extent` grown by ``REGION_PAD_M``: the box a set's region is read around."""
    x0, y0, x1, y1 = extent(frt)
    pad = REGION_PAD_M
    return (x0 - pad, y0 - pad, x1 + pad, y1 + pad)


def lane_cut(
    inner: FRTSet,
    road: RoadMap,
    margin: float,
    drivable: bool = True,
    lane_types: tuple[str, ...] = VEHICLE_LANE_TYPES,
    tolerance: float = HEADING_TOLERANCE,
) -> CutSet | None:
    """``inner`` cut to the lanes its agent reaches within the box its region is read around
    (``reach.lanes``: R ∩ L if ``drivable``, else L); None where the assumption does not apply
    (no start lane holds the agent: answer without it)."""
    box = padded_extent(inner)
    region = road.lane_region(
        inner.pose, world_box(inner.pose, box), margin, drivable, lane_types, tolerance
    )
    return None if region is None else CutSet(inner, region, box=box)


def speed_discs(
    inner: FRTSet,
    road: RoadMap,
    margin: float,
    speed: tuple[float, np.ndarray],
    factor: float = DEFAULT_FACTOR,
    box: tuple[float, float, float, float] | None = None,
) -> ReachDiscs | None:
    """The discs of the ``speed_limit`` assumption (``reach.speed_limit``) for ``inner``, set of
    a car observed at speed v_start under acceleration bounds ``bounds`` (``speed`` = (v_start,
    bounds)): v_cap from the lanes it reaches within the box its region is read around (``box``,
    :func:`padded_extent` of ``inner`` unless given); None where there is no v_cap or v_start
    exceeds it (the car breaks the assumption already)."""
    v_start, bounds = speed
    box = padded_extent(inner) if box is None else box
    v_cap = road.speed_cap(inner.pose, world_box(inner.pose, box), margin, factor)
    if v_cap is None or v_start > v_cap:
        return None
    radii = reach_radii(v_start, bounds, v_cap, inner.slice_dt, inner.n_slices, inner.horizon_s)
    return ReachDiscs(v_cap, radii)


def observation_box(
    pose: Pose, v_start: float, horizon: float, accel_max: float = U2_LIMIT
) -> tuple[float, float, float, float]:
    """A map-frame box holding the box every set of a car observed at ``pose`` and speed
    ``v_start`` is read around (:func:`padded_extent`), whatever its acceleration bounds within
    ±``accel_max``: the outer bound's speed is at most v_start + e_v + accel_max·t (one grid
    step more, at most accel_max·horizon/480 m/s), so its boxes lie within
    r₀ + (v_start + e_v)·T + accel_max·T²/2 of the position, plus 1 m for the grid and
    ``REGION_PAD_M``. For testing ``speed_limit`` at an observation, before the set is built."""
    m, t = INITIAL_SET, horizon
    half = m.radius_m + (v_start + m.speed_margin_mps) * t + accel_max * t * t / 2.0
    half += 1.0 + REGION_PAD_M
    return world_box(pose, (-half, -half, half, half))


def assumption_cut(
    inner: FRTSet,
    road: RoadMap,
    margin: float,
    assumptions: tuple[str, ...],
    speed: tuple[float, np.ndarray] | None = None,
    factor: float = DEFAULT_FACTOR,
) -> CutSet | None:
    """``inner`` cut by the map ``assumptions`` that apply to it: the region R for
    ``drivable_area``, R ∩ L with ``reachable_lanes`` too, L for ``reachable_lanes`` alone (R
    alone, or nothing, where the lanes do not apply: :func:`lane_cut`), with the discs of
    ``speed_limit`` where ``speed`` (v_start, bounds) is given and they apply
    (:func:`speed_discs`); None where nothing applies. The set lists what cut it."""
    box = padded_extent(inner)
    drivable = DRIVABLE_AREA in assumptions
    region: DrivableRegion | LaneRegion | None = None
    if REACHABLE_LANES in assumptions:
        world = world_box(inner.pose, box)
        region = road.lane_region(inner.pose, world, margin, drivable)
    if region is None and drivable:
        region = road.region(margin)
    discs = None
    if SPEED_LIMIT in assumptions and speed is not None:
        discs = speed_discs(inner, road, margin, speed, factor, box)
    if region is None and discs is None:
        return None
    return CutSet(inner, region, box=box, discs=discs)


def _boxes(frt: Any) -> np.ndarray | None:
    """[M, 4] boxes (x_lo, x_hi, y_lo, y_hi) whose union holds the set, if it has them."""
    if isinstance(frt, BoxTubeSet):
        return frt.boxes
    outer = getattr(frt, "outer", None)
    if isinstance(outer, BoxTubeSet):
        return outer.boxes
    members = getattr(frt, "members", None)
    if members:
        found = [_boxes(m) for m in members]
        if all(b is not None for b in found):
            return np.vstack(found)  # type: ignore[arg-type]
    return None


class CutSet(FRTSet):
    """``inner`` cut by a region (see the module): tubes, slices and intervals in the human frame,
    each drawn on first use and kept. Clearances measure to the cut tubes.

    The region is a map's R for ``margin`` (``road`` a ``RoadMap``) or any region read the same
    way (``road`` a ``DrivableRegion`` or ``reach.lanes.LaneRegion``, ``margin`` unused), or the
    whole plane (``road`` None). With ``discs`` (``reach.speed_limit``) each tube is cut to its
    disc as well: a trajectory keeping both assumptions stays in region ∩ disc j over [0, s_j],
    so its positions lie in the components of tube_j ∩ region ∩ disc_j that meet the start. The
    set lists the region's assumptions, then ``speed_limit`` with discs. ``box`` is
    :func:`padded_extent` of ``inner``, given where the caller has it."""

    clearance_from_tubes = True

    def __init__(
        self,
        inner: FRTSet,
        road: RoadMap | DrivableRegion | LaneRegion | None,
        margin: float = 0.0,
        box: tuple[float, float, float, float] | None = None,
        discs: ReachDiscs | None = None,
    ) -> None:
        super().__init__(
            inner.pose, inner.slice_dt, inner.horizon_s, inner.n_slices, inner.conservative
        )
        self.inner = inner
        self.source = road.region(margin) if isinstance(road, RoadMap) else road
        self.discs = discs
        named = () if self.source is None else self.source.assumptions
        self.assumptions: tuple[str, ...] = named + (() if discs is None else (SPEED_LIMIT,))
        self.notch = inner.notch
        self.notch_possible = inner.notch_possible
        self.evaluations = inner.evaluations
        self._tubes: dict[int, BaseGeometry] = {}
        self._slices: dict[int, BaseGeometry] = {}
        self._intervals: dict[int, BaseGeometry] = {}
        self._lock = threading.Lock()
        self._box = padded_extent(inner) if box is None else box
        self._region = (
            None if self.source is None else region_in_frame(self.source, inner.pose, self._box)
        )
        self._start: BaseGeometry | None = None

    def region_for(self, geometry: BaseGeometry) -> BaseGeometry | None:
        """R (human frame) around ``geometry``: the set's region, rebuilt around both if the
        geometry reaches past its box; None for the whole plane."""
        bounds = geometry.bounds
        with self._lock:
            if self.source is None:
                return None
            if not geometry.is_empty and not covers_box(self._box, bounds):
                pad = REGION_PAD_M
                self._box = (
                    min(self._box[0], bounds[0] - pad),
                    min(self._box[1], bounds[1] - pad),
                    max(self._box[2], bounds[2] + pad),
                    max(self._box[3], bounds[3] + pad),
                )
                self._region = region_in_frame(self.source, self.pose, self._box)
            return self._region

    def cut(self, geometry: BaseGeometry, j: int | None = None) -> BaseGeometry:
        """``geometry`` ∩ R, and ∩ disc ``j`` where the set has discs and ``j`` is given (no
        components dropped)."""
        region = self.region_for(geometry)
        found = geometry if region is None else cut_to(geometry, region)
        if self.discs is not None and j is not None:
            found = self.discs.cut(found, j)
        return found

    def start(self) -> BaseGeometry:
        """slice_0 ∩ R (∩ disc 0): where a trajectory keeping to R may start."""
        if self._start is None:
            self._start = self.cut(self.inner.slice(0), 0)
        return self._start

    def tube(self, j: int) -> BaseGeometry:
        found = self._tubes.get(j)
        if found is None:
            found = connected_to(self.cut(self.inner.tube(j), j), self.start())
            self._tubes[j] = found
        return found

    def slice(self, j: int) -> BaseGeometry:
        found = self._slices.get(j)
        if found is None:
            found = self.start() if j == 0 else _within(self.inner.slice(j), self.tube(j))
            self._slices[j] = found
        return found

    def interval(self, j: int) -> BaseGeometry:
        j = max(j, 1)
        found = self._intervals.get(j)
        if found is None:
            found = _within(self.inner.interval(j), self.tube(j))
            self._intervals[j] = found
        return found

    def missing_tubes(self, indices: list[int]) -> list[int]:
        return sorted(set(indices).difference(self._tubes))

    def nearest_built_tube(self, j: int) -> int:
        later = [i for i in list(self._tubes) if i >= j]
        return min(later) if later else self.n_slices - 1


def _within(geometry: BaseGeometry, container: BaseGeometry) -> BaseGeometry:
    """geometry ∩ container, geometry itself where the container holds it."""
    if geometry.is_empty or container.is_empty:
        return shapely.Polygon() if container.is_empty else geometry
    return cut_to(geometry, container)


def connected_to(geometry: BaseGeometry, start: BaseGeometry) -> BaseGeometry:
    """The connected components of ``geometry`` that meet ``start`` (parts that touch count as
    connected), as polygons; parts of lower dimension kept grown by ``THIN_PART_M``."""
    if geometry.is_empty or start.is_empty:
        return shapely.Polygon()
    if isinstance(geometry, shapely.Polygon):  # one component
        return geometry if geometry.intersects(start) else shapely.Polygon()
    parts = _flat_parts(geometry)
    kept = shapely.intersects(parts, start)
    frontier = kept.copy()
    while frontier.any() and not kept.all():  # add the parts touching those added last
        added = shapely.union_all(parts[frontier])
        frontier = ~kept & shapely.intersects(parts, added)
        kept |= frontier
    if kept.all() and isinstance(geometry, shapely.Polygon | shapely.MultiPolygon):
        return geometry
    polygons = [p for p in parts[kept] if isinstance(p, shapely.Polygon)]
    thin = [
        p.buffer(THIN_PART_M, quad_segs=1)
        for p in parts[kept]
        if not isinstance(p, shapely.Polygon)
    ]
    if thin:
        return shapely.union_all(polygons + thin)
    if not polygons:
        return shapely.Polygon()
    return polygons[0] if len(polygons) == 1 else shapely.MultiPolygon(polygons)


def _flat_parts(geometry: BaseGeometry) -> np.ndarray:
    """The single parts of a geometry (collections within collections opened too)."""
    parts = shapely.get_parts(geometry)
    while any(isinstance(p, BaseMultipartGeometry) for p in parts):
        parts = shapely.get_parts(parts)
    return parts
