"""The body limit with its own, larger limit for map archives (``PUT /v1/maps/{map_id}``)."""

from __future__ import annotations

from starlette.types import ASGIApp

from service.api.middleware import BodySizeLimitMiddleware

#: Paths whose bodies are map archives.
MAPS_PATH_PREFIX = "/v1/maps/"


class BodySizeLimitWithMaps(BodySizeLimitMiddleware):
    """:class:`BodySizeLimitMiddleware` (413 by Content-Length, or as the body streams in), whose
    limit under ``/v1/maps/`` is ``max_map_bytes`` (``FRT_MAX_MAP_BYTES``)."""

    def __init__(
        self,
        app: ASGIApp,
        max_bytes: int,
        max_check_bytes: int | None = None,
        max_map_bytes: int | None = None,
    ) -> None:
        super().__init__(app, max_bytes, max_check_bytes)
        self.map_bytes = max_bytes if max_map_bytes is None else max_map_bytes

    def limit_for(self, path: str) -> int:
        if path.startswith(MAPS_PATH_PREFIX):
            return self.map_bytes
        return super().limit_for(path)
