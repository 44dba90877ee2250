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

Only the points inside the answering set's C are searched, deepest first: a witnessed point
lies in the exact set's C, which that set contains. The search is optional: an agent's rows of
bounds (a multi-modal agent's modes) are searched one by one while the check's deadline leaves
time (``until``, read on ``clock`` before each row), and an agent whose search is cut short is
answered not witnessed. A search of one row over at most :data:`UNTIMED_POINTS` points (an agent
of one mode checked along a short trajectory) is made whatever the time: it costs microseconds
once the row's rollouts are kept (``reach.witness``), as they are after a version's first check.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

import numpy as np

from reach.engine import FRTEngine
from reach.frames import to_human_frame
from reach.witness import first_witnessed, witnesses
from service.flows.check_points import CheckPoints
from service.runtime.jobs import FRTJob
from service.runtime.stores import AgentState
from service.wire.schemas import CollisionCheckRequest

#: Points a search of one row of bounds may hold and be made whatever the time.
UNTIMED_POINTS = 64


def witnessed_collisions(
    engine: FRTEngine,
    states: Sequence[AgentState],
    jobs: Sequence[FRTJob],
    request: CollisionCheckRequest,
    points: CheckPoints,
    answered: tuple[np.ndarray, np.ndarray, Sequence[int]],
    until: float = math.inf,
    clock: Callable[[], float] = time.perf_counter,
) -> set[int]:
    """Of the agents ``candidates`` (answered conservatively, in collision, without map
    assumptions), those whose collision a witness position shows, where ``engine``'s value
    network does not cut the agent's set. ``answered`` is (R_col per agent, the clearances
    [A, N] of the answers, ``candidates``); rows of bounds are searched while ``clock()`` is
    before ``until``, but for the searches of one row over at most :data:`UNTIMED_POINTS`
    points."""
    radii, clearance, candidates = answered
    if points.batch or points.cover is not None:
        return set()
    found = set()
    for i in candidates:
        job = jobs[i]
        rows = np.asarray(job.bounds).reshape(-1, 8)
        if any(engine.cuts(job.v_start, row) for row in rows):
            continue
        search = _search(states[i], job, request, points, clearance[i], float(radii[i]))
        timed = len(rows) > 1 or len(search[0]) > UNTIMED_POINTS
        if _witnessed_by_rows(job.v_start, rows, search, until if timed else math.inf, clock):
            found.add(i)
    return found


def _search(
    state: AgentState,
    job: FRTJob,
    request: CollisionCheckRequest,
    points: CheckPoints,
    clearance: np.ndarray,
    radius: float,
) -> tuple[np.ndarray, np.ndarray | None, float]:
    """What one agent's search looks for: its points inside C (``clearance`` below 0), deepest
    first, in the human frame; their times after the observation (None for a whole-tube
    check); R_col."""
    inside = np.flatnonzero(clearance < 0.0)
    inside = inside[np.argsort(clearance[inside], kind="stable")]
    times = None
    if request.mode == "time_indexed":
        times = np.maximum(points.times[inside] - state.timestamp, 0.0)
    return to_human_frame(points.xy[inside], job.pose), times, radius


def _witnessed_by_rows(
    v_start: float,
    rows: np.ndarray,
    search: tuple[np.ndarray, np.ndarray | None, float],
    until: float,
    clock: Callable[[], float],
) -> bool:
    """Whether a rollout of some row of bounds (``reach.witness``) witnesses one of ``search``'s
    points (human frame, their times after the observation or None, R_col), the rows searched
    one by one while ``clock()`` is before ``until`` (False once it is not)."""
    xy, times, radius = search
    for row in rows:
        if clock() >= until:
            return False
        if first_witnessed(witnesses(v_start, row), xy, times, radius) >= 0:
            return True
    return False
