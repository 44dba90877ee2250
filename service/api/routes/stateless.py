"""``POST /v1/frt``: the FRT of a state and bounds given in full, with no agent kept."""

from __future__ import annotations

from fastapi import APIRouter, Request

from service.api.middleware import arrival_time
from service.api.routes.params import ServicesDep
from service.flows import stateless
from service.wire.schemas import FRTRequest, FRTResponse

router = APIRouter(prefix="/v1", tags=["frt"])


@router.post("/frt", response_model=FRTResponse)
async def frt(body: FRTRequest, request: Request, services: ServicesDep) -> FRTResponse:
    """State plus control bounds (or prediction plus beta) in; contours and/or a check out."""
    return await stateless.stateless_frt(services, body, arrival_time(request.scope))
