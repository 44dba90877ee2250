"""``/v1/maps/{map_id}``: Argoverse 2 map archives whose drivable area cuts the sets."""

from __future__ import annotations

from typing import Annotated

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


@router.put("/{map_id}", response_model=MapResponse, openapi_extra=body_openapi(MapArchive))
async def put_map(map_id: MapIdPath, request: Request, services: ServicesDep) -> MapResponse:
    """Register an Argoverse 2 map archive as ``map_id`` (replacing the map of that id)."""
    return await maps.put_map(services, map_id, await request.body())


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
