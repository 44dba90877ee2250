"""``GET /v1/agents/{agent_id}/constraints``: convex pieces containing C, for a planner's MPC."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from reach.constraints import DEFAULT_PIECES, DEFAULT_SIDES, PIECES_RANGE, SIDES_RANGE
from service.api.routes.params import (
    AgentIdPath,
    CollisionRadiusQuery,
    ServicesDep,
    SlicesQuery,
    joined,
)
from service.flows import constraints
from service.wire.schemas import ConstraintsResponse

router = APIRouter(prefix="/v1", tags=["frt"])


@router.get("/agents/{agent_id}/constraints", response_model=ConstraintsResponse)
async def agent_constraints(
    agent_id: AgentIdPath,
    services: ServicesDep,
    slices: SlicesQuery = None,
    max_sides: Annotated[
        int, Query(ge=SIDES_RANGE[0], le=SIDES_RANGE[1], description="sides of a piece at most")
    ] = DEFAULT_SIDES,
    max_pieces: Annotated[
        int, Query(ge=PIECES_RANGE[0], le=PIECES_RANGE[1], description="pieces per time at most")
    ] = DEFAULT_PIECES,
    collision_radius: CollisionRadiusQuery = None,
) -> ConstraintsResponse:
    """Per requested time, convex pieces {x : A x <= b} in the world frame whose union contains C."""
    query = constraints.parse_query(
        joined("slices", slices, 4096), max_sides, max_pieces, collision_radius
    )
    return await constraints.agent_constraints(services, agent_id, query)
