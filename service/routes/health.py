"""Liveness, readiness (model loaded) and Prometheus metrics; never behind auth."""

from __future__ import annotations

from fastapi import APIRouter, Response
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from service.routes.params import ServicesDep
from service.schemas import Health, Readiness

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health)
async def healthz() -> Health:
    return Health(status="ok")


@router.get("/readyz", response_model=Readiness, responses={503: {"model": Readiness}})
async def readyz(services: ServicesDep) -> JSONResponse:
    ready = services.engine is not None
    body = Readiness(ready=ready, model=services.model_name, detail=services.model_error)
    return JSONResponse(body.model_dump(), status_code=200 if ready else 503)


@router.get("/metrics", response_class=Response)
async def metrics(services: ServicesDep) -> Response:
    services.metrics.agents.set(await services.store.count())
    body = await run_in_threadpool(services.metrics.render)
    return Response(body, media_type=services.metrics.content_type)
