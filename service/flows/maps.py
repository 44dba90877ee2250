"""Maps over the API (``/v1/maps/{map_id}``): register an Argoverse 2 map archive, read its
summary, forget it (``service.runtime.maps``; docs/maps.md)."""

from __future__ import annotations

from starlette.concurrency import run_in_threadpool

from service.runtime.maps import MapEntry
from service.runtime.services import Services
from service.wire.schemas import MapDeleteResponse, MapResponse


def _response(services: Services, entry: MapEntry, replaced: bool | None) -> MapResponse:
    return MapResponse(**entry.summary(), margin_m=services.maps.margin, replaced=replaced)


async def put_map(services: Services, map_id: str, raw: bytes) -> MapResponse:
    """Parse, validate and index the archive in a worker thread (422 naming the field that is
    wrong: nothing is registered), then register it as ``map_id``, replacing any map of that id
    (409 when the server holds ``FRT_MAX_MAPS`` others)."""
    road = await run_in_threadpool(services.maps.parse, raw)
    entry, replaced = services.maps.put(map_id, road, "api", len(raw))
    return _response(services, entry, replaced)


async def get_map(services: Services, map_id: str) -> MapResponse:
    """The map's summary (404 if unknown)."""
    return _response(services, services.maps.found(map_id), None)


async def delete_map(services: Services, map_id: str) -> MapDeleteResponse:
    """Forget the map and the sets cut by it (404 if unknown)."""
    services.maps.delete(map_id)
    return MapDeleteResponse(map_id=map_id, deleted=True)
