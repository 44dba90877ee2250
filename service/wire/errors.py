"""The service's errors: one tree, each with its HTTP status and JSON shape.

Every error body has a ``detail``; a 422 also names the offending ``field`` (dotted, e.g.
``prediction.cov.2``) and carries the validation list of ``{loc, msg, type}``. The handlers that
answer them over HTTP are in ``service.api.errors``; the WebSocket stream sends the same payloads.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

Loc = Sequence[str | int]


class APIError(Exception):
    """An error with an HTTP status, shaped the same over HTTP and the WebSocket."""

    def __init__(
        self,
        status: int,
        detail: str,
        *,
        field: str | None = None,
        headers: dict[str, str] | None = None,
    ) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.field = field
        self.headers = headers

    def payload(self, prefix: Loc = ()) -> dict[str, Any]:
        if self.status != 422:
            return {"detail": self.detail}
        loc = [*prefix, *(self.field.split(".") if self.field else [])]
        return {
            "detail": [
                {"loc": [_int_or_str(p) for p in loc], "msg": self.detail, "type": "value_error"}
            ],
            "field": self.field,
        }


class FieldError(APIError):
    """422: a value the schema accepts but the service cannot (ranges, shapes, positive definiteness)."""

    def __init__(self, field: str, message: str, *, location: str = "body") -> None:
        super().__init__(422, message, field=field)
        self.location = location


class AgentNotFoundError(APIError):
    def __init__(self, agent_id: str) -> None:
        super().__init__(404, f"unknown agent {agent_id!r}")


class StaleTimestampError(APIError):
    def __init__(self, agent_id: str, timestamp: float, last: float) -> None:
        super().__init__(
            409,
            f"stale observation for agent {agent_id!r}: timestamp {timestamp!r} is not after "
            f"the last one ({last!r})",
        )
        self.last = last


class ServiceUnavailableError(APIError):
    def __init__(self, detail: str) -> None:
        super().__init__(503, detail, headers={"Retry-After": "1"})


class UnauthorizedError(APIError):
    def __init__(self) -> None:
        super().__init__(
            401, "missing or invalid bearer token", headers={"WWW-Authenticate": "Bearer"}
        )


class AgentClassChangedError(APIError):
    """409: an observation names another class than the agent's."""

    def __init__(self, agent_id: str, fixed: str, requested: str) -> None:
        super().__init__(
            409,
            f"agent {agent_id!r} is a {fixed}; its class is fixed once set (got {requested!r})",
        )


def _int_or_str(part: str | int) -> str | int:
    return int(part) if isinstance(part, str) and part.isdigit() else part


def dotted(loc: Loc) -> str:
    """``("body", "prediction", "cov", 2)`` -> ``"prediction.cov.2"`` (the request part dropped)."""
    parts = [str(p) for p in loc]
    if parts and parts[0] in ("body", "query", "path", "header", "cookie"):
        parts = parts[1:]
    return ".".join(parts)


def validation_payload(errors: Sequence[Any], prefix: Loc = ()) -> dict[str, Any]:
    """FastAPI's 422 list, trimmed to JSON-safe ``{loc, msg, type}``, plus the first ``field``."""
    detail = [
        {
            "loc": [*prefix, *(p if isinstance(p, int) else str(p) for p in err.get("loc", ()))],
            "msg": str(err.get("msg", "invalid value")),
            "type": str(err.get("type", "value_error")),
        }
        for err in errors
    ]
    field = None
    if detail:
        first = detail[0]
        # Malformed JSON is located by a character offset, a missing or non-object body by "body"
        # alone: both name the body as a whole.
        field = "body" if first["type"] == "json_invalid" else dotted(first["loc"]) or "body"
        if first["type"] == "json_invalid" and isinstance(first["loc"][-1], int):
            first["msg"] = f"{first['msg']} at character {first['loc'][-1]}"
    return {"detail": detail, "field": field}
