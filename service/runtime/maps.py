"""The maps this server holds, by id: one loaded at start-up (``FRT_MAP``, as ``FRT_MAP_ID``) and
those registered over the API (``PUT /v1/maps/{map_id}``), and the sets cut by them.

A map is an Argoverse 2 map archive (``reach.road_map``) or a Lanelet2 OSM file
(``reach.lanelet2_map``), read into the same ``RoadMap``; its region R for the server's margin
(``FRT_MAP_MARGIN_M``) is built when it is registered, so no request pays for it. Registering an
id again replaces its map; sets cut by the map before are not reused (each registration has its
own generation). Cut sets (``reach.road_cut.CutSet``) are kept per (set, map, assumptions) in a
small LRU: a request asking again for the same inputs reads the cut geometry drawn before. The
``speed_limit`` assumption's v_cap is the lane limit times the server's factor
(``FRT_SPEED_LIMIT_FACTOR``).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable
from dataclasses import dataclass
from itertools import count
from pathlib import Path
from typing import Any

import numpy as np

from reach.lanelet2_map import road_map_from_osm
from reach.lanes import (
    DRIVABLE_AREA,
    HEADING_TOLERANCE,
    REACHABLE_LANES,
    VEHICLE_LANE_TYPES,
    LaneRegion,
)
from reach.road_cut import CutSet, assumption_cut, padded_extent
from reach.road_map import MapFormatError, RoadMap, world_box
from reach.sets import FRTSet
from reach.speed_limit import DEFAULT_FACTOR
from service.runtime.settings import Settings
from service.wire.errors import APIError, FieldError

#: Cut sets kept (the latest used).
CUT_CACHE_SIZE = 512
#: The map formats read: an Argoverse 2 archive (JSON), a Lanelet2 OSM file (XML).
FORMATS = ("argoverse2", "lanelet2")


@dataclass(frozen=True)
class MapEntry:
    """One registered map."""

    map_id: str
    road: RoadMap
    #: Distinct per registration: a replaced map's cut sets are not reused.
    generation: int
    #: "file" (``FRT_MAP``) or "api".
    source: str
    size_bytes: int

    def summary(self) -> dict[str, Any]:
        return {
            "map_id": self.map_id,
            "source": self.source,
            "size_bytes": self.size_bytes,
            **self.road.summary(),
        }


class MapRegistry:
    """Maps by id, at most ``max_maps``; each one's region R for ``margin`` built on registering;
    ``speed_factor`` × a lane's limit is the ``speed_limit`` assumption's v_cap."""

    def __init__(
        self, max_maps: int, margin: float, max_points: int, speed_factor: float = DEFAULT_FACTOR
    ) -> None:
        self.max_maps = max_maps
        self.margin = margin
        self.max_points = max_points
        self.speed_factor = speed_factor
        self._maps: dict[str, MapEntry] = {}
        self._lock = threading.Lock()
        self._generations = count(1)
        self._cuts: OrderedDict[Hashable, tuple[FRTSet, CutSet | None]] = OrderedDict()

    def parse(
        self,
        raw: bytes,
        map_format: str = "argoverse2",
        origin: tuple[float, float] | None = None,
    ) -> RoadMap:
        """The map of an archive's JSON bytes or (``lanelet2``) an OSM file's XML bytes, lat/lon
        projected about ``origin`` where given, its region built (blocking: call from a thread);
        422 naming the field that is wrong."""
        try:
            if map_format == "lanelet2":
                road = road_map_from_osm(raw, self.max_points, origin)
            else:
                road = RoadMap.from_json(raw, self.max_points)
        except MapFormatError as exc:
            raise FieldError(exc.field, exc.message) from None
        road.region(self.margin)
        return road

    def put(
        self, map_id: str, road: RoadMap, source: str, size_bytes: int
    ) -> tuple[MapEntry, bool]:
        """Register ``road`` as ``map_id`` (replacing the map of that id): (entry, replaced).
        409 if the server holds ``max_maps`` other maps."""
        with self._lock:
            replaced = map_id in self._maps
            if not replaced and len(self._maps) >= self.max_maps:
                raise APIError(
                    409,
                    f"the server holds {self.max_maps} maps (FRT_MAX_MAPS): delete one or "
                    "replace one by its id",
                )
            entry = MapEntry(map_id, road, next(self._generations), source, size_bytes)
            self._maps[map_id] = entry
        return entry, replaced

    def load_file(self, path: Path, map_id: str) -> MapEntry:
        """Register the map at ``path`` as ``map_id`` (at start-up; a bad file raises): a Lanelet2
        OSM file when its name ends in ``.osm``, else an Argoverse 2 archive."""
        raw = Path(path).read_bytes()
        map_format = "lanelet2" if Path(path).suffix.lower() == ".osm" else "argoverse2"
        try:
            road = self.parse(raw, map_format)
        except FieldError as exc:
            raise ValueError(f"FRT_MAP={path}: {exc.field}: {exc.detail}") from None
        return self.put(map_id, road, "file", len(raw))[0]

    def get(self, map_id: str) -> MapEntry | None:
        return self._maps.get(map_id)

    def require(self, map_id: str, field: str = "map_id") -> MapEntry:
        """The map of ``map_id``; 422 naming ``field`` if there is none."""
        entry = self._maps.get(map_id)
        if entry is None:
            raise FieldError(field, f"unknown map {map_id!r} (register it: PUT /v1/maps/{map_id})")
        return entry

    def found(self, map_id: str) -> MapEntry:
        """The map of ``map_id``; 404 if there is none (the map's own routes)."""
        entry = self._maps.get(map_id)
        if entry is None:
            raise APIError(404, f"unknown map {map_id!r}")
        return entry

    def delete(self, map_id: str) -> MapEntry:
        """Forget the map of ``map_id`` (404 if none) and the sets cut by it."""
        with self._lock:
            entry = self._maps.pop(map_id, None)
            if entry is None:
                raise APIError(404, f"unknown map {map_id!r}")
            for key in [k for k in self._cuts if k[1] == entry.generation]:  # type: ignore[index]
                del self._cuts[key]
        return entry

    def __len__(self) -> int:
        return len(self._maps)

    def cut(self, entry: MapEntry, key: Hashable, frt: FRTSet) -> CutSet:
        """``frt`` cut by the map's region R (``reach.road_cut.CutSet``), kept as :meth:`cut_for`
        keeps it."""
        cut = self.cut_for(entry, key, frt, (DRIVABLE_AREA,))
        assert cut is not None  # R always applies
        return cut

    def cut_for(
        self,
        entry: MapEntry,
        key: Hashable,
        frt: FRTSet,
        assumptions: tuple[str, ...],
        speed: tuple[float, np.ndarray] | None = None,
    ) -> CutSet | None:
        """``frt`` cut by the region of ``assumptions`` (R for ``drivable_area``, R ∩ L with
        ``reachable_lanes`` too, L for ``reachable_lanes`` alone; ``reach.road_cut``), or by R
        alone where the lanes do not apply (``lane_cut`` None), and by the discs of
        ``speed_limit`` where ``speed`` (the set's v_start and bounds) is given and they apply
        (the set lists what cut it); None where nothing applies. Kept under (``key``,
        ``assumptions``, the map's generation) while ``frt`` is the set cut: a refined set
        replacing it is cut anew (``key`` stands for the set's inputs, ``speed`` among them)."""
        cache_key = ((key, assumptions), entry.generation)
        with self._lock:
            found = self._cuts.get(cache_key)
            if found is not None and found[0] is frt:
                self._cuts.move_to_end(cache_key)
                return found[1]
        cut = assumption_cut(frt, entry.road, self.margin, assumptions, speed, self.speed_factor)
        with self._lock:
            self._cuts[cache_key] = (frt, cut)
            self._cuts.move_to_end(cache_key)
            while len(self._cuts) > CUT_CACHE_SIZE:
                self._cuts.popitem(last=False)
        return cut

    def kept_cut(
        self, entry: MapEntry, key: Hashable, frt: FRTSet, assumptions: tuple[str, ...]
    ) -> tuple[bool, CutSet | None]:
        """Whether :meth:`cut_for` keeps ``frt`` cut by ``assumptions``, and that cut (None where
        nothing applied), without cutting, keeping or reordering anything."""
        with self._lock:
            found = self._cuts.get(((key, assumptions), entry.generation))
        if found is not None and found[0] is frt:
            return True, found[1]
        return False, None


@dataclass(frozen=True, slots=True)
class RoadProbe:
    """Where one map-frame point lies on a map, read once for every version it is audited
    against (:meth:`VersionRoad.probe`): on R or not, and the vehicle lanes whose area grown by
    the margin holds it (None outside the map's extent, where every L holds it)."""

    on_road: bool
    lanes: frozenset[int] | None


@dataclass(slots=True)
class _SetRegions:
    """The regions that cut one set of a version: R or not, and its reachable lanes (None where
    the lane assumption does not cut it; found on first need)."""

    frt: FRTSet
    drivable: bool
    lanes: bool
    reached: frozenset[int] | None = None


class VersionRoad:
    """What one version of an agent was answered under on a map, for the coverage audit: its
    map, its key and the assumptions in force. :meth:`off` says which of them a point is off the
    region of, for the version's exact or conservative set: the regions of that set's cut where
    :meth:`MapRegistry.cut_for` keeps it (what the answers came from), else read as the cut reads
    them (``reach.road_cut.lane_cut``: R, and the lanes reachable within the set's box where they
    apply), as sets of lane indices: no cut, no union of lanes built. The start lanes are found
    once per version, the lanes they reach once per set and only for a point in a lane that is
    not a start lane."""

    __slots__ = ("_sets", "_start", "assumptions", "entry", "key", "registry")

    def __init__(
        self, registry: MapRegistry, entry: MapEntry, key: Hashable, assumptions: tuple[str, ...]
    ) -> None:
        self.registry = registry
        self.entry = entry
        self.key = key
        self.assumptions = assumptions
        self._start: frozenset[int] | None = None
        self._sets: dict[bool, _SetRegions] = {}

    def probe(self, x: float, y: float) -> RoadProbe:
        """Where the map-frame point (x, y) lies on this version's map."""
        road, margin = self.entry.road, self.registry.margin
        x0, y0, x1, y1 = road.extent
        if x < x0 or x > x1 or y < y0 or y > y1:
            return RoadProbe(True, None)
        graph = road.lane_graph
        index = graph.index(margin, road.region(margin))
        found = index.holding(x, y)
        lanes = found[graph.of_types(VEHICLE_LANE_TYPES)[found]].tolist()
        return RoadProbe(road.on_road(x, y, margin), frozenset(lanes))

    def off(self, frt: FRTSet, probe: RoadProbe) -> tuple[str, ...]:
        """The assumptions that cut ``frt`` (a set of this version) whose region the point of
        ``probe`` is off: R for ``drivable_area``, L for ``reachable_lanes``."""
        regions = self._sets.get(frt.conservative)
        if regions is None or regions.frt is not frt:
            regions = self._regions(frt)
            self._sets[frt.conservative] = regions
        off = (DRIVABLE_AREA,) if regions.drivable and not probe.on_road else ()
        if regions.lanes and probe.lanes is not None and not self._in_lanes(regions, probe.lanes):
            off += (REACHABLE_LANES,)
        return off

    def _regions(self, frt: FRTSet) -> _SetRegions:
        key = (self.key, frt.conservative)
        kept, cut = self.registry.kept_cut(self.entry, key, frt, self.assumptions)
        if kept:
            source = None if cut is None else cut.source
            drivable = source is not None and DRIVABLE_AREA in source.assumptions
            if not isinstance(source, LaneRegion):
                return _SetRegions(frt, drivable, False)
            return _SetRegions(frt, drivable, True, frozenset(source.indices.tolist()))
        drivable = DRIVABLE_AREA in self.assumptions
        return _SetRegions(
            frt, drivable, REACHABLE_LANES in self.assumptions and self._applies(frt)
        )

    def _applies(self, frt: FRTSet) -> bool:
        """Whether the lanes cut ``frt`` (``lane_cut`` not None): a start lane holds its pose."""
        if self._start is None:
            road, margin, pose = self.entry.road, self.registry.margin, frt.pose
            graph = road.lane_graph
            index = graph.index(margin, road.region(margin))
            xy = (pose.x, pose.y)
            start = graph.start(index, xy, pose.heading, VEHICLE_LANE_TYPES, HEADING_TOLERANCE)
            self._start = frozenset(start)
        return bool(self._start)

    def _in_lanes(self, regions: _SetRegions, holding: frozenset[int]) -> bool:
        """Whether a lane the set reaches holds the point (``holding``: the lanes that do)."""
        if not holding:
            return False
        if regions.reached is None:
            if self._start is not None and not holding.isdisjoint(self._start):
                return True  # a start lane: reached by every set of the version
            road, margin, pose = self.entry.road, self.registry.margin, regions.frt.pose
            graph = road.lane_graph
            index = graph.index(margin, road.region(margin))
            box = world_box(pose, padded_extent(regions.frt))
            start = sorted(self._start or ())
            regions.reached = graph.reachable(index, start, box, VEHICLE_LANE_TYPES)
        return not holding.isdisjoint(regions.reached)


def registry_for(settings: Settings) -> MapRegistry:
    """The server's registry, with the map of ``FRT_MAP`` (if set) loaded as ``FRT_MAP_ID``."""
    registry = MapRegistry(
        settings.max_maps,
        settings.map_margin_m,
        settings.max_map_points,
        settings.speed_limit_factor,
    )
    if settings.map is not None:
        registry.load_file(settings.map, settings.map_id)
    return registry
