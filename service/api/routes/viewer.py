"""``GET /viewer``: the operator's live page, and its static files under ``/viewer/static/``.

The page is plain HTML and JavaScript (``service/api/viewer/``, libraries vendored as built files),
so nothing is built or fetched at run time. It reads the agents over ``WS /v1/stream``, their
contours over ``GET /v1/agents/{id}/frt`` and the maps they name over
``GET /v1/maps/{id}/geojson``, which carry ``/v1``'s auth; the page itself follows the
same rule: with an ``auth_token`` set, ``Authorization: Bearer`` or (a browser's address bar sets
no headers) ``?token=``. The static files hold no data and are served to anyone. Registered only
when the ``viewer`` setting is on (``FRT_VIEWER=0``: every path here is a 404).
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse

from service.api.auth import bearer_token, token_matches
from service.runtime.services import services_of
from service.wire.errors import APIError, UnauthorizedError

VIEWER_DIR = Path(__file__).resolve().parent.parent / "viewer"
MEDIA_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
}
#: The page may load only its own files and talk only to its own origin.
PAGE_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
        "connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'"
    ),
    "Referrer-Policy": "no-referrer",  # the address may carry ?token=
    "Cache-Control": "no-store",
    "X-Content-Type-Options": "nosniff",
}


def static_files(root: Path = VIEWER_DIR) -> dict[str, Path]:
    """The servable files by their path under ``/viewer/static/``: scripts and styles only."""
    return {
        path.relative_to(root).as_posix(): path
        for path in sorted(root.rglob("*"))
        if path.is_file() and path.suffix in (".js", ".css") and "__pycache__" not in path.parts
    }


STATIC = static_files()

router = APIRouter(tags=["viewer"])


def _authorised(request: Request) -> bool:
    expected = services_of(request).settings.auth_token
    if not expected:
        return True
    given = bearer_token(request.scope) or request.query_params.get("token")
    return token_matches(given, expected)


@router.get("/viewer", include_in_schema=False)
async def viewer_page(request: Request) -> FileResponse:
    """The live view of the agents and their sets (see docs/viewer.md)."""
    if not _authorised(request):
        raise UnauthorizedError()
    return FileResponse(
        VIEWER_DIR / "index.html", media_type=MEDIA_TYPES[".html"], headers=PAGE_HEADERS
    )


@router.get("/viewer/static/{name:path}", include_in_schema=False)
async def viewer_static(name: str) -> FileResponse:
    path = STATIC.get(name)
    if path is None:
        raise APIError(404, "no such viewer file")
    return FileResponse(
        path,
        media_type=MEDIA_TYPES[path.suffix],
        headers={"Cache-Control": "no-cache", "X-Content-Type-Options": "nosniff"},
    )
