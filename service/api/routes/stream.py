"""``WS /v1/stream``: the operations of the HTTP API as messages (see :mod:`service.api.stream`)."""

from __future__ import annotations

import time

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from service.api import stream
from service.runtime.services import services_of

router = APIRouter(prefix="/v1", tags=["stream"])


@router.websocket("/stream")
async def stream_socket(websocket: WebSocket) -> None:
    services = services_of(websocket)
    await websocket.accept()
    try:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                return
            arrival = time.perf_counter()
            text = message.get("text")
            if text is None:
                data = message.get("bytes") or b""
                try:
                    text = data.decode()
                except UnicodeDecodeError:
                    text = ""
            answer = await stream.handle(services, text, arrival)
            await websocket.send_text(answer)
    except (WebSocketDisconnect, OSError):  # the client went away, possibly mid-answer
        return
