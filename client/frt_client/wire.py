"""What the sync and async clients share: options, headers, and turning responses into results."""

from __future__ import annotations

from typing import Any, TypeVar
from urllib.parse import urlsplit

import httpx
import pydantic

from frt_client.calls import Call
from frt_client.errors import DeadlineError, FRTError, UnavailableError, from_status
from frt_client.models import Response

T = TypeVar("T", bound=Response)

DEFAULT_URL = "http://127.0.0.1:8000"
#: Explicit timeouts: 2 s to connect, 5 s for anything else (read, write, pool). A collision check
#: answers within its ``deadline_ms`` (20 ms by default), so 5 s only catches a dead service.
DEFAULT_TIMEOUT = httpx.Timeout(5.0, connect=2.0)
#: Pooled connections. Idle ones are dropped after 2 s, before the server's keep-alive timeout
#: (uvicorn's default is 5 s, the same as httpx's default expiry): otherwise a request can race
#: the server closing the connection and fail with a ReadError it never had to.
DEFAULT_LIMITS = httpx.Limits(
    max_connections=100, max_keepalive_connections=20, keepalive_expiry=2.0
)
USER_AGENT = "frt-client/0.1"
#: The header naming the client's scene: behind nginx (docker/nginx.conf) every request of one scene
#: goes to one replica, which then computes each of the scene's sets once.
SCENE_HEADER = "X-FRT-Scene"
MAX_SCENE_CHARS = 128

TimeoutLike = float | httpx.Timeout | None


def base_url(url: str) -> str:
    """``url`` checked to be ``http(s)://host[:port][/prefix]``, without a trailing slash."""
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError(f"base_url must be http(s)://host[:port], got {url!r}")
    return url.rstrip("/")


def websocket_url(url: str, path: str = "/v1/stream") -> str:
    """The stream's ``ws(s)://`` URL for an ``http(s)://`` base URL."""
    parts = urlsplit(base_url(url))
    scheme = "wss" if parts.scheme == "https" else "ws"
    return f"{scheme}://{parts.netloc}{parts.path}{path}"


def headers(
    token: str | None, extra: dict[str, str] | None = None, scene: str | None = None
) -> dict[str, str]:
    result = {"user-agent": USER_AGENT, "accept": "application/json"}
    if token:
        result["authorization"] = f"Bearer {token}"
    result.update(scene_header(scene))
    result.update(extra or {})
    return result


def scene_header(scene: str | None) -> dict[str, str]:
    """``{SCENE_HEADER: scene}``, or nothing for None; a scene is 1-128 printable ASCII characters,
    not only spaces."""
    if scene is None:
        return {}
    if (
        not isinstance(scene, str)
        or not scene.strip()
        or len(scene) > MAX_SCENE_CHARS
        or not all(" " <= c <= "~" for c in scene)
    ):
        raise ValueError(f"scene must be 1-{MAX_SCENE_CHARS} printable ASCII characters: {scene!r}")
    return {SCENE_HEADER: scene}


def timeout(value: TimeoutLike) -> httpx.Timeout:
    if isinstance(value, httpx.Timeout):
        return value
    if value is None:
        raise ValueError("an explicit timeout is required (a number of seconds or httpx.Timeout)")
    return httpx.Timeout(float(value))


def read_timeout(value: httpx.Timeout) -> float:
    """Seconds a stream waits for each answer, from a client's timeout."""
    return value.read if value.read is not None else DEFAULT_TIMEOUT.read or 5.0


def connect_timeout(value: httpx.Timeout) -> float:
    """Seconds a stream waits for its opening handshake, from a client's timeout."""
    return value.connect if value.connect is not None else DEFAULT_TIMEOUT.connect or 2.0


def parse(model: type[T], data: Any, *, status: int | None = None) -> T:
    """``data`` as ``model``; an answer that does not fit is an :class:`FRTError`."""
    try:
        return model.model_validate(data)
    except pydantic.ValidationError as exc:
        raise FRTError(
            f"unexpected answer for {model.__name__}: {exc}", status=status, body=data
        ) from None


def result(call: Call[T], response: httpx.Response) -> T:
    """The typed result of a response, or the matching :class:`FRTError`."""
    try:
        body: Any = response.json()
    except ValueError:
        body = response.text
    request_id = response.headers.get("x-request-id")
    status = response.status_code
    if 200 <= status < 300 or status in call.ok_statuses:
        return parse(call.model, body, status=status)
    raise from_status(status, body, request_id=request_id, reason=response.reason_phrase)


def transport_error(exc: httpx.TransportError, call: Call[Any]) -> FRTError:
    """A failure without a response: timeouts are :class:`DeadlineError`, the rest unavailable."""
    where = f"{call.method} {call.path}"
    if isinstance(exc, httpx.TimeoutException):
        return DeadlineError(f"{where}: timed out ({type(exc).__name__})", detail=str(exc))
    return UnavailableError(
        f"{where}: service unreachable ({type(exc).__name__}: {exc})", detail=str(exc)
    )
