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
from service.wire.frame_body import TypedFrame
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
#: A frame's observations validated in one call: a call per entry costs more than validating it.
_observations: TypeAdapter[list[ObservationRequest]] = TypeAdapter(list[ObservationRequest])


def _rejection(index: int, agent_id: str | None, exc: APIError) -> FrameRejection:
    field = f"agents.{index}" + (f".{exc.field}" if exc.field else "")
    return FrameRejection(
        agent_id=agent_id,
        index=index,
        error=FrameError(status=exc.status, detail=exc.detail, field=field),
    )


def _entry_body(raw: Any, timestamp: float) -> tuple[str, dict[str, Any]]:
    """The entry's agent id and its observation's body (the frame's timestamp in it), or a 422
    naming its field (within the entry)."""
    if not isinstance(raw, dict):
        raise APIError(422, "an entry must be an object")
    if "agent_id" not in raw:
        raise APIError(422, "agent_id is required", field="agent_id")
    try:
        agent_id = _agent_id.validate_python(raw["agent_id"])
    except ValidationError:
        raise APIError(422, "agent_id must be 1-128 of [A-Za-z0-9_.:-]", field="agent_id") from None
    if "timestamp" in raw:
        raise APIError(422, "the frame's timestamp applies to every agent", field="timestamp")
    body = {k: v for k, v in raw.items() if k != "agent_id"}
    body["timestamp"] = timestamp
    return agent_id, body


def _observation_or_error(body: dict[str, Any]) -> ObservationRequest | APIError:
    """One entry's observation, or a 422 naming its first invalid field (within the entry)."""
    try:
        return ObservationRequest.model_validate(body)
    except ValidationError as exc:
        payload = validation_payload(exc.errors())
        first = payload["detail"][0] if payload["detail"] else {"msg": "invalid value"}
        return APIError(422, str(first["msg"]), field=payload["field"])


def _entries(
    request: FrameRequest, results: list[ObservationResponse | FrameRejection | None]
) -> list[tuple[int, str, ObservationRequest]]:
    """The frame's valid entries (index, agent id, observation), each validated as its own
    observation would be, an agent's second valid entry refused; the others' rejections into
    ``results``. A frame read typed (:class:`TypedFrame`: every entry valid) is validated
    already; otherwise the observations are validated in one call, and entry by entry (to name
    what is wrong) only when one fails."""
    if isinstance(request, TypedFrame):
        observations = request.observations()
        checked: list[tuple[int, str, ObservationRequest | APIError]] = [
            (index, agent_id, observation)
            for index, (agent_id, observation) in enumerate(observations)
        ]
    else:
        checked = _checked(request, results)
    valid, seen = [], set()
    for index, agent_id, observation in checked:
        if not isinstance(observation, APIError) and agent_id in seen:
            observation = APIError(422, "agent appears twice in the frame", field="agent_id")
        if isinstance(observation, APIError):
            results[index] = _rejection(index, agent_id, observation)
            continue
        seen.add(agent_id)
        valid.append((index, agent_id, observation))
    return valid


def _checked(
    request: FrameRequest, results: list[ObservationResponse | FrameRejection | None]
) -> list[tuple[int, str, ObservationRequest | APIError]]:
    """Each entry with a valid agent id and no timestamp of its own: its observation, or the
    422 naming what is wrong in it (the others' rejections into ``results``)."""
    bodies: list[tuple[int, str, dict[str, Any]]] = []
    for index, raw in enumerate(request.agents):
        try:
            bodies.append((index, *_entry_body(raw, request.timestamp)))
        except APIError as exc:
            named = raw.get("agent_id") if isinstance(raw, dict) else None
            agent_id = named if isinstance(named, str) else None
            results[index] = _rejection(index, agent_id, exc)
    try:
        observations: list[ObservationRequest | APIError] = list(
            _observations.validate_python([body for _, _, body in bodies])
        )
    except ValidationError:
        observations = [_observation_or_error(body) for _, _, body in bodies]
    return [(i, a, o) for (i, a, _), o in zip(bodies, observations, strict=True)]


async def _met_first(
    services: Services, observations: list[tuple[str, ObservationRequest]]
) -> list[agents.Applied | APIError]:
    """``agents.observe_many`` of the agents whose sets a planner's trajectory met
    (``ExactDemand.met``) on their own, then of the others: the met agents' new versions are
    stored, and their exact sets under way, before the rest of a large frame is built, so that
    the checks answered meanwhile read those versions rather than the ones whose sets the new
    versions replaced in the queue."""
    demand = services.scheduler.demand
    if demand is None or len(observations) <= agents.STATES_PER_TURN:
        return await agents.observe_many(services, observations)
    met = [demand.met(agent_id) for agent_id, _ in observations]
    if all(met) or not any(met):
        return await agents.observe_many(services, observations)
    first = await agents.observe_many(
        services, [o for o, m in zip(observations, met, strict=True) if m]
    )
    rest = await agents.observe_many(
        services, [o for o, m in zip(observations, met, strict=True) if not m]
    )
    order = iter(first), iter(rest)
    return [next(order[0] if m else order[1]) for m in met]


async def apply_frame(services: Services, request: FrameRequest) -> FrameResponse:
    """Apply every valid entry of ``request``; one result per entry, in order."""
    check_length("agents", request.agents, services.settings.max_agents_per_frame)
    services.require_engine()
    results: list[ObservationResponse | FrameRejection | None] = [None] * len(request.agents)
    valid = _entries(request, results)
    applied = await _met_first(services, [(a, o) for _, a, o in valid])
    stored: list[tuple[int, ObservationRequest, agents.Applied]] = []
    for (index, agent_id, observation), result in zip(valid, applied, strict=True):
        if isinstance(result, APIError):
            results[index] = _rejection(index, agent_id, result)
        else:
            stored.append((index, observation, result))
    answers = agents.observation_responses(
        services, [o for _, o, _ in stored], [a for _, _, a in stored]
    )
    for (index, _, _), answer in zip(stored, answers, strict=True):
        results[index] = answer
    rejected = sum(isinstance(r, FrameRejection) for r in results)
    return FrameResponse(
        timestamp=request.timestamp,
        applied=len(results) - rejected,
        rejected=rejected,
        results=results,  # type: ignore[arg-type]
    )
