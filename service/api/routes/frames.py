"""``POST /v1/frames``: one frame of many agents' observations (``service.flows.frames``)."""

from __future__ import annotations

from fastapi import APIRouter

from service.api.routes.params import ServicesDep
from service.flows import frames
from service.wire.schemas import FrameRequest, FrameResponse

router = APIRouter(prefix="/v1", tags=["agents"])


@router.post("/frames", response_model=FrameResponse)
async def apply_frame(body: FrameRequest, services: ServicesDep) -> FrameResponse:
    """Apply one frame: every agent's observation at the frame's timestamp, each on its own (a
    rejected agent is answered by index and field, nothing of it changes; the others apply)."""
    return await frames.apply_frame(services, body)
