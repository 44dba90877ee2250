"""Agents: the observation flow (API.md, "Observation"), the agent view, forgetting an agent.

One observation: validate its prediction once -> the agent's next state from its last one
(``service.flows.next_state``: the belief updated by the observed action, each mode's bounds, the
class's range check) -> store it atomically with the timestamp check -> start the exact FRT of the
new version in the background and answer at once.

The observed position is audited against the agent's earlier sets (``service.runtime.audit``) after
the answer is sent; for an agent with ``coverage_target``, before its new state is built, since the
misses move the gamma the new version's bounds are fitted with (``service.flows.adaptive_gamma``).
"""

from __future__ import annotations

import asyncio
from typing import Any

from reach.sets import FRTSet
from service.flows.adaptive_gamma import next_state as next_state_of_gamma
from service.flows.adaptive_gamma import served_gamma
from service.flows.agent_config import AgentConfig
from service.flows.confidence import Belief
from service.flows.next_state import (
    ObservedPrediction,
    StateInputs,
    modes_out,
    next_state,
    observed_prediction,
    resolve_class,
)
from service.runtime.audit import Scored, ServedVersion
from service.runtime.scheduler import FRTKey
from service.runtime.services import Services
from service.runtime.settings import Settings
from service.runtime.stores import AgentState
from service.wire.errors import AgentNotFoundError, StaleTimestampError
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


def belief_out(belief: Belief) -> tuple[BeliefOut, BeliefOut]:
    """(probabilities, beta values) keyed as API.md does: beta_low and beta_high."""
    probs, betas = belief.probs, belief.betas
    return (
        BeliefOut(beta_low=float(probs[0]), beta_high=float(probs[-1])),
        BeliefOut(beta_low=float(betas[0]), beta_high=float(betas[-1])),
    )


async def observe(
    services: Services, agent_id: str, request: ObservationRequest, wait_frt_s: float = 0.0
) -> ObservationResponse:
    """The observation flow. The numerical work (validation, Bayes update, bounds fit: well under a
    millisecond, run inline, a thread hop would cost more) uses the state read first; the store's
    atomic update then only checks that nobody wrote in between (else it recomputes from the fresh
    state, under the agent's lock). With ``wait_frt_s`` > 0 the answer waits that long at most for
    the new version's exact FRT (``frt_ready`` says whether it came): a planner that needs the
    fresh set saves the round trip of a waiting ``GET``."""
    # Collision checks (deadlines) before this observation's few milliseconds of numerical work:
    # requests already waiting on the event loop go first, and checks in flight finish first.
    await services.priority.observation_turn()
    settings = services.settings
    engine = services.require_engine()
    prediction = observed_prediction(request.prediction, settings)
    patch = request.config.model_dump(exclude_none=True) if request.config else {}
    previous = await services.store.get(agent_id)
    if previous is not None and request.timestamp <= previous.timestamp:
        raise StaleTimestampError(agent_id, request.timestamp, previous.timestamp)
    if previous is None:
        services.audit.forget(agent_id)  # versions of an earlier life of this id
    scored = _scored_before_building(services, agent_id, request, previous, patch)
    built: list[Belief] = []

    def build(prior: AgentState | None) -> AgentState:
        inputs = _state_inputs(settings, agent_id, request, prediction, patch, prior, scored)
        state, belief = next_state(prior, inputs, settings, engine)
        built.append(belief)
        return state

    candidate = build(previous)

    def apply(current: AgentState | None) -> AgentState:
        return candidate if _same(current, previous) else build(current)

    state = await services.store.update(agent_id, apply, timestamp=request.timestamp)
    job = services.job_for(state)
    services.submit(job)
    # Built now, so that checks finding the exact set late look it up; the audit keeps it.
    conservative = services.conservative(job)
    if settings.audit:
        _record_for_audit(services, state, job.key, conservative, request, scored)
    if wait_frt_s > 0:
        await services.exact_within(job, wait_frt_s)
    return _observation_response(services, request, state, job.key, built[-1])


def _observation_response(
    services: Services,
    request: ObservationRequest,
    state: AgentState,
    key: FRTKey,
    last_built: Belief,
) -> ObservationResponse:
    """The answer to an observation stored as ``state``."""
    # The belief just built, unless the stored one is another (from_dict would give the same arrays:
    # a stored belief is normalised already, and normalising it again changes no bit).
    same = last_built.to_dict() == state.belief
    belief = last_built if same else Belief.from_dict(state.belief)
    probs, _ = belief_out(belief)
    return ObservationResponse(
        agent_id=state.agent_id,
        timestamp=state.timestamp,
        beta=belief.beta,
        belief=probs,
        control_bounds=ControlBoundsOut.from_list(state.control_bounds),
        frt_version=state.frt_version,
        # A previous state existed exactly when the version went past 1.
        action_scored=request.observed_action is not None and state.frt_version > 1,
        frt_ready=services.scheduler.is_ready(key),
        modes=modes_out(state.modes),
        mode_mass=state.modes["mode_mass"] if state.modes else None,
    )


def _scored_before_building(
    services: Services,
    agent_id: str,
    request: ObservationRequest,
    previous: AgentState | None,
    patch: dict[str, Any],
) -> list[Scored] | None:
    """The observed position scored against the agent's earlier sets now, where the new bounds
    depend on it (adaptive gamma); None where it is scored after the answer."""
    overrides = {**(previous.config if previous else {}), **patch}
    settings = services.settings
    if not (settings.audit and AgentConfig.of(settings, overrides).coverage_target is not None):
        return None
    position = request.state
    return services.score_position(agent_id, position.x, position.y, request.timestamp)


def _state_inputs(
    settings: Settings,
    agent_id: str,
    request: ObservationRequest,
    prediction: ObservedPrediction,
    patch: dict[str, Any],
    prior: AgentState | None,
    scored: list[Scored] | None,
) -> StateInputs:
    """The observation's inputs to the agent's next state from ``prior``: its class, overrides
    and config, with adaptive gamma's step taken where ``scored``."""
    overrides = {**(prior.config if prior else {}), **patch}
    klass, overrides = resolve_class(agent_id, request.agent_class, prior, overrides)
    config = AgentConfig.of(settings, overrides)
    gamma_state = None
    if scored is not None:
        gamma_state = adapt_gamma(prior, scored, config)
        config = config.with_gamma(served_gamma(gamma_state))
    return StateInputs(agent_id, request, prediction, overrides, config, klass, gamma_state)


def _record_for_audit(
    services: Services,
    state: AgentState,
    key: FRTKey,
    conservative: FRTSet,
    request: ObservationRequest,
    scored: list[Scored] | None,
) -> None:
    """Keep the new version for auditing later positions, and audit this one: after the answer,
    or at once where it was scored already (adaptive gamma)."""
    config = AgentConfig.of(services.settings, state.config)
    services.audit.record(
        state.agent_id,
        ServedVersion(
            version=state.frt_version,
            key=key,
            t0=state.timestamp,
            horizon_end=state.timestamp + services.horizon_s(),
            collision_radius=float(config.collision_radius),
            agent_class=str(state.config.get("agent_class", "car")),
            conservative=conservative,
        ),
    )
    if scored is None:
        position = request.state
        asyncio.get_running_loop().call_soon(
            services.audit_later, state.agent_id, position.x, position.y, request.timestamp
        )
    else:
        services.take_audit(state.agent_id, scored, request.timestamp)


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
    )


async def delete_agent(services: Services, agent_id: str) -> DeleteResponse:
    if not await services.store.delete(agent_id):
        raise AgentNotFoundError(agent_id)
    services.forget(agent_id)
    return DeleteResponse(agent_id=agent_id, deleted=True)
