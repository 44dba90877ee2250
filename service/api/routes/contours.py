"""``GET /v1/agents/{agent_id}/frt``: GeoJSON contours of K and C."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from service.api.routes.params import (
    AgentIdPath,
    CollisionRadiusQuery,
    ServicesDep,
    SlicesQuery,
    joined,
)
from service.flows import contours
from service.wire.schemas import ContoursResponse

router = APIRouter(prefix="/v1", tags=["frt"])


@router.get("/agents/{agent_id}/frt", response_model=ContoursResponse)
async def agent_contours(
    agent_id: AgentIdPath,
    services: ServicesDep,
    slices: SlicesQuery = None,
    include: Annotated[
        list[str] | None, Query(description="comma-separated subset of K,C (default: both)")
    ] = None,
    tube: Annotated[bool, Query(description="include the whole-horizon tube")] = True,
    collision_radius: CollisionRadiusQuery = None,
    include_uncut: Annotated[
        bool,
        Query(
            description="also the contours of the set before the map assumptions cut it "
            "(`uncut`, null when none cut it)"
        ),
    ] = False,
) -> ContoursResponse:
    """The whole-horizon tube and the requested time slices, in the world frame."""
    query = contours.parse_query(
        joined("slices", slices, 4096), joined("include", include, 16), tube
    )
    return await contours.agent_contours(
        services, agent_id, query, collision_radius, include_uncut=include_uncut
    )
