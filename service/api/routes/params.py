"""Parameters shared by several routes."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Path, Query
from fastapi.routing import APIRoute
from starlette.requests import HTTPConnection, Request

from service.runtime.services import Services, services_of
from service.wire.errors import FieldError
from service.wire.schemas import AGENT_ID_PATTERN

#: Query parameters that take a comma-separated list: a repeat adds to it (``slices=1&slices=2``
#: is ``slices=1,2``; :func:`joined`).
LIST_QUERY_PARAMETERS = frozenset({"slices", "include"})

AgentIdPath = Annotated[
    str, Path(pattern=AGENT_ID_PATTERN, description="the caller's id of the human")
]


async def services_dependency(conn: HTTPConnection) -> Services:
    """The app's :class:`Services`, as an async dependency: FastAPI runs a plain function
    dependency in its thread pool, a thread hop on every request for a dictionary lookup."""
    return services_of(conn)


ServicesDep = Annotated[Services, Depends(services_dependency)]

#: ``slices``: seconds after the observation, comma-separated (joined with :func:`joined`).
SlicesQuery = Annotated[
    list[str] | None,
    Query(description="comma-separated seconds after the observation (repeats add to it)"),
]
CollisionRadiusQuery = Annotated[
    float | None, Query(ge=0.0, le=100.0, description="default: the agent's R_col")
]


def _declared_query_parameters(route: APIRoute) -> frozenset[str]:
    return frozenset(param.alias for param in route.dependant.query_params)


async def query_parameters_checked(request: Request) -> None:
    """422 for a query parameter the route does not take, or a single-valued one given twice:
    either would otherwise be dropped without a word (FastAPI ignores unknown parameters and keeps
    the last of repeated ones)."""
    route = request.scope.get("route")
    if not isinstance(route, APIRoute):
        return
    declared = _declared_query_parameters(route)
    seen: set[str] = set()
    for name, _ in request.query_params.multi_items():
        if name not in declared:
            expected = ", ".join(sorted(declared)) or "none"
            raise FieldError(
                name, f"unknown query parameter (this route takes: {expected})", location="query"
            )
        if name in seen and name not in LIST_QUERY_PARAMETERS:
            raise FieldError(name, "given more than once", location="query")
        seen.add(name)


def joined(name: str, values: list[str] | None, max_chars: int) -> str | None:
    """A list query parameter's repeats as one comma-separated value (None if absent); 422 if
    longer than ``max_chars``."""
    if values is None:
        return None
    text = ",".join(values)
    if len(text) > max_chars:
        raise FieldError(name, f"longer than {max_chars} characters", location="query")
    return text
