"""An agent's next state from its last one and one observation: the one path every observation takes.

Every prediction is a mixture; a single Gaussian is a mixture of one mode, and for it each step
below is the paper's single-Gaussian filter exactly (``tests/test_next_state.py`` holds them equal,
bit for bit, against ``service.flows.confidence.update_belief`` and the paper's bounds):

1. the belief over (mode, beta) of the last state is updated by the observed action, scored
   against the first step of every mode of the last prediction (``service.flows.modes``: the
   epsilon-static transition, then Bayes; paper, eq. ``beta``) and carried to the new prediction;
2. the modes the served set holds are the most probable ones (``select_modes``);
3. each of them gets control bounds from its own beta under the agent's confidence-to-bounds rule
   (``service.flows.bounds``, paper, "Collision Set Update"), within its class's limits, and the
   bounds and the speed are checked against the class's ranges (one check, from the class);
4. the state stores the marginal belief over beta, the most probable mode's prediction and
   bounds, and, for several modes, the joint belief and the set's modes (:class:`ModeSet`). The
   job of a state (``AgentState.set_bounds``) has one row of bounds per mode in the set; its set
   is their union (``reach.union``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from reach.agent_classes import DEFAULT_CLASS, AgentClass, agent_class, engine_for_class
from reach.engine import FRTEngine, OutOfRangeError
from service.flows.agent_config import AgentConfig
from service.flows.bounds import PredictionError, control_bounds, validate_prediction
from service.flows.confidence import Belief, hypotheses, prior_belief
from service.flows.modes import (
    MODE_FLOOR,
    MODE_MASS,
    JointBelief,
    Mixture,
    select_modes,
    validate_mixture,
)
from service.runtime.settings import Settings
from service.runtime.stores import AgentState
from service.wire.errors import AgentClassChangedError, FieldError
from service.wire.limits import RequestLimits, check_prediction_steps
from service.wire.schemas import (
    MAX_MODES,
    ControlBoundsOut,
    ModeOut,
    ObservationPrediction,
    ObservationRequest,
    Prediction,
)


@dataclass(frozen=True)
class ObservedPrediction:
    """An observation's validated prediction as a mixture, and how its fields are named: a
    prediction given as one Gaussian (or a list of one mode) is ``prediction``, mode m of several
    ``prediction.modes.m``."""

    mixture: Mixture
    as_modes: bool

    def field(self, m: int) -> str:
        return f"prediction.modes.{m}" if self.as_modes else "prediction"


@dataclass(frozen=True)
class ModeSet:
    """The modes of a multi-modal agent's state (``AgentState.modes``, stored as :meth:`to_dict`)."""

    belief: dict[str, Any]  # JointBelief.to_dict()
    first_mean: list[list[float]]  # [M, 2]: each mode's first step, scored by the next action
    first_cov: list[list[list[float]]]  # [M, 2, 2]
    posterior: list[float]  # P(m)
    beta: list[float]  # E[beta | m]
    set: list[int]  # the modes the served set holds, ascending
    bounds: list[list[float]]  # their bounds, one row of eight each, in ``set`` order
    mode_mass: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModeSet:
        return cls(**data)


def observed_prediction(
    prediction: ObservationPrediction | Prediction, settings: RequestLimits
) -> ObservedPrediction:
    """An observation's prediction validated once (422 naming the field): one Gaussian, or a
    list of modes (a list of one is that Gaussian, named as one)."""
    modes = getattr(prediction, "modes", None)
    if modes is not None and len(modes) == 1:
        prediction = prediction.model_copy(
            update={"mean": modes[0].mean, "cov": modes[0].cov, "modes": None}
        )
        modes = None
    if modes is None:
        check_prediction_steps("prediction", prediction.mean, settings)
        try:
            mean, cov = validate_prediction(
                prediction.mean, prediction.cov, prediction.dt, settings.max_prediction_steps
            )
        except PredictionError as exc:
            raise _field_error(exc) from None
        return ObservedPrediction(Mixture(prediction.dt, np.ones(1), mean[None], cov[None]), False)
    for m, mode in enumerate(modes[:MAX_MODES]):
        check_prediction_steps(f"prediction.modes.{m}", mode.mean, settings)
    try:
        mixture = validate_mixture(modes, prediction.dt, settings.max_prediction_steps, MAX_MODES)
    except PredictionError as exc:
        raise _field_error(exc) from None
    return ObservedPrediction(mixture, True)


def _field_error(exc: PredictionError) -> FieldError:
    """``prediction.cov[3]`` -> a 422 on ``prediction.cov.3``."""
    return FieldError(exc.field.replace("[", ".").replace("]", ""), exc.message)


def resolve_class(
    agent_id: str, requested: str | None, prior: AgentState | None, overrides: dict[str, Any]
) -> tuple[AgentClass, dict[str, Any]]:
    """The agent's class (the prior state's, else the requested one, else the car) and the
    overrides with it written in and, for a class other than the car, its default collision
    radius unless the agent sets one; 409 if the request names another class than the prior's."""
    fixed = (prior.config.get("agent_class") or DEFAULT_CLASS) if prior is not None else None
    name = fixed or requested or DEFAULT_CLASS
    if fixed is not None and requested is not None and requested != fixed:
        raise AgentClassChangedError(agent_id, fixed, requested)
    klass = agent_class(name)
    resolved = {**overrides, "agent_class": name}
    if name != DEFAULT_CLASS and resolved.get("collision_radius") is None:
        resolved["collision_radius"] = klass.collision_radius_m
    return klass, resolved


def class_limits(klass: AgentClass, settings: Settings) -> tuple[float, float]:
    """The hard control limits: the server's for a car, the registry's for the other classes."""
    if klass.name == DEFAULT_CLASS:
        return (settings.u1_limit, settings.u2_limit)
    return klass.limits


def check_ranges(
    engine: FRTEngine,
    klass: AgentClass,
    v_start: float,
    bounds: Any,
    bounds_field: str = "prediction",
) -> None:
    """422 unless ``v_start`` and the bounds lie in the class's ranges (the car: the model's
    trained ones). The speed is named ``state.speed``; bounds derived from a prediction are named
    by it, bounds given as such by their column (``control_bounds.u1_min``)."""
    try:
        engine_for_class(engine, klass).validate(v_start, np.asarray(bounds, dtype=np.float64))
    except OutOfRangeError as exc:
        if exc.field == "v_start":
            field = "state.speed"
        elif bounds_field.startswith("prediction"):
            field = bounds_field
        else:
            field = f"{bounds_field}.{exc.field}"
        suffix = "" if klass.name == DEFAULT_CLASS else f" for a {klass.name}"
        raise FieldError(field, f"{exc}{suffix}") from None


def previous_joint(prior: AgentState, betas: np.ndarray) -> JointBelief:
    """The prior state's belief over (mode, beta) on the hypotheses ``betas`` (a new beta_low
    keeps the weights); a single Gaussian's is its beta belief with one mode."""
    if prior.modes is not None:
        return JointBelief.from_dict(prior.modes["belief"]).regrid(betas)
    belief = Belief.from_dict(prior.belief)
    if not np.array_equal(belief.betas, betas):
        belief = Belief(betas=betas, log_probs=belief.log_probs)
    return JointBelief.from_beta_belief(belief, [1.0])


def previous_first_steps(prior: AgentState) -> tuple[np.ndarray, np.ndarray]:
    """Each mode's first predicted step of the prior state: means [M, 2], covs [M, 2, 2]."""
    if prior.modes is not None:
        return (
            np.asarray(prior.modes["first_mean"], dtype=np.float64),
            np.asarray(prior.modes["first_cov"], dtype=np.float64),
        )
    return (
        np.asarray(prior.prediction["mean"][:1], dtype=np.float64),
        np.asarray(prior.prediction["cov"][:1], dtype=np.float64),
    )


def updated_joint(
    prior: AgentState | None,
    request: ObservationRequest,
    weights: np.ndarray,
    config: AgentConfig,
) -> JointBelief:
    """Step 1: the prior's joint belief after the observed action, carried to ``weights``; the
    prior over (mode, beta) for a new agent."""
    betas = hypotheses(config.beta_low)
    if prior is None:
        return JointBelief.from_beta_belief(prior_belief(betas), weights)
    joint = previous_joint(prior, betas)
    action = request.observed_action
    if action is not None:
        observed = np.array([action.steering_rate, action.acceleration], dtype=np.float64)
        means, covs = previous_first_steps(prior)
        joint = joint.update(observed, means, covs, config.epsilon)
    return joint.for_prediction(weights)


def mode_bounds(
    prediction: ObservedPrediction,
    m: int,
    beta: float,
    config: AgentConfig,
    settings: Settings,
    limits: tuple[float, float],
) -> list[float]:
    """Step 3: mode m's eight control bounds (contract order) for ``beta``."""
    mixture = prediction.mixture
    try:
        bounds = control_bounds(
            mixture.means[m],
            mixture.covs[m],
            mixture.dt,
            beta,
            config.gamma,
            horizon=settings.horizon_s,
            method=config.bounds_fit,  # type: ignore[arg-type]
            limits=limits,
            rule=config.bounds_rule,  # type: ignore[arg-type]
            onset=config.rescue_onset,
        )
    except PredictionError as exc:
        if prediction.as_modes:
            raise FieldError(prediction.field(m), str(exc)) from None
        raise _field_error(exc) from None
    except ValueError as exc:
        raise FieldError(prediction.field(m), str(exc)) from None
    return [float(b) for b in bounds.as_array()]


@dataclass(frozen=True)
class StateInputs:
    """What an observation brings to the next state besides the prior: the request, its
    prediction, the agent's overrides (stored) and effective config, its class."""

    agent_id: str
    request: ObservationRequest
    prediction: ObservedPrediction
    overrides: dict[str, Any]
    config: AgentConfig
    klass: AgentClass
    gamma_state: float | None


def next_state(
    prior: AgentState | None, inputs: StateInputs, settings: Settings, engine: FRTEngine
) -> tuple[AgentState, Belief]:
    """The agent's next state (see the module) and its marginal belief over beta."""
    mixture, config = inputs.prediction.mixture, inputs.config
    joint = updated_joint(prior, inputs.request, mixture.weights, config)
    posterior, mode_betas = joint.mode_probs, joint.mode_betas
    mass = float(inputs.overrides.get("mode_mass") or MODE_MASS)
    floor = inputs.overrides.get("mode_floor")
    chosen = select_modes(posterior, mass, MODE_FLOOR if floor is None else float(floor))
    limits = class_limits(inputs.klass, settings)
    bounds: dict[int, list[float]] = {}
    for m in chosen:
        bounds[m] = mode_bounds(
            inputs.prediction, m, float(mode_betas[m]), config, settings, limits
        )
        check_ranges(engine, inputs.klass, inputs.request.state.speed, bounds[m])
    main = int(np.argmax(posterior))
    belief = joint.beta_belief()
    modes = None
    if len(mixture.weights) > 1:
        modes = ModeSet(
            belief=joint.to_dict(),
            first_mean=mixture.means[:, 0].tolist(),
            first_cov=mixture.covs[:, 0].tolist(),
            posterior=posterior.tolist(),
            beta=mode_betas.tolist(),
            set=chosen,
            bounds=[bounds[m] for m in chosen],
            mode_mass=mass,
        ).to_dict()
    pose = inputs.request.state
    state = AgentState(
        agent_id=inputs.agent_id,
        timestamp=inputs.request.timestamp,
        x=pose.x,
        y=pose.y,
        heading=pose.heading,
        speed=pose.speed,
        belief=belief.to_dict(),
        prediction={
            "dt": mixture.dt,
            "mean": mixture.means[main].tolist(),
            "cov": mixture.covs[main].tolist(),
        },
        control_bounds=bounds[main],
        config=inputs.overrides,
        frt_version=(prior.frt_version + 1) if prior else 1,
        modes=modes,
        gamma_state=inputs.gamma_state,
    )
    return state, belief


def modes_out(modes: dict[str, Any] | None) -> list[ModeOut] | None:
    """The ``modes`` of a response: per mode, in the order given, its weight, posterior, beta and
    whether (with which bounds) the served set holds it; None for a single Gaussian."""
    if modes is None:
        return None
    mode_set = ModeSet.from_dict(modes)
    bounds = dict(zip(mode_set.set, mode_set.bounds, strict=True))
    weights = mode_set.belief["weights"]
    return [
        ModeOut(
            weight=float(weights[m]),
            posterior=float(p),
            beta=float(mode_set.beta[m]),
            in_set=m in bounds,
            control_bounds=ControlBoundsOut.from_list(bounds[m]) if m in bounds else None,
        )
        for m, p in enumerate(mode_set.posterior)
    ]
