"""Request parts, and their conversion from whatever a planner has at hand to JSON.

Every method of the clients accepts, for each part, either the typed model below, a plain dict with
the same keys, or a bare sequence (a list, a tuple, or a numpy array; anything with ``.tolist()`` is
converted with it, so numpy stays optional):

- a state ``(x, y, heading, speed)``; an action ``(steering_rate, acceleration)``;
- a prediction ``{"dt": 0.1, "mean": (S, 2) array, "cov": (S, 2, 2) array}``;
- a trajectory ``(N, 3)`` of rows ``(t, x, y)`` (``(N, 4)`` with the ego's heading), or a list of
  ``{"t", "x", "y"[, "heading"]}`` points; a batch of them as a sequence of trajectories;
- a footprint ``(length, width[, rear_axle_to_center])``;
- control bounds: eight numbers in the model contract's order (see :data:`BOUND_COLUMNS`).

The SDK only reshapes and type-checks; ranges, shapes and positive definiteness are the service's to
judge (its 422 names the field). A part the SDK cannot even reshape raises
:class:`~frt_client.errors.ValidationError` with ``status=None``.
"""

from __future__ import annotations

import base64
import sys
from array import array
from collections.abc import Mapping, Sequence
from typing import Any

import pydantic
from pydantic import BaseModel, ConfigDict, field_validator

from frt_client.errors import ValidationError
from frt_client.models import Assumption, BoundsFit, BoundsRule, ControlBounds

#: The eight control-bound columns, in the model contract's order.
BOUND_COLUMNS: tuple[str, ...] = (
    "u1_min_start",
    "u2_min_start",
    "u1_min_end",
    "u2_min_end",
    "u1_max_start",
    "u2_max_start",
    "u1_max_end",
    "u2_max_end",
)


def plain(value: Any) -> Any:
    """``value`` as JSON-ready Python: arrays and numpy scalars via ``.tolist()``, models dumped."""
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json", exclude_none=True)
    if hasattr(value, "tolist") and not isinstance(value, str | bytes):
        return value.tolist()
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    return value


class RequestPart(BaseModel):
    """Base of the request parts: no unknown keys, numpy arrays accepted."""

    model_config = ConfigDict(extra="forbid")

    @field_validator("*", mode="before")
    @classmethod
    def _numpy_to_lists(cls, value: Any) -> Any:
        return plain(value)


class HumanState(RequestPart):
    """The human's state in the world frame: metres, radians from +x (CCW), m/s."""

    x: float
    y: float
    heading: float
    speed: float


class ObservedAction(RequestPart):
    """The action the human took since the previous observation: rad/s and m/s²."""

    steering_rate: float
    acceleration: float


class Prediction(RequestPart):
    """A predictor's Gaussian over the controls, one step of ``dt`` seconds per row.

    ``mean`` is ``(S, 2)`` (steering rate, acceleration); ``cov`` is ``(S, 2, 2)``.
    """

    dt: float
    mean: list[list[float]]
    cov: list[list[list[float]]]


class AgentConfig(RequestPart):
    """Per-agent settings; omitted fields keep the agent's (or the server's) values."""

    beta_low: float | None = None
    gamma: float | None = None
    epsilon: float | None = None
    collision_radius: float | None = None
    bounds_fit: BoundsFit | None = None
    #: How confidence widens the bounds: "paper", "uniform_mixture" or "mass_ramp"
    #: (docs/confidence.md), and the distrust 1 - beta below which every rule is the paper's.
    bounds_rule: BoundsRule | None = None
    rescue_onset: float | None = None
    #: Adaptive gamma: the long-run share of audited positions inside C to hold, and its step.
    coverage_target: float | None = None
    coverage_step: float | None = None
    #: The map assumptions to answer under where the agent names a map ("drivable_area",
    #: "reachable_lanes", "speed_limit"; [] for none; default: the server's).
    assumptions: list[Assumption] | None = None


class TrajectoryPoint(RequestPart):
    """A robot position at time ``t`` (seconds, on the observations' clock), and its heading
    (radians; needed with a footprint)."""

    t: float
    x: float
    y: float
    heading: float | None = None


class Footprint(RequestPart):
    """The ego's box (metres), along each point's heading; its centre ``rear_axle_to_center``
    ahead of the point."""

    length: float
    width: float
    rear_axle_to_center: float = 0.0


def _model(cls: type[RequestPart], value: Any, name: str, fields: Sequence[str]) -> dict[str, Any]:
    """``value`` (a model, mapping or sequence in ``fields`` order) validated as ``cls``, dumped."""
    if isinstance(value, cls):
        return value.model_dump(mode="json", exclude_none=True)
    data = plain(value)
    if isinstance(data, list):
        if len(data) != len(fields):
            raise ValidationError(
                f"{name}: expected {len(fields)} numbers ({', '.join(fields)}), got {len(data)}",
                field=name,
            )
        data = dict(zip(fields, data, strict=True))
    try:
        return cls.model_validate(data).model_dump(mode="json", exclude_none=True)
    except pydantic.ValidationError as exc:
        raise ValidationError(f"{name}: {exc}", field=name, detail=exc.errors()) from None


def state(value: Any) -> dict[str, Any]:
    """A :class:`HumanState`, a mapping, or ``(x, y, heading, speed)``."""
    return _model(HumanState, value, "state", ("x", "y", "heading", "speed"))


def action(value: Any) -> dict[str, Any] | None:
    """An :class:`ObservedAction`, a mapping, ``(steering_rate, acceleration)``, or ``None``."""
    if value is None:
        return None
    return _model(ObservedAction, value, "observed_action", ("steering_rate", "acceleration"))


class PredictionMode(RequestPart):
    """One mode of a multi-modal prediction: its weight and its Gaussian, one row per step."""

    weight: float
    mean: list[list[float]]
    cov: list[list[list[float]]]


class MixturePrediction(RequestPart):
    """A multi-modal prediction (at most 32 modes; see :mod:`frt_client.mixtures`)."""

    dt: float
    modes: list[PredictionMode]


def prediction(value: Any) -> dict[str, Any]:
    """A :class:`Prediction` or :class:`MixturePrediction`, or a mapping with ``dt`` and either
    ``mean`` and ``cov`` or ``modes``."""
    if isinstance(value, MixturePrediction) or (isinstance(value, Mapping) and "modes" in value):
        return _model(MixturePrediction, value, "prediction", ("dt", "modes"))
    return _model(Prediction, value, "prediction", ("dt", "mean", "cov"))


def config(value: Any) -> dict[str, Any] | None:
    """An :class:`AgentConfig`, a mapping, or ``None``."""
    if value is None:
        return None
    return _model(AgentConfig, value, "config", ())


def bounds(value: Any) -> dict[str, Any]:
    """Control bounds: a model or mapping with the eight columns, or eight numbers in order."""
    if isinstance(value, ControlBounds):
        return value.model_dump(mode="json")
    data = plain(value)
    if isinstance(data, list):
        if len(data) != len(BOUND_COLUMNS):
            raise ValidationError(
                f"control_bounds: expected 8 numbers, got {len(data)}", field="control_bounds"
            )
        data = dict(zip(BOUND_COLUMNS, data, strict=True))
    if not isinstance(data, dict):
        raise ValidationError(
            "control_bounds: expected 8 numbers or a mapping", field="control_bounds"
        )
    return data


_POINT_FIELDS = ("t", "x", "y")
_HEADED_POINT_FIELDS = ("t", "x", "y", "heading")


def trajectory(value: Any, name: str = "trajectory") -> list[dict[str, Any]]:
    """Points as ``(N, 3)`` rows ``(t, x, y)`` or ``(N, 4)`` rows ``(t, x, y, heading)``, or
    :class:`TrajectoryPoint` s, or mappings."""
    if isinstance(value, BaseModel):
        value = [value]
    data = plain(value)
    if isinstance(data, Mapping) or not isinstance(data, Sequence) or isinstance(data, str):
        raise ValidationError(f"{name}: expected a sequence of (t, x, y) points", field=name)
    return [
        _model(
            TrajectoryPoint,
            point,
            f"{name}.{i}",
            _HEADED_POINT_FIELDS if isinstance(point, list) and len(point) == 4 else _POINT_FIELDS,
        )
        for i, point in enumerate(data)
    ]


def trajectory_columns(value: Any, name: str) -> dict[str, list[float]]:
    """One trajectory (any form :func:`trajectory` takes) as the columns ``{t, x, y[, heading]}``
    the service parses fastest."""
    points = trajectory(value, name)
    columns = {key: [p[key] for p in points] for key in _POINT_FIELDS}
    headings = [p.get("heading") for p in points]
    if any(h is not None for h in headings):
        if any(h is None for h in headings):
            raise ValidationError(f"{name}: a heading at every point or none", field=name)
        columns["heading"] = headings
    return columns


def trajectories(value: Any) -> list[dict[str, list[float]]]:
    """A batch: a sequence of trajectories (an ``(M, N, 3 or 4)`` array, or a list of any form
    :func:`trajectory` takes), as columns."""
    data = plain(value)
    if isinstance(data, Mapping) or not isinstance(data, Sequence) or isinstance(data, str):
        raise ValidationError(
            "trajectories: expected a sequence of trajectories", field="trajectories"
        )
    return [trajectory_columns(t, f"trajectories.{k}") for k, t in enumerate(data)]


def packed_trajectories(value: Any) -> dict[str, Any] | None:
    """A batch (any form :func:`trajectories` takes) as the service's packed columns
    ``{lengths, t, x, y[, heading]}``, each column the points' numbers as base64 of
    little-endian float64s: read by the service without a JSON number per point. An ``(M, N, 3
    or 4)`` array's columns are taken as they are. None where some trajectories carry headings
    and others not (the columns form says that; the packed one does not)."""
    if getattr(value, "ndim", None) == 3 and value.shape[-1] in (3, 4) and value.shape[0]:
        keys = _HEADED_POINT_FIELDS if value.shape[-1] == 4 else _POINT_FIELDS
        packed: dict[str, Any] = {"lengths": [int(value.shape[1])] * int(value.shape[0])}
        for i, key in enumerate(keys):
            packed[key] = _binary64(value[..., i].reshape(-1).astype("<f8").tobytes())
        return packed
    parts = trajectories(value)
    headed = {"heading" in part for part in parts}
    if len(headed) > 1:
        return None
    packed = {"lengths": [len(part["t"]) for part in parts]}
    for key in _HEADED_POINT_FIELDS if headed == {True} else _POINT_FIELDS:
        numbers = array("d", [v for part in parts for v in part[key]])
        if sys.byteorder != "little":
            numbers.byteswap()
        packed[key] = _binary64(numbers.tobytes())
    return packed


def _binary64(raw: bytes) -> str:
    return base64.b64encode(raw).decode("ascii")


def footprint(value: Any) -> dict[str, Any] | None:
    """A :class:`Footprint`, a mapping, or ``(length, width[, rear_axle_to_center])``."""
    if value is None:
        return None
    data = plain(value) if not isinstance(value, BaseModel) else value
    fields = ("length", "width", "rear_axle_to_center")
    if isinstance(data, list):
        fields = fields[: len(data)] if len(data) in (2, 3) else fields
    return _model(Footprint, data, "footprint", fields)


def without_none(body: Mapping[str, Any]) -> dict[str, Any]:
    """``body`` without its ``None`` values (the service then applies its defaults)."""
    return {k: v for k, v in body.items() if v is not None}
