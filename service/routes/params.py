"""Parameters shared by several routes."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Path
from starlette.requests import HTTPConnection

from service.schemas import AGENT_ID_PATTERN
from service.services import Services, services_of

AgentIdPath = Annotated[
    str, Path(pattern=AGENT_ID_PATTERN, description="the caller's id of the human")
]


async def services_dependency(conn: HTTPConnection) -> Services:
    """The app's :class:`Services`, as an async dependency: FastAPI runs a plain function
    dependency in its thread pool, a thread hop on every request for a dictionary lookup."""
    return services_of(conn)


ServicesDep = Annotated[Services, Depends(services_dependency)]
