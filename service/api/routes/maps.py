"""``/v1/maps/{map_id}``: Argoverse 2 map archives and Lanelet2 OSM files whose drivable area
cuts the sets."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path, Query, Request

from service.api.routes.json_body import body_openapi
from service.api.routes.params import ServicesDep
from service.flows import maps
from service.wire.schemas import (
    AGENT_ID_PATTERN,
    MapArchive,
    MapDeleteResponse,
    MapGeoJSONResponse,
    MapResponse,
)

router = APIRouter(prefix="/v1/maps", tags=["maps"])

MapIdPath = Annotated[str, Path(pattern=AGENT_ID_PATTERN, description="the map's id")]


def _put_openapi() -> dict[str, Any]:
    """The JSON archive's schema, and the Lanelet2 OSM file as XML beside it."""
    extra = body_openapi(MapArchive)
    osm = {"schema": {"type": "string", "description": "a Lanelet2 OSM file (XML)"}}
    for media in maps.XML_TYPES:
        extra["requestBody"]["content"][media] = osm
    return extra


@router.put("/{map_id}", response_model=MapResponse, openapi_extra=_put_openapi())
async def put_map(
    map_id: MapIdPath,
    request: Request,
    services: ServicesDep,
    origin_lat: Annotated[
        float | None,
        Query(ge=-90.0, le=90.0, description="a Lanelet2 map's projection origin, degrees"),
    ] = None,
    origin_lon: Annotated[
        float | None,
        Query(ge=-180.0, le=180.0, description="a Lanelet2 map's projection origin, degrees"),
    ] = None,
) -> MapResponse:
    """Register a map as ``map_id`` (replacing the map of that id): an Argoverse 2 archive
    (JSON) or a Lanelet2 OSM file (XML), told apart by the content type or the first byte."""
    origin = maps.origin_of(origin_lat, origin_lon)
    content_type = request.headers.get("content-type")
    return await maps.put_map(services, map_id, await request.body(), content_type, origin)


@router.get("/{map_id}", response_model=MapResponse)
async def get_map(map_id: MapIdPath, services: ServicesDep) -> MapResponse:
    """The map's summary: counts, extent, drivable area."""
    return await maps.get_map(services, map_id)


@router.delete("/{map_id}", response_model=MapDeleteResponse)
async def delete_map(map_id: MapIdPath, services: ServicesDep) -> MapDeleteResponse:
    """Forget the map and the sets cut by it."""
    return await maps.delete_map(services, map_id)


@router.get("/{map_id}/geojson", response_model=MapGeoJSONResponse)
async def map_geojson(
    map_id: MapIdPath,
    services: ServicesDep,
    bbox: Annotated[
        str | None,
        Query(
            max_length=256,
            description="x_min,y_min,x_max,y_max in metres, the map's frame, at most "
            f"{maps.MAX_BBOX_M:g} m on a side (default: the map's extent)",
        ),
    ] = None,
    simplify_m: Annotated[
        float,
        Query(
            ge=0.0,
            le=10.0,
            description="simplification tolerance, metres (doubled while the "
            f"answer holds more than {maps.MAX_VERTICES} vertices)",
        ),
    ] = 0.1,
    lanes: Annotated[bool, Query(description="each lane's area and centre line too")] = True,
) -> MapGeoJSONResponse:
    """The drivable area (and lanes) within the box, as a GeoJSON FeatureCollection."""
    return await maps.map_geojson(services, map_id, bbox, simplify_m, lanes)
