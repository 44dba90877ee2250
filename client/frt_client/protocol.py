"""The ``WS /v1/stream`` message format, for both streams.

Request: ``{"id": n, "op": "observe" | "collision_check" | "frt" | "get_agent" | "delete_agent" |
"ping", ...}`` with the fields of the matching HTTP body, plus ``agent_id`` where the HTTP path has
one. Answer: ``{"id": n, "ok": true, "result": {...}}`` or ``{"id": n, "ok": false, "error":
{"status": 422, "detail": ..., "field": ...}}``. The service handles one connection's messages in
order, so observations sent on one stream keep their order.
"""

from __future__ import annotations

import json
from typing import Any, TypeVar

from frt_client.calls import Call
from frt_client.errors import FRTError, UnavailableError, from_status
from frt_client.models import Response
from frt_client.wire import parse

T = TypeVar("T", bound=Response)


class Pong(Response):
    """Answer to a stream's ``ping``."""

    pong: bool


PING: Call[Pong] = Call("GET", "", Pong, idempotent=True, op="ping")


def encode(call: Call[Any], message_id: int) -> str:
    """The text frame of ``call``; :class:`FRTError` if the stream has no such operation."""
    if call.op is None:
        raise FRTError(f"{call.method} {call.path} is not available on the stream; use HTTP")
    return json.dumps({"id": message_id, "op": call.op, **call.message})


def decode(text: str | bytes) -> dict[str, Any]:
    """A received frame as a dict (an :class:`UnavailableError` if it is not a JSON object)."""
    try:
        answer = json.loads(text)
    except ValueError:
        raise UnavailableError(f"stream answered with invalid JSON: {text[:200]!r}") from None
    if not isinstance(answer, dict):
        raise UnavailableError(f"stream answered with a non-object: {text[:200]!r}")
    return answer


def outcome(call: Call[T], answer: dict[str, Any]) -> T:
    """The typed result of an answer, or the matching :class:`FRTError`."""
    if answer.get("ok"):
        return parse(call.model, answer.get("result"))
    error = answer.get("error")
    error = error if isinstance(error, dict) else {"detail": str(error)}
    status = error.get("status")
    raise from_status(status if isinstance(status, int) else 500, error)
