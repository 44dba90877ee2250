"""Constraints for a planner's MPC: per requested time, convex pieces ``A x ≤ b`` in the world
frame whose union contains C = K ⊕ R_col at that time (``reach.constraints`` has the maths)."""

from __future__ import annotations

from starlette.concurrency import run_in_threadpool

from reach.constraints import ConvexPiece, slice_pieces
from reach.sets import FRTSet
from service.flows.contours import agent_set, parse_times, query_model
from service.runtime.services import Services
from service.wire.schemas import (
    ConstraintPiece,
    ConstraintQuery,
    ConstraintSlice,
    ConstraintsResponse,
)


def parse_query(
    slices: str | None, max_sides: int, max_pieces: int, collision_radius: float | None
) -> ConstraintQuery:
    """The query parameters as a :class:`ConstraintQuery` (422 naming the parameter)."""
    return query_model(
        ConstraintQuery,
        slices=parse_times(slices),
        max_sides=max_sides,
        max_pieces=max_pieces,
        collision_radius=collision_radius,
    )


def _piece(piece: ConvexPiece) -> ConstraintPiece:
    return ConstraintPiece(
        A=piece.normals.tolist(), b=piece.offsets.tolist(), vertices=piece.corners.tolist()
    )


def build(
    frt: FRTSet, query: ConstraintQuery, collision_radius: float, t_origin: float
) -> list[ConstraintSlice]:
    """The pieces of every requested time (blocking: geometry work, call from a thread)."""
    return [
        ConstraintSlice(
            t=t,
            time=t_origin + t,
            pieces=[
                _piece(p)
                for p in slice_pieces(frt, t, collision_radius, query.max_sides, query.max_pieces)
            ],
        )
        for t in query.slices
    ]


async def agent_constraints(
    services: Services, agent_id: str, query: ConstraintQuery, location: str = "query"
) -> ConstraintsResponse:
    """The agent's constraints from its exact set if ready within ``FRT_EXACT_TIMEOUT_S``, else
    from the conservative set (which contains it), cut by the agent's map assumptions where it
    names a map (``AgentSet.on_the_road``). Changes nothing."""
    served = await agent_set(services, agent_id, query.slices, query.collision_radius, location)
    state, radius = served.state, served.collision_radius

    def compute() -> tuple[list[ConstraintSlice], bool, list[str]]:
        frt, conservative, assumptions = served.on_the_road(services)
        return build(frt, query, radius, state.timestamp), conservative, assumptions

    slices, conservative, assumptions = await run_in_threadpool(compute)
    return ConstraintsResponse(
        agent_id=agent_id,
        frt_version=state.frt_version,
        timestamp=state.timestamp,
        horizon_s=served.horizon_s,
        collision_radius=radius,
        conservative=conservative,
        assumptions=assumptions,
        max_sides=query.max_sides,
        max_pieces=query.max_pieces,
        slices=slices,
    )
