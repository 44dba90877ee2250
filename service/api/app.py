"""The FastAPI application: ``uvicorn service.api.app:app`` (or ``--factory service.api.app:create_app``)."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import Depends, FastAPI

from service.api.auth import BearerAuthMiddleware, bearer_scheme
from service.api.errors import install_error_handlers
from service.api.map_body_limit import BodySizeLimitWithMaps
from service.api.middleware import RequestContextMiddleware
from service.api.routes import (
    agents,
    collision,
    constraints,
    contours,
    frames,
    health,
    maps,
    model,
    stateless,
    stream,
    viewer,
)
from service.api.routes.json_body import add_body_schemas
from service.api.routes.params import query_parameters_checked
from service.runtime.logs import configure_logging
from service.runtime.services import Services
from service.runtime.settings import Settings, get_settings
from service.wire.limits import openapi_with_limits

DESCRIPTION = """Confidence-aware forward reachable tubes (FRTs) of human-driven cars.

The contract is API.md. Every `/v1` route needs `Authorization: Bearer <token>` when the server
has an `auth_token`; the WebSocket `/v1/stream` also takes `?token=`.
"""


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()
    configure_logging(settings.log_level, settings.log_json)
    services = Services.build(settings)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await services.start()
        try:
            yield
        finally:
            await services.stop()

    app = FastAPI(title="FRT service", version="0.1.0", description=DESCRIPTION, lifespan=lifespan)
    app.state.services = services
    install_error_handlers(app)
    # Added last = outermost: context (timing, id, logs) -> auth -> body limit -> routes.
    app.add_middleware(
        BodySizeLimitWithMaps,
        max_bytes=settings.max_body_bytes,
        max_check_bytes=settings.max_check_body_bytes,
        max_map_bytes=settings.max_map_bytes,
    )
    app.add_middleware(BearerAuthMiddleware, token=settings.auth_token)
    app.add_middleware(
        RequestContextMiddleware,
        metrics=services.metrics,
        log_requests=settings.log_requests,
        replica=settings.replica_id,
    )

    generate_openapi = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            spec = add_body_schemas(generate_openapi())
            app.openapi_schema = openapi_with_limits(spec, settings)
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]

    app.include_router(health.router)
    checked = [Depends(bearer_scheme), Depends(query_parameters_checked)]
    for router in (agents, frames, collision, contours, constraints, stateless, model, maps):
        app.include_router(router.router, dependencies=checked)
    app.include_router(stream.router)
    if settings.viewer:
        app.include_router(viewer.router)
    return app


app = create_app()
