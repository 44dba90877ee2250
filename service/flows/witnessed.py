"""Conservative collisions that the exact set's verdict is known for: a position the human
reaches (``reach.witness``) within R_col of a check point, reached no later than the point's time
(any time of the horizon for a whole-tube check), lies in the exact set's tube for that point,
so the exact set collides there too. The answer stays ``conservative`` (its clearances and first
collision are the conservative set's); ``collision_witnessed`` says its verdict is certain.

Only single trajectories of points are witnessed (a footprint's discs and a batch's candidates
are not), only answers without map assumptions (a set cut to the road need not hold a position
off it that the dynamics reach) and only settings the value network does not cut (its cut holds
the reachable states with a calibrated probability, not for certain; with the shipped card the
network cuts none).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from reach.engine import FRTEngine
from reach.frames import to_human_frame
from reach.witness import witnessed, witnesses
from service.flows.check_points import CheckPoints
from service.runtime.jobs import FRTJob
from service.runtime.stores import AgentState
from service.wire.schemas import CollisionCheckRequest


def witnessed_collisions(
    engine: FRTEngine,
    states: Sequence[AgentState],
    jobs: Sequence[FRTJob],
    request: CollisionCheckRequest,
    points: CheckPoints,
    radii: np.ndarray,
    candidates: Sequence[int],
) -> set[int]:
    """Of the agents ``candidates`` (answered conservatively, in collision, without map
    assumptions), those whose collision a witness position shows, where ``engine``'s value
    network does not cut the agent's set."""
    if points.batch or points.cover is not None:
        return set()
    found = set()
    for i in candidates:
        job = jobs[i]
        if any(engine.cuts(job.v_start, row) for row in np.asarray(job.bounds).reshape(-1, 8)):
            continue
        until = None
        if request.mode == "time_indexed":
            until = np.maximum(points.times - states[i].timestamp, 0.0)
        xy = to_human_frame(points.xy, job.pose)
        if witnessed(witnesses(job.v_start, job.bounds), xy, until, float(radii[i])).any():
            found.add(i)
    return found
