"""The blocking client, :class:`FRTClient` (the async twin is :mod:`frt_client.async_client`)."""

from __future__ import annotations

import time
from types import TracebackType
from typing import TypeVar

import httpx

from frt_client import calls, wire
from frt_client.calls import Call
from frt_client.errors import DeadlineError, UnavailableError
from frt_client.models import Health, ModelCard, Readiness, Response
from frt_client.operations import Operations
from frt_client.retry import RetryPolicy, note
from frt_client.stream import Stream

T = TypeVar("T", bound=Response)


class FRTClient(Operations):
    """A blocking client of the FRT service; one per thread or share it (httpx pools connections).

    Args:
        base_url: ``http(s)://host:port`` of the service.
        token: bearer token, if the service has one configured.
        timeout: seconds (or an ``httpx.Timeout``) for every request; required, never infinite.
        retry: when to resend (see :class:`~frt_client.retry.RetryPolicy`); ``NO_RETRY`` disables.
        headers: extra headers for every request.
        limits: the connection pool (``httpx.Limits``); keep ``keepalive_expiry`` below the
            server's keep-alive timeout.
        scene: the scene this client's agents belong to, sent as ``X-FRT-Scene`` on every request
            and stream: behind nginx every request of one scene goes to one replica (none: nginx
            routes by the client's address).

    Use it as a context manager, or call :meth:`close`::

        with FRTClient("http://127.0.0.1:8000") as frt:
            frt.observe("car-1", timestamp=0.0, state=(0, 0, 0, 5), prediction=pred)
            frt.collision_check("car-1", [(0.1, 10.0, 0.0)]).collision

    Every method raises a subclass of :class:`~frt_client.errors.FRTError` on failure.
    """

    def __init__(
        self,
        base_url: str = wire.DEFAULT_URL,
        *,
        token: str | None = None,
        timeout: wire.TimeoutLike = wire.DEFAULT_TIMEOUT,
        retry: RetryPolicy | None = None,
        headers: dict[str, str] | None = None,
        limits: httpx.Limits | None = None,
        scene: str | None = None,
    ) -> None:
        self.base_url = wire.base_url(base_url)
        self.token = token
        self.scene = scene
        self.timeout = wire.timeout(timeout)
        self.retry = retry if retry is not None else RetryPolicy()
        self._http = httpx.Client(
            base_url=self.base_url,
            timeout=self.timeout,
            headers=wire.headers(token, headers, scene),
            limits=limits or wire.DEFAULT_LIMITS,
        )

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        """Close the pooled connections."""
        self._http.close()

    def __enter__(self) -> FRTClient:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # ------------------------------------------------------------------ execution
    def send(self, call: Call[T]) -> T:
        """Execute one :class:`~frt_client.calls.Call`, retrying where the policy says it is safe."""
        attempt = 0
        while True:
            try:
                response = self._http.request(
                    call.method, call.path, json=call.json, params=call.params
                )
            except httpx.TransportError as exc:
                delay = self.retry.delay(attempt, idempotent=call.idempotent, error=exc)
                if delay is None:
                    raise wire.transport_error(exc, call) from exc
                why: object = type(exc).__name__
            else:
                delay = self.retry.delay(
                    attempt,
                    idempotent=call.idempotent,
                    response=response,
                    ok_statuses=call.ok_statuses,
                )
                if delay is None:
                    return wire.result(call, response)
                why = response.status_code
            note(f"{call.method} {call.path}", attempt, delay, why)
            time.sleep(delay)
            attempt += 1

    # ------------------------------------------------------------------ service
    def model(self) -> ModelCard:
        """The served model's card."""
        return self.send(calls.model())

    def health(self) -> Health:
        """Liveness (``/healthz``)."""
        return self.send(calls.health())

    def ready(self) -> Readiness:
        """Readiness (``/readyz``): ``ready`` is false while the model loads (no error raised)."""
        return self.send(calls.ready())

    def wait_ready(self, timeout_s: float = 30.0, poll_s: float = 0.1) -> Readiness:
        """Poll :meth:`ready` until the model is loaded; :class:`DeadlineError` after
        ``timeout_s``."""
        end = time.monotonic() + timeout_s
        while True:
            try:
                state = self.ready()
                if state.ready:
                    return state
            except UnavailableError:
                pass
            if time.monotonic() >= end:
                raise DeadlineError(f"service not ready after {timeout_s} s")
            time.sleep(poll_s)

    # ------------------------------------------------------------------ streaming
    def stream(self, *, timeout: float | None = None) -> Stream:
        """A WebSocket session (``WS /v1/stream``) with the same operations, for 10-20 Hz loops.

        Use as a context manager: ``with client.stream() as s: s.collision_check(...)``.
        ``timeout`` (seconds per answer) defaults to the client's read timeout.
        """
        return Stream(
            wire.websocket_url(self.base_url),
            token=self.token,
            scene=self.scene,
            timeout=timeout if timeout is not None else wire.read_timeout(self.timeout),
            connect_timeout=wire.connect_timeout(self.timeout),
            retry=self.retry,
        )
