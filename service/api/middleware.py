"""Pure ASGI middleware: request context (arrival time, id, metrics, access log) and the body limit."""

from __future__ import annotations

import json
import logging
import time
import uuid
from typing import Any

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.api.errors import BodyTooLargeError
from service.runtime.metrics import Metrics

access_log = logging.getLogger("frt.access")


def arrival_time(scope: Scope) -> float:
    """``time.perf_counter()`` at the request's arrival (set by :class:`RequestContextMiddleware`)."""
    state = scope.get("state") or {}
    return float(state.get("arrival", time.perf_counter()))


async def send_json(
    send: Send, status: int, body: dict[str, Any], headers: dict[str, str] | None = None
) -> None:
    """Answer with a JSON body from middleware, before any route runs."""
    data = json.dumps(body).encode()
    raw_headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(data)).encode()),
    ]
    raw_headers += [(k.lower().encode(), v.encode()) for k, v in (headers or {}).items()]
    await send({"type": "http.response.start", "status": status, "headers": raw_headers})
    await send({"type": "http.response.body", "body": data})


class RequestContextMiddleware:
    """Stamps arrival time and a request id, then records latency per route and logs the request.

    Every HTTP response carries ``Server-Timing: app;dur=<ms>``, the time from the request's arrival
    to the response's start: a client subtracts it from its own round trip to see what the trip,
    not the service, cost (a planner's deadline counts both); and, with a ``replica`` name,
    ``X-FRT-Replica: <replica>`` (which replica behind a load balancer answered)."""

    def __init__(
        self,
        app: ASGIApp,
        metrics: Metrics,
        log_requests: bool = True,
        replica: str | None = None,
    ) -> None:
        self.app = app
        self.metrics = metrics
        self.log_requests = log_requests
        self.replica_header = [(b"x-frt-replica", replica.encode())] if replica else []

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        state = scope.setdefault("state", {})
        state["arrival"] = start
        request_id = _request_id(_header(scope, b"x-request-id"))
        state["request_id"] = request_id
        if scope["type"] == "websocket":
            await self.app(scope, receive, send)
            return

        status = 500

        async def send_wrapper(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
                headers = list(message.get("headers", []))
                headers.append((b"x-request-id", request_id.encode()))
                duration_ms = (time.perf_counter() - start) * 1000.0
                headers.append((b"server-timing", f"app;dur={duration_ms:.3f}".encode()))
                headers += self.replica_header
                message = {**message, "headers": headers}
            await send(message)

        try:
            await self.app(scope, receive, send_wrapper)
        finally:
            elapsed = time.perf_counter() - start
            route = scope.get("route")
            template = getattr(route, "path", None) or "unmatched"
            method = scope.get("method", "")
            self.metrics.request_seconds.labels(template, method, str(status)).observe(elapsed)
            if self.log_requests:
                access_log.info(
                    "request",
                    extra={
                        "request_id": request_id,
                        "method": method,
                        "path": scope.get("path", ""),
                        "route": template,
                        "status": status,
                        "duration_ms": round(elapsed * 1000.0, 3),
                    },
                )


#: Paths whose bodies have the collision checks' limit (a batch of trajectories is large).
CHECK_PATH_SUFFIX = "/collision-check"


class BodySizeLimitMiddleware:
    """413 for bodies over the limit: by Content-Length up front, and by counting what streams in.

    The limit is ``max_bytes``, or ``max_check_bytes`` on collision checks. A chunked or lying
    client is cut off as soon as the count passes it.
    """

    def __init__(self, app: ASGIApp, max_bytes: int, max_check_bytes: int | None = None) -> None:
        self.app = app
        self.default_bytes = max_bytes
        self.check_bytes = max_bytes if max_check_bytes is None else max_check_bytes

    def limit_for(self, path: str) -> int:
        return self.check_bytes if path.endswith(CHECK_PATH_SUFFIX) else self.default_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        await self._limited(scope, receive, send, self.limit_for(scope.get("path", "")))

    async def _limited(self, scope: Scope, receive: Receive, send: Send, max_bytes: int) -> None:
        declared = _header(scope, b"content-length")
        if declared is not None:
            try:
                length = int(declared)
            except ValueError:
                await send_json(send, 400, {"detail": "invalid Content-Length header"})
                return
            if length > max_bytes:
                await send_json(
                    send, 413, {"detail": f"request body larger than {max_bytes} bytes"}
                )
                return

        received = 0
        started = False

        async def counting_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > max_bytes:
                    raise BodyTooLargeError(max_bytes)
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counting_receive, tracking_send)
        except BodyTooLargeError as exc:
            # Normally FastAPI turns this into the 413 itself; this catches reads outside a route.
            if not started:
                await send_json(send, 413, {"detail": exc.detail})


def _request_id(given: str | None) -> str:
    """The client's X-Request-ID if it is short and plain, else a fresh one."""
    if given and len(given) <= 64 and all(c.isalnum() or c in "-_.:" for c in given):
        return given
    return uuid.uuid4().hex[:16]


def _header(scope: Scope, name: bytes) -> str | None:
    for key, value in scope.get("headers", []):
        if key == name:
            return value.decode("latin-1")
    return None
