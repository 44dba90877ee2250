"""The server's array-length limits (settings), enforced on parsed requests with a 422 naming the field.

The schemas carry fixed hard caps; these are the tighter, configurable ones.
"""

from __future__ import annotations

from collections.abc import Sized
from typing import Any, Protocol

from service.wire.errors import FieldError


class RequestLimits(Protocol):
    """The configurable limits (``service.runtime.settings.Settings`` has them)."""

    max_prediction_steps: int
    max_trajectory_points: int
    max_agents_per_check: int
    max_agents_per_frame: int
    max_slices: int
    max_trajectories: int
    max_check_points: int
    max_check_work: int


def check_length(field: str, value: Sized | None, limit: int) -> None:
    if value is not None and len(value) > limit:
        raise FieldError(field, f"at most {limit} items allowed, got {len(value)}")


def check_prediction_steps(field: str, mean: Sized, settings: RequestLimits) -> None:
    check_length(f"{field}.mean", mean, settings.max_prediction_steps)


def check_trajectory(field: str, trajectory: Sized | None, settings: RequestLimits) -> None:
    check_length(field, trajectory, settings.max_trajectory_points)


def check_agents(field: str, agent_ids: Sized | None, settings: RequestLimits) -> None:
    check_length(field, agent_ids, settings.max_agents_per_check)


def check_slices(
    field: str, slices: list[float], horizon_s: float, settings: RequestLimits
) -> None:
    check_length(field, slices, settings.max_slices)
    for i, t in enumerate(slices):
        if not 0.0 <= t <= horizon_s:
            raise FieldError(f"{field}.{i}", f"slice time {t} is outside [0, {horizon_s}] s")


def openapi_with_limits(spec: dict[str, Any], settings: RequestLimits) -> dict[str, Any]:
    """Write the settings' limits into the schema's ``maxItems`` (the models carry the hard caps),
    so clients and fuzzers see the limits this server enforces."""
    limits = {
        "mean": settings.max_prediction_steps,
        "cov": settings.max_prediction_steps,
        "trajectory": settings.max_trajectory_points,
        "agent_ids": settings.max_agents_per_check,
        "agents": settings.max_agents_per_frame,
        "trajectories": settings.max_trajectories,
        "slices": settings.max_slices,
    }

    def tighten(schema: Any, limit: int) -> None:
        if isinstance(schema, dict):
            if schema.get("type") == "array" and "maxItems" in schema:
                schema["maxItems"] = min(schema["maxItems"], limit)
            for option in schema.get("anyOf", []):
                tighten(option, limit)

    for component in spec.get("components", {}).get("schemas", {}).values():
        for name, prop in component.get("properties", {}).items():
            if name in limits:
                tighten(prop, limits[name])
    return spec
