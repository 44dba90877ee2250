"""Liveness, readiness (model loaded, store answering) and Prometheus metrics; never behind auth."""

from __future__ import annotations

from fastapi import APIRouter, Response
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from service.api.routes.params import ServicesDep
from service.wire.schemas import Health, Readiness

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health)
async def healthz() -> Health:
    return Health(status="ok")


@router.get("/readyz", response_model=Readiness, responses={503: {"model": Readiness}})
async def readyz(services: ServicesDep) -> JSONResponse:
    """Ready when the model is loaded and the agent store answers (a replica whose Redis is down
    cannot serve observations, so a load balancer or orchestrator should route around it)."""
    detail = services.model_error
    ready = services.engine is not None
    if ready and not await services.store.ping():
        ready, detail = False, "agent store unreachable"
    body = Readiness(ready=ready, model=services.model_name, detail=detail, active=services.parts)
    return JSONResponse(body.model_dump(), status_code=200 if ready else 503)


@router.get("/metrics", response_class=Response)
async def metrics(services: ServicesDep) -> Response:
    services.metrics.agents.set(await services.store.count())
    body = await run_in_threadpool(services.metrics.render)
    return Response(body, media_type=services.metrics.content_type)
