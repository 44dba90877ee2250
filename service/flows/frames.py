"""One frame of many agents (API.md, "Frames"): every agent's observation of one instant in one
request, applied by the observation flow of ``service.flows.agents`` for all of them together
(``observe_many``: each stage once over the frame's agents; each agent's state is the one its
observation alone would give).

Each entry is validated on its own: an entry that is not a valid observation, names an agent
twice in the frame, or is refused by the flow (a stale timestamp, a range, a class change) is
answered by its index and dotted field and changes nothing of its agent; the others are applied.
Agents absent from a frame keep their state until their TTL.
"""

from __future__ import annotations

from typing import Any

from pydantic import TypeAdapter, ValidationError

from service.flows import agents
from service.runtime.services import Services
from service.wire.errors import APIError, validation_payload
from service.wire.limits import check_length
from service.wire.schemas import (
    AgentId,
    FrameError,
    FrameRejection,
    FrameRequest,
    FrameResponse,
    ObservationRequest,
    ObservationResponse,
)

_agent_id: TypeAdapter[str] = TypeAdapter(AgentId)


def _rejection(index: int, agent_id: str | None, exc: APIError) -> FrameRejection:
    field = f"agents.{index}" + (f".{exc.field}" if exc.field else "")
    return FrameRejection(
        agent_id=agent_id,
        index=index,
        error=FrameError(status=exc.status, detail=exc.detail, field=field),
    )


def _entry(index: int, raw: dict[str, Any], timestamp: float) -> tuple[str, ObservationRequest]:
    """The entry's agent id and observation, or a 422 naming its field (within the entry)."""
    if "agent_id" not in raw:
        raise APIError(422, "agent_id is required", field="agent_id")
    try:
        agent_id = _agent_id.validate_python(raw["agent_id"])
    except ValidationError:
        raise APIError(422, "agent_id must be 1-128 of [A-Za-z0-9_.:-]", field="agent_id") from None
    if "timestamp" in raw:
        raise APIError(422, "the frame's timestamp applies to every agent", field="timestamp")
    body = {k: v for k, v in raw.items() if k != "agent_id"}
    try:
        return agent_id, ObservationRequest.model_validate({**body, "timestamp": timestamp})
    except ValidationError as exc:
        payload = validation_payload(exc.errors())
        first = payload["detail"][0] if payload["detail"] else {"msg": "invalid value"}
        raise APIError(422, str(first["msg"]), field=payload["field"]) from None


async def apply_frame(services: Services, request: FrameRequest) -> FrameResponse:
    """Apply every valid entry of ``request``; one result per entry, in order."""
    check_length("agents", request.agents, services.settings.max_agents_per_frame)
    services.require_engine()
    seen: set[str] = set()
    results: list[ObservationResponse | FrameRejection | None] = [None] * len(request.agents)
    valid: list[tuple[int, str, ObservationRequest]] = []
    for index, raw in enumerate(request.agents):
        agent_id = raw.get("agent_id") if isinstance(raw.get("agent_id"), str) else None
        try:
            agent_id, observation = _entry(index, raw, request.timestamp)
            if agent_id in seen:
                raise APIError(422, "agent appears twice in the frame", field="agent_id")
        except APIError as exc:
            results[index] = _rejection(index, agent_id, exc)
            continue
        seen.add(agent_id)
        valid.append((index, agent_id, observation))
    applied = await agents.observe_many(services, [(a, o) for _, a, o in valid])
    for (index, agent_id, observation), result in zip(valid, applied, strict=True):
        if isinstance(result, APIError):
            results[index] = _rejection(index, agent_id, result)
        else:
            results[index] = agents.observation_response(services, observation, result)
    rejected = sum(isinstance(r, FrameRejection) for r in results)
    return FrameResponse(
        timestamp=request.timestamp,
        applied=len(results) - rejected,
        rejected=rejected,
        results=results,  # type: ignore[arg-type]
    )
