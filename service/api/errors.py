"""The error handlers: every :class:`~service.wire.errors.APIError` and FastAPI's validation
errors answered as JSON in the shape ``service.wire.errors`` defines.

Nothing a client sends may produce a 500: the catch-all at the bottom exists for bugs, logs them,
and still answers JSON.
"""

from __future__ import annotations

import json
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


#: FastAPI's answer to a body that ``json.loads`` cannot read other than as malformed JSON (an
#: integer too long to convert, nesting deeper than the recursion limit).
_UNPARSED_BODY = "There was an error parsing the body"


class ErrorJSONResponse(JSONResponse):
    """An error's JSON, every non-ASCII character escaped: a key the client sent, named in a 422,
    may hold a lone surrogate, which has no UTF-8 form."""

    def render(self, content: Any) -> bytes:
        return json.dumps(content, separators=(",", ":")).encode("ascii")


def error_response(status: int, body: dict[str, Any], headers: dict[str, str] | None = None):
    return ErrorJSONResponse(body, status_code=status, headers=headers)


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
    if exc.status_code == 400 and exc.detail == _UNPARSED_BODY:
        # Answered as malformed JSON is: a 422 naming the body.
        msg = "body is not JSON this service reads (an integer too long, or nesting too deep)"
        error = {"loc": ("body",), "msg": msg, "type": "json_invalid"}
        return error_response(422, validation_payload([error]))
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
