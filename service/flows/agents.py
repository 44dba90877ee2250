"""Agents: the observation flow (API.md, "Observation"), the agent view, forgetting an agent.

One observation: validate -> score the observed action against the first step of the previous
prediction (epsilon-static transition, then Bayes) -> beta -> control bounds of the new prediction ->
check them against the model's trained ranges -> store the new state atomically with the timestamp
check -> start the exact FRT of the new version in the background and answer at once.

The observed position is audited against the agent's earlier sets (``service.flows.audit``) after
the answer is sent; for an agent with ``coverage_target``, before its new state is built, since the
misses move the gamma the new version's bounds are fitted with (``service.flows.adaptive_gamma``).
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from reach.agent_classes import AgentClass
from reach.engine import FRTEngine, OutOfRangeError
from reach.sets import FRTSet
from service.api.errors import AgentNotFoundError, FieldError, StaleTimestampError
from service.api.limits import check_prediction_steps
from service.api.schemas import (
    MAX_MODES,
    AgentResponse,
    AuditOut,
    BeliefOut,
    ControlBoundsOut,
    DeleteResponse,
    EffectiveConfig,
    ObservationRequest,
    ObservationResponse,
    Prediction,
)
from service.flows.adaptive_gamma import next_state, served_gamma
from service.flows.audit import Scored, ServedVersion
from service.flows.bounds import PredictionError, control_bounds, validate_prediction
from service.flows.confidence import Belief, hypotheses, prior_belief, update_belief
from service.flows.mode_states import (
    build_mode_state,
    check_class_ranges,
    class_limits,
    modes_out,
    observed_state,
    resolve_class,
)
from service.flows.modes import Mixture, validate_mixture
from service.runtime.scheduler import FRTKey
from service.runtime.services import Services
from service.runtime.settings import Settings
from service.runtime.store import AgentState

CONFIG_KEYS = (
    "beta_low",
    "gamma",
    "epsilon",
    "collision_radius",
    "bounds_fit",
    "bounds_rule",
    "rescue_onset",
    "coverage_target",
    "coverage_step",
)


def effective_config(settings: Settings, overrides: dict[str, Any]) -> dict[str, Any]:
    """Server settings overlaid with an agent's overrides."""
    config = {key: getattr(settings, key) for key in CONFIG_KEYS}
    config.update({k: v for k, v in overrides.items() if k in CONFIG_KEYS and v is not None})
    return config


def prediction_error(exc: PredictionError) -> FieldError:
    """``prediction.cov[3]`` -> a 422 on ``prediction.cov.3``."""
    field = exc.field.replace("[", ".").replace("]", "")
    return FieldError(field, exc.message)


def validated_prediction(
    prediction: Prediction, settings: Settings, field: str = "prediction"
) -> tuple[np.ndarray, np.ndarray]:
    check_prediction_steps(field, prediction.mean, settings)
    try:
        return validate_prediction(
            prediction.mean, prediction.cov, prediction.dt, settings.max_prediction_steps
        )
    except PredictionError as exc:
        raise prediction_error(exc) from None


def fit_bounds(
    mean: np.ndarray,
    cov: np.ndarray,
    dt: float,
    beta: float,
    gamma: float,
    bounds_fit: str,
    settings: Settings,
    limits: tuple[float, float] | None = None,
    rule: str = "paper",
    onset: float = 0.0,
) -> np.ndarray:
    """The eight control bounds (contract order) of a prediction tempered by beta under the
    confidence-to-bounds ``rule``, within ``limits`` (default: the server's hard limits)."""
    try:
        bounds = control_bounds(
            mean,
            cov,
            dt,
            beta,
            gamma,
            horizon=settings.horizon_s,
            method=bounds_fit,  # type: ignore[arg-type]
            limits=limits or (settings.u1_limit, settings.u2_limit),
            rule=rule,  # type: ignore[arg-type]
            onset=onset,
        )
    except PredictionError as exc:
        raise prediction_error(exc) from None
    except ValueError as exc:
        raise FieldError("prediction", str(exc)) from None
    return bounds.as_array()


def _belief(previous: AgentState | None, beta_low: float) -> Belief:
    """The agent's belief over the hypotheses for ``beta_low`` (a new beta_low keeps the weights)."""
    betas = hypotheses(beta_low)
    if previous is None:
        return prior_belief(betas)
    belief = Belief.from_dict(previous.belief)
    if not np.array_equal(belief.betas, betas):
        belief = Belief(betas=betas, log_probs=belief.log_probs)
    return belief


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
    services.require_engine()
    request, mixture = _prediction_form(request, settings)
    patch = request.config.model_dump(exclude_none=True) if request.config else {}
    previous = await services.store.get(agent_id)
    if previous is not None and request.timestamp <= previous.timestamp:
        raise StaleTimestampError(agent_id, request.timestamp, previous.timestamp)
    if previous is None:
        services.audit.forget(agent_id)  # versions of an earlier life of this id
    # Scored now only where the new bounds depend on it (adaptive gamma); else after the answer.
    adaptive = settings.audit and _coverage_target(settings, previous, patch) is not None
    position = request.state
    scored = (
        services.score_position(agent_id, position.x, position.y, request.timestamp)
        if adaptive
        else None
    )
    builder = _StateBuilder(services, agent_id, request, mixture, patch, scored)
    if mixture is not None:
        mean, cov = mixture.means[0], mixture.covs[0]
    else:
        mean, cov = validated_prediction(request.prediction, settings)
    candidate = builder.build(previous, mean, cov)

    def apply(current: AgentState | None) -> AgentState:
        return candidate if _same(current, previous) else builder.build(current, mean, cov)

    state = await services.store.update(agent_id, apply, timestamp=request.timestamp)
    job = services.job_for(state)
    services.submit(job)
    # Built now, so that checks finding the exact set late look it up; the audit keeps it.
    conservative = services.conservative(job)
    if settings.audit:
        _record_for_audit(services, state, job.key, conservative, request, scored)
    if wait_frt_s > 0:
        await services.exact_within(job, wait_frt_s)
    # The belief just built, unless the stored one is another (from_dict would give the same arrays:
    # a stored belief is normalised already, and normalising it again changes no bit).
    last = builder.built[-1]
    belief = last if last.to_dict() == state.belief else Belief.from_dict(state.belief)
    probs, _ = belief_out(belief)
    return ObservationResponse(
        agent_id=agent_id,
        timestamp=state.timestamp,
        beta=belief.beta,
        belief=probs,
        control_bounds=ControlBoundsOut.from_list(state.control_bounds),
        frt_version=state.frt_version,
        # A previous state existed exactly when the version went past 1.
        action_scored=request.observed_action is not None and state.frt_version > 1,
        frt_ready=services.scheduler.is_ready(job.key),
        modes=modes_out(state.modes),
        mode_mass=state.modes["mode_mass"] if state.modes else None,
    )


@dataclass
class _StateBuilder:
    """Builds the agent's next state from the one before it (``prior``) and this observation:
    the belief updated by the observed action, the bounds of the new prediction, their ranges
    checked. ``built`` holds the belief of each state built, the last one last."""

    services: Services
    agent_id: str
    request: ObservationRequest
    mixture: Mixture | None
    patch: dict[str, Any]
    scored: list[Scored] | None
    built: list[Belief] = field(default_factory=list)

    def build(self, prior: AgentState | None, mean: np.ndarray, cov: np.ndarray) -> AgentState:
        settings, request = self.services.settings, self.request
        overrides = {**(prior.config if prior else {}), **self.patch}
        klass = resolve_class(self.agent_id, request.agent_class, prior, overrides)
        config = effective_config(settings, overrides)
        gamma_state = adapt_gamma(prior, self.scored, config) if self.scored is not None else None
        if self.mixture is not None or (prior is not None and prior.modes is not None):
            one_mode = Mixture(request.prediction.dt, np.ones(1), mean[None], cov[None])
            state, marginal = build_mode_state(
                self.agent_id,
                request,
                prior,
                self.mixture or one_mode,
                overrides,
                config,
                klass,
                settings,
                self.services.require_engine(),
            )
            state.gamma_state = gamma_state
            self.built.append(marginal)
            return state
        belief = self._updated_belief(prior, config)
        bounds = self._bounds(mean, cov, belief, config, klass)
        self.built.append(belief)
        return observed_state(
            self.agent_id,
            request,
            prior,
            belief=belief.to_dict(),
            prediction={"dt": request.prediction.dt, "mean": mean.tolist(), "cov": cov.tolist()},
            control_bounds=[float(b) for b in bounds],
            config=overrides,
            gamma_state=gamma_state,
        )

    def _updated_belief(self, prior: AgentState | None, config: dict[str, Any]) -> Belief:
        """The prior's belief after the observed action, scored against the first step of the
        prior's prediction (paper, the beta filter)."""
        belief = _belief(prior, config["beta_low"])
        action = self.request.observed_action
        if action is None or prior is None:
            return belief
        prev_mean = np.asarray(prior.prediction["mean"][0], dtype=np.float64)
        prev_cov = np.asarray(prior.prediction["cov"][0], dtype=np.float64)
        observed = np.array([action.steering_rate, action.acceleration], dtype=np.float64)
        return update_belief(belief, observed, prev_mean, prev_cov, config["epsilon"])

    def _bounds(
        self,
        mean: np.ndarray,
        cov: np.ndarray,
        belief: Belief,
        config: dict[str, Any],
        klass: AgentClass,
    ) -> np.ndarray:
        """The new prediction's control bounds within the class's limits, their ranges checked."""
        settings, engine = self.services.settings, self.services.require_engine()
        bounds = fit_bounds(
            mean,
            cov,
            self.request.prediction.dt,
            belief.beta,
            config["gamma"],
            config["bounds_fit"],
            settings,
            limits=class_limits(klass, settings),
            rule=config["bounds_rule"],
            onset=config["rescue_onset"],
        )
        if klass.name == "car":
            check_ranges(engine, self.request.state.speed, bounds, bounds_field="prediction")
        else:
            check_class_ranges(engine, klass, self.request.state.speed, bounds)
        return bounds


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
    config = effective_config(services.settings, state.config)
    services.audit.record(
        state.agent_id,
        ServedVersion(
            version=state.frt_version,
            key=key,
            t0=state.timestamp,
            horizon_end=state.timestamp + services.horizon_s(),
            collision_radius=float(config["collision_radius"]),
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


def _coverage_target(
    settings: Settings, previous: AgentState | None, patch: dict[str, Any]
) -> float | None:
    """The agent's coverage target with this observation's config applied (None: gamma fixed)."""
    overrides = {**(previous.config if previous else {}), **patch}
    return effective_config(settings, overrides)["coverage_target"]  # type: ignore[no-any-return]


def adapt_gamma(prior: AgentState | None, scored: list[Scored], config: dict[str, Any]) -> float:
    """Adaptive gamma's next state after ``scored`` (``service.flows.adaptive_gamma``, starting at
    the configured gamma); ``config["gamma"]`` becomes, in place, the gamma the new version is
    built with."""
    g = prior.gamma_state if prior is not None else None
    missed = sum(not s.in_c for s in scored)
    g = next_state(
        config["gamma"] if g is None else g,
        len(scored),
        missed,
        config["coverage_target"],
        config["coverage_step"],
    )
    config["gamma"] = served_gamma(g)
    return g


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


def gamma_effective(config: dict[str, Any], gamma_state: float | None) -> float:
    """The gamma the agent's current version is built with."""
    if config.get("coverage_target") is None or gamma_state is None:
        return float(config["gamma"])
    return served_gamma(gamma_state)


def _prediction_form(
    request: ObservationRequest, settings: Settings
) -> tuple[ObservationRequest, Mixture | None]:
    """The request with a one-mode mixture in the single-Gaussian form (answered exactly as that
    form is), and the validated mixture if there are several modes (422 naming the field)."""
    modes = request.prediction.modes
    if modes is None:
        check_prediction_steps("prediction", request.prediction.mean, settings)
        return request, None
    for m, mode in enumerate(modes[:MAX_MODES]):
        check_prediction_steps(f"prediction.modes.{m}", mode.mean, settings)
    if len(modes) == 1:
        plain = request.prediction.model_copy(
            update={"mean": modes[0].mean, "cov": modes[0].cov, "modes": None}
        )
        return request.model_copy(update={"prediction": plain}), None
    try:
        mixture = validate_mixture(
            modes, request.prediction.dt, settings.max_prediction_steps, MAX_MODES
        )
    except PredictionError as exc:
        raise prediction_error(exc) from None
    return request, mixture


def _same(a: AgentState | None, b: AgentState | None) -> bool:
    if a is None or b is None:
        return a is b
    return a == b  # field by field, lists and dicts by value: what comparing to_dict() did


def check_ranges(engine: FRTEngine, v_start: float, bounds: np.ndarray, bounds_field: str) -> None:
    """422 unless v_start and the bounds lie in the model's trained ranges.

    ``v_start`` is the state's speed; the bounds are named under ``bounds_field``.
    """
    try:
        engine.validate(v_start, bounds)
    except OutOfRangeError as exc:
        field = "state.speed" if exc.field == "v_start" else f"{bounds_field}.{exc.field}"
        if bounds_field == "prediction" and exc.field != "v_start":
            field = "prediction"  # the bounds are derived from it; the message names the bound
        raise FieldError(field, str(exc)) from None


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
    config = effective_config(services.settings, state.config)
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
        config=EffectiveConfig(beta_high=float(belief.betas[-1]), **config),
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
