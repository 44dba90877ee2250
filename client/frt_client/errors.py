"""One exception hierarchy for everything the SDK raises.

Every error is an :class:`FRTError` carrying the HTTP ``status`` (``None`` when no response was
received, or when the SDK itself refused the input) and the service's ``detail``. The subclass
says what happened, so a planner can catch exactly what it can handle::

    FRTError
    ├── ValidationError        422 (and 400): the request is malformed; ``field`` names the culprit
    ├── AuthError              401 / 403: missing or wrong bearer token
    ├── NotFoundError          404: unknown agent (or path)
    ├── ConflictError          409: stale observation timestamp
    ├── PayloadTooLargeError   413: request body over the server's limit
    ├── DeadlineError          the client's timeout expired (or a 504)
    ├── UnavailableError       503, or the service could not be reached (status None)
    └── ServerError            any other 5xx
"""

from __future__ import annotations

from typing import Any


class FRTError(Exception):
    """Base of every SDK error.

    Attributes:
        status: HTTP status of the response, or ``None`` if there was none.
        detail: the service's ``detail`` (a string, or FastAPI's list of ``{loc, msg, type}``
            for a 422), or a description of the local failure.
        field: for a 422, the dotted name of the offending field (e.g. ``prediction.cov.2``).
        request_id: the ``X-Request-ID`` the service answered with, for its logs.
        body: the decoded JSON body of the error response, if any.
    """

    def __init__(
        self,
        message: str,
        *,
        status: int | None = None,
        detail: Any = None,
        field: str | None = None,
        request_id: str | None = None,
        body: Any = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.status = status
        self.detail = detail if detail is not None else message
        self.field = field
        self.request_id = request_id
        self.body = body

    def __repr__(self) -> str:
        return f"{type(self).__name__}(status={self.status!r}, detail={self.detail!r})"


class ValidationError(FRTError):
    """422 (or 400): the service (or the SDK, with ``status=None``) rejected the input."""


class AuthError(FRTError):
    """401 or 403: the bearer token is missing or wrong."""


class NotFoundError(FRTError):
    """404: the agent is unknown (never observed, deleted, or expired by the TTL)."""


class ConflictError(FRTError):
    """409: the observation's timestamp is not after the agent's last one."""


class PayloadTooLargeError(FRTError):
    """413: the request body is larger than the service accepts."""


class DeadlineError(FRTError):
    """The client's timeout expired before an answer arrived (or the service answered 504)."""


class UnavailableError(FRTError):
    """503 (model loading, store full), or the service could not be reached (``status`` None)."""


class ServerError(FRTError):
    """Any other 5xx: a bug in the service; ``request_id`` finds it in the service's logs."""


_BY_STATUS: dict[int, type[FRTError]] = {
    400: ValidationError,
    401: AuthError,
    403: AuthError,
    404: NotFoundError,
    408: DeadlineError,
    409: ConflictError,
    413: PayloadTooLargeError,
    422: ValidationError,
    503: UnavailableError,
    504: DeadlineError,
}


def error_class(status: int) -> type[FRTError]:
    """The exception class for an HTTP error status."""
    if status in _BY_STATUS:
        return _BY_STATUS[status]
    return ServerError if status >= 500 else FRTError


def describe(detail: Any) -> str:
    """A one-line message from a ``detail`` (a string, or a list of ``{loc, msg}`` dicts)."""
    if isinstance(detail, list):
        parts = []
        for item in detail:
            if isinstance(item, dict):
                loc = ".".join(str(p) for p in item.get("loc", ()) if p != "body")
                msg = str(item.get("msg", item))
                parts.append(f"{loc}: {msg}" if loc else msg)
            else:
                parts.append(str(item))
        return "; ".join(parts)
    return str(detail)


def from_status(
    status: int, body: Any, *, request_id: str | None = None, reason: str = ""
) -> FRTError:
    """Build the error for an HTTP (or WebSocket) error answer with a JSON ``body``."""
    detail = body.get("detail") if isinstance(body, dict) else None
    field = body.get("field") if isinstance(body, dict) else None
    if detail is None:
        detail = reason or (str(body) if body not in (None, "") else f"HTTP {status}")
    message = f"{status}: {describe(detail)}"
    cls = error_class(status)
    return cls(message, status=status, detail=detail, field=field, request_id=request_id, body=body)
