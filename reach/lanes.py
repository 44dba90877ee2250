"""The lane graph of a map and the region of the lanes an agent can reach along it.

The assumption ``reachable_lanes`` (SPOT's lane constraints, Koschi & Althoff, *SPOT: A Tool for
Set-Based Prediction of Traffic Participants*, IEEE IV 2017: road users do not drive backwards in
their lane and keep to the lanes they can reach), for vehicles, with its definitions:

* a lane's **area** is the polygon between its left and right boundaries; its **direction** at a
  point is the direction of its centre line (given, or the mean of its boundaries) on the segment
  nearest the point;
* the **start lanes** of an agent at position p with heading θ are the lanes of the agent's lane
  types whose area grown by the margin holds p and whose direction at p is within the heading
  tolerance (``HEADING_TOLERANCE``, 30°) of θ;
* lane b **follows** lane a when b is a successor of a, or a's left or right neighbour whose
  overall direction (first to last centre-line point) makes an acute angle with a's;
* the **reachable lanes** within a box B are the start lanes and every lane of the agent's types
  that follows a reachable lane and whose grown area's bounding box meets B (successors and
  same-direction lane changes, as often as B allows; ids the map does not hold are not followed);
* the region is L = (⋃ reachable lanes' areas ⊕ margin) ∪ (the plane outside the map's extent);
  with the drivable area assumed too, each grown lane area is cut to D ⊕ margin first, so the
  region is R ∩ L.

B is the map-frame bounding box of the box a set's region is read around
(``reach.road_cut.padded_extent``: its outer bound's boxes, grown): a trajectory inside the set
never leaves B, so every lane it drives along meets B. The assumption does not apply (no region:
the set is answered without it) where the agent breaks it already: no start lane holds it (off
every lane of its types, or its heading more than the tolerance off every lane holding it), or,
with the drivable area, its position is off R.

A trajectory respecting the assumption keeps its position in the region, so the cut of
``reach.road_cut.CutSet`` (components of tube ∩ region connected to the start) applies to it.
The graph (with its centre lines' segments, so a start lane's direction is one pass over its
own) is indexed once per map; each margin's grown areas once per margin, in an STRtree; the
region of each set of reachable lanes once, kept (``REGIONS_KEPT``).
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from reach.frames import covers_box

if TYPE_CHECKING:
    from reach.road_map import DrivableRegion, Lane

#: The label of this assumption in answers.
REACHABLE_LANES = "reachable_lanes"
#: The label of the drivable-area assumption (``reach.road_cut``), listed with it where both hold.
DRIVABLE_AREA = "drivable_area"
#: Lane types a vehicle starts in and follows.
VEHICLE_LANE_TYPES = ("VEHICLE", "BUS")
#: A lane holding the agent is a start lane when its direction there is within this of the
#: agent's heading (radians).
HEADING_TOLERANCE = math.radians(30.0)
#: Regions kept per map and margin (the latest used).
REGIONS_KEPT = 256
#: Up to this many lanes, the lanes holding a point are found by one pass over their bounding
#: boxes (cheaper than a tree query's wrapping); past it, by the STRtree.
SCAN_LANES = 4096


def _resample(line: np.ndarray, n: int) -> np.ndarray:
    """``line`` ([m, 2]) at ``n`` points evenly spaced along its length."""
    step = np.linalg.norm(np.diff(line, axis=0), axis=1)
    along = np.concatenate([[0.0], np.cumsum(step)])
    if along[-1] <= 0.0:
        return np.repeat(line[:1], n, axis=0)
    at = np.linspace(0.0, along[-1], n)
    return np.stack([np.interp(at, along, line[:, 0]), np.interp(at, along, line[:, 1])], axis=1)


def centre_line(lane: Lane) -> np.ndarray:
    """The lane's centre line: given, or the mean of its boundaries resampled alike."""
    if lane.centerline is not None:
        return lane.centerline
    n = max(len(lane.left), len(lane.right), 2)
    return (_resample(lane.left, n) + _resample(lane.right, n)) / 2.0


def lane_area(lane: Lane) -> BaseGeometry:
    """The polygon between the lane's boundaries (made valid; empty where it encloses none)."""
    ring = np.vstack([lane.left, lane.right[::-1]])
    parts = shapely.get_parts(shapely.make_valid(shapely.Polygon(ring)))
    polygons = [p for p in parts if isinstance(p, shapely.Polygon) and p.area > 0.0]
    return shapely.union_all(polygons) if polygons else shapely.Polygon()


def direction_at(line: np.ndarray, x: float, y: float) -> float:
    """The direction (radians) of the segment of ``line`` nearest the point (x, y)."""
    a, b = line[:-1], line[1:]
    d = b - a
    length2 = np.maximum((d * d).sum(axis=1), 1e-18)
    t = np.clip(((x - a[:, 0]) * d[:, 0] + (y - a[:, 1]) * d[:, 1]) / length2, 0.0, 1.0)
    gap = np.hypot(a[:, 0] + t * d[:, 0] - x, a[:, 1] + t * d[:, 1] - y)
    k = int(np.argmin(gap))
    return math.atan2(d[k, 1], d[k, 0])


class _Segments:
    """Each lane's centre-line segments as column arrays, computed once, for
    :func:`direction_at` of a lane at a point without recomputing them (the same arithmetic, so
    the same direction)."""

    def __init__(self, lines: Sequence[np.ndarray]) -> None:
        self.columns: list[tuple[np.ndarray, ...]] = []
        self.angles: list[list[float]] = []
        for line in lines:
            a, d = line[:-1], line[1:] - line[:-1]
            length2 = np.maximum((d * d).sum(axis=1), 1e-18)
            columns = (a[:, 0].copy(), a[:, 1].copy(), d[:, 0].copy(), d[:, 1].copy(), length2)
            self.columns.append(columns)
            self.angles.append([math.atan2(dy, dx) for dx, dy in d.tolist()])

    def direction(self, lane: int, x: float, y: float) -> float:
        """:func:`direction_at` of lane ``lane``'s centre line at (x, y)."""
        ax, ay, dx, dy, length2 = self.columns[lane]
        t = np.minimum(np.maximum(((x - ax) * dx + (y - ay) * dy) / length2, 0.0), 1.0)
        gap = np.hypot(ax + t * dx - x, ay + t * dy - y)
        return self.angles[lane][int(gap.argmin())]


def _angle(a: float, b: float) -> float:
    """|a - b| wrapped into [0, π]."""
    return abs((a - b + math.pi) % (2.0 * math.pi) - math.pi)


class LaneRegion:
    """L (or R ∩ L) of one set of reachable lanes, in the map's frame (see the module): the same
    reading interface as ``reach.road_map.DrivableRegion``."""

    def __init__(
        self,
        lanes: frozenset[str],
        pieces: Sequence[BaseGeometry],
        index: MarginIndex,
        drivable: bool,
        indices: Sequence[int] = (),
    ) -> None:
        self.lanes = lanes
        #: The lanes' indices in the lane graph (``lanes`` are their ids).
        self.indices = np.asarray(indices, dtype=np.intp)
        self.margin = index.margin
        self.drivable = drivable
        self.assumptions = (DRIVABLE_AREA, REACHABLE_LANES) if drivable else (REACHABLE_LANES,)
        self.extent = index.extent
        self.indexed = index.indexed
        self.grown = shapely.union_all(list(pieces)) if len(pieces) else shapely.Polygon()
        shapely.prepare(self.grown)
        self._strips = index.strips
        self._union: BaseGeometry | None = None

    def near(self, bounds: tuple[float, ...]) -> BaseGeometry:
        """The region within (at least) the box ``bounds`` (x0, y0, x1, y1): the grown lanes
        where the box is within the extent, else with the plane outside it."""
        if covers_box(self.extent, bounds):
            return self.grown
        if self._union is None:
            union = shapely.union_all([self.grown, *self._strips])
            shapely.prepare(union)
            self._union = union
        if covers_box(self.indexed, bounds):
            return self._union
        box = shapely.box(*bounds)
        return shapely.union(self._union, box.difference(shapely.box(*self.indexed)))

    def covers_xy(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether each point lies in the region."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        e0, f0, e1, f1 = self.extent
        outside = (x < e0) | (x > e1) | (y < f0) | (y > f1)
        return outside | shapely.intersects_xy(self.grown, x, y)

    def covers(self, x: float, y: float) -> bool:
        """Whether the point (x, y) lies in the region (one point of :meth:`covers_xy`)."""
        e0, f0, e1, f1 = self.extent
        if x < e0 or x > e1 or y < f0 or y > f1:
            return True
        return bool(shapely.intersects_xy(self.grown, x, y))


class MarginIndex:
    """The lanes' areas grown by one margin, as they are and cut to D ⊕ margin, in an STRtree,
    with the strips indexing the plane outside the extent (those of the map's drivable region
    R for the same margin), and the regions read from them."""

    def __init__(self, graph: LaneGraph, margin: float, drivable: DrivableRegion) -> None:
        self.margin = margin
        self.extent = graph.extent
        areas = graph.areas
        self.grown = shapely.buffer(areas, margin, quad_segs=4) if margin > 0 else areas
        self.clipped = shapely.intersection(self.grown, drivable.grown)
        self.tree = shapely.STRtree(self.grown)
        bounds = shapely.bounds(self.grown).reshape(-1, 4)
        self._bounds = tuple(np.ascontiguousarray(bounds[:, k]) for k in range(4))
        self.strips = list(drivable.tiles[drivable.road_tiles :])
        self.indexed = drivable.indexed
        self._regions: OrderedDict[tuple[frozenset[int], bool], LaneRegion] = OrderedDict()
        self._lock = threading.Lock()

    def holding(self, x: float, y: float) -> np.ndarray:
        """The lanes (indices, increasing) whose area grown by the margin holds the point (x, y):
        those whose bounding box holds it and that intersect it (the STRtree's ``intersects``
        query, by one pass over the boxes up to ``SCAN_LANES`` lanes)."""
        if len(self.grown) > SCAN_LANES:
            return np.sort(self.tree.query(shapely.Point(x, y), predicate="intersects"))
        x0, y0, x1, y1 = self._bounds
        near = np.flatnonzero((x0 <= x) & (x1 >= x) & (y0 <= y) & (y1 >= y))
        return near[shapely.intersects_xy(self.grown[near], x, y)] if len(near) else near

    def meeting(self, box: tuple[float, ...]) -> np.ndarray:
        """The lanes (indices, increasing) whose grown area's bounding box meets the box ``box``
        (x0, y0, x1, y1): the STRtree's query of the box, by one pass over the boxes up to
        ``SCAN_LANES`` lanes."""
        if len(self.grown) > SCAN_LANES:
            return np.sort(self.tree.query(shapely.box(*box)))
        x0, y0, x1, y1 = self._bounds
        return np.flatnonzero((x0 <= box[2]) & (x1 >= box[0]) & (y0 <= box[3]) & (y1 >= box[1]))

    def region(self, reached: frozenset[int], ids: Sequence[str], drivable: bool) -> LaneRegion:
        """The region of the lanes ``reached`` (indices), R ∩ L if ``drivable`` else L; built on
        first use and kept."""
        key = (reached, drivable)
        with self._lock:
            found = self._regions.get(key)
            if found is not None:
                self._regions.move_to_end(key)
                return found
        order = sorted(reached)
        pieces = (self.clipped if drivable else self.grown)[order]
        region = LaneRegion(frozenset(ids[i] for i in order), pieces, self, drivable, order)
        with self._lock:
            self._regions[key] = region
            while len(self._regions) > REGIONS_KEPT:
                self._regions.popitem(last=False)
        return region


class LaneGraph:
    """A map's lanes: areas, centre lines, the ``follows`` relation (see the module), indexed
    once; each margin's grown areas on first use (:meth:`index`)."""

    def __init__(self, lanes: Sequence[Lane], extent: tuple[float, ...]) -> None:
        self.extent = extent
        self.ids = [lane.id for lane in lanes]
        self.types = np.array([lane.lane_type for lane in lanes], dtype=object)
        self.areas = np.array([lane_area(lane) for lane in lanes], dtype=object)
        self.lines = [centre_line(lane) for lane in lanes]
        at = {lane_id: i for i, lane_id in enumerate(self.ids)}
        overall = np.array([line[-1] - line[0] for line in self.lines]).reshape(-1, 2)
        self.follow: list[tuple[int, ...]] = []
        for i, lane in enumerate(lanes):
            nexts = [at[str(s)] for s in lane.successors if str(s) in at]
            for n in (lane.left_neighbor, lane.right_neighbor):
                j = at.get(str(n)) if n is not None else None
                if j is not None and float(overall[i] @ overall[j]) > 0.0:
                    nexts.append(j)
            self.follow.append(tuple(dict.fromkeys(nexts)))
        self.segments = _Segments(self.lines)
        #: Each lane's speed limit (m/s), NaN where the map gives none.
        self.limits = np.array(
            [math.nan if lane.speed_limit is None else lane.speed_limit for lane in lanes],
            dtype=np.float64,
        )
        self._margins: dict[float, MarginIndex] = {}
        self._type_masks: dict[frozenset[str], np.ndarray] = {}
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self.ids)

    def index(self, margin: float, drivable: DrivableRegion) -> MarginIndex:
        """The grown areas of ``margin`` (with R of the same margin), built on first use."""
        with self._lock:
            if margin not in self._margins:
                self._margins[margin] = MarginIndex(self, margin, drivable)
            return self._margins[margin]

    def of_types(self, lane_types: Iterable[str]) -> np.ndarray:
        """Whether each lane is of one of ``lane_types`` (a boolean per lane, kept per set of
        types)."""
        key = frozenset(lane_types)
        found = self._type_masks.get(key)
        if found is None:
            found = np.array([t in key for t in self.types], dtype=bool)
            self._type_masks[key] = found
        return found

    def start(
        self,
        index: MarginIndex,
        xy: tuple[float, float],
        heading: float,
        lane_types: Iterable[str],
        tolerance: float,
    ) -> list[int]:
        """The start lanes of an agent at ``xy`` heading ``heading`` (see the module)."""
        x, y = float(xy[0]), float(xy[1])
        found = index.holding(x, y)
        of_types = self.of_types(lane_types)
        direction = self.segments.direction
        return [
            i
            for i in found.tolist()
            if of_types[i] and _angle(direction(i, x, y), heading) <= tolerance
        ]

    def reachable(
        self,
        index: MarginIndex,
        start: list[int],
        box: tuple[float, ...],
        lane_types: Iterable[str],
    ) -> frozenset[int]:
        """The start lanes and the lanes of ``lane_types`` whose grown area's bounding box meets
        ``box`` that follow them."""
        met = index.meeting(box)
        within = set(met[self.of_types(lane_types)[met]].tolist())
        reached = set(start)
        frontier = list(start)
        while frontier:
            i = frontier.pop()
            for j in self.follow[i]:
                if j in within and j not in reached:
                    reached.add(j)
                    frontier.append(j)
        return frozenset(reached)

    def speed_cap(
        self,
        index: MarginIndex,
        pose: Any,
        box: tuple[float, ...],
        factor: float,
        lane_types: Iterable[str] = VEHICLE_LANE_TYPES,
        tolerance: float = HEADING_TOLERANCE,
    ) -> float | None:
        """v_cap of the ``speed_limit`` assumption (``reach.speed_limit``): ``factor`` × the
        highest speed limit among the lanes an agent at ``pose`` reaches within ``box`` (the
        map's frame); None where the box reaches past the map's extent, no start lane holds the
        agent or a lane reached has no limit."""
        if not covers_box(self.extent, box):
            return None
        start = self.start(index, (pose.x, pose.y), pose.heading, lane_types, tolerance)
        if not start:
            return None
        limits = self.limits[sorted(self.reachable(index, start, box, lane_types))]
        if np.isnan(limits).any():
            return None
        return factor * float(limits.max())

    def region(
        self,
        index: MarginIndex,
        pose: Any,
        box: tuple[float, ...],
        drivable: bool = True,
        lane_types: Iterable[str] = VEHICLE_LANE_TYPES,
        tolerance: float = HEADING_TOLERANCE,
    ) -> LaneRegion | None:
        """The region of the lanes an agent at ``pose`` (x, y, heading) reaches within ``box``
        (the map's frame); None where it breaks the assumption already: no start lane holds it,
        or (``drivable``) its position is off R."""
        start = self.start(index, (pose.x, pose.y), pose.heading, lane_types, tolerance)
        if not start:
            return None
        region = index.region(self.reachable(index, start, box, lane_types), self.ids, drivable)
        return region if region.covers(pose.x, pose.y) else None
