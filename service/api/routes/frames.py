"""``POST /v1/frames``: one frame of many agents' observations (``service.flows.frames``)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter

from service.api.routes.json_body import body_openapi, json_body
from service.api.routes.model_json import ModelJSONResponse
from service.api.routes.params import ServicesDep
from service.flows import frames
from service.wire.frame_body import parse_frame
from service.wire.schemas import FrameRequest, FrameResponse

router = APIRouter(prefix="/v1", tags=["agents"])

FrameBody = Annotated[FrameRequest, json_body(FrameRequest, parse_frame)]


@router.post("/frames", response_model=FrameResponse, openapi_extra=body_openapi(FrameRequest))
async def apply_frame(body: FrameBody, services: ServicesDep) -> ModelJSONResponse:
    """Apply one frame: every agent's observation at the frame's timestamp, each on its own (a
    rejected agent is answered by index and field, nothing of it changes; the others apply)."""
    return ModelJSONResponse(await frames.apply_frame(services, body))
