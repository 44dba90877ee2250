"""Collision checks of a robot trajectory (or a batch of them) against one agent or several."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Request

from service.api import recent_checks
from service.api.middleware import arrival_time
from service.api.routes.json_body import body_openapi, json_body
from service.api.routes.model_json import ModelJSONResponse
from service.api.routes.params import AgentIdPath, ServicesDep
from service.flows import checks
from service.wire.batch_body import parse_batch_check
from service.wire.schemas import (
    CollisionCheckRequest,
    CollisionCheckResponse,
    MultiCollisionCheckRequest,
    MultiCollisionCheckResponse,
)

router = APIRouter(prefix="/v1", tags=["collision"])

OneAgentCheck = Annotated[
    CollisionCheckRequest, json_body(CollisionCheckRequest, parse_batch_check)
]
ManyAgentsCheck = Annotated[
    MultiCollisionCheckRequest, json_body(MultiCollisionCheckRequest, parse_batch_check)
]


@router.post(
    "/agents/{agent_id}/collision-check",
    response_model=CollisionCheckResponse,
    openapi_extra=body_openapi(CollisionCheckRequest),
)
async def check_agent(
    agent_id: AgentIdPath,
    body: OneAgentCheck,
    request: Request,
    services: ServicesDep,
) -> ModelJSONResponse:
    """Is the trajectory inside C = K ⊕ R_col? Answers within ``deadline_ms``, conservatively if
    the exact set is not ready."""
    answer = await checks.check_agent(services, agent_id, body, arrival_time(request.scope))
    recent_checks.of(services).record(body, [answer])
    return ModelJSONResponse(answer)


@router.post(
    "/collision-check",
    response_model=MultiCollisionCheckResponse,
    openapi_extra=body_openapi(MultiCollisionCheckRequest),
)
async def check_many(
    body: ManyAgentsCheck,
    request: Request,
    services: ServicesDep,
) -> ModelJSONResponse:
    """The same check against several agents (``agent_ids``) or all of them (``null``)."""
    answer = await checks.check_agents_at_once(services, body, arrival_time(request.scope))
    recent_checks.of(services).record(body, answer.results)
    return ModelJSONResponse(answer)
