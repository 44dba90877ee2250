"""The maps this server holds, by id: one loaded at start-up (``FRT_MAP``, as ``FRT_MAP_ID``) and
those registered over the API (``PUT /v1/maps/{map_id}``), and the sets cut by them.

A map is an Argoverse 2 map archive (``reach.road_map``) or a Lanelet2 OSM file
(``reach.lanelet2_map``), read into the same ``RoadMap``; its region R for the server's margin
(``FRT_MAP_MARGIN_M``) is built when it is registered, so no request pays for it. Registering an
id again replaces its map; sets cut by the map before are not reused (each registration has its
own generation). Cut sets (``reach.road_cut.CutSet``) are kept per (set, map, assumptions) in a
small LRU: a request asking again for the same inputs reads the cut geometry drawn before.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable
from dataclasses import dataclass
from itertools import count
from pathlib import Path
from typing import Any

from reach.lanelet2_map import road_map_from_osm
from reach.lanes import DRIVABLE_AREA, REACHABLE_LANES
from reach.road_cut import CutSet, lane_cut
from reach.road_map import MapFormatError, RoadMap
from reach.sets import FRTSet
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
    """Maps by id, at most ``max_maps``; each one's region R for ``margin`` built on registering."""

    def __init__(self, max_maps: int, margin: float, max_points: int) -> None:
        self.max_maps = max_maps
        self.margin = margin
        self.max_points = max_points
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
        self, entry: MapEntry, key: Hashable, frt: FRTSet, assumptions: tuple[str, ...]
    ) -> CutSet | None:
        """``frt`` cut by the region of ``assumptions`` (R for ``drivable_area``, R ∩ L with
        ``reachable_lanes`` too, L for ``reachable_lanes`` alone; ``reach.road_cut``), or by R
        alone where the lanes do not apply (``lane_cut`` None; the set lists what cut it), None
        where nothing applies. Kept under (``key``, ``assumptions``, the map's generation) while
        ``frt`` is the set cut: a refined set replacing it is cut anew."""
        cache_key = ((key, assumptions), entry.generation)
        with self._lock:
            found = self._cuts.get(cache_key)
            if found is not None and found[0] is frt:
                self._cuts.move_to_end(cache_key)
                return found[1]
        drivable = DRIVABLE_AREA in assumptions
        cut = None
        if REACHABLE_LANES in assumptions:
            cut = lane_cut(frt, entry.road, self.margin, drivable)
        if cut is None and drivable:
            cut = CutSet(frt, entry.road, self.margin)
        with self._lock:
            self._cuts[cache_key] = (frt, cut)
            self._cuts.move_to_end(cache_key)
            while len(self._cuts) > CUT_CACHE_SIZE:
                self._cuts.popitem(last=False)
        return cut


def registry_for(settings: Settings) -> MapRegistry:
    """The server's registry, with the map of ``FRT_MAP`` (if set) loaded as ``FRT_MAP_ID``."""
    registry = MapRegistry(settings.max_maps, settings.map_margin_m, settings.max_map_points)
    if settings.map is not None:
        registry.load_file(settings.map, settings.map_id)
    return registry
