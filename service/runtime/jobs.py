"""What one FRT depends on (:class:`FRTJob`), and the job of an agent's state made once per version."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from reach.contract import BOUND_COLUMNS
from reach.frames import Pose
from service.runtime.scheduler import FRTKey
from service.runtime.stores import AgentState


@dataclass(frozen=True)
class FRTJob:
    """What one FRT depends on, and its cache key."""

    key: FRTKey
    pose: Pose
    v_start: float
    bounds: np.ndarray

    @classmethod
    def make(cls, agent_id: str, version: int, pose: Pose, v_start: float, bounds: Any) -> FRTJob:
        bounds = np.asarray(bounds, dtype=np.float64)
        inputs = (pose.x, pose.y, pose.heading, v_start, *bounds.ravel().tolist())
        if bounds.size > len(BOUND_COLUMNS):  # a multi-modal set: one row per mode, a union
            bounds = bounds.reshape(-1, len(BOUND_COLUMNS))
        return cls(FRTKey.of(agent_id, version, inputs), pose, float(v_start), bounds)


#: Enough for the largest multi-agent check (max_agents_per_check) twice over; each entry is a
#: few objects the garbage collector walks, so not more.
@functools.lru_cache(maxsize=512)
def _job_of(
    agent_id: str,
    version: int,
    x: float,
    y: float,
    heading: float,
    v_start: float,
    bounds: tuple[float, ...],
) -> FRTJob:
    """The job of an agent's state, made once per version (a planner checks each agent at 10 Hz;
    the key's digest of the inputs is the cost). Keyed by every input, so it cannot go stale."""
    return FRTJob.make(agent_id, version, Pose(x, y, heading), v_start, bounds)


def job_for(state: AgentState) -> FRTJob:
    """The job of the agent's current version (its pose, speed and the bounds of its set)."""
    return _job_of(
        state.agent_id,
        state.frt_version,
        state.x,
        state.y,
        state.heading,
        state.speed,
        tuple(state.set_bounds()),
    )
