"""The WebSocket protocol (``WS /v1/stream``): the HTTP operations as JSON messages.

Request: ``{"id": <any JSON>, "op": <op>, ...fields}``; the fields are those of the matching HTTP
body, plus ``agent_id`` where the HTTP path has one:

- ``observe``: ``agent_id`` + an observation (``POST /v1/agents/{agent_id}/observations``);
- ``frame``: one frame of many agents (``POST /v1/frames``);
- ``collision_check``: ``agent_id`` + a check; without ``agent_id``, the multi-agent check
  (``agent_ids`` or all);
- ``frt``: ``agent_id`` + ``slices``, ``include``, ``tube``, ``collision_radius``,
  ``include_uncut`` (the agent's contours, and with ``include_uncut`` those of its set before the
  map assumptions cut it); without ``agent_id``, the stateless ``POST /v1/frt`` body;
- ``constraints``: ``agent_id`` + ``slices``, ``max_sides``, ``max_pieces``, ``collision_radius``
  (``GET /v1/agents/{agent_id}/constraints``);
- ``get_agent``, ``delete_agent``: ``agent_id``;
- ``list_agents``: no fields; ``{"agents": [...], "total": n, "truncated": bool, "checks": [...]}``,
  each agent as ``get_agent`` answers it, sorted by id, at most ``max_agents_per_check`` of them,
  and the trajectories checked in the last seconds (:mod:`service.api.recent_checks`); what the
  viewer, ``GET /viewer``, polls;
- ``ping``: answers ``{"pong": true}``.

Answer: ``{"id": ..., "ok": true, "result": ...}`` or ``{"id": ..., "ok": false, "error": {"status":
422, "detail": ..., "field": ...}}``. A malformed message gets an error answer; the socket stays open.
Messages are handled one at a time, in order, so a client's observations keep their order.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Awaitable, Callable
from typing import Any

from pydantic import BaseModel, ConfigDict, StrictBool, TypeAdapter, ValidationError

from service.api import recent_checks
from service.flows import agents, checks, constraints, contours, frames, stateless
from service.runtime.services import Services
from service.wire.errors import AgentNotFoundError, APIError, validation_payload
from service.wire.schemas import (
    AgentId,
    CollisionCheckRequest,
    ConstraintQuery,
    ContourQuery,
    FrameRequest,
    FRTRequest,
    MultiCollisionCheckRequest,
    ObservationRequest,
    Radius,
)

log = logging.getLogger("frt.stream")

_agent_id = TypeAdapter(AgentId)
#: Strict, as a JSON body's number is: "7" or true is not a radius.
_radius = TypeAdapter(Radius | None, config=ConfigDict(strict=True))
_flag = TypeAdapter(StrictBool)

Handler = Callable[[Services, dict[str, Any], float], Awaitable[BaseModel | dict[str, Any]]]


def _pop_agent_id(message: dict[str, Any], required: bool) -> str | None:
    if message.get("agent_id") is None:  # absent or null
        message.pop("agent_id", None)
        if required:
            raise APIError(422, "agent_id is required for this op", field="agent_id")
        return None
    value = message.pop("agent_id")
    try:
        return _agent_id.validate_python(value)
    except ValidationError:
        raise APIError(422, "agent_id must be 1-128 of [A-Za-z0-9_.:-]", field="agent_id") from None


async def _observe(services: Services, msg: dict[str, Any], arrival: float) -> BaseModel:
    agent_id = _pop_agent_id(msg, required=True)
    assert agent_id is not None
    return await agents.observe(services, agent_id, ObservationRequest.model_validate(msg))


async def _frame(services: Services, msg: dict[str, Any], arrival: float) -> BaseModel:
    return await frames.apply_frame(services, FrameRequest.model_validate(msg))


async def _collision_check(services: Services, msg: dict[str, Any], arrival: float) -> BaseModel:
    agent_id = _pop_agent_id(msg, required=False)
    if agent_id is None:
        body = MultiCollisionCheckRequest.model_validate(msg)
        many = await checks.check_agents_at_once(services, body, arrival)
        recent_checks.of(services).record(body, many.results)
        return many
    request = CollisionCheckRequest.model_validate(msg)
    answer = await checks.check_agent(services, agent_id, request, arrival)
    recent_checks.of(services).record(request, [answer])
    return answer


async def _frt(services: Services, msg: dict[str, Any], arrival: float) -> BaseModel:
    agent_id = _pop_agent_id(msg, required=False)
    if agent_id is None:
        return await stateless.stateless_frt(services, FRTRequest.model_validate(msg), arrival)
    try:
        radius = _radius.validate_python(msg.pop("collision_radius", None))
    except ValidationError:
        raise APIError(
            422, "collision_radius must be a number in [0, 100] m", field="collision_radius"
        ) from None
    try:
        include_uncut = _flag.validate_python(msg.pop("include_uncut", False))
    except ValidationError:
        raise APIError(422, "include_uncut must be true or false", field="include_uncut") from None
    query = ContourQuery.model_validate(msg)
    return await contours.agent_contours(
        services, agent_id, query, radius, location="", include_uncut=include_uncut
    )


async def _constraints(services: Services, msg: dict[str, Any], arrival: float) -> BaseModel:
    agent_id = _pop_agent_id(msg, required=True)
    assert agent_id is not None
    query = ConstraintQuery.model_validate(msg)
    return await constraints.agent_constraints(services, agent_id, query, location="")


def _no_other_fields(msg: dict[str, Any]) -> None:
    """422 naming the first field an op without a body does not know (HTTP bodies forbid them)."""
    if msg:
        raise APIError(422, "unknown field for this op", field=str(next(iter(msg))))


async def _get_agent(services: Services, msg: dict[str, Any], arrival: float) -> BaseModel:
    agent_id = _pop_agent_id(msg, required=True)
    assert agent_id is not None
    _no_other_fields(msg)
    return await agents.get_agent(services, agent_id)


async def _delete_agent(services: Services, msg: dict[str, Any], arrival: float) -> BaseModel:
    agent_id = _pop_agent_id(msg, required=True)
    assert agent_id is not None
    _no_other_fields(msg)
    return await agents.delete_agent(services, agent_id)


async def _list_agents(services: Services, msg: dict[str, Any], arrival: float) -> dict[str, Any]:
    _no_other_fields(msg)
    ids = sorted(await services.store.ids())
    limit = services.settings.max_agents_per_check
    listed = []
    for agent_id in ids[:limit]:
        try:
            listed.append((await agents.get_agent(services, agent_id)).model_dump(mode="json"))
        except AgentNotFoundError:  # deleted or expired since the ids were read
            continue
    checked = recent_checks.of(services).recent()
    return {"agents": listed, "total": len(ids), "truncated": len(ids) > limit, "checks": checked}


async def _ping(services: Services, msg: dict[str, Any], arrival: float) -> dict[str, Any]:
    _no_other_fields(msg)
    return {"pong": True}


OPS: dict[str, Handler] = {
    "observe": _observe,
    "frame": _frame,
    "collision_check": _collision_check,
    "frt": _frt,
    "constraints": _constraints,
    "get_agent": _get_agent,
    "delete_agent": _delete_agent,
    "list_agents": _list_agents,
    "ping": _ping,
}


def _json(value: Any) -> str:
    """Compact JSON, every non-ASCII character escaped: a string the client sent (an id, a key
    named in an error) may hold a lone surrogate, which has no UTF-8 form to send."""
    return json.dumps(value, separators=(",", ":"))


def _echoable(message_id: Any) -> bool:
    """Whether an id can be sent back as JSON (NaN and infinities have no JSON form)."""
    try:
        json.dumps(message_id, allow_nan=False)
    except ValueError:
        return False
    return True


def _error(message_id: Any, status: int, body: dict[str, Any]) -> str:
    return _json({"id": message_id, "ok": False, "error": {"status": status, **body}})


def _result(message_id: Any, result: BaseModel | dict[str, Any]) -> str:
    """The answer's text; a model is encoded by pydantic's own serialiser (a tenth of the cost of
    dumping it to a dict and encoding that, ``service.api.routes.model_json``)."""
    body = result.model_dump_json() if isinstance(result, BaseModel) else _json(result)
    return f'{{"id":{_json(message_id)},"ok":true,"result":{body}}}'


async def handle(services: Services, text: str, arrival: float) -> str:
    """One message in, the JSON text of one answer out; never raises."""
    if len(text.encode()) > services.settings.max_body_bytes:
        detail = f"message larger than {services.settings.max_body_bytes} bytes"
        return _error(None, 413, {"detail": detail})
    try:
        message = json.loads(text)
    except (ValueError, RecursionError):  # ValueError: also an integer too long to convert
        return _error(None, 400, {"detail": "message is not valid JSON"})
    if not isinstance(message, dict):
        return _error(None, 400, {"detail": "message must be a JSON object"})
    message_id = message.pop("id", None)
    if not _echoable(message_id):
        detail = "id must be JSON without NaN or infinite numbers"
        return _error(None, 422, {"detail": detail, "field": "id"})
    op = message.pop("op", None)
    handler = OPS.get(op) if isinstance(op, str) else None
    if handler is None:
        detail = f"op must be one of {', '.join(OPS)}"
        return _error(message_id, 422, {"detail": detail, "field": "op"})
    start = time.perf_counter()
    ok = False
    try:
        result = await handler(services, message, arrival)
        ok = True
    except ValidationError as exc:
        return _error(message_id, 422, validation_payload(exc.errors()))
    except APIError as exc:
        return _error(message_id, exc.status, exc.payload())
    except Exception as exc:  # a bug: log it, answer, keep the socket open
        log.exception("stream message failed", extra={"op": op, "error": repr(exc)})
        return _error(message_id, 500, {"detail": "internal server error"})
    finally:
        elapsed = time.perf_counter() - start
        services.metrics.ws_message_seconds.labels(op, "true" if ok else "false").observe(elapsed)
    return _result(message_id, result)
