"""``/v1/agents/{agent_id}``: observations, the agent's state, forgetting it."""

from __future__ import annotations

from fastapi import APIRouter

from service import agents
from service.routes.params import AgentIdPath, ServicesDep
from service.schemas import AgentResponse, DeleteResponse, ObservationRequest, ObservationResponse

router = APIRouter(prefix="/v1/agents", tags=["agents"])


@router.post("/{agent_id}/observations", response_model=ObservationResponse)
async def observe(
    agent_id: AgentIdPath, body: ObservationRequest, services: ServicesDep
) -> ObservationResponse:
    """Score the observed action, update beta, store the new prediction, start the new FRT."""
    return await agents.observe(services, agent_id, body)


@router.get("/{agent_id}", response_model=AgentResponse)
async def get_agent(agent_id: AgentIdPath, services: ServicesDep) -> AgentResponse:
    """The agent's beta, belief, control bounds, last timestamp, FRT version and config."""
    return await agents.get_agent(services, agent_id)


@router.delete("/{agent_id}", response_model=DeleteResponse)
async def delete_agent(agent_id: AgentIdPath, services: ServicesDep) -> DeleteResponse:
    """Forget the agent and its cached sets."""
    return await agents.delete_agent(services, agent_id)
