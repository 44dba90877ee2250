"""``/v1/agents/{agent_id}``: observations, the agent's state, forgetting it."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from service.api.routes.params import AgentIdPath, ServicesDep
from service.flows import agents
from service.wire.schemas import (
    AgentResponse,
    DeleteResponse,
    ObservationRequest,
    ObservationResponse,
)

router = APIRouter(prefix="/v1/agents", tags=["agents"])

WaitFrtMs = Annotated[
    float,
    Query(
        ge=0.0,
        le=10_000.0,
        description="wait up to this long for the exact FRT of the current version "
        "(answer as soon as frt_ready is true): one request instead of polling",
    ),
]


@router.post("/{agent_id}/observations", response_model=ObservationResponse)
async def observe(
    agent_id: AgentIdPath,
    body: ObservationRequest,
    services: ServicesDep,
    wait_frt_ms: WaitFrtMs = 0.0,
) -> ObservationResponse:
    """Score the observed action, update beta, store the new prediction, start the new FRT;
    with ``wait_frt_ms``, answer once that FRT is computed (or the wait is over)."""
    return await agents.observe(services, agent_id, body, wait_frt_ms / 1000.0)


@router.get("/{agent_id}", response_model=AgentResponse)
async def get_agent(
    agent_id: AgentIdPath, services: ServicesDep, wait_frt_ms: WaitFrtMs = 0.0
) -> AgentResponse:
    """The agent's beta, belief, control bounds, last timestamp, FRT version and config."""
    return await agents.get_agent(services, agent_id, wait_frt_ms / 1000.0)


@router.delete("/{agent_id}", response_model=DeleteResponse)
async def delete_agent(agent_id: AgentIdPath, services: ServicesDep) -> DeleteResponse:
    """Forget the agent and its cached sets."""
    return await agents.delete_agent(services, agent_id)
