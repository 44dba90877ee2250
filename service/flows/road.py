"""Sets that know the road (docs/maps.md): the map assumptions a state is answered under, and its
set cut by them.

The stateless endpoint (:func:`stateless_cut`): a car's state that names a map is cut by the
assumptions asked for that its pose keeps, tested as an observation's are (below); one it breaks
is counted (``frt_assumption_violations_total``), and a state that keeps none is served uncut,
with no assumption listed.

Agents (:func:`observed_on_map`, :func:`agent_cut`): an agent that names a map keeps it
(``map_id`` in its stored overrides) and is answered under the assumptions its configuration
names (``config.assumptions``, else ``FRT_ASSUMPTIONS``) that its class allows
(:data:`CLASS_ASSUMPTIONS`). Each observation tests them at the observed pose (SPOT's
self-relaxation): ``drivable_area`` is broken off R, ``reachable_lanes`` where the pose is
within the map's extent and no start lane holds it (``reach.lanes``: off every vehicle lane ⊕
margin, or heading more than 30° off every lane holding it), ``speed_limit`` where the observed
speed exceeds v_cap (``reach.speed_limit``) read over a box holding the box of every set the car
may have (``reach.road_cut.observation_box``: a superset of the lanes the set's own box reaches,
so a higher or equal v_cap; not tested where it has none). A broken assumption is dropped for
the agent until ``FRT_ASSUMPTION_RELAX_S`` after that observation on its clock, in its stored
state (so every replica reads the same); the first observation at or after that time tests it
again. Outside the map's extent ``reachable_lanes`` is not tested and does not apply (no lane is
known there); ``drivable_area`` holds there (R is the whole plane outside the extent). A set is
cut by ``speed_limit`` where its own box's v_cap is at least the observed speed.
"""

from __future__ import annotations

import time
from collections.abc import Hashable, Sequence
from typing import Any

import numpy as np

from reach.agent_classes import DEFAULT_CLASS
from reach.frames import Pose
from reach.lanes import HEADING_TOLERANCE, REACHABLE_LANES, VEHICLE_LANE_TYPES
from reach.road_cut import DRIVABLE_AREA, observation_box
from reach.sets import FRTSet
from reach.speed_limit import SPEED_LIMIT
from service.runtime.jobs import FRTJob
from service.runtime.maps import MapEntry, VersionRoad
from service.runtime.services import Services
from service.runtime.stores import AgentState
from service.wire.schemas import HumanState, RelaxedAssumptionOut

#: The assumptions each agent class may be answered under: vehicles keep to the drivable area
#: and their reachable lanes, below their lanes' speed limit times the factor; cyclists to the
#: drivable area (bike lanes are not used); pedestrians to none (they walk on pavements and
#: cross anywhere; a model with crossings is not built).
CLASS_ASSUMPTIONS: dict[str, tuple[str, ...]] = {
    "car": (DRIVABLE_AREA, REACHABLE_LANES, SPEED_LIMIT),
    "cyclist": (DRIVABLE_AREA,),
    "pedestrian": (),
}
#: Keys of an agent's stored overrides (``AgentState.config``): the map it named, the assumptions
#: its current version is answered under, and those dropped for it ({name: until}).
MAP_KEY = "map_id"
ACTIVE_KEY = "assumptions_active"
RELAXED_KEY = "assumptions_relaxed"


def map_entry(services: Services, map_id: str | None, field: str = "map_id") -> MapEntry | None:
    """The registered map a request names (422 naming ``field`` if unknown), None if it names
    none."""
    return None if map_id is None else services.maps.require(map_id, field)


def stateless_cut(
    services: Services,
    entry: MapEntry | None,
    job: FRTJob,
    frt: FRTSet,
    pose: HumanState,
    configured: Sequence[str],
) -> tuple[FRTSet, list[str]]:
    """A car's ``frt`` (the stateless endpoint's, of ``job``, for a state at ``pose``) cut by
    the ``configured`` assumptions its pose keeps, and those it was cut by: ``frt`` itself and
    none without a map or where the pose keeps none (a broken one is counted). The cut is kept
    per (the job's key, whether ``frt`` is conservative) while ``frt`` is the set answered
    from."""
    if entry is None:
        return frt, []
    wanted = [a for a in CLASS_ASSUMPTIONS[DEFAULT_CLASS] if a in configured]
    held, broken = _tested(services, entry, wanted, pose)
    for name in broken:
        services.metrics.assumption_violations.labels(name, DEFAULT_CLASS).inc()
    if not held:
        services.metrics.road_cuts.labels("off_road").inc()
        return frt, []
    return agent_cut(services, entry, job, frt, held)


def _tested(
    services: Services, entry: MapEntry, names: Sequence[str], pose: HumanState
) -> tuple[list[str], list[str]]:
    """Of the assumptions ``names``, those the pose keeps and those it breaks, in order (one not
    tested, the lanes outside the map's extent, is neither)."""
    held, broken = [], []
    for name in names:
        holds = _holds(services, entry, name, pose)
        if holds is not None:
            (held if holds else broken).append(name)
    return held, broken


def _holds(services: Services, entry: MapEntry, name: str, pose: HumanState) -> bool | None:
    """Whether the pose keeps assumption ``name``; None where it is not tested (the lanes
    outside the map's extent; the speed limit where no v_cap is known)."""
    road, margin = entry.road, services.maps.margin
    if name == DRIVABLE_AREA:
        return road.on_road(pose.x, pose.y, margin)
    if name == SPEED_LIMIT:
        at = Pose(pose.x, pose.y, pose.heading)
        box = observation_box(at, pose.speed, services.horizon_s())
        v_cap = road.speed_cap(at, box, margin, services.maps.speed_factor)
        return None if v_cap is None else pose.speed <= v_cap
    x0, y0, x1, y1 = road.extent
    if not (x0 <= pose.x <= x1 and y0 <= pose.y <= y1):
        return None
    graph = road.lane_graph
    index = graph.index(margin, road.region(margin))
    xy = (pose.x, pose.y)
    return bool(graph.start(index, xy, pose.heading, VEHICLE_LANE_TYPES, HEADING_TOLERANCE))


def observed_on_map(
    services: Services,
    overrides: dict[str, Any],
    map_id: str | None,
    configured: tuple[str, ...],
    observed: tuple[float, HumanState],
) -> tuple[dict[str, Any], tuple[str, ...]]:
    """The agent's overrides with its map, active and relaxed assumptions after an observation
    (``observed``: its time and pose), and the assumptions it broke there. ``map_id``: the one
    the observation names (422 naming ``map_id`` if unknown), else the agent's; ``overrides``
    itself where neither names one. A map deleted since the agent named it: no assumption;
    another map than the agent's: its relaxations start anew."""
    named = map_id if map_id is not None else overrides.get(MAP_KEY)
    if named is None:
        return overrides, ()
    entry = services.maps.require(named) if map_id is not None else services.maps.get(named)
    t, pose = observed
    kept = overrides.get(RELAXED_KEY) if named == overrides.get(MAP_KEY) else None
    relaxed = {a: u for a, u in (kept or {}).items() if u > t}
    wanted = [
        a
        for a in CLASS_ASSUMPTIONS.get(str(overrides.get("agent_class", "car")), ())
        if a in configured
    ]
    held, broken = _tested(services, entry, wanted, pose) if entry is not None else ([], [])
    for name in broken:
        relaxed[name] = t + services.settings.assumption_relax_s
    active = [name for name in held if name not in relaxed]
    out = {**overrides, MAP_KEY: named, ACTIVE_KEY: active}
    if relaxed:
        out[RELAXED_KEY] = relaxed
    else:
        out.pop(RELAXED_KEY, None)
    return out, tuple(broken)


def agent_assumptions(services: Services, state: AgentState) -> tuple[MapEntry | None, list[str]]:
    """The map and the assumptions the agent's current version is answered under (none without
    a map, or once its map is deleted)."""
    active = state.config.get(ACTIVE_KEY)
    if not active:
        return None, []
    entry = services.maps.get(state.config[MAP_KEY])
    return (entry, list(active)) if entry is not None else (None, [])


def version_road(services: Services, state: AgentState, key: Hashable) -> VersionRoad | None:
    """What the agent's version ``key`` (of ``state``) is answered under on its map, for the
    audit to attribute its cut sets' misses (``service.runtime.audit``); None without a map or
    assumptions in force."""
    entry, active = agent_assumptions(services, state)
    return None if entry is None else VersionRoad(services.maps, entry, key, tuple(active))


def relaxed_out(state: AgentState) -> list[RelaxedAssumptionOut]:
    """The assumptions dropped for the agent, with the time each is tested again."""
    relaxed = state.config.get(RELAXED_KEY) or {}
    return [RelaxedAssumptionOut(assumption=a, until=float(u)) for a, u in relaxed.items()]


def agent_cut(
    services: Services, entry: MapEntry, job: FRTJob, frt: FRTSet, active: Sequence[str]
) -> tuple[FRTSet, list[str]]:
    """``frt`` (the set of ``job``, the agent's version) cut by its ``active`` assumptions, and
    those it was cut by (the lanes fall away where they do not apply to the set: R alone; the
    speed limit where the set's lanes give no v_cap at least the observed speed); ``frt`` and
    none where nothing cuts it. Cut sets are kept (``MapRegistry.cut_for``)."""
    key = (job.key, frt.conservative)
    speed = (job.v_start, job.bounds)
    cut = services.maps.cut_for(entry, key, frt, tuple(active), speed)
    if cut is None:
        return frt, []
    services.metrics.road_cuts.labels("cut").inc()
    return cut, list(cut.assumptions)


def cut_near(
    services: Services,
    states: Sequence[AgentState],
    jobs: Sequence[FRTJob],
    sets: dict[int, FRTSet],
    distances: dict[int, np.ndarray],
    probes: tuple[np.ndarray, Sequence[np.ndarray | None], np.ndarray],
    until: float,
    coarse: set[int] | frozenset[int] = frozenset(),
) -> list[list[str]]:
    """The assumptions of each agent's answer, its probes' distances to K in ``distances``
    (changed in place) measured to its set cut by them where they come within
    ``exact_demand_margin_m`` of colliding. ``probes``: (points, their times after each agent's
    observation, each agent's collision threshold). The cut set lies inside the uncut one, so a
    probe farther than that keeps its distance to the uncut set, a lower bound of the cut
    set's, and an agent none of whose probes is near is not cut: its verdict is the cut set's
    already. An agent near once ``until`` (``time.perf_counter()``) has passed, or in ``coarse``
    (answered with later tubes than its points' own), is answered from the uncut set, without
    assumptions."""
    xy, t_rel, thresholds = probes
    margin = services.settings.exact_demand_margin_m
    labels: list[list[str]] = []
    for i, state in enumerate(states):
        entry, active = agent_assumptions(services, state)
        if entry is None:
            labels.append([])
            continue
        near = np.asarray(distances[i]) < thresholds[i] + margin
        if not near.any():
            labels.append(active)
            continue
        if i in coarse or time.perf_counter() > until:
            labels.append([])
            continue
        frt, used = agent_cut(services, entry, jobs[i], sets[i], active)
        if used:
            measured = np.array(distances[i], dtype=np.float64)
            times = None if t_rel[i] is None else t_rel[i][near]  # type: ignore[index]
            measured[near] = frt.clearance(xy[near], times)
            distances[i] = measured
        labels.append(used)
    return labels
