"""The asyncio client, :class:`AsyncFRTClient`: the methods of :class:`~frt_client.FRTClient`,
awaited."""

from __future__ import annotations

import asyncio
import time
from types import TracebackType
from typing import TypeVar

import httpx

from frt_client import calls, wire
from frt_client.async_stream import AsyncStream
from frt_client.calls import Call
from frt_client.errors import DeadlineError, UnavailableError
from frt_client.models import Health, ModelCard, Readiness, Response
from frt_client.operations import AsyncOperations
from frt_client.retry import RetryPolicy, note

T = TypeVar("T", bound=Response)


class AsyncFRTClient(AsyncOperations):
    """An asyncio client of the FRT service; share one per event loop (httpx pools connections).

    Args are those of :class:`~frt_client.FRTClient`. Use ``async with AsyncFRTClient(url) as frt:`` or ``await frt.aclose()``.
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
        self._http = httpx.AsyncClient(
            base_url=self.base_url,
            timeout=self.timeout,
            headers=wire.headers(token, headers, scene),
            limits=limits or wire.DEFAULT_LIMITS,
        )

    # ------------------------------------------------------------------ lifecycle
    async def aclose(self) -> None:
        """Close the pooled connections."""
        await self._http.aclose()

    async def __aenter__(self) -> AsyncFRTClient:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.aclose()

    # ------------------------------------------------------------------ execution
    async def send(self, call: Call[T]) -> T:
        """Execute one :class:`~frt_client.calls.Call`, retrying where the policy says it is safe."""
        attempt = 0
        while True:
            try:
                response = await self._http.request(
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
            await asyncio.sleep(delay)
            attempt += 1

    # ------------------------------------------------------------------ service
    async def model(self) -> ModelCard:
        """The served model's card."""
        return await self.send(calls.model())

    async def health(self) -> Health:
        """Liveness (``/healthz``)."""
        return await self.send(calls.health())

    async def ready(self) -> Readiness:
        """Readiness (``/readyz``): ``ready`` is false while the model loads (no error raised)."""
        return await self.send(calls.ready())

    async def wait_ready(self, timeout_s: float = 30.0, poll_s: float = 0.1) -> Readiness:
        """Poll :meth:`ready` until the model is loaded; :class:`DeadlineError` after
        ``timeout_s``."""
        end = time.monotonic() + timeout_s
        while True:
            try:
                state = await self.ready()
                if state.ready:
                    return state
            except UnavailableError:
                pass
            if time.monotonic() >= end:
                raise DeadlineError(f"service not ready after {timeout_s} s")
            await asyncio.sleep(poll_s)

    # ------------------------------------------------------------------ streaming
    def stream(self, *, timeout: float | None = None) -> AsyncStream:
        """A WebSocket session (``WS /v1/stream``) with the same operations, for 10-20 Hz loops.

        Use ``async with client.stream() as s: await s.collision_check(...)``. ``timeout``
        (seconds per answer) defaults to the client's read timeout.
        """
        return AsyncStream(
            wire.websocket_url(self.base_url),
            token=self.token,
            scene=self.scene,
            timeout=timeout if timeout is not None else wire.read_timeout(self.timeout),
            connect_timeout=wire.connect_timeout(self.timeout),
            retry=self.retry,
        )
