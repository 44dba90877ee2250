"""The blocking WebSocket session, :class:`Stream` (``WS /v1/stream``).

One connection, one message in flight: each method sends its message and waits for the answer with
the same id (answers to earlier calls that timed out are skipped). Not for sharing between threads
without care: a lock serialises calls, so threads take turns. Nothing is ever sent twice; only
opening the connection is retried (nothing has been sent then).
"""

from __future__ import annotations

import threading
import time
from contextlib import ExitStack
from types import TracebackType
from typing import Any, TypeVar

from websockets.exceptions import ConnectionClosed, InvalidStatus, WebSocketException
from websockets.sync.client import ClientConnection, connect

from frt_client import protocol
from frt_client.calls import Call
from frt_client.errors import DeadlineError, FRTError, UnavailableError, from_status
from frt_client.models import Response
from frt_client.operations import Operations
from frt_client.retry import RetryPolicy, note
from frt_client.wire import scene_header

T = TypeVar("T", bound=Response)

#: Largest answer accepted (contours of many slices can be large).
MAX_MESSAGE_BYTES = 16 * 2**20


def handshake_error(exc: Exception, url: str) -> FRTError:
    """The error for a failed opening handshake (401/403 -> AuthError, else unavailable)."""
    if isinstance(exc, InvalidStatus):
        status = exc.response.status_code
        return from_status(status, {"detail": f"stream handshake refused: HTTP {status}"})
    return UnavailableError(f"cannot open {url}: {type(exc).__name__}: {exc}", detail=str(exc))


class Stream(Operations):
    """A blocking ``WS /v1/stream`` session with the operations of :class:`~frt_client.FRTClient`
    (observe, get_agent, delete_agent, collision_check, collision_check_many, contours, frt) and
    :meth:`ping`. Open it with ``with client.stream() as stream:`` (or :meth:`open`/:meth:`close`).

    Args:
        url: ``ws(s)://host:port/v1/stream``.
        token: bearer token, if the service has one.
        timeout: seconds to wait for each answer (:class:`DeadlineError` after that).
        connect_timeout: seconds for the opening handshake.
        retry: backoff for opening the connection (connection refused, handshake timeout).
        scene: sent as ``X-FRT-Scene`` in the opening handshake (the stream's replica, behind nginx).
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
        self._stack = ExitStack()  # holds the connection's context open between calls
        self._next_id = 0
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> Stream:
        """Open the connection (a no-op if open), retrying refused connections with backoff."""
        if self._ws is not None:
            return self
        attempt = 0
        while True:
            try:
                self._ws = self._stack.enter_context(
                    connect(
                        self.url,
                        additional_headers=self._headers,
                        open_timeout=self.connect_timeout,
                        max_size=MAX_MESSAGE_BYTES,
                        compression=None,
                    )
                )
                return self
            except (OSError, TimeoutError) as exc:
                if attempt >= self.retry.retries:
                    raise handshake_error(exc, self.url) from exc
            except WebSocketException as exc:
                raise handshake_error(exc, self.url) from exc
            delay = self.retry.backoff(attempt)
            note(f"connect {self.url}", attempt, delay, "connection refused or timed out")
            time.sleep(delay)
            attempt += 1

    def close(self) -> None:
        """Close the connection (idempotent)."""
        self._ws = None
        self._stack.close()

    def __enter__(self) -> Stream:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # ------------------------------------------------------------------ execution
    def send(self, call: Call[T]) -> T:
        """Send one call's message and wait for its answer."""
        with self._lock:
            return protocol.outcome(call, self._exchange(call))

    def ping(self) -> float:
        """Round-trip time of a ``ping`` message, in seconds."""
        start = time.perf_counter()
        self.send(protocol.PING)
        return time.perf_counter() - start

    def _exchange(self, call: Call[Any]) -> dict[str, Any]:
        ws = self.open()._ws
        assert ws is not None
        self._next_id += 1
        message_id = self._next_id
        deadline = time.monotonic() + self.timeout
        try:
            ws.send(protocol.encode(call, message_id))
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError
                answer = protocol.decode(ws.recv(timeout=remaining))
                if answer.get("id") == message_id:
                    return answer
                if answer.get("id") is None and not answer.get("ok"):
                    return answer  # the service could not read our message's id (e.g. too large)
        except TimeoutError:
            raise DeadlineError(f"{call.op}: no answer within {self.timeout} s") from None
        except ConnectionClosed as exc:
            self.close()
            raise UnavailableError(f"stream closed: {exc}", detail=str(exc)) from exc
