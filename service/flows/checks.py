"""Collision checks (API.md, "Collision check") within a deadline.

Each agent's answer comes from the exact FRT of its current version if that is ready in time and
there is time left to measure it, else from the engine's conservative set, which contains the exact
one (``conservative: true``). "In time" is :func:`wait_budget_s`: the deadline runs from the
request's arrival, and part of it is kept for answering, at what answering costs here
(``service.runtime.answer_cost``), and for the trip back. Sets that should not be done within the
wait at the workers' recent pace (running or queued) are not waited for. Clearance is the signed
distance to K minus R_col: negative inside C.

An agent answered under map assumptions (``service.flows.road``) is measured on its uncut set
first; only one that comes within ``exact_demand_margin_m`` of colliding there has its set cut
and those points measured again (:func:`service.flows.road.cut_near`): the cut set lies inside
the uncut one, so the others' verdicts are the cut set's already and their clearances lower
bounds of the cut set's. Batch checks are answered from the uncut sets, without assumptions.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import TypeAdapter

from reach.batch import (
    Reduction,
    least_member_clearances,
    trajectory_surrogates_of,
    tube_clearances,
    tubes_of_many,
)
from reach.contract import BOUND_COLUMNS
from reach.sets import FRTSet
from reach.union import box_members
from service.flows.agent_config import AgentConfig
from service.flows.check_points import CheckPoints, batch_answers, check_points, check_work
from service.flows.confidence import stored_estimates
from service.flows.road import cut_near
from service.flows.witnessed import witnessed_collisions
from service.runtime.answer_cost import AnswerCosts, work_units
from service.runtime.jobs import FRTJob
from service.runtime.services import Services
from service.runtime.settings import Settings
from service.runtime.stores import AgentState
from service.runtime.tube_builder import within_built_tubes
from service.wire.errors import AgentNotFoundError, FieldError
from service.wire.limits import check_agents
from service.wire.schemas import (
    CollisionAnswer,
    CollisionCheckRequest,
    CollisionCheckResponse,
    MultiCollisionCheckRequest,
    MultiCollisionCheckResponse,
    TrajectoryPoint,
)

log = logging.getLogger("frt.checks")

#: Clearances are clipped to +-this (metres) so that "no set at all" (infinite distance) stays JSON.
CLEARANCE_LIMIT = 1e9
#: Share of the time the deadline leaves while answering that the optional witness search may
#: take: the rest absorbs what the estimates of answering miss, such as writing the reply.
WITNESS_SHARE = 0.5


def answer(
    frt: FRTSet,
    trajectory: Sequence[TrajectoryPoint],
    collision_radius: float,
    t_origin: float | None,
) -> CollisionAnswer:
    """Check a trajectory against one set. ``t_origin`` None: the whole-horizon tube; else each point
    at time t against the tube up to ``t - t_origin``."""
    xy = np.array([[p.x, p.y] for p in trajectory], dtype=np.float64)
    times = np.array([p.t for p in trajectory], dtype=np.float64)
    return CollisionAnswer.model_construct(
        **answer_fields(frt, xy, times, collision_radius, t_origin)
    )


def answer_fields(
    frt: FRTSet, xy: np.ndarray, times: np.ndarray, collision_radius: float, t_origin: float | None
) -> dict[str, Any]:
    """The fields of :class:`CollisionAnswer` for points ``xy`` at ``times`` (see :func:`answer`)."""
    t_rel = None if t_origin is None else times - t_origin
    clearance, first = clearance_rows(
        np.asarray(frt.clearance(xy, t_rel), dtype=np.float64)[None, :],
        np.array([collision_radius], dtype=np.float64),
    )
    index = int(first[0]) if first[0] >= 0 else None
    return {
        "collision": index is not None,
        "first_collision_index": index,
        "first_collision_time": None if index is None else float(times[index]),
        "clearance": clearance[0].tolist(),
    }


def clearance_rows(distance_to_k: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances [A, N] of A agents' points to K and their R_col [A] -> clearances to C [A, N],
    clipped to +-CLEARANCE_LIMIT, and each row's first colliding point (-1 if none)."""
    distance = distance_to_k - radii[:, None]
    # NaN would be a bug in the geometry; count it as a collision rather than as clear.
    distance = np.where(np.isnan(distance), -CLEARANCE_LIMIT, distance)
    clearance = np.clip(distance, -CLEARANCE_LIMIT, CLEARANCE_LIMIT)
    hit = clearance < 0.0
    return clearance, np.where(hit.any(axis=1), hit.argmax(axis=1), -1)


def wait_budget_s(arrival: float, deadline_ms: float, settings: Settings) -> float:
    """Seconds to wait for an exact set before answering conservatively: at most
    ``deadline_wait_fraction`` of the deadline, and never into the last ``deadline_reserve_ms``."""
    deadline_s = deadline_ms / 1000.0
    elapsed = time.perf_counter() - arrival
    until_reserve = deadline_s - elapsed - settings.deadline_reserve_ms / 1000.0
    return min(until_reserve, settings.deadline_wait_fraction * deadline_s - elapsed)


@dataclass
class _Timeline:
    """When each phase of one check ended (``time.perf_counter()``), for the late-answer log."""

    arrival: float
    entered: float
    waited: float = 0.0
    boxes_done: float = 0.0
    sets_done: float = 0.0
    done: float = 0.0
    #: Seconds spent cutting sets to the road while answering (not answering's own cost).
    cut_s: float = 0.0
    #: Seconds spent searching for witnessed collisions (optional: within what the deadline
    #: leaves, not answering's own cost).
    witness_s: float = 0.0

    def phases_ms(self) -> dict[str, float]:
        """Where the time went: before this module ran (parsing, the event loop busy with other
        work), waiting for exact sets, then each answering phase."""
        marks = (
            self.arrival,
            self.entered,
            self.waited,
            self.boxes_done,
            self.sets_done,
            self.done,
        )
        names = ("before_ms", "wait_ms", "boxes_ms", "sets_ms", "response_ms")
        return {
            n: round((b - a) * 1e3, 3) for n, a, b in zip(names, marks[:-1], marks[1:], strict=True)
        }


async def answer_states(
    services: Services,
    states: Sequence[AgentState],
    request: CollisionCheckRequest,
    points: CheckPoints,
    arrival: float,
) -> list[CollisionCheckResponse]:
    """Answer one check of ``states`` at ``points`` in phases: wait for the exact sets that may
    make it, measure the conservative sets of the rest, measure the exact sets (drawing the tubes a
    time-indexed check needs while its budget allows), respond."""
    services.require_engine()
    timeline = _Timeline(arrival, time.perf_counter())
    deadline_ms = request.deadline_ms or services.settings.deadline_ms
    costs = services.answer_costs_for(points.batch)
    jobs = [services.job_for(state) for state in states]
    work = _Work.of_check(points, jobs)
    exact = await _exact_sets_in_time(services, (costs, work), jobs, (arrival, deadline_ms))
    not_ready = sum(frt is None for frt in exact)
    found = list(exact)
    no_time = _answer_in_time(services, (costs, work), exact, (arrival, deadline_ms))
    xy, times = points.probe_xy, points.probe_times
    t_rel = _times_after(times, states) if request.mode == "time_indexed" else [None] * len(states)
    radii = _collision_radii(services.settings, states, request)
    reduction = _reduction(request, points, radii)
    # Answered on the event loop: cheaper per agent than the thread hop and the GIL hand-offs
    # with the loop that answering in a worker thread cost.
    timeline.waited = time.perf_counter()
    chosen, distances = _conservative_distances(services, jobs, exact, xy, t_rel)
    timeline.boxes_done = time.perf_counter()
    costs.conservative.record(timeline.boxes_done - timeline.waited, work.of(distances))
    _note_tube_demand(services, states, chosen, t_rel)
    pending = [i for i in chosen if i not in distances]
    drawn_before = services.tubes.spent_s
    coarse = _exact_distances(
        services,
        chosen,
        pending,
        distances,
        (xy, t_rel, reduction),
        (costs, arrival, deadline_ms, work),
    )
    timeline.sets_done = time.perf_counter()
    # Tubes drawn for this check are budgeted on their own (TubeBuilder.cost).
    drawing = services.tubes.spent_s - drawn_before
    costs.exact.record(timeline.sets_done - timeline.boxes_done - drawing, work.of(pending))
    road = _RoadCut(jobs, chosen, coarse, t_rel, timeline, deadline_ms, costs, work.answering)
    results = _respond_all(services, states, exact, request, points, radii, distances, road)
    _count_reasons(services, not_ready=not_ready, no_time=no_time, tubes=len(coarse))
    timeline.done = time.perf_counter()
    answering = timeline.done - timeline.sets_done - timeline.cut_s - timeline.witness_s
    costs.response.record(answering, work.answering)
    skipped_all = no_time and not any(frt is not None for frt in exact)
    if skipped_all and time.perf_counter() >= costs.remeasure_after:
        _measure_one_skipped(found, (costs, work), (xy, t_rel, reduction))
    _note_deadline(services, timeline, deadline_ms, len(states), not_ready, no_time)
    return results


def _measure_one_skipped(
    found: list[FRTSet | None],
    costed: tuple[AnswerCosts, _Work],
    probes: tuple[np.ndarray, list[np.ndarray | None], Reduction | None],
) -> None:
    """After a check that answered every agent conservatively for want of time, measure what
    answering the first exact set it ``found`` would have cost (:func:`_measure_exact_answer`),
    once the loop is free (at most ``AnswerCosts.remeasure_after``'s share of its time)."""
    costs, work = costed
    xy, t_rel, reduction = probes
    skipped = next(i for i, frt in enumerate(found) if frt is not None)
    asyncio.get_running_loop().call_soon(
        _measure_exact_answer,
        (costs, float(work.measuring[skipped])),
        found[skipped],
        (xy, t_rel[skipped], _for_agent(reduction, skipped)),
    )


def _times_after(times: np.ndarray, states: Sequence[AgentState]) -> list[np.ndarray]:
    """The points' times after each state's observation, one array per distinct observation
    time (the agents of a frame share theirs, and ``reach.batch.tubes_of_many`` finds the tubes
    of one array once). The arrays are only read."""
    after: dict[float, np.ndarray] = {}
    for state in states:
        if state.timestamp not in after:
            after[state.timestamp] = times - state.timestamp
    return [after[state.timestamp] for state in states]


@dataclass(frozen=True)
class _Work:
    """A check's work in units (``service.runtime.answer_cost.work_units``): per agent, measuring
    its set's members at the check's probes; answering every agent."""

    measuring: np.ndarray  # [A]
    answering: float

    @classmethod
    def of_check(cls, points: CheckPoints, jobs: Sequence[FRTJob]) -> _Work:
        members = np.array([job.bounds.size // len(BOUND_COLUMNS) for job in jobs])
        measuring = work_units(points.n_probes, members)
        return cls(measuring, len(jobs) * work_units(points.n_points))

    @property
    def total(self) -> float:
        """Units of measuring every agent."""
        return float(self.measuring.sum())

    def of(self, agents: Iterable[int]) -> float:
        """Units of measuring ``agents`` (indices)."""
        return float(self.measuring[list(agents)].sum())


@dataclass(frozen=True)
class _RoadCut:
    """What cutting a check's sets to the road needs besides the distances: each agent's job,
    the set it is answered from, those answered with later tubes than their points' own (not
    cut), the points' times after each observation, the check's timeline and deadline."""

    jobs: list[FRTJob]
    chosen: dict[int, FRTSet]
    coarse: set[int]
    t_rel: list[np.ndarray | None]
    timeline: _Timeline
    deadline_ms: float
    costs: AnswerCosts
    #: Units of answering every agent of the check (``_Work.answering``).
    answering: float


def _road_assumptions(
    services: Services,
    states: Sequence[AgentState],
    points: CheckPoints,
    radii: np.ndarray,
    distances: dict[int, np.ndarray],
    road: _RoadCut,
) -> list[list[str]]:
    """Each agent's map assumptions, its distances measured to its cut set where they come near
    (``service.flows.road.cut_near``) while the deadline leaves time to answer them all. A
    batch's distances may be lower bounds away from its trajectories' least and first colliding
    points (``reach.packed_rings``): a point near by its bound is measured to the cut set, one
    that is not is farther from the uncut set, and so from the cut one, than the margin.
    The time it takes goes into ``road.timeline.cut_s``."""
    start = time.perf_counter()
    until = _answer_until(services, road)
    labels = cut_near(
        services,
        states,
        road.jobs,
        road.chosen,
        distances,
        (points.probe_xy, road.t_rel, points.thresholds(radii)),
        until,
        road.coarse,
    )
    road.timeline.cut_s = time.perf_counter() - start
    return labels


def _answer_until(services: Services, road: _RoadCut) -> float:
    """When (``time.perf_counter()``) optional work while answering must stop: the deadline's
    reserve less what answering the check's agents rarely exceeds."""
    return (
        road.timeline.arrival
        + (road.deadline_ms - services.settings.deadline_reserve_ms) / 1000.0
        - road.costs.response.upper_s(road.answering)
    )


def _note_deadline(
    services: Services,
    timeline: _Timeline,
    deadline_ms: float,
    agents: int,
    not_ready: int,
    no_time: int,
) -> None:
    """Count and log a check answered after its deadline, with its phases."""
    elapsed_s = timeline.done - timeline.arrival
    if elapsed_s <= deadline_ms / 1000.0:
        return
    services.metrics.deadline_misses.inc()
    log.warning(
        "collision check answered after its deadline",
        extra={
            "deadline_ms": deadline_ms,
            "elapsed_ms": round(elapsed_s * 1e3, 3),
            **timeline.phases_ms(),
            "agents": agents,
            "not_ready": not_ready,
            "no_time": no_time,
        },
    )


async def _exact_sets_in_time(
    services: Services,
    costed: tuple[AnswerCosts, _Work],
    jobs: list[FRTJob],
    deadline: tuple[float, float],
) -> list[FRTSet | None]:
    """Each job's exact set if it is cached or lands within the wait budget, else None. The
    budget keeps time to answer every agent once the wait is over: a planner's check of 50 agents
    takes milliseconds to answer, which a wait up to half the deadline would push past it."""
    arrival, deadline_ms = deadline
    budget = wait_budget_s(arrival, deadline_ms, services.settings)
    costs, work = costed
    budget -= costs.upper_s(work.total, 0, work.answering)
    # Cached sets first, without a task each (a planner's check of 50 agents mostly finds them).
    exact = services.cached_exact(jobs)
    late = [i for i, frt in enumerate(exact) if frt is None]
    # The late ones: only sets that may still make it are waited for, all in one wait.
    futures = dict(zip(late, services.exact_futures([jobs[i] for i in late], budget), strict=True))
    waiting = {i: f for i, f in futures.items() if f is not None}
    if waiting and budget > 0:
        await asyncio.wait({asyncio.wrap_future(f) for f in waiting.values()}, timeout=budget)
    for i, future in waiting.items():
        if future.done() and not future.cancelled() and future.exception() is None:
            exact[i] = future.result()
    return exact


def _conservative_distances(
    services: Services,
    jobs: list[FRTJob],
    exact: list[FRTSet | None],
    xy: np.ndarray,
    t_rel: list[np.ndarray | None],
) -> tuple[dict[int, FRTSet], dict[int, np.ndarray]]:
    """The set each agent is answered from (its exact set, else its conservative one), and the
    clearances of the agents answered from box sets, measured together
    (``reach.batch.least_member_clearances``: a union's, its members' least)."""
    conservative = {i: services.conservative(jobs[i]) for i, frt in enumerate(exact) if frt is None}
    members = {i: m for i, frt in conservative.items() if (m := box_members(frt))}
    measured = least_member_clearances(list(members.values()), xy, [t_rel[i] for i in members])
    distances = dict(zip(members, measured, strict=True))
    chosen = {i: frt if frt is not None else conservative[i] for i, frt in enumerate(exact)}
    return chosen, distances


def _exact_distances(
    services: Services,
    chosen: dict[int, FRTSet],
    pending: list[int],
    distances: dict[int, np.ndarray],
    probes: tuple[np.ndarray, list[np.ndarray | None], Reduction | None],
    check: tuple[AnswerCosts, float, float, _Work],
) -> set[int]:
    """Clearances of the ``pending`` agents into ``distances``: the sets that measure against
    their tubes (``FRTSet.clearance``) together, in one vectorised call, any other kind alone.
    ``probes`` is (points, their times after each agent's observation, the batch's reduction);
    with a reduction, the tube sets' values are its surrogates. ``check`` is the answer costs
    of its kind, its arrival, its deadline_ms and its work. Returns the agents answered against
    tubes already drawn that end later than theirs (conservatively)."""
    xy, t_rel, reduction = probes
    costs, arrival, deadline_ms, work = check
    plain = [i for i in pending if chosen[i].clearance_from_tubes]
    plain_times = {i: t_rel[i] for i in plain}
    # Each time-indexed agent's tubes and its points' places among them, found once (once a
    # point for a footprint's discs, which share its time; once for agents with the same times).
    group = 1 if reduction is None else reduction.group
    timed = [i for i, t in plain_times.items() if t is not None]
    found = tubes_of_many([chosen[i] for i in timed], [plain_times[i] for i in timed], group)
    places = dict(zip(timed, found, strict=True))
    coarse = _fit_tubes_to_deadline(
        services,
        {i: chosen[i] for i in plain},
        plain_times,
        (arrival, deadline_ms),
        costs.exact.upper_s(work.of(pending)) + costs.response.upper_s(work.answering),
        places,
    )
    sets, times = [chosen[i] for i in plain], [plain_times[i] for i in plain]
    if reduction is None:
        together = tube_clearances(sets, xy, times)
    else:
        thresholds = [reduction.thresholds[i] for i in plain]
        together = trajectory_surrogates_of(
            sets,
            xy,
            times,
            Reduction(reduction.starts, thresholds, reduction.group, reduction.every_point),
            [None if i in coarse else places.get(i) for i in plain],
        )
    distances.update(zip(plain, together, strict=True))
    for i in pending:
        if i not in distances:
            distances[i] = chosen[i].clearance(xy, t_rel[i])
    return coarse


def _note_tube_demand(
    services: Services,
    states: Sequence[AgentState],
    sets: dict[int, FRTSet],
    t_rel: Sequence[np.ndarray | None],
) -> None:
    """Tell the workers which tubes of each agent's next sets this check would have needed
    (``service.runtime.tube_demand``): the largest tube index of its points, 0 for a whole-tube
    check (the engine draws the whole tube itself): the tube of its latest time, as tube
    indices grow with time. Agents observed at one time share their array of times
    (:func:`_times_after`): its latest time is found once."""
    latest: dict[int, float] = {}
    demand = []
    for i, (state, t) in enumerate(zip(states, t_rel, strict=True)):
        if t is None or not len(t):
            demand.append((state.agent_id, 0))
            continue
        last = latest.get(id(t))
        if last is None:
            last = latest[id(t)] = float(t.max())
        demand.append((state.agent_id, sets[i].tube_index(last)))
    services.tube_demand.note_many(demand)


def _answer_in_time(
    services: Services,
    costed: tuple[AnswerCosts, _Work],
    exact: list[FRTSet | None],
    deadline: tuple[float, float],
) -> int:
    """Answer from the conservative sets, which contain the exact ones and cost a fraction to
    measure, the agents whose exact sets there is no time left to answer from (under load,
    answering takes several times its quiet cost): ``exact[i]`` set to None, in place, beyond the
    first that fit before the deadline's reserve. Returns how many."""
    found = [i for i, frt in enumerate(exact) if frt is not None]
    if not found:
        return 0
    arrival, deadline_ms = deadline
    left = (
        deadline_ms / 1000.0
        - (time.perf_counter() - arrival)
        - services.settings.deadline_reserve_ms / 1000.0
    )
    costs, work = costed
    exact_units = work.measuring[found].tolist()
    keep = costs.exact_agents_within(left, exact_units, work.total, work.answering)
    for i in found[keep:]:
        exact[i] = None
    return len(found) - keep


def _measure_exact_answer(
    costed: tuple[AnswerCosts, float],
    frt: FRTSet,
    probes: tuple[np.ndarray, np.ndarray | None, Reduction | None],
) -> None:
    """Measure, after a check has answered, what answering it from ``frt`` (an exact set it left
    out for want of time) would have cost, if its tubes are drawn: a check that answers every agent
    conservatively records no exact cost, so an estimate once too high (a first, cold answer; a
    pause under load) would otherwise never come down, and every later check with a short
    deadline would answer conservatively too. ``costed``: the costs and the agent's units of
    work; ``probes``: the check's points, their times after the agent's observation and the
    batch's reduction (for this agent alone)."""
    costs, units = costed
    xy, t_rel, reduction = probes
    if not frt.clearance_from_tubes:
        return
    if t_rel is not None and frt.missing_tubes(frt.tube_indices(t_rel).tolist()):
        return  # drawing tubes is the tube builder's to time (service.runtime.tube_builder)
    start = time.perf_counter()
    if reduction is None:
        tube_clearances([frt], xy, [t_rel])
    else:
        trajectory_surrogates_of([frt], xy, [t_rel], reduction)
    end = time.perf_counter()
    costs.exact.record(end - start, units)
    costs.remeasured(start, end)


def _fit_tubes_to_deadline(
    services: Services,
    sets: dict[int, FRTSet],
    t_rel: dict[int, np.ndarray | None],
    deadline: tuple[float, float],
    answer_s: float,
    places: dict[int, tuple[np.ndarray, np.ndarray]],
) -> set[int]:
    """Draw the tubes a time-indexed check needs, agent by agent, where all of an agent's fit in
    the check's budget (:func:`wait_budget_s` of ``deadline``, its arrival and ``deadline_ms``,
    less the ``answer_s`` that answering then takes) at the learned cost, reading the clock
    before each; check the agents still lacking some against tubes already drawn
    (``service.runtime.tube_builder``), changing their ``t_rel`` in place, and draw the rest
    between requests. ``places[i]``: ``tubes_of`` agent i's set and times. Returns the agents
    answered so (conservatively)."""
    arrival, deadline_ms = deadline
    until = time.perf_counter() + wait_budget_s(arrival, deadline_ms, services.settings) - answer_s
    per_tube = services.tubes.cost.upper_s(1)
    coarse: set[int] = set()
    for i, frt in sets.items():
        times = t_rel[i]
        if times is None:
            continue
        needed = places[i][0].tolist()
        missing = frt.missing_tubes(needed)
        if not missing:
            continue
        fits = time.perf_counter() + len(missing) * per_tube <= until
        if not (fits and services.tubes.build(frt, missing, until)):
            coarse.add(i)
            t_rel[i] = within_built_tubes(frt, times)
            services.tubes.later(frt, frt.missing_tubes(missing))
    return coarse


def _count_reasons(services: Services, **counts: int) -> None:
    """Count the agents answered conservatively, by reason."""
    for reason, count in counts.items():
        if count:
            services.metrics.conservative_reasons.labels(reason).inc(count)


def _for_agent(reduction: Reduction | None, i: int) -> Reduction | None:
    """``reduction`` with agent i's threshold alone."""
    if reduction is None:
        return None
    return Reduction(
        reduction.starts, [reduction.thresholds[i]], reduction.group, reduction.every_point
    )


def _reduction(
    request: CollisionCheckRequest, points: CheckPoints, radii: np.ndarray
) -> Reduction | None:
    """What a batch's answers read of the distances: per trajectory only the least clearance and
    the first collision, or every point's with ``include_clearance`` (None: a single trajectory,
    measured as ``FRTSet.clearance`` does)."""
    if not points.batch:
        return None
    group = 1 if points.cover is None else points.cover.count
    return Reduction(
        points.starts, points.thresholds(radii).tolist(), group, request.include_clearance
    )


def _collision_radii(
    settings: Settings, states: Sequence[AgentState], request: CollisionCheckRequest
) -> np.ndarray:
    """R_col per agent: the request's, else each agent's own."""
    return np.array(
        [
            request.collision_radius
            if request.collision_radius is not None
            else float(AgentConfig.value_of(settings, state.config, "collision_radius"))
            for state in states
        ],
        dtype=np.float64,
    )


def _count_sources(services: Services, exact: Sequence[FRTSet | None], coarse: set[int]) -> None:
    """Count the answers by the set they came from: once per source, not once per agent."""
    from_conservative = sum(frt is None or i in coarse for i, frt in enumerate(exact))
    answered = services.metrics.collision_checks
    for source, count in (
        ("exact", len(exact) - from_conservative),
        ("conservative", from_conservative),
    ):
        if count:
            answered.labels(source).inc(count)


def _respond_all(
    services: Services,
    states: Sequence[AgentState],
    exact: Sequence[FRTSet | None],
    request: CollisionCheckRequest,
    points: CheckPoints,
    radii: np.ndarray,
    distances: dict[int, np.ndarray],
    road: _RoadCut,
) -> list[CollisionCheckResponse]:
    """Every agent's answer from its probes' distances to K (``distances[i]``, before R_col),
    measured again to its set cut to the road where that can change it (:func:`_road_assumptions`),
    the clearance arithmetic done for all agents at once; ``road.coarse``: agents whose exact set
    was checked with later tubes than the points' own (conservative)."""
    labels = _road_assumptions(services, states, points, radii, distances, road)
    coarse = road.coarse
    if not states:
        return []
    probed = [np.asarray(distances[i], dtype=np.float64) for i in range(len(states))]
    if points.batch:
        answers = batch_answers(probed, points, radii, request, CLEARANCE_LIMIT)
        batches: list[Any] | None = answers.answers
        batch_field = answers.field
        rows: list[list[float]] = [[] for _ in states]
        clearance, first = np.empty((len(states), 0)), np.full(len(states), -1)
        colliding, least = answers.colliding, answers.least
    else:
        clearance, first = clearance_rows(points.point_distances(np.stack(probed)), radii)
        colliding = (clearance < 0.0).any(axis=1).tolist()  # a point in C
        batches, rows, least = None, clearance.tolist(), clearance.min(axis=1)
        batch_field = ""
    times, horizon = points.times, services.horizon_s()
    _count_sources(services, exact, coarse)
    answered = (exact, coarse, labels, colliding, clearance)
    witnessed = _witnessed(services, states, answered, request, points, radii, road)
    betas = stored_estimates([state.belief for state in states])
    fields = []
    for i, state in enumerate(states):
        index = int(first[i]) if first[i] >= 0 else None
        fields.append(
            {
                "collision": colliding[i],
                "first_collision_index": index,
                "first_collision_time": None if index is None else float(times[index]),
                "clearance": rows[i],
                "agent_id": state.agent_id,
                "mode": request.mode,
                "collision_radius": float(radii[i]),
                "beta": betas[i],
                "frt_version": state.frt_version,
                "conservative": exact[i] is None or i in coarse,
                "horizon_end": state.timestamp + horizon,
                "assumptions": labels[i],
                "collision_witnessed": i in witnessed,
            }
        )
    results = _answers_of(fields, batches, batch_field)
    _note_demand(services, results, least, points.batch)
    return results


def _answers_of(
    fields: list[dict[str, Any]], batches: list[Any] | None, batch_field: str
) -> list[CollisionCheckResponse]:
    """The answers from their fields: a check of one trajectory's validated together in
    pydantic's compiled core (cheaper than building each model in Python, and every value
    checked); a batch's built as they are, each with its answers per trajectory
    (``batches[i]`` as ``batch_field``), which are not validated again item by item."""
    if batches is None:
        return _ANSWERS.validate_python(fields)  # type: ignore[no-any-return]
    return [
        CollisionCheckResponse.model_construct(**f, **{batch_field: batches[i]})
        for i, f in enumerate(fields)
    ]


#: The answers of a check of one trajectory, validated together.
_ANSWERS = TypeAdapter(list[CollisionCheckResponse])


def _witnessed(
    services: Services,
    states: Sequence[AgentState],
    answered: tuple[Sequence[FRTSet | None], set[int], list[list[str]], list[bool], np.ndarray],
    request: CollisionCheckRequest,
    points: CheckPoints,
    radii: np.ndarray,
    road: _RoadCut,
) -> set[int]:
    """The agents whose conservative collision a reached position witnesses
    (``service.flows.witnessed``), of ``answered`` = (exact sets, agents answered with later
    tubes, map assumptions, collisions, clearances [A, N] of a single trajectory's points),
    searched for :data:`WITNESS_SHARE` of the time the deadline leaves to answer them all (the
    time it takes goes into ``road.timeline.witness_s``); counted in
    ``frt_collisions_witnessed``."""
    exact, coarse, labels, colliding, clearance = answered
    candidates = [
        i
        for i in range(len(states))
        if (exact[i] is None or i in coarse) and colliding[i] and not labels[i]
    ]
    if not candidates:
        return set()
    engine = services.require_engine()
    start = time.perf_counter()
    until = start + WITNESS_SHARE * (_answer_until(services, road) - start)
    answered_as = (radii, clearance, candidates)
    found = witnessed_collisions(engine, states, road.jobs, request, points, answered_as, until)
    road.timeline.witness_s = time.perf_counter() - start
    if found:
        services.metrics.collisions_witnessed.inc(len(found))
    return found


def _note_demand(
    services: Services,
    results: Sequence[CollisionCheckResponse],
    least: np.ndarray,
    batch: bool,
) -> None:
    """Count the answers by verdict, and demand the exact sets of the agents whose answer they
    would change or nearly (``service.runtime.demand``): a conservative verdict, or a least
    clearance below ``exact_demand_margin_m``, from the exact set or (a lower bound of the
    exact set's) from the conservative one: a trajectory that passes that close to an agent's
    set is likely to meet it at the next check, and its exact set is then under way. An agent
    whose set the trajectory met (a collision, from either set) is noted as met: its next
    sets go first. A ``batch``'s collision is of some candidate among many, which the planner
    may not take: its agents are demanded, not met."""
    verdicts = Counter(r.verdict for r in results)
    for verdict, count in verdicts.items():
        services.metrics.check_verdicts.labels(verdict).inc(count)
    margin = services.settings.exact_demand_margin_m
    near, met = [], []
    for r, clearance in zip(results, least.tolist(), strict=True):
        if r.collision and not batch:
            met.append(r.agent_id)
        elif r.verdict == "conservative" or clearance < margin:
            near.append(r.agent_id)
    if near:
        services.demand.note(near)
    if met:
        services.demand.note(met, met=True)


async def check_agent(
    services: Services, agent_id: str, request: CollisionCheckRequest, arrival: float
) -> CollisionCheckResponse:
    with services.priority.check():
        points = check_points(request, services.settings)
        services.require_engine()
        state = await services.store.get(agent_id)
        if state is None:
            raise AgentNotFoundError(agent_id)
        return (await answer_states(services, [state], request, points, arrival))[0]


async def check_agents_at_once(
    services: Services, request: MultiCollisionCheckRequest, arrival: float
) -> MultiCollisionCheckResponse:
    with services.priority.check():
        return await _check_agents_at_once(services, request, arrival)


async def _check_agents_at_once(
    services: Services, request: MultiCollisionCheckRequest, arrival: float
) -> MultiCollisionCheckResponse:
    settings = services.settings
    points = check_points(request, settings)
    services.require_engine()
    if request.agent_ids is None:
        ids = await services.store.ids()
        if len(ids) > settings.max_agents_per_check:
            raise FieldError(
                "agent_ids",
                f"{len(ids)} agents are known, more than {settings.max_agents_per_check} per "
                "check: name the agents to check",
            )
    else:
        ids = list(dict.fromkeys(request.agent_ids))  # drop repeats, keep the order
        check_agents("agent_ids", ids, settings)
    check_work(points, len(ids), settings)
    states, missing = [], []
    # Read only here: the states may be shared with other checks (no copy per agent).
    for agent_id, state in zip(ids, await services.store.get_many(ids, shared=True), strict=True):
        if state is None:
            missing.append(agent_id)
        else:
            states.append(state)
    results = await answer_states(services, states, request, points, arrival) if states else []
    return MultiCollisionCheckResponse(
        collision=any(r.collision for r in results),
        conservative=any(r.conservative for r in results),
        results=results,
        missing=missing,
    )
