"""The error handlers: every :class:`~service.wire.errors.APIError` and FastAPI's validation
errors answered as JSON in the shape ``service.wire.errors`` defines.

Nothing a client sends may produce a 500: the catch-all at the bottom exists for bugs, logs them,
and still answers JSON.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from service.wire.errors import APIError, Loc, validation_payload

log = logging.getLogger("frt.errors")


class BodyTooLargeError(StarletteHTTPException):
    """413, raised while the body streams in. An HTTPException so FastAPI re-raises it unchanged."""

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body larger than {limit} bytes")


def error_response(status: int, body: dict[str, Any], headers: dict[str, str] | None = None):
    return JSONResponse(body, status_code=status, headers=headers)


async def _api_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, APIError)
    location = getattr(exc, "location", None)
    prefix: Loc = (location,) if location else ()
    return error_response(exc.status, exc.payload(prefix), exc.headers)


async def _request_validation(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    return error_response(422, validation_payload(exc.errors()))


async def _http_exception(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    headers = getattr(exc, "headers", None)
    return error_response(exc.status_code, {"detail": exc.detail}, headers)


async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
    request_id = getattr(request.state, "request_id", None)
    log.exception(
        "unhandled error",
        extra={"request_id": request_id, "path": request.url.path, "error": repr(exc)},
    )
    headers = {"x-request-id": request_id} if request_id else None
    return error_response(
        500, {"detail": "internal server error", "request_id": request_id}, headers
    )


def install_error_handlers(app: FastAPI) -> None:
    app.add_exception_handler(APIError, _api_error)
    app.add_exception_handler(RequestValidationError, _request_validation)
    app.add_exception_handler(StarletteHTTPException, _http_exception)
    app.add_exception_handler(Exception, _unexpected)
