"""The trajectories planners had checked in the last seconds, with their answers, for the viewer.

Collision checks (HTTP and the stream) append a reference to their request and answers, nothing
copied on the check's path; ``list_agents`` (the viewer's poll) turns the recent ones into JSON.
Per server process: behind a load balancer each replica knows the checks it answered.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np

from service.wire.schemas import (
    CollisionCheckRequest,
    CollisionCheckResponse,
    TrajectoryColumns,
)

#: Checks kept, and how long one counts as the planner's current trajectory.
KEEP = 64
MAX_AGE_S = 2.0
#: Points of a trajectory sent to the viewer (evenly thinned beyond this).
MAX_POINTS = 100


class RecentChecks:
    def __init__(self, keep: int = KEEP, max_age_s: float = MAX_AGE_S) -> None:
        self.max_age_s = max_age_s
        self._checks: deque[
            tuple[float, CollisionCheckRequest, Sequence[CollisionCheckResponse]]
        ] = deque(maxlen=keep)

    def record(
        self, request: CollisionCheckRequest, answers: Sequence[CollisionCheckResponse]
    ) -> None:
        """Keep a check for the viewer: a batch's answers without their per-trajectory entries or
        columns (the viewer reads each agent's verdict), which would otherwise stay alive by the
        thousand for every recent batch, for the garbage collector to traverse."""
        kept = [
            a
            if a.trajectories is None and a.trajectory_columns is None
            else a.model_copy(update={"trajectories": None, "trajectory_columns": None})
            for a in answers
        ]
        self._checks.append((time.monotonic(), request, kept))

    def recent(self) -> list[dict[str, Any]]:
        """The checks of the last ``max_age_s``, newest first."""
        now = time.monotonic()
        out = []
        for at, request, answers in reversed(self._checks):
            age = now - at
            if age > self.max_age_s:
                break
            points = _drawn_trajectory(request)
            step = max(1, -(-len(points) // MAX_POINTS))
            out.append(
                {
                    "age_s": round(age, 3),
                    "mode": request.mode,
                    "trajectory": points[::step],
                    "collision": any(a.collision for a in answers),
                    "conservative": any(a.conservative for a in answers),
                    "agents": {
                        a.agent_id: {
                            "collision": a.collision,
                            "first_collision_index": a.first_collision_index,
                            "conservative": a.conservative,
                        }
                        for a in answers
                    },
                }
            )
        return out


def _drawn_trajectory(request: CollisionCheckRequest) -> list[list[float]]:
    """The check's trajectory as ``[t, x, y]`` rows; of a batch, its first."""
    if request.trajectory is not None:
        return [[p.t, p.x, p.y] for p in request.trajectory]
    if request.packed_trajectories is not None:
        packed = request.packed_trajectories
        n = packed.lengths[0]
        return np.stack([packed.t[:n], packed.x[:n], packed.y[:n]], axis=1).tolist()
    assert request.trajectories is not None
    first = request.trajectories[0]
    if isinstance(first, TrajectoryColumns):
        return [list(row) for row in zip(first.t, first.x, first.y, strict=True)]
    return [[p.t, p.x, p.y] for p in first]


_BY_SERVICES: dict[int, RecentChecks] = {}


def of(services: object) -> RecentChecks:
    """The recorder of one app's services (one per app: tests build several in one process)."""
    recorder = _BY_SERVICES.get(id(services))
    if recorder is None:
        recorder = _BY_SERVICES[id(services)] = RecentChecks()
    return recorder
