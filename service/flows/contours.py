"""Contours of K and C as GeoJSON in the world frame: the whole-horizon tube and time slices.

Also the steps every read of one agent's set shares (:func:`parse_times`, :func:`query_model`,
:func:`agent_set`), which ``service.flows.constraints`` reads its set with too.

An agent answered under map assumptions (``service.flows.road``) has its contours drawn from its
set cut by them, and the answer lists them (C = cut K ⊕ R_col); asked with ``include_uncut``, the
answer carries the contours of the set before the cut beside them (``uncut``), which contain the
cut ones.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError
from starlette.concurrency import run_in_threadpool

from reach.sets import FRTSet
from service.flows.agent_config import AgentConfig
from service.flows.road import agent_assumptions, agent_cut
from service.runtime.services import Services
from service.runtime.stores import AgentState
from service.wire.errors import AgentNotFoundError, FieldError, dotted
from service.wire.limits import check_slices
from service.wire.schemas import ContourPair, ContourQuery, Contours, ContourSlice, ContoursResponse

M = TypeVar("M", bound=BaseModel)


#: A decimal number as JSON writes one (no ``1_0``, no other scripts' digits), with an optional
#: sign or leading dot; NaN and infinities are not numbers here.
_DECIMAL = re.compile(r"\s*[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\s*")


def parse_times(slices: str | None) -> list[float]:
    """``slices=1.0,2.0`` as numbers (422 naming ``slices.i``, in the query, if one is not)."""
    times: list[float] = []
    for i, text in enumerate(s for s in (slices or "").split(",") if s.strip()):
        if not _DECIMAL.fullmatch(text):
            raise FieldError(f"slices.{i}", f"not a number: {text!r}", location="query")
        times.append(float(text))
    return times


def query_model(model: type[M], **fields: Any) -> M:
    """``model`` of query parameters; its validation error (nan, inf, too many slices, ...) is the
    query's 422 naming the field."""
    try:
        return model(**fields)
    except ValidationError as exc:
        error = exc.errors()[0]
        raise FieldError(dotted(error["loc"]), error["msg"], location="query") from None


def parse_query(slices: str | None, include: str | None, tube: bool) -> ContourQuery:
    """``slices=1.0,2.0&include=K,C`` as a :class:`ContourQuery` (422 on the query parameter)."""
    times = parse_times(slices)
    parts = [p.strip() for p in (include if include is not None else "K,C").split(",") if p.strip()]
    if not parts or any(p not in ("K", "C") for p in parts):
        raise FieldError("include", "a comma-separated subset of K,C", location="query")
    return query_model(ContourQuery, slices=times, include=list(dict.fromkeys(parts)), tube=tube)


def build(frt: FRTSet, query: ContourQuery, collision_radius: float, t_origin: float) -> Contours:
    """The requested contours of one set (blocking: geometry work, call from a thread)."""

    def pick(geo: dict) -> dict:
        return {part: geo[part] for part in query.include}

    tube = ContourPair(**pick(frt.geojson("tube", None, collision_radius))) if query.tube else None
    slices = [
        ContourSlice(t=t, time=t_origin + t, **pick(frt.geojson("slice", t, collision_radius)))
        for t in query.slices
    ]
    return Contours(tube=tube, slices=slices)


@dataclass(frozen=True)
class AgentSet:
    """One agent's current version to answer from: its state, the R_col of C, the horizon, and
    the exact set if it was ready in time (else :meth:`frt` builds the conservative one)."""

    state: AgentState
    collision_radius: float
    horizon_s: float
    exact: FRTSet | None
    conservative: Callable[[], FRTSet]

    def frt(self) -> tuple[FRTSet, bool]:
        """(the set, whether it is the conservative one); blocking, call from a thread."""
        if self.exact is not None:
            return self.exact, False
        return self.conservative(), True

    def on_the_road(self, services: Services) -> tuple[FRTSet, bool, list[str]]:
        """:meth:`frt` cut by the agent's map assumptions, and those it was cut by (none without
        a map); blocking, call from a thread."""
        cut, _, conservative, used = self.cut_and_uncut(services)
        return cut, conservative, used

    def cut_and_uncut(self, services: Services) -> tuple[FRTSet, FRTSet, bool, list[str]]:
        """(:meth:`frt` cut by the agent's map assumptions, :meth:`frt` itself, whether it is the
        conservative set, the assumptions it was cut by); the first two are one set where none
        cut it. Blocking, call from a thread."""
        frt, conservative = self.frt()
        entry, active = agent_assumptions(services, self.state)
        if entry is None:
            return frt, frt, conservative, []
        cut, used = agent_cut(services, entry, services.job_for(self.state), frt, active)
        return cut, frt, conservative, used


async def agent_set(
    services: Services,
    agent_id: str,
    slices: list[float],
    collision_radius: float | None,
    location: str = "query",
) -> AgentSet:
    """The agent's set once ``slices`` are checked against the horizon and the server's limit
    (422 naming ``slices.i`` at ``location``): exact if ready within ``FRT_EXACT_TIMEOUT_S``;
    404 for an unknown agent, 503 before the model is loaded. Changes nothing."""
    settings = services.settings
    services.require_engine()
    horizon = services.horizon_s()
    try:
        check_slices("slices", slices, horizon, settings)
    except FieldError as exc:
        exc.location = location
        raise
    state = await services.store.get(agent_id)
    if state is None:
        raise AgentNotFoundError(agent_id)
    radius = collision_radius
    if radius is None:
        radius = float(AgentConfig.value_of(settings, state.config, "collision_radius"))
    job = services.job_for(state)
    exact = await services.exact_within(job, settings.exact_timeout_s)
    return AgentSet(state, radius, horizon, exact, lambda: services.conservative(job))


async def agent_contours(
    services: Services,
    agent_id: str,
    query: ContourQuery,
    collision_radius: float | None = None,
    location: str = "query",
    include_uncut: bool = False,
) -> ContoursResponse:
    """The agent's contours, from its set cut by its map assumptions; with ``include_uncut`` the
    set's contours before the cut beside them (``uncut``: null where nothing cut it), else no
    ``uncut`` field at all."""
    served = await agent_set(services, agent_id, query.slices, collision_radius, location)
    state, radius = served.state, served.collision_radius

    def compute() -> tuple[Contours, Contours | None, bool, list[str]]:
        cut, whole, conservative, assumptions = served.cut_and_uncut(services)
        contours = build(cut, query, radius, state.timestamp)
        uncut = None
        if include_uncut and assumptions:
            uncut = build(whole, query, radius, state.timestamp)
        return contours, uncut, conservative, assumptions

    contours, uncut, conservative, assumptions = await run_in_threadpool(compute)
    extra = {"uncut": uncut} if include_uncut else {}
    return ContoursResponse(
        **contours.model_dump(),
        agent_id=agent_id,
        frt_version=state.frt_version,
        timestamp=state.timestamp,
        horizon_s=served.horizon_s,
        collision_radius=radius,
        conservative=conservative,
        assumptions=assumptions,
        **extra,
    )
