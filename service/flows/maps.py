"""Maps over the API (``/v1/maps/{map_id}``): register an Argoverse 2 map archive or a Lanelet2
OSM file (told apart by the content type, else by the body's first non-blank byte), read its
summary, forget it (``service.runtime.maps``; docs/maps.md), and draw it: its drivable area and
lanes within a box as GeoJSON (``/v1/maps/{map_id}/geojson``), bounded in the box's size and the
answer's vertices."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry
from starlette.concurrency import run_in_threadpool

from reach.geojson import to_geojson
from reach.road_map import RoadMap
from service.runtime.maps import MapEntry
from service.runtime.services import Services
from service.wire.errors import FieldError
from service.wire.schemas import COORD_MAX, MapDeleteResponse, MapGeoJSONResponse, MapResponse


def _response(services: Services, entry: MapEntry, replaced: bool | None) -> MapResponse:
    return MapResponse(**entry.summary(), margin_m=services.maps.margin, replaced=replaced)


#: Content types of each map format; another (or none) is told by the body's first byte.
JSON_TYPES = ("application/json",)
XML_TYPES = ("application/xml", "text/xml", "application/osm+xml")


def map_format(content_type: str | None, raw: bytes) -> str:
    """``lanelet2`` for an XML content type, ``argoverse2`` for JSON; else ``lanelet2`` when the
    body's first non-blank byte is ``<`` and ``argoverse2`` otherwise."""
    media = (content_type or "").split(";", 1)[0].strip().lower()
    if media in JSON_TYPES:
        return "argoverse2"
    if media in XML_TYPES:
        return "lanelet2"
    return "lanelet2" if raw.lstrip()[:1] == b"<" else "argoverse2"


def origin_of(lat: float | None, lon: float | None) -> tuple[float, float] | None:
    """The projection origin of a Lanelet2 map's lat/lon: both given or neither (422)."""
    if (lat is None) != (lon is None):
        name = "origin_lon" if lon is None else "origin_lat"
        raise FieldError(name, "origin_lat and origin_lon go together", location="query")
    return None if lat is None or lon is None else (lat, lon)


async def put_map(
    services: Services,
    map_id: str,
    raw: bytes,
    content_type: str | None = None,
    origin: tuple[float, float] | None = None,
) -> MapResponse:
    """Parse, validate and index the map (its format by :func:`map_format`) in a worker thread
    (422 naming the field that is wrong: nothing is registered), then register it as
    ``map_id``, replacing any map of that id (409 when the server holds ``FRT_MAX_MAPS``
    others)."""
    kind = map_format(content_type, raw)
    road = await run_in_threadpool(services.maps.parse, raw, kind, origin)
    entry, replaced = services.maps.put(map_id, road, "api", len(raw))
    return _response(services, entry, replaced)


async def get_map(services: Services, map_id: str) -> MapResponse:
    """The map's summary (404 if unknown)."""
    return _response(services, services.maps.found(map_id), None)


async def delete_map(services: Services, map_id: str) -> MapDeleteResponse:
    """Forget the map and the sets cut by it (404 if unknown)."""
    services.maps.delete(map_id)
    return MapDeleteResponse(map_id=map_id, deleted=True)


#: The widest box one map GeoJSON answer covers (metres, on either side).
MAX_BBOX_M = 2000.0
#: Vertices one map GeoJSON answer holds at most: the simplification tolerance doubles until the
#: answer fits (:data:`SIMPLIFY_STEPS` times at most; past that the box is refused as too dense).
MAX_VERTICES = 50_000
SIMPLIFY_STEPS = 12
#: The tolerance the doubling starts from when the one asked for is 0 (metres).
MIN_STEP_M = 0.05

Feature = tuple[dict[str, Any], BaseGeometry]


def _bbox_error(message: str) -> FieldError:
    return FieldError("bbox", message, location="query")


def parse_bbox(text: str | None, extent: Sequence[float]) -> tuple[float, float, float, float]:
    """``bbox=x_min,y_min,x_max,y_max`` (metres, the map's frame), the map's extent without one;
    422 naming ``bbox`` unless it is four finite numbers within ±10⁷ m, each max above its min,
    at most :data:`MAX_BBOX_M` on a side."""
    if text is None:
        values = [float(v) for v in extent]
    else:
        parts = text.split(",")
        if len(parts) != 4:
            raise _bbox_error("four comma-separated numbers: x_min,y_min,x_max,y_max")
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise _bbox_error(f"not four numbers: {text!r}") from None
    if not all(math.isfinite(v) and abs(v) <= COORD_MAX for v in values):
        raise _bbox_error(f"numbers must be finite and within ±{COORD_MAX:g} m")
    x0, y0, x1, y1 = values
    if not (x1 > x0 and y1 > y0):
        raise _bbox_error("x_max must exceed x_min and y_max y_min")
    if max(x1 - x0, y1 - y0) > MAX_BBOX_M:
        whose = "the map's extent" if text is None else "the box"
        raise _bbox_error(
            f"{whose} is {x1 - x0:.0f} × {y1 - y0:.0f} m: at most {MAX_BBOX_M:g} m on a side"
        )
    return x0, y0, x1, y1


def _lines(geometry: BaseGeometry) -> dict[str, Any] | None:
    """A GeoJSON MultiLineString of the geometry's lines (millimetres), None if it has none."""
    lines = [
        np.round(shapely.get_coordinates(part), 3).tolist()
        for part in shapely.get_parts(geometry)
        if isinstance(part, shapely.LineString) and not part.is_empty
    ]
    return {"type": "MultiLineString", "coordinates": lines} if lines else None


def map_features(
    road: RoadMap, margin: float, box: tuple[float, ...], lanes: bool
) -> list[Feature]:
    """The map within ``box``: D, and each lane's area and centre line (``lanes``), clipped to
    the box. The lanes come from the lanes' STRtree; D is clipped (a pass over its vertices) only
    when a tile of R's index meets the box."""
    region = road.region(margin)
    rect = shapely.box(*box)
    features: list[Feature] = []
    if (region.tree.query(rect) < region.road_tiles).any():
        features.append(({"kind": "drivable_area"}, shapely.clip_by_rect(road.drivable, *box)))
    if lanes:
        graph = road.lane_graph
        for i in sorted(graph.index(margin, region).tree.query(rect).tolist()):
            lane = road.lanes[i]
            props = {
                "lane_id": lane.id,
                "lane_type": lane.lane_type,
                "is_intersection": lane.is_intersection,
            }
            area = shapely.clip_by_rect(graph.areas[i], *box)
            line = shapely.clip_by_rect(shapely.LineString(graph.lines[i]), *box)
            features += [({"kind": "lane", **props}, area), ({"kind": "centerline", **props}, line)]
    return features


def simplified(features: list[Feature], tolerance: float) -> tuple[list[Feature], float, int]:
    """``features`` simplified (topology kept) at ``tolerance``, doubled while they hold more
    than :data:`MAX_VERTICES` vertices: (features, tolerance used, vertices); 422 naming ``bbox``
    if they do not fit after :data:`SIMPLIFY_STEPS` doublings."""
    geometries = np.array([g for _, g in features], dtype=object)
    for _ in range(SIMPLIFY_STEPS + 1):
        out = shapely.simplify(geometries, tolerance, preserve_topology=True)
        vertices = int(shapely.get_num_coordinates(out).sum()) if len(out) else 0
        if vertices <= MAX_VERTICES:
            return [(p, g) for (p, _), g in zip(features, out, strict=True)], tolerance, vertices
        tolerance = max(2.0 * tolerance, MIN_STEP_M)
    raise _bbox_error(f"more than {MAX_VERTICES} vertices of map in the box: ask for a smaller one")


def feature_collection(features: list[Feature]) -> list[dict[str, Any]]:
    """GeoJSON Features of ``features``; parts left without area or length are left out."""
    out = []
    for props, geometry in features:
        if props["kind"] == "centerline":
            shape = _lines(geometry)
        else:
            shape = to_geojson(geometry)
            shape = shape if shape["coordinates"] else None
        if shape is not None:
            out.append({"type": "Feature", "properties": props, "geometry": shape})
    return out


async def map_geojson(
    services: Services, map_id: str, bbox: str | None, simplify_m: float, lanes: bool
) -> MapGeoJSONResponse:
    """The map's geometry within ``bbox`` for drawing (404 if the map is unknown, 422 naming
    ``bbox`` if it is malformed, too large or holds too much); the geometry work runs in a
    worker thread."""
    entry = services.maps.found(map_id)
    box = parse_bbox(bbox, entry.road.extent)
    margin = services.maps.margin

    def compute() -> tuple[list[dict[str, Any]], float, int]:
        features = map_features(entry.road, margin, box, lanes)
        kept, tolerance, vertices = simplified(features, simplify_m)
        return feature_collection(kept), tolerance, vertices

    features, tolerance, vertices = await run_in_threadpool(compute)
    return MapGeoJSONResponse(
        features=features,
        map_id=map_id,
        bbox=list(box),
        extent=list(entry.road.extent),
        simplify_m=tolerance,
        vertices=vertices,
    )
