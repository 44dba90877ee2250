"""Road maps: an Argoverse 2 map archive parsed, validated and indexed for cutting sets.

An archive (Argoverse 2 ``log_map_archive_*.json``) is a JSON object with three collections, each
an object from id to element:

* ``drivable_areas``: ``{"id", "area_boundary": [{"x", "y", "z"}, ...]}``, a polygon's ring;
* ``lane_segments``: ``{"id", "lane_type", "is_intersection", "left_lane_boundary",
  "right_lane_boundary", "centerline"?, "successors", "predecessors", "left_neighbor_id",
  "right_neighbor_id", "left_lane_mark_type", "right_lane_mark_type"}``;
* ``pedestrian_crossings``: ``{"id", "edge1", "edge2"}``, two polylines.

Points are metres in the map's frame (``z`` optional, not used). Fields an element does not need
are ignored; a top-level key other than the three is an error, and so is every value the map
uses that is missing or malformed: :class:`MapFormatError` names it by its dotted path
(``drivable_areas.11055391.area_boundary.3.x``).

The drivable area D is the union of the drivable areas. The map knows the road only within its
extent (the bounding box of all its elements): the region a set may be cut to is

    R = (D ⊕ margin) ∪ (the plane outside the extent),

so a set is never cut where the map says nothing. R within the extent is indexed once per margin
(:class:`DrivableRegion`): split into tiles, each with at most ``TILE_VERTICES`` vertices (a
quadtree: a tile with more is split in four, down to ``MIN_TILE_M``), with four strips around the
extent for the plane outside it, in an STRtree. Cutting a set K reads only the tiles its bounding
box meets: K ∩ R = K ∩ their union.

The lanes are indexed once per map too (``reach.lanes.LaneGraph``: areas, centre lines, the lanes
each one leads to), their areas grown by each margin with R: the region of the lanes an agent can
reach (:meth:`RoadMap.lane_region`) is read like R, and cut the same way (``reach.road_cut``).
Successor and neighbour ids the archive does not hold are kept as read and not followed.
Archives carry no speed limits: every lane's ``speed_limit`` is None (a Lanelet2 map's may not be).
"""

from __future__ import annotations

import json
import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry.base import BaseGeometry

from reach.frames import Pose, covers_box
from reach.lanes import DRIVABLE_AREA, HEADING_TOLERANCE, VEHICLE_LANE_TYPES, LaneGraph, LaneRegion

#: The collections of an archive, in the order they are read.
COLLECTIONS = ("drivable_areas", "lane_segments", "pedestrian_crossings")
#: Coordinates beyond this (metres) are refused, as in the API's own states.
COORDINATE_LIMIT = 1e7
#: Points one archive may hold, over all its elements.
MAX_POINTS = 2_000_000
#: A tile of the indexed region is split in four while it has more vertices than this ...
TILE_VERTICES = 256
#: ... and is wider than this (metres).
MIN_TILE_M = 8.0
#: The plane outside the extent is indexed this far (metres) around it.
OUTSIDE_M = 500.0
#: Unions of tiles kept per region.
UNIONS_KEPT = 512


class MapFormatError(ValueError):
    """An archive that is not a valid map: ``field`` names the offending value (dotted)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


@dataclass(frozen=True)
class Lane:
    """One lane segment: its boundaries (and centre line, where given) as [n, 2] arrays; the
    lanes it leads to by id (an archive's integers, a Lanelet2 map's strings); its speed limit
    where known."""

    id: str
    lane_type: str
    is_intersection: bool
    left: np.ndarray
    right: np.ndarray
    centerline: np.ndarray | None
    successors: tuple[int | str, ...]
    predecessors: tuple[int | str, ...]
    left_neighbor: int | str | None = None
    right_neighbor: int | str | None = None
    #: The lane's speed limit (m/s) where the map gives one (a Lanelet2 map may; an archive
    #: does not), else None.
    speed_limit: float | None = None


@dataclass(frozen=True)
class Crossing:
    """One pedestrian crossing: its two edges as [n, 2] arrays."""

    id: str
    edge1: np.ndarray
    edge2: np.ndarray


class _Points:
    """Counts the points read against ``limit`` (:data:`MAX_POINTS`)."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.count = 0

    def read(self, value: Any, field: str, at_least: int) -> np.ndarray:
        """A list of ``{x, y, z?}`` as an [n, 2] array (finite, within the coordinate limit)."""
        if not isinstance(value, list):
            raise MapFormatError(field, "must be a list of points {x, y, z}")
        if len(value) < at_least:
            raise MapFormatError(field, f"needs at least {at_least} points, got {len(value)}")
        self.count += len(value)
        if self.count > self.limit:
            raise MapFormatError(field, f"the map holds more than {self.limit} points")
        out = np.empty((len(value), 2))
        for i, point in enumerate(value):
            if not isinstance(point, dict):
                raise MapFormatError(f"{field}.{i}", "must be a point {x, y, z}")
            for k, name in enumerate(("x", "y")):
                out[i, k] = _coordinate(point, name, f"{field}.{i}.{name}", required=True)
            _coordinate(point, "z", f"{field}.{i}.z", required=False)
        return out


def _coordinate(point: dict, name: str, field: str, required: bool) -> float:
    if name not in point:
        if required:
            raise MapFormatError(field, "missing")
        return 0.0
    value = point[name]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise MapFormatError(field, f"must be a number, got {type(value).__name__}")
    if abs(value) > COORDINATE_LIMIT or not math.isfinite(value):  # a huge int: no float
        raise MapFormatError(field, f"must be finite and within ±{COORDINATE_LIMIT:g} m")
    return float(value)


def _element(collection: dict, field: str) -> list[tuple[str, dict]]:
    """The (id, element) pairs of a collection, each element an object."""
    if not isinstance(collection, dict):
        raise MapFormatError(field, "must be an object from id to element")
    out = []
    for key, element in collection.items():
        if not isinstance(element, dict):
            raise MapFormatError(f"{field}.{key}", "must be an object")
        if "id" in element and (
            isinstance(element["id"], bool) or not isinstance(element["id"], int | str)
        ):
            raise MapFormatError(f"{field}.{key}.id", "must be an integer or a string")
        out.append((str(key), element))
    return out


def _ids(element: dict, name: str, field: str) -> tuple[int, ...]:
    value = element.get(name, [])
    if not isinstance(value, list) or any(
        isinstance(v, bool) or not isinstance(v, int) for v in value
    ):
        raise MapFormatError(f"{field}.{name}", "must be a list of integer ids")
    return tuple(value)


def _lane(key: str, element: dict, field: str, points: _Points) -> Lane:
    neighbors = []
    for name in ("left_neighbor_id", "right_neighbor_id"):
        value = element.get(name)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
            raise MapFormatError(f"{field}.{name}", "must be an integer id or null")
        neighbors.append(value)
    lane_type = element.get("lane_type")
    if not isinstance(lane_type, str) or not lane_type:
        raise MapFormatError(f"{field}.lane_type", "must be a string (VEHICLE, BIKE, BUS)")
    is_intersection = element.get("is_intersection", False)
    if not isinstance(is_intersection, bool):
        raise MapFormatError(f"{field}.is_intersection", "must be true or false")
    centerline = element.get("centerline")
    return Lane(
        id=key,
        lane_type=lane_type,
        is_intersection=is_intersection,
        left=points.read(element.get("left_lane_boundary"), f"{field}.left_lane_boundary", 2),
        right=points.read(element.get("right_lane_boundary"), f"{field}.right_lane_boundary", 2),
        centerline=None
        if centerline is None
        else points.read(centerline, f"{field}.centerline", 2),
        successors=_ids(element, "successors", field),
        predecessors=_ids(element, "predecessors", field),
        left_neighbor=neighbors[0],
        right_neighbor=neighbors[1],
    )


def _drivable_polygon(ring: np.ndarray, field: str) -> BaseGeometry:
    """The polygon a drivable area's boundary encloses (a self-touching ring made valid)."""
    polygon = shapely.make_valid(shapely.Polygon(ring))
    polygonal = [p for p in shapely.get_parts(polygon) if isinstance(p, shapely.Polygon)]
    if not polygonal or sum(p.area for p in polygonal) <= 0.0:
        raise MapFormatError(field, "encloses no area")
    return shapely.union_all(polygonal)


def parse_archive(
    archive: Any, max_points: int = MAX_POINTS
) -> tuple[list[BaseGeometry], list[Lane], list[Crossing]]:
    """The drivable polygons, lanes and crossings of an archive (already JSON-decoded)."""
    if not isinstance(archive, dict):
        raise MapFormatError("body", "must be a JSON object with " + ", ".join(COLLECTIONS))
    for key in archive:
        if key not in COLLECTIONS:
            raise MapFormatError(
                str(key), "unknown field (an archive has " + ", ".join(COLLECTIONS) + ")"
            )
    if "drivable_areas" not in archive:
        raise MapFormatError("drivable_areas", "missing")
    points = _Points(max_points)
    areas = []
    for key, element in _element(archive["drivable_areas"], "drivable_areas"):
        field = f"drivable_areas.{key}.area_boundary"
        areas.append(_drivable_polygon(points.read(element.get("area_boundary"), field, 3), field))
    if not areas:
        raise MapFormatError("drivable_areas", "must hold at least one drivable area")
    lanes = [
        _lane(key, element, f"lane_segments.{key}", points)
        for key, element in _element(archive.get("lane_segments", {}), "lane_segments")
    ]
    crossings = [
        Crossing(
            key,
            points.read(element.get("edge1"), f"pedestrian_crossings.{key}.edge1", 2),
            points.read(element.get("edge2"), f"pedestrian_crossings.{key}.edge2", 2),
        )
        for key, element in _element(
            archive.get("pedestrian_crossings", {}), "pedestrian_crossings"
        )
    ]
    return areas, lanes, crossings


def _tiles(geometry: BaseGeometry, bounds: tuple[float, ...], out: list[BaseGeometry]) -> None:
    """``geometry``'s polygonal parts within ``bounds``, split in quadrants until each tile has at
    most ``TILE_VERTICES`` vertices or is ``MIN_TILE_M`` wide, appended to ``out``."""
    x0, y0, x1, y1 = bounds
    if geometry.is_empty:
        return
    if (
        shapely.get_num_coordinates(geometry) <= TILE_VERTICES
        or max(x1 - x0, y1 - y0) <= MIN_TILE_M
    ):
        out.extend(p for p in shapely.get_parts(geometry) if isinstance(p, shapely.Polygon))
        return
    xm, ym = (x0 + x1) / 2.0, (y0 + y1) / 2.0
    for quadrant in ((x0, y0, xm, ym), (xm, y0, x1, ym), (x0, ym, xm, y1), (xm, ym, x1, y1)):
        part = shapely.intersection(geometry, shapely.box(*quadrant))
        polygonal = [p for p in shapely.get_parts(part) if isinstance(p, shapely.Polygon)]
        if polygonal:
            _tiles(shapely.union_all(polygonal), quadrant, out)


class DrivableRegion:
    """R = (D ⊕ margin) ∪ (the plane outside the map's extent), indexed in tiles (see the module).

    The plane outside the extent is indexed too, as four strips ``OUTSIDE_M`` wide around it, so
    R near any box within them is a union of tiles; the unions read are kept by the tiles they
    join (``UNIONS_KEPT``, the oldest dropped first): sets near each other read one union."""

    assumptions = (DRIVABLE_AREA,)

    def __init__(self, drivable: BaseGeometry, extent: tuple[float, ...], margin: float) -> None:
        grown = drivable.buffer(margin, quad_segs=4) if margin > 0 else drivable
        self.margin = margin
        self.grown = grown
        shapely.prepare(grown)
        self.extent = extent
        e0, f0, e1, f1 = extent
        w = OUTSIDE_M
        self.indexed = (e0 - w, f0 - w, e1 + w, f1 + w)
        tiles: list[BaseGeometry] = []
        _tiles(grown, grown.bounds, tiles)
        strips = [(e0 - w, f0 - w, e0, f1 + w), (e1, f0 - w, e1 + w, f1 + w),
                  (e0, f0 - w, e1, f0), (e0, f1, e1, f1 + w)]  # fmt: skip
        #: The tiles of D ⊕ margin come first, then the four strips.
        self.road_tiles = len(tiles)
        tiles += [shapely.box(*strip) for strip in strips]
        self.tiles = np.array(tiles, dtype=object)
        self.tree = shapely.STRtree(self.tiles)
        self._unions: dict[tuple[int, ...], BaseGeometry] = {}
        self._lock = threading.Lock()

    def near(self, bounds: tuple[float, ...]) -> BaseGeometry:
        """R within (at least) the box ``bounds`` (x0, y0, x1, y1): the union of the tiles the box
        meets, and of the part of the box beyond the indexed strips."""
        box = shapely.box(*bounds)
        union = self._union(tuple(sorted(self.tree.query(box).tolist())))
        if covers_box(self.indexed, bounds):
            return union
        return shapely.union(union, box.difference(shapely.box(*self.indexed)))

    def _union(self, indices: tuple[int, ...]) -> BaseGeometry:
        """The union of the tiles ``indices`` (prepared), kept."""
        with self._lock:
            found = self._unions.get(indices)
        if found is not None:
            return found
        parts = self.tiles[list(indices)]
        union = shapely.Polygon() if not len(parts) else shapely.union_all(parts)
        shapely.prepare(union)
        with self._lock:
            if len(self._unions) >= UNIONS_KEPT:
                del self._unions[next(iter(self._unions))]
            self._unions[indices] = union
        return union

    def covers_xy(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether each point lies in R."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        e0, f0, e1, f1 = self.extent
        outside = (x < e0) | (x > e1) | (y < f0) | (y > f1)
        return outside | shapely.intersects_xy(self.grown, x, y)

    def covers(self, x: float, y: float) -> bool:
        """Whether the point (x, y) lies in R (one point of :meth:`covers_xy`)."""
        e0, f0, e1, f1 = self.extent
        if x < e0 or x > e1 or y < f0 or y > f1:
            return True
        return bool(shapely.intersects_xy(self.grown, x, y))


def world_box(pose: Pose, bounds: tuple[float, ...]) -> tuple[float, float, float, float]:
    """The map-frame bounding box of the box ``bounds`` of the frame of ``pose``."""
    x0, y0, x1, y1 = bounds
    c, s = math.cos(pose.heading), math.sin(pose.heading)
    xs = [pose.x + c * x - s * y for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1))]
    ys = [pose.y + s * x + c * y for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1))]
    return min(xs), min(ys), max(xs), max(ys)


def region_in_frame(region: Any, pose: Pose, bounds: tuple[float, ...]) -> BaseGeometry:
    """A region (``DrivableRegion``, ``reach.lanes.LaneRegion``: anything with ``near``) around
    the box ``bounds`` of the frame of ``pose`` (the human frame), in that frame: read around the
    box's map-frame bounding box, moved into the frame."""
    world = region.near(world_box(pose, bounds))
    c, s = math.cos(pose.heading), math.sin(pose.heading)
    # p_human = R(-heading) (p_world - (x, y))
    offset_x = -(c * pose.x + s * pose.y)
    offset_y = s * pose.x - c * pose.y
    return affinity.affine_transform(world, [c, s, -s, c, offset_x, offset_y])


def cut_to(k_set: BaseGeometry, region: BaseGeometry) -> BaseGeometry:
    """K ∩ region, K itself where the region holds it (a prepared test, no overlay)."""
    if k_set.is_empty:
        return k_set
    shapely.prepare(region)
    if region.contains(k_set):
        return k_set
    return k_set.intersection(region)


class RoadMap:
    """One map: the drivable area D (one shapely geometry), its lanes and crossings, its extent,
    and the region R of each margin asked for (built once, kept). Read from an Argoverse 2
    archive (:meth:`from_json`) or a Lanelet2 OSM file (``reach.lanelet2_map``)."""

    def __init__(
        self,
        areas: list[BaseGeometry],
        lanes: list[Lane],
        crossings: list[Crossing],
        map_format: str = "argoverse2",
    ) -> None:
        #: "argoverse2" (an archive) or "lanelet2" (``reach.lanelet2_map``).
        self.format = map_format
        self.drivable = shapely.union_all(areas)
        self.lanes = tuple(lanes)
        self.crossings = tuple(crossings)
        parts = [self.drivable]
        parts += [shapely.multipoints(np.vstack([lane.left, lane.right])) for lane in lanes]
        parts += [shapely.multipoints(np.vstack([c.edge1, c.edge2])) for c in crossings]
        self.extent: tuple[float, ...] = tuple(
            float(v) for v in shapely.total_bounds(np.array(parts, dtype=object))
        )
        self.areas = len(areas)
        self.lane_graph = LaneGraph(self.lanes, self.extent)
        self._regions: dict[float, DrivableRegion] = {}
        self._lock = threading.Lock()

    @classmethod
    def from_archive(cls, archive: Any, max_points: int = MAX_POINTS) -> RoadMap:
        return cls(*parse_archive(archive, max_points))

    @classmethod
    def from_json(cls, text: str | bytes, max_points: int = MAX_POINTS) -> RoadMap:
        """The map of an archive's JSON text (an error naming ``body`` if it is not JSON)."""
        try:
            archive = json.loads(text)
        except (ValueError, RecursionError) as exc:
            raise MapFormatError("body", f"not JSON: {exc}") from None
        return cls.from_archive(archive, max_points)

    @classmethod
    def load(cls, path: str | Path, max_points: int = MAX_POINTS) -> RoadMap:
        """The map of a file: a Lanelet2 OSM file when it ends in ``.osm``, else an archive."""
        raw = Path(path).read_bytes()
        if Path(path).suffix.lower() == ".osm":
            from reach.lanelet2_map import road_map_from_osm

            return road_map_from_osm(raw, max_points)
        return cls.from_json(raw, max_points)

    def region(self, margin: float) -> DrivableRegion:
        """R for ``margin`` (metres, >= 0), built on first use, with the lanes' areas grown by the
        same margin (``reach.lanes``)."""
        if not margin >= 0.0:
            raise ValueError(f"margin must be >= 0, got {margin!r}")
        with self._lock:
            if margin not in self._regions:
                region = DrivableRegion(self.drivable, self.extent, margin)
                self.lane_graph.index(margin, region)
                self._regions[margin] = region
            return self._regions[margin]

    def lane_region(
        self,
        pose: Pose,
        box: tuple[float, ...],
        margin: float,
        drivable: bool = True,
        lane_types: tuple[str, ...] = VEHICLE_LANE_TYPES,
        tolerance: float = HEADING_TOLERANCE,
    ) -> LaneRegion | None:
        """The region of the lanes an agent at ``pose`` reaches within the box ``box`` (map frame):
        R ∩ L if ``drivable`` else L (``reach.lanes``); None where no start lane holds the agent."""
        index = self.lane_graph.index(margin, self.region(margin))
        return self.lane_graph.region(index, pose, box, drivable, lane_types, tolerance)

    def speed_cap(
        self, pose: Pose, box: tuple[float, ...], margin: float, factor: float
    ) -> float | None:
        """v_cap of an agent at ``pose`` whose set stays within the box ``box`` (map frame):
        ``factor`` × the highest limit among the vehicle lanes it reaches within it
        (``reach.lanes.LaneGraph.speed_cap``); None where that is not known."""
        index = self.lane_graph.index(margin, self.region(margin))
        return self.lane_graph.speed_cap(index, pose, box, factor)

    def cut(self, k_world: BaseGeometry, margin: float) -> BaseGeometry:
        """K ∩ R for a set K in the map's frame: R read near K's bounding box only."""
        if k_world.is_empty:
            return k_world
        return cut_to(k_world, self.region(margin).near(k_world.bounds))

    def on_road(self, x: float, y: float, margin: float) -> bool:
        """Whether the point (x, y) lies in R."""
        return self.region(margin).covers(float(x), float(y))

    def region_in_frame(self, pose: Pose, bounds: tuple[float, ...], margin: float) -> BaseGeometry:
        """R around the box ``bounds`` of the frame of ``pose`` (the human frame), in that frame."""
        return region_in_frame(self.region(margin), pose, bounds)

    def summary(self) -> dict[str, Any]:
        """Counts, extent and drivable area, for the API."""
        return {
            "format": self.format,
            "drivable_areas": self.areas,
            "lane_segments": len(self.lanes),
            "speed_limited_lanes": sum(lane.speed_limit is not None for lane in self.lanes),
            "pedestrian_crossings": len(self.crossings),
            "extent": list(self.extent),
            "drivable_area_m2": float(self.drivable.area),
            "vertices": int(shapely.get_num_coordinates(self.drivable)),
        }
