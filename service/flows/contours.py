"""Contours of K and C as GeoJSON in the world frame: the whole-horizon tube and time slices."""

from __future__ import annotations

from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool

from reach.sets import FRTSet
from service.flows.agent_config import AgentConfig
from service.runtime.services import Services
from service.wire.errors import AgentNotFoundError, FieldError, dotted
from service.wire.limits import check_slices
from service.wire.schemas import ContourPair, ContourQuery, Contours, ContourSlice, ContoursResponse


def parse_query(slices: str | None, include: str | None, tube: bool) -> ContourQuery:
    """``slices=1.0,2.0&include=K,C`` as a :class:`ContourQuery` (422 on the query parameter)."""
    times: list[float] = []
    for i, text in enumerate(s for s in (slices or "").split(",") if s.strip()):
        try:
            times.append(float(text))
        except ValueError:
            raise FieldError(f"slices.{i}", f"not a number: {text!r}", location="query") from None
    parts = [p.strip() for p in (include if include is not None else "K,C").split(",") if p.strip()]
    if not parts or any(p not in ("K", "C") for p in parts):
        raise FieldError("include", "a comma-separated subset of K,C", location="query")
    try:
        return ContourQuery(slices=times, include=list(dict.fromkeys(parts)), tube=tube)  # type: ignore[arg-type]
    except ValidationError as exc:  # e.g. nan, inf or too many slices: the query's fault
        error = exc.errors()[0]
        raise FieldError(dotted(error["loc"]), error["msg"], location="query") from None


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


async def agent_contours(
    services: Services,
    agent_id: str,
    query: ContourQuery,
    collision_radius: float | None = None,
    location: str = "query",
) -> ContoursResponse:
    settings = services.settings
    services.require_engine()
    horizon = services.horizon_s()
    try:
        check_slices("slices", query.slices, horizon, settings)
    except FieldError as exc:
        exc.location = location
        raise
    state = await services.store.get(agent_id)
    if state is None:
        raise AgentNotFoundError(agent_id)
    radius = collision_radius
    if radius is None:
        radius = float(AgentConfig.of(settings, state.config).collision_radius)
    job = services.job_for(state)
    exact = await services.exact_within(job, settings.exact_timeout_s)

    def compute() -> tuple[Contours, bool]:
        frt = exact if exact is not None else services.conservative(job)
        return build(frt, query, radius, state.timestamp), exact is None

    contours, conservative = await run_in_threadpool(compute)
    return ContoursResponse(
        **contours.model_dump(),
        agent_id=agent_id,
        frt_version=state.frt_version,
        timestamp=state.timestamp,
        horizon_s=horizon,
        collision_radius=radius,
        conservative=conservative,
    )
