"""The operations of the API, described once, without I/O ("sans-IO").

Each function turns a method's arguments into a :class:`Call`: the HTTP request (method, path,
query, JSON body), the same operation as a ``WS /v1/stream`` message, the response type, and
whether the call is idempotent (safe to send twice). :class:`~frt_client.FRTClient`,
:class:`~frt_client.AsyncFRTClient` and the streams only execute calls, so the three stay in step.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar
from urllib.parse import quote

from frt_client import inputs
from frt_client.errors import ValidationError
from frt_client.models import (
    Agent,
    AgentConstraints,
    AgentContours,
    CollisionCheck,
    DeleteResult,
    FrameResult,
    FRTResult,
    Health,
    ModelCard,
    MultiCollisionCheck,
    ObservationResult,
    Readiness,
    Response,
)

T = TypeVar("T", bound=Response)


@dataclass(frozen=True)
class Call(Generic[T]):
    """One operation: how to send it over HTTP and over the stream, and what comes back."""

    method: str
    path: str
    model: type[T]
    #: Safe to repeat: reads, checks and deletes. Observations are not (they move the filter).
    idempotent: bool
    json: dict[str, Any] | None = None
    params: dict[str, Any] | None = None
    #: The ``op`` of the stream message, or ``None`` if the stream has no such operation.
    op: str | None = None
    #: The stream message's fields besides ``id`` and ``op``.
    message: dict[str, Any] = field(default_factory=dict)
    #: HTTP error statuses whose body is still a valid answer (``/readyz`` answers 503 + body).
    ok_statuses: tuple[int, ...] = ()


def _agent_path(agent_id: str, suffix: str = "") -> str:
    if not isinstance(agent_id, str) or not agent_id:
        raise ValidationError("agent_id must be a non-empty string", field="agent_id")
    return f"/v1/agents/{quote(agent_id, safe='')}{suffix}"


def observe(
    agent_id: str,
    *,
    timestamp: float,
    state: Any,
    prediction: Any,
    observed_action: Any = None,
    config: Any = None,
    wait_frt_ms: float = 0.0,
    agent_class: str | None = None,
    map_id: str | None = None,
) -> Call[ObservationResult]:
    body = inputs.without_none(
        {
            "timestamp": inputs.plain(timestamp),
            "state": inputs.state(state),
            "observed_action": inputs.action(observed_action),
            "prediction": inputs.prediction(prediction),
            "config": inputs.config(config),
            "agent_class": agent_class,
            "map_id": map_id,
        }
    )
    return Call(
        "POST",
        _agent_path(agent_id, "/observations"),
        ObservationResult,
        idempotent=False,
        json=body,
        op="observe",
        message={"agent_id": agent_id, **body},
        params={"wait_frt_ms": wait_frt_ms} if wait_frt_ms > 0 else None,
    )


def frame(*, timestamp: float, agents: Iterable[Any]) -> Call[FrameResult]:
    """One frame: per agent a mapping of ``agent_id``, ``state``, ``prediction`` and, as in
    :func:`observe`, ``observed_action``, ``config``, ``agent_class``, ``map_id``."""
    entries = []
    for i, agent in enumerate(agents):
        if not isinstance(agent, dict) or "agent_id" not in agent:
            raise ValidationError("each agent needs an agent_id", field=f"agents.{i}.agent_id")
        entries.append(
            inputs.without_none(
                {
                    "agent_id": agent["agent_id"],
                    "state": inputs.state(agent.get("state")),
                    "observed_action": inputs.action(agent.get("observed_action")),
                    "prediction": inputs.prediction(agent.get("prediction")),
                    "config": inputs.config(agent.get("config")),
                    "agent_class": agent.get("agent_class"),
                    "map_id": agent.get("map_id"),
                }
            )
        )
    body = {"timestamp": inputs.plain(timestamp), "agents": entries}
    return Call(
        "POST", "/v1/frames", FrameResult, idempotent=False, json=body, op="frame", message=body
    )


def get_agent(agent_id: str, wait_frt_ms: float = 0.0) -> Call[Agent]:
    return Call(
        "GET",
        _agent_path(agent_id),
        Agent,
        idempotent=True,
        op="get_agent",
        message={"agent_id": agent_id},
        params={"wait_frt_ms": wait_frt_ms} if wait_frt_ms > 0 else None,
    )


def delete_agent(agent_id: str) -> Call[DeleteResult]:
    return Call(
        "DELETE",
        _agent_path(agent_id),
        DeleteResult,
        idempotent=True,
        op="delete_agent",
        message={"agent_id": agent_id},
    )


@dataclass(frozen=True)
class CheckOptions:
    """What a collision check asks besides its points (see ``FRTClient.collision_check``)."""

    mode: str = "tube"
    collision_radius: float | None = None
    deadline_ms: float | None = None
    footprint: Any = None
    include_clearance: bool = False


def _check_body(trajectory: Any, trajectories: Any, options: CheckOptions) -> dict[str, Any]:
    """The body of a check: a batch as packed columns (``inputs.packed_trajectories``), or as
    columns where its trajectories differ in carrying headings."""
    if (trajectory is None) == (trajectories is None):
        raise ValidationError("give exactly one of trajectory and trajectories", field="trajectory")
    packed = None if trajectories is None else inputs.packed_trajectories(trajectories)
    columns = None
    if trajectories is not None and packed is None:
        columns = inputs.trajectories(trajectories)
    return inputs.without_none(
        {
            "trajectory": None if trajectory is None else inputs.trajectory(trajectory),
            "trajectories": columns,
            "packed_trajectories": packed,
            "mode": options.mode,
            "collision_radius": inputs.plain(options.collision_radius),
            "deadline_ms": inputs.plain(options.deadline_ms),
            "footprint": inputs.footprint(options.footprint),
            "include_clearance": True if options.include_clearance else None,
            # A batch's answers as a list per field: written and read faster than an entry each.
            "answer_columns": None if trajectories is None else True,
        }
    )


def collision_check(
    agent_id: str,
    trajectory: Any = None,
    *,
    trajectories: Any = None,
    options: CheckOptions = CheckOptions(),
) -> Call[CollisionCheck]:
    body = _check_body(trajectory, trajectories, options)
    return Call(
        "POST",
        _agent_path(agent_id, "/collision-check"),
        CollisionCheck,
        idempotent=True,
        json=body,
        op="collision_check",
        message={"agent_id": agent_id, **body},
    )


def collision_check_many(
    trajectory: Any = None,
    agent_ids: Iterable[str] | None = None,
    *,
    trajectories: Any = None,
    options: CheckOptions = CheckOptions(),
) -> Call[MultiCollisionCheck]:
    body = _check_body(trajectory, trajectories, options)
    # An explicit null means "every known agent"; an empty list means none.
    body["agent_ids"] = None if agent_ids is None else [str(a) for a in agent_ids]
    return Call(
        "POST",
        "/v1/collision-check",
        MultiCollisionCheck,
        idempotent=True,
        json=body,
        op="collision_check",
        message=body,
    )


def contours(
    agent_id: str,
    *,
    slices: Iterable[float] = (),
    include: Iterable[str] = ("K", "C"),
    tube: bool = True,
    collision_radius: float | None = None,
    include_uncut: bool = False,
) -> Call[AgentContours]:
    times = [float(t) for t in inputs.plain(slices)]
    parts = [str(p) for p in include]
    radius = None if collision_radius is None else float(collision_radius)
    params: dict[str, Any] = {"include": ",".join(parts), "tube": "true" if tube else "false"}
    if times:
        params["slices"] = ",".join(repr(t) for t in times)
    if radius is not None:
        params["collision_radius"] = repr(radius)
    if include_uncut:
        params["include_uncut"] = "true"
    message = inputs.without_none(
        {
            "agent_id": agent_id,
            "slices": times,
            "include": parts,
            "tube": bool(tube),
            "collision_radius": radius,
            "include_uncut": True if include_uncut else None,
        }
    )
    return Call(
        "GET",
        _agent_path(agent_id, "/frt"),
        AgentContours,
        idempotent=True,
        params=params,
        op="frt",
        message=message,
    )


def constraints(
    agent_id: str,
    *,
    slices: Iterable[float],
    collision_radius: float | None = None,
    max_sides: int | None = None,
    max_pieces: int | None = None,
) -> Call[AgentConstraints]:
    times = [float(t) for t in inputs.plain(slices)]
    fields = inputs.without_none(
        {
            "slices": times,
            "collision_radius": None if collision_radius is None else float(collision_radius),
            "max_sides": inputs.plain(max_sides),
            "max_pieces": inputs.plain(max_pieces),
        }
    )
    params = {
        key: ",".join(repr(t) for t in value) if key == "slices" else repr(value)
        for key, value in fields.items()
    }
    return Call(
        "GET",
        _agent_path(agent_id, "/constraints"),
        AgentConstraints,
        idempotent=True,
        params=params,
        op="constraints",
        message={"agent_id": agent_id, **fields},
    )


def frt(
    state: Any,
    *,
    control_bounds: Any = None,
    prediction: Any = None,
    beta: float | None = None,
    gamma: float | None = None,
    bounds_fit: str | None = None,
    bounds_rule: str | None = None,
    rescue_onset: float | None = None,
    collision_radius: float | None = None,
    contours: dict[str, Any] | None = None,
    trajectory: Any = None,
    mode: str = "tube",
    deadline_ms: float | None = None,
    timestamp: float = 0.0,
) -> Call[FRTResult]:
    body = inputs.without_none(
        {
            "timestamp": inputs.plain(timestamp),
            "state": inputs.state(state),
            "control_bounds": None if control_bounds is None else inputs.bounds(control_bounds),
            "prediction": None if prediction is None else inputs.prediction(prediction),
            "beta": inputs.plain(beta),
            "gamma": inputs.plain(gamma),
            "bounds_fit": bounds_fit,
            "bounds_rule": bounds_rule,
            "rescue_onset": inputs.plain(rescue_onset),
            "collision_radius": inputs.plain(collision_radius),
            "contours": None if contours is None else inputs.plain(contours),
            "trajectory": None if trajectory is None else inputs.trajectory(trajectory),
            "mode": mode,
            "deadline_ms": inputs.plain(deadline_ms),
        }
    )
    return Call("POST", "/v1/frt", FRTResult, idempotent=True, json=body, op="frt", message=body)


def model() -> Call[ModelCard]:
    return Call("GET", "/v1/model", ModelCard, idempotent=True)


def health() -> Call[Health]:
    return Call("GET", "/healthz", Health, idempotent=True)


def ready() -> Call[Readiness]:
    return Call("GET", "/readyz", Readiness, idempotent=True, ok_statuses=(503,))
