"""The asyncio WebSocket session, :class:`AsyncStream` (``WS /v1/stream``).

Several calls may be in flight at once (from several tasks): a reader task matches answers to calls
by id. The service handles one connection's messages in order, so observations sent on one stream
keep their order. Nothing is ever sent twice; only opening the connection is retried.
"""

from __future__ import annotations

import asyncio
from types import TracebackType
from typing import Any, TypeVar

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, WebSocketException

from frt_client import protocol
from frt_client.calls import Call
from frt_client.errors import DeadlineError, FRTError, UnavailableError
from frt_client.models import Response
from frt_client.operations import AsyncOperations
from frt_client.retry import RetryPolicy, note
from frt_client.stream import MAX_MESSAGE_BYTES, handshake_error
from frt_client.wire import scene_header

T = TypeVar("T", bound=Response)


class AsyncStream(AsyncOperations):
    """An asyncio ``WS /v1/stream`` session with the operations of
    :class:`~frt_client.AsyncFRTClient` and :meth:`ping`. Open it with
    ``async with client.stream() as stream:`` (or :meth:`open`/:meth:`close`).

    Args are those of :class:`~frt_client.stream.Stream`.
    """

    def __init__(
        self,
        url: str,
        *,
        token: str | None = None,
        timeout: float = 5.0,
        connect_timeout: float = 2.0,
        retry: RetryPolicy | None = None,
        scene: str | None = None,
    ) -> None:
        self.url = url
        self.timeout = timeout
        self.connect_timeout = connect_timeout
        self.retry = retry if retry is not None else RetryPolicy()
        self._headers = {"Authorization": f"Bearer {token}"} if token else {}
        self._headers.update(scene_header(scene))
        self._ws: ClientConnection | None = None
        self._reader: asyncio.Task[None] | None = None
        self._pending: dict[int, asyncio.Future[dict[str, Any]]] = {}
        self._next_id = 0
        self._open_lock = asyncio.Lock()

    # ------------------------------------------------------------------ lifecycle
    async def open(self) -> AsyncStream:
        """Open the connection (a no-op if open), retrying refused connections with backoff."""
        async with self._open_lock:
            if self._ws is None:
                self._ws = await self._connect()
                self._reader = asyncio.create_task(self._read(self._ws))
        return self

    async def close(self) -> None:
        """Close the connection; calls still waiting get :class:`UnavailableError`."""
        ws, self._ws = self._ws, None
        if ws is not None:
            await ws.close()
        if self._reader is not None:
            await asyncio.gather(self._reader, return_exceptions=True)
            self._reader = None

    async def __aenter__(self) -> AsyncStream:
        return await self.open()

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    # ------------------------------------------------------------------ execution
    async def send(self, call: Call[T]) -> T:
        """Send one call's message and wait for its answer (other calls may overlap)."""
        await self.open()
        ws = self._ws
        if ws is None:
            raise UnavailableError("stream closed")
        self._next_id += 1
        message_id = self._next_id
        future: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._pending[message_id] = future
        try:
            await ws.send(protocol.encode(call, message_id))
            answer = await asyncio.wait_for(future, self.timeout)
        except (TimeoutError, asyncio.TimeoutError):  # noqa: UP041 - distinct types on Python 3.10
            raise DeadlineError(f"{call.op}: no answer within {self.timeout} s") from None
        except ConnectionClosed as exc:
            raise UnavailableError(f"stream closed: {exc}", detail=str(exc)) from exc
        finally:
            self._pending.pop(message_id, None)
        return protocol.outcome(call, answer)

    async def ping(self) -> float:
        """Round-trip time of a ``ping`` message, in seconds."""
        loop = asyncio.get_running_loop()
        start = loop.time()
        await self.send(protocol.PING)
        return loop.time() - start

    async def _connect(self) -> ClientConnection:
        attempt = 0
        while True:
            try:
                return await connect(
                    self.url,
                    additional_headers=self._headers,
                    open_timeout=self.connect_timeout,
                    max_size=MAX_MESSAGE_BYTES,
                    compression=None,
                )
            except (OSError, TimeoutError) as exc:
                if attempt >= self.retry.retries:
                    raise handshake_error(exc, self.url) from exc
            except WebSocketException as exc:
                raise handshake_error(exc, self.url) from exc
            delay = self.retry.backoff(attempt)
            note(f"connect {self.url}", attempt, delay, "connection refused or timed out")
            await asyncio.sleep(delay)
            attempt += 1

    async def _read(self, ws: ClientConnection) -> None:
        """Deliver each answer to the call waiting for its id, until the connection closes."""
        error: FRTError = UnavailableError("stream closed")
        try:
            async for frame in ws:
                answer = protocol.decode(frame)
                message_id = answer.get("id")
                if message_id is None and not answer.get("ok") and self._pending:
                    message_id = next(iter(self._pending))  # unreadable message: the oldest
                future = self._pending.get(message_id) if isinstance(message_id, int) else None
                if future is not None and not future.done():
                    future.set_result(answer)
        except ConnectionClosed as exc:
            error = UnavailableError(f"stream closed: {exc}", detail=str(exc))
        except FRTError as exc:  # an unreadable answer: the session can no longer be trusted
            error = exc
            await ws.close()
        finally:
            if self._ws is ws:
                self._ws = None
            for future in self._pending.values():
                if not future.done():
                    future.set_exception(error)
