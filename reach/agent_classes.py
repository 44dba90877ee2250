"""Road-user classes: each class's hard control limits, speed range and default collision radius.

Every class moves as the same extended unicycle (paper, "Running example": x' = v cos th,
y' = v sin th, th' = u1, v' = u2, with the stop rule at v = 0); a class only changes the box the
controls live in (``|u1| <= u1_limit``, ``|u2| <= u2_limit``), the speeds it is served at and the
collision radius R_col of C = K ⊕ R_col. The certified geometry (``reach.engine.FRTEngine``) is
built for any bounds, so it serves every class: :func:`engine_for_class` is the engine with the
class's ranges, sharing the value field, which cuts only where its own trained ranges cover a
setting (``ValueField.covers``). The sources of the figures are in docs/multimodal.md ("Agent classes").

The dynamics have no speed ceiling: a pedestrian accelerating for the whole horizon reaches
``v_max + u2_limit * T`` in the set, which contains what a pedestrian capped at ``v_max`` reaches.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

from reach.contract import BOUND_COLUMNS, U1_LIMIT, U2_LIMIT, V_START_MAX
from reach.engine import FRTEngine

ClassName = Literal["car", "cyclist", "pedestrian"]


@dataclass(frozen=True)
class AgentClass:
    """One class of road user (units: rad/s, m/s^2, m/s, m)."""

    name: ClassName
    #: |yaw rate u1| <= this (rad/s).
    u1_limit: float
    #: |acceleration u2| <= this (m/s^2).
    u2_limit: float
    #: The speeds (v_start) an observation of this class may have.
    speed_min: float
    speed_max: float
    #: R_col of C = K ⊕ R_col unless the agent's config sets one.
    collision_radius_m: float

    @property
    def limits(self) -> tuple[float, float]:
        """``(u1_limit, u2_limit)``, as ``service.flows.bounds`` takes them."""
        return (self.u1_limit, self.u2_limit)

    def ranges(self) -> dict[str, tuple[float, float]]:
        """The range of each FRT parameter (v_start and the eight bound columns) for this class."""
        out: dict[str, tuple[float, float]] = {"v_start": (self.speed_min, self.speed_max)}
        for column in BOUND_COLUMNS:
            limit = self.u1_limit if column.startswith("u1_") else self.u2_limit
            out[column] = (-limit, limit)
        return out


#: The registry. Car: the paper's limits and the network's trained v_start range. Cyclist and
#: pedestrian: see docs/multimodal.md ("Agent classes") for the sources behind each figure.
AGENT_CLASSES: dict[str, AgentClass] = {
    "car": AgentClass("car", U1_LIMIT, U2_LIMIT, 0.0, V_START_MAX, 1.5),
    "cyclist": AgentClass("cyclist", 1.5, 5.0, 0.0, 12.0, 1.0),
    "pedestrian": AgentClass("pedestrian", 4.0, 3.0, 0.0, 3.0, 0.75),
}
DEFAULT_CLASS: ClassName = "car"


def agent_class(name: str) -> AgentClass:
    """The registry's class ``name``; KeyError for an unknown one."""
    return AGENT_CLASSES[name]


def engine_for_class(engine: FRTEngine, klass: AgentClass) -> FRTEngine:
    """``engine`` validating against ``klass``'s ranges (the car: ``engine`` itself, whose ranges
    are its value field's trained ones). The copy shares the value field and every setting but the
    ranges, which only :meth:`FRTEngine.validate` reads: the sets it builds are the engine's."""
    if klass.name == DEFAULT_CLASS:
        return engine
    return _class_engine(engine, klass)


@lru_cache(maxsize=16)
def _class_engine(engine: FRTEngine, klass: AgentClass) -> FRTEngine:
    copied = copy.copy(engine)
    copied.ranges = klass.ranges()
    return copied
