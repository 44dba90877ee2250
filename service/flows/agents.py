"""Agents: the observation flow (API.md, "Observation"), the agent view, forgetting an agent.

One observation: validate its prediction once -> the agent's next state from its last one
(``service.flows.next_state``: the belief updated by the observed action, each mode's bounds, the
class's range check) -> store it atomically with the timestamp check -> start the exact FRT of the
new version in the background, build its conservative set, and answer at once. A frame's
observations (``service.flows.frames``) take the same flow together, each stage once over all of
them (:func:`observe_many`); an observation alone is a frame of one.

The observed position is audited against the agent's earlier sets (``service.runtime.audit``) after
the answer is sent; for an agent with ``coverage_target``, before its new state is built, since the
misses move the gamma the new version's bounds are fitted with (``service.flows.adaptive_gamma``).

An observation naming a map (``map_id``), or of an agent that named one, tests the agent's map
assumptions at its pose and keeps the map, the assumptions in force and those it dropped in the
stored state (``service.flows.road.observed_on_map``); breaches are counted once stored.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from pydantic import TypeAdapter

from reach.sets import FRTSet
from service.flows.adaptive_gamma import next_state as next_state_of_gamma
from service.flows.adaptive_gamma import served_gamma
from service.flows.agent_config import AgentConfig
from service.flows.confidence import Belief
from service.flows.next_state import (
    ObservedPrediction,
    StateInputs,
    modes_fields,
    modes_out,
    next_state,
    next_states,
    observed_predictions,
    resolve_class,
)
from service.flows.road import agent_assumptions, observed_on_map, relaxed_out, version_road
from service.runtime.audit import Scored, ServedVersion, count_audited_many, score_many
from service.runtime.conservative import (
    ConservativeBuild,
    cached_conservative,
    start_conservative,
)
from service.runtime.jobs import FRTJob
from service.runtime.scheduler import FRTKey
from service.runtime.services import Services
from service.runtime.stores import AgentState, Update, UpdateFn
from service.wire.errors import AgentNotFoundError, APIError, StaleTimestampError
from service.wire.schemas import (
    AgentResponse,
    AuditOut,
    BeliefOut,
    ControlBoundsOut,
    DeleteResponse,
    EffectiveConfig,
    ObservationRequest,
    ObservationResponse,
)

log = logging.getLogger("frt.services")


def belief_out(belief: Belief) -> tuple[BeliefOut, BeliefOut]:
    """(probabilities, beta values) keyed as API.md does: beta_low and beta_high."""
    return (
        BeliefOut(**BeliefOut.fields_of(belief.probs)),
        BeliefOut(**BeliefOut.fields_of(belief.betas)),
    )


@dataclass(frozen=True)
class Applied:
    """An observation stored: the agent's new state, the job of its version and the belief over
    beta built for it last."""

    state: AgentState
    job: FRTJob
    belief: Belief


async def observe(
    services: Services, agent_id: str, request: ObservationRequest, wait_frt_s: float = 0.0
) -> ObservationResponse:
    """The observation flow: the agent alone through :func:`observe_many`. With ``wait_frt_s`` >
    0 the answer waits that long at most for the new version's exact FRT (``frt_ready`` says
    whether it came): a planner that needs the fresh set saves the round trip of a waiting
    ``GET``."""
    (result,) = await observe_many(services, [(agent_id, request)])
    if isinstance(result, APIError):
        raise result
    if wait_frt_s > 0:
        await services.exact_within(result.job, wait_frt_s)
    return observation_response(services, request, result)


@dataclass
class _Entry:
    """One observation on its way through :func:`observe_many`."""

    index: int
    agent_id: str
    request: ObservationRequest
    prediction: ObservedPrediction
    patch: dict[str, Any]
    previous: AgentState | None = None
    scored: list[Scored] | None = None
    inputs: StateInputs | None = None
    built: list[Belief] = field(default_factory=list)
    #: The map assumptions the observed pose broke (``service.flows.road``).
    broken: tuple[str, ...] = ()


#: Agents whose next states are built in one turn of the event loop: a frame of a hundred takes
#: several, with the checks that arrive meanwhile answered between them.
STATES_PER_TURN = 32


async def observe_many(
    services: Services, observations: Sequence[tuple[str, ObservationRequest]]
) -> list[Applied | APIError]:
    """The observation flow of each ``(agent_id, request)`` (distinct agents), stage by stage
    over all of them: one wait for the checks in flight, the predictions validated, the agents'
    states read in one ``get_many``, their next states built together (``next_states``: Bayes
    update, bounds fit), stored in one ``update_many`` (per agent the atomic update with the
    timestamp check: a state someone wrote in between is rebuilt from, under the agent's lock),
    their exact sets submitted and their conservative sets built together; between stages, the
    checks waiting on the event loop go first. Per observation the stored result, or the error
    that refused it (nothing of that agent changed)."""
    # Collision checks (deadlines) before this numerical work: requests already waiting on the
    # event loop go first, and checks in flight finish first; the frame's turns together hold
    # it back for the priority's max_hold_s at most.
    priority = services.priority
    held = await priority.observation_turn()
    settings = services.settings
    engine = services.require_engine()
    results: list[Applied | APIError | None] = [None] * len(observations)
    entries = _validated(services, observations, results)
    # Read, never modified: the next states are built anew (the store's update takes a copy).
    previous = await services.store.get_many([e.agent_id for e in entries], shared=True)
    entries = _demanded_first(
        services,
        [
            e
            for e, prior in zip(entries, previous, strict=True)
            if _prepared(services, e, prior, results)
        ],
    )
    built: list[tuple[AgentState, Belief] | APIError] = []
    for start in range(0, len(entries), STATES_PER_TURN):
        # Between stages, the checks that arrived go first.
        held += await priority.observation_turn(priority.max_hold_s - held)
        part = entries[start : start + STATES_PER_TURN]
        inputs = [e.inputs for e in part]  # each set by _prepared
        states = next_states([e.previous for e in part], inputs, settings, engine)  # type: ignore[arg-type]
        _start_demanded(services, part, states)
        built += states
    stored_entries, updates = _updates(services, entries, built, results)
    # The new versions' conservative sets are under way while they are stored (a state
    # rebuilt by the store's update gets its own below).
    jobs = {id(r[0]): services.job_for(r[0]) for r in built if not isinstance(r, APIError)}
    building = start_conservative(services, list(jobs.values()))  # type: ignore[index]
    held += await priority.observation_turn(priority.max_hold_s - held)
    await building.propagated()  # checks answered meanwhile, from the states before the frame
    stored = await services.store.update_many(updates)
    audited = _submitted(services, stored_entries, stored, results, (building, jobs))
    if len(entries) > STATES_PER_TURN:
        # The stored versions' sets are queued and their conservative sets cached: the checks
        # that arrived go before a frame's answers are built.
        await priority.observation_turn(priority.max_hold_s - held)
    if audited:  # scored once the answers are on their way
        asyncio.get_running_loop().call_soon(_audit_later, services, audited)
    return results  # type: ignore[return-value]


def _updates(
    services: Services,
    entries: list[_Entry],
    built: list[tuple[AgentState, Belief] | APIError],
    results: list[Applied | APIError | None],
) -> tuple[list[_Entry], list[Update]]:
    """The entries whose next states were built and the store's update of each (the refused
    ones' errors into ``results``)."""
    stored_entries, updates = [], []
    for entry, result in zip(entries, built, strict=True):
        if isinstance(result, APIError):
            results[entry.index] = result
            continue
        entry.built.append(result[1])
        updates.append(
            (entry.agent_id, _apply(services, entry, result[0]), entry.request.timestamp)
        )
        stored_entries.append(entry)
    return stored_entries, updates


def _demanded_first(services: Services, entries: list[_Entry]) -> list[_Entry]:
    """``entries`` with the demanded agents' first, those a trajectory met before the others
    (``ExactDemand.rank``), else in order."""
    demand = services.scheduler.demand
    if demand is None:
        return entries
    now = time.perf_counter()
    return sorted(entries, key=lambda e: -demand.rank(e.agent_id, now))


def _start_demanded(
    services: Services, part: list[_Entry], built: list[tuple[AgentState, Belief] | APIError]
) -> None:
    """Submit the exact sets of the demanded agents' states just built, before the rest of the
    frame is built and stored: a planner's check reads the new versions once they are stored,
    and their sets are then under way or done. (A state the store rebuilds from a write in
    between gets its own set when stored; this one is then superseded.)"""
    demand = services.scheduler.demand
    if demand is None:
        return
    jobs = [
        services.job_for(result[0])
        for entry, result in zip(part, built, strict=True)
        if not isinstance(result, APIError) and demand.wants(entry.agent_id)
    ]
    if jobs:
        services.submit_many(jobs)


def _validated(
    services: Services,
    observations: Sequence[tuple[str, ObservationRequest]],
    results: list[Applied | APIError | None],
) -> list[_Entry]:
    """The observations whose predictions are valid (the others' 422s into ``results``)."""
    requests = [request for _, request in observations]
    predictions = observed_predictions([r.prediction for r in requests], services.settings)
    entries = []
    for i, ((agent_id, request), prediction) in enumerate(
        zip(observations, predictions, strict=True)
    ):
        if isinstance(prediction, APIError):
            results[i] = prediction
            continue
        patch = request.config.model_dump(exclude_none=True) if request.config else {}
        entries.append(_Entry(i, agent_id, request, prediction, patch))
    return entries


def _prepared(
    services: Services,
    entry: _Entry,
    previous: AgentState | None,
    results: list[Applied | APIError | None],
) -> bool:
    """Whether ``entry`` goes on to its next state, its inputs made from ``previous`` (the state
    read); else its error (a stale timestamp, a class change) is in ``results``."""
    request = entry.request
    entry.previous = previous
    if previous is not None and request.timestamp <= previous.timestamp:
        results[entry.index] = StaleTimestampError(
            entry.agent_id, request.timestamp, previous.timestamp
        )
        return False
    if previous is None:
        services.audit.forget(entry.agent_id)  # versions of an earlier life of this id
    try:
        entry.inputs = _state_inputs(services, entry, previous, score=True)
    except APIError as exc:
        results[entry.index] = exc
        return False
    return True


def _apply(services: Services, entry: _Entry, candidate: AgentState) -> UpdateFn:
    """The store's update of ``entry``'s agent: ``candidate`` if the stored state is still the
    one it was built from, else the next state built from the stored one."""
    settings, engine = services.settings, services.require_engine()

    def apply(current: AgentState | None) -> AgentState:
        if _same(current, entry.previous):
            return candidate
        inputs = _state_inputs(services, entry, current)
        state, belief = next_state(current, inputs, settings, engine)
        entry.built.append(belief)
        return state

    return apply


def _submitted(
    services: Services,
    entries: list[_Entry],
    stored: list[AgentState | APIError],
    results: list[Applied | APIError | None],
    first: tuple[ConservativeBuild, dict[int, FRTJob]],
) -> list[tuple[str, float, float, float]]:
    """The stored versions' exact sets submitted, their conservative sets built and recorded for
    the audit; the positions to audit (:func:`_audit_later`). ``first``: what finishes the
    conservative sets of the states first built (checks finding the exact set late look them
    up; the audit keeps them), and those states' jobs by ``id`` (a stored state is mostly the one
    first built)."""
    building, jobs = first
    applied = []
    for entry, state in zip(entries, stored, strict=True):
        if isinstance(state, APIError):
            results[entry.index] = state
            continue
        job = jobs.get(id(state))
        applied.append((entry, state, job if job is not None else services.job_for(state)))
    services.submit_many([job for _, _, job in applied])
    building.finish()
    conservative = cached_conservative(services, [job for _, _, job in applied])
    later = []
    for (entry, state, job), frt in zip(applied, conservative, strict=True):
        for name in entry.broken:
            klass = str(state.config.get("agent_class", "car"))
            services.metrics.assumption_violations.labels(name, klass).inc()
        if services.settings.audit:
            later += _record_for_audit(services, entry, state, job.key, frt)
        results[entry.index] = Applied(state, job, entry.built[-1])
    return later


def observation_response(
    services: Services, request: ObservationRequest, applied: Applied
) -> ObservationResponse:
    """The answer to an observation stored as ``applied``."""
    (response,) = observation_responses(services, [request], [applied])
    return response


def observation_responses(
    services: Services, requests: Sequence[ObservationRequest], applied: Sequence[Applied]
) -> list[ObservationResponse]:
    """The answers to observations stored as ``applied`` (a frame's), their fields validated
    together in one call of pydantic's compiled core (cheaper than building each model in
    Python)."""
    fields = [
        _response_fields(services, request, stored)
        for request, stored in zip(requests, applied, strict=True)
    ]
    return _OBSERVATION_RESPONSES.validate_python(fields)


#: A frame's answers, validated together.
_OBSERVATION_RESPONSES = TypeAdapter(list[ObservationResponse])


def _response_fields(
    services: Services, request: ObservationRequest, applied: Applied
) -> dict[str, Any]:
    """The fields of the answer to an observation stored as ``applied``."""
    state, last_built = applied.state, applied.belief
    # The belief just built, unless the stored one is another (from_dict would give the same arrays:
    # a stored belief is normalised already, and normalising it again changes no bit).
    same = last_built.to_dict() == state.belief
    belief = last_built if same else Belief.from_dict(state.belief)
    return {
        "agent_id": state.agent_id,
        "timestamp": state.timestamp,
        "beta": belief.beta,
        "belief": BeliefOut.fields_of(belief.probs),
        "control_bounds": ControlBoundsOut.fields_of(state.control_bounds),
        "frt_version": state.frt_version,
        # A previous state existed exactly when the version went past 1.
        "action_scored": request.observed_action is not None and state.frt_version > 1,
        "frt_ready": services.scheduler.is_ready(applied.job.key),
        "modes": modes_fields(state.modes),
        "mode_mass": float(state.modes["mode_mass"]) if state.modes else None,
    }


def _state_inputs(
    services: Services, entry: _Entry, prior: AgentState | None, score: bool = False
) -> StateInputs:
    """The observation's inputs to the agent's next state from ``prior``: its class, overrides
    and config, with adaptive gamma's step taken where the observed position was scored against
    the agent's earlier sets before building (with ``score``, it is scored now for an agent with
    a ``coverage_target``: the misses move the gamma its bounds are fitted with)."""
    request = entry.request
    overrides = {**(prior.config if prior else {}), **entry.patch}
    klass, overrides = resolve_class(entry.agent_id, request.agent_class, prior, overrides)
    config = AgentConfig.of(services.settings, overrides)
    overrides, entry.broken = observed_on_map(
        services,
        overrides,
        request.map_id,
        config.assumptions,
        (request.timestamp, request.state),
    )
    if score and services.settings.audit and config.coverage_target is not None:
        position = request.state
        entry.scored = services.score_position(
            entry.agent_id, position.x, position.y, request.timestamp
        )
    gamma_state = None
    if entry.scored is not None:
        gamma_state = adapt_gamma(prior, entry.scored, config)
        config = config.with_gamma(served_gamma(gamma_state))
    return StateInputs(
        entry.agent_id, request, entry.prediction, overrides, config, klass, gamma_state
    )


def _record_for_audit(
    services: Services, entry: _Entry, state: AgentState, key: FRTKey, conservative: FRTSet
) -> list[tuple[str, float, float, float]]:
    """Keep the new version for auditing later positions, and audit this one: at once where it
    was scored already (adaptive gamma); else the position to score after the answer."""
    inputs = entry.inputs
    if inputs is not None and state.config is inputs.overrides:  # the state built first
        radius = inputs.config.collision_radius
    else:
        radius = AgentConfig.value_of(services.settings, state.config, "collision_radius")
    services.audit.record(
        state.agent_id,
        ServedVersion(
            version=state.frt_version,
            key=key,
            t0=state.timestamp,
            horizon_end=state.timestamp + services.horizon_s(),
            collision_radius=float(radius),
            agent_class=str(state.config.get("agent_class", "car")),
            conservative=conservative,
            road=version_road(services, state, key),
        ),
    )
    request = entry.request
    if entry.scored is not None:
        services.take_audit(state.agent_id, entry.scored, request.timestamp)
        return []
    position = request.state
    return [(state.agent_id, position.x, position.y, request.timestamp)]


#: Positions :func:`_audit_later` scores in one turn of the event loop: a frame's audit runs in
#: several turns, with the requests that arrive meanwhile served between them.
AUDIT_POSITIONS_PER_TURN = 25


def _audit_later(services: Services, positions: list[tuple[str, float, float, float]]) -> None:
    """Score each (agent, x, y, t) against the agent's versions due at t
    (``AuditLedger.due``), ``AUDIT_POSITIONS_PER_TURN`` together (``score_many``) per turn of
    the event loop, and count them."""
    now, rest = positions[:AUDIT_POSITIONS_PER_TURN], positions[AUDIT_POSITIONS_PER_TURN:]
    if rest:
        asyncio.get_running_loop().call_soon(_audit_later, services, rest)
    try:
        versions = [services.audit.due(agent_id, t) for agent_id, _, _, t in now]
        scored = score_many(
            [(x, y, t, v) for (_, x, y, t), v in zip(now, versions, strict=True)],
            services.scheduler.lookup,
        )
    except Exception as exc:  # a measurement: it must never take the service down
        log.error("coverage audit failed", extra={"error": repr(exc)})
        return
    audited = [(a, s, t) for (a, _, _, t), s in zip(now, scored, strict=True)]
    count_audited_many(services.metrics, services.audit, services.coverage, audited)


def adapt_gamma(prior: AgentState | None, scored: list[Scored], config: AgentConfig) -> float:
    """Adaptive gamma's next state after ``scored`` (``service.flows.adaptive_gamma``), starting
    at the configured gamma; the new version is built with ``served_gamma`` of it."""
    g = prior.gamma_state if prior is not None else None
    missed = sum(not s.in_c for s in scored)
    return next_state_of_gamma(
        config.gamma if g is None else g,
        len(scored),
        missed,
        config.coverage_target,  # type: ignore[arg-type]
        config.coverage_step,
    )


def audit_out(counts: dict[str, Any] | None, gamma_state: float | None) -> AuditOut:
    """The ``audit`` of the agent's view (zeros before any audit)."""
    counts = counts or {}
    n = int(counts.get("audited", 0))
    return AuditOut(
        audited=n,
        missed_k=int(counts.get("missed_k", 0)),
        missed_c=int(counts.get("missed_c", 0)),
        exact=int(counts.get("exact", 0)),
        coverage_k=1.0 - counts["missed_k"] / n if n else None,
        coverage_c=1.0 - counts["missed_c"] / n if n else None,
        last_miss=counts.get("last_miss"),
        assumption_misses=dict(counts.get("assumption_misses") or {}),
        gamma_state=gamma_state,
    )


def gamma_effective(config: AgentConfig, gamma_state: float | None) -> float:
    """The gamma the agent's current version is built with."""
    if config.coverage_target is None or gamma_state is None:
        return float(config.gamma)
    return served_gamma(gamma_state)


def _same(a: AgentState | None, b: AgentState | None) -> bool:
    if a is None or b is None:
        return a is b
    return a == b  # field by field, lists and dicts by value


async def get_agent(services: Services, agent_id: str, wait_frt_s: float = 0.0) -> AgentResponse:
    """The agent's view; with ``wait_frt_s`` > 0, once the exact FRT of its current version is
    ready or that many seconds have passed (the state is the one read first)."""
    state = await services.store.get(agent_id)
    if state is None:
        raise AgentNotFoundError(agent_id)
    if wait_frt_s > 0 and services.engine is not None:
        await services.exact_within(services.job_for(state), wait_frt_s)
    belief = Belief.from_dict(state.belief)
    probs, betas = belief_out(belief)
    config = AgentConfig.of(services.settings, state.config)
    key = services.job_for(state).key
    exact = services.scheduler.lookup(key) if services.engine else None
    ready = exact is not None
    _, assumptions = agent_assumptions(services, state)
    return AgentResponse(
        agent_id=agent_id,
        timestamp=state.timestamp,
        state={"x": state.x, "y": state.y, "heading": state.heading, "speed": state.speed},
        beta=belief.beta,
        belief=probs,
        hypotheses=betas,
        control_bounds=ControlBoundsOut.from_list(state.control_bounds),
        frt_version=state.frt_version,
        frt_ready=ready,
        frt_refinement=services.refinement_state(exact, key),
        frt_refinement_stage=services.refinement_stage(exact),
        config=EffectiveConfig(beta_high=float(belief.betas[-1]), **config.as_dict()),
        agent_class=state.config.get("agent_class", "car"),
        modes=modes_out(state.modes),
        mode_mass=state.modes["mode_mass"] if state.modes else None,
        gamma_effective=gamma_effective(config, state.gamma_state),
        audit=(
            audit_out(services.audit.counts(agent_id), state.gamma_state)
            if services.settings.audit
            else None
        ),
        map_id=state.config.get("map_id"),
        assumptions=assumptions,
        relaxed_assumptions=relaxed_out(state),
    )


async def delete_agent(services: Services, agent_id: str) -> DeleteResponse:
    if not await services.store.delete(agent_id):
        raise AgentNotFoundError(agent_id)
    services.forget(agent_id)
    return DeleteResponse(agent_id=agent_id, deleted=True)
