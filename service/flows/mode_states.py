"""The observation flow's state for a multi-modal agent, and agents' classes.

``service.flows.agents`` calls :func:`build_mode_state` when the new prediction has several modes
or the agent's last one had: score the observed action against the first step of every mode of
the last prediction (the joint filter of ``service.flows.modes``), carry the belief to the new
prediction, choose the modes the served set holds, and fit each one's control bounds from its own
beta. The job of such a state (``Services.job_for``) has one row of bounds per mode in the set and
its set is their union (``reach.union``). A state whose new prediction has one mode is stored as a
single Gaussian's: the same layout, beta and bounds as the single-Gaussian flow gives.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from reach.agent_classes import DEFAULT_CLASS, AgentClass, agent_class, engine_for_class
from reach.engine import FRTEngine, OutOfRangeError
from service.api.errors import APIError, FieldError
from service.api.schemas import ControlBoundsOut, ModeOut, ObservationRequest
from service.flows.bounds import PredictionError, control_bounds
from service.flows.confidence import Belief, hypotheses, prior_belief
from service.flows.modes import MODE_FLOOR, MODE_MASS, JointBelief, Mixture, select_modes
from service.runtime.settings import Settings
from service.runtime.store import AgentState


class AgentClassChangedError(APIError):
    """409: an observation names another class than the agent's."""

    def __init__(self, agent_id: str, fixed: str, requested: str) -> None:
        super().__init__(
            409,
            f"agent {agent_id!r} is a {fixed}; its class is fixed once set (got {requested!r})",
        )


def resolve_class(
    agent_id: str, requested: str | None, prior: AgentState | None, overrides: dict[str, Any]
) -> AgentClass:
    """The agent's class (the prior state's, else the requested one, else the car), written into
    ``overrides`` with, for a class other than the car, its default collision radius unless the
    agent sets one; 409 if the request names another class than the prior state's."""
    fixed = (prior.config.get("agent_class") or DEFAULT_CLASS) if prior is not None else None
    name = fixed or requested or DEFAULT_CLASS
    if fixed is not None and requested is not None and requested != fixed:
        raise AgentClassChangedError(agent_id, fixed, requested)
    klass = agent_class(name)
    overrides["agent_class"] = name
    if name != DEFAULT_CLASS and overrides.get("collision_radius") is None:
        overrides["collision_radius"] = klass.collision_radius_m
    return klass


def class_limits(klass: AgentClass, settings: Settings) -> tuple[float, float]:
    """The hard control limits: the server's for a car, the registry's for the other classes."""
    if klass.name == DEFAULT_CLASS:
        return (settings.u1_limit, settings.u2_limit)
    return klass.limits


def check_class_ranges(engine: FRTEngine, klass: AgentClass, v_start: float, bounds: Any) -> None:
    """422 unless the speed and the bounds lie in the class's ranges (the car: the engine's)."""
    try:
        engine_for_class(engine, klass).validate(v_start, np.asarray(bounds))
    except OutOfRangeError as exc:
        field = "state.speed" if exc.field == "v_start" else "prediction"
        raise FieldError(field, f"{exc} for a {klass.name}") from None


def _previous_joint(prior: AgentState | None, betas: np.ndarray) -> JointBelief | None:
    if prior is None:
        return None
    if prior.modes is not None:
        return JointBelief.from_dict(prior.modes["belief"]).regrid(betas)
    belief = Belief.from_dict(prior.belief)
    if not np.array_equal(belief.betas, betas):
        belief = Belief(betas=betas, log_probs=belief.log_probs)
    return JointBelief.from_beta_belief(belief, [1.0])


def _previous_first_steps(prior: AgentState) -> tuple[np.ndarray, np.ndarray]:
    if prior.modes is not None:
        return (
            np.asarray(prior.modes["first_mean"], dtype=np.float64),
            np.asarray(prior.modes["first_cov"], dtype=np.float64),
        )
    return (
        np.asarray(prior.prediction["mean"][:1], dtype=np.float64),
        np.asarray(prior.prediction["cov"][:1], dtype=np.float64),
    )


def build_mode_state(
    agent_id: str,
    request: ObservationRequest,
    prior: AgentState | None,
    mixture: Mixture,
    overrides: dict[str, Any],
    config: dict[str, Any],
    klass: AgentClass,
    settings: Settings,
    engine: FRTEngine,
) -> tuple[AgentState, Belief]:
    """The agent's next state for ``mixture`` (see the module docstring) and its marginal belief
    over beta."""
    betas = hypotheses(config["beta_low"])
    joint = _previous_joint(prior, betas)
    action = request.observed_action
    if joint is not None and action is not None and prior is not None:
        observed = np.array([action.steering_rate, action.acceleration], dtype=np.float64)
        means, covs = _previous_first_steps(prior)
        joint = joint.update(observed, means, covs, config["epsilon"])
    if joint is None:
        joint = JointBelief.from_beta_belief(prior_belief(betas), mixture.weights)
    else:
        joint = joint.for_prediction(mixture.weights)
    posterior = joint.mode_probs
    mode_betas = joint.mode_betas
    mass = float(overrides.get("mode_mass") or MODE_MASS)
    floor = overrides.get("mode_floor")
    chosen = select_modes(posterior, mass, MODE_FLOOR if floor is None else float(floor))
    limits = class_limits(klass, settings)
    bounds: dict[int, list[float]] = {}
    for m in chosen:
        bounds[m] = _bounds(mixture, m, float(mode_betas[m]), config, settings, limits)
        check_class_ranges(engine, klass, request.state.speed, bounds[m])
    main = int(np.argmax(posterior))
    single = len(mixture.weights) == 1
    belief = joint.beta_belief()
    modes = None
    if not single:
        modes = {
            "belief": joint.to_dict(),
            "first_mean": mixture.means[:, 0].tolist(),
            "first_cov": mixture.covs[:, 0].tolist(),
            "posterior": posterior.tolist(),
            "beta": mode_betas.tolist(),
            "set": chosen,
            "bounds": [bounds[m] for m in chosen],
            "mode_mass": mass,
        }
    state = observed_state(
        agent_id,
        request,
        prior,
        belief=belief.to_dict(),
        prediction={
            "dt": mixture.dt,
            "mean": mixture.means[main].tolist(),
            "cov": mixture.covs[main].tolist(),
        },
        control_bounds=bounds[main],
        config=overrides,
        modes=modes,
    )
    return state, belief


def observed_state(
    agent_id: str, request: ObservationRequest, prior: AgentState | None, **fields: Any
) -> AgentState:
    """The agent's next state: the observation's time and pose, the version after ``prior``'s,
    and ``fields`` (belief, prediction, bounds, config, ...)."""
    pose = request.state
    return AgentState(
        agent_id=agent_id,
        timestamp=request.timestamp,
        x=pose.x,
        y=pose.y,
        heading=pose.heading,
        speed=pose.speed,
        frt_version=(prior.frt_version + 1) if prior else 1,
        **fields,
    )


def _bounds(
    mixture: Mixture,
    m: int,
    beta: float,
    config: dict[str, Any],
    settings: Settings,
    limits: tuple[float, float],
) -> list[float]:
    try:
        bounds = control_bounds(
            mixture.means[m],
            mixture.covs[m],
            mixture.dt,
            beta,
            config["gamma"],
            horizon=settings.horizon_s,
            method=config["bounds_fit"],
            limits=limits,
            rule=config["bounds_rule"],
            onset=config["rescue_onset"],
        )
    except (PredictionError, ValueError) as exc:
        raise FieldError(f"prediction.modes.{m}", str(exc)) from None
    return [float(b) for b in bounds.as_array()]


def modes_out(modes: dict[str, Any] | None) -> list[ModeOut] | None:
    """The ``modes`` of a response: per mode, in the order given, its weight, posterior, beta and
    whether (with which bounds) the served set holds it; None for a single Gaussian."""
    if modes is None:
        return None
    bounds = dict(zip(modes["set"], modes["bounds"], strict=True))
    weights = modes["belief"]["weights"]
    return [
        ModeOut(
            weight=float(weights[m]),
            posterior=float(p),
            beta=float(modes["beta"][m]),
            in_set=m in bounds,
            control_bounds=ControlBoundsOut.from_list(bounds[m]) if m in bounds else None,
        )
        for m, p in enumerate(modes["posterior"])
    ]


def set_bounds(state: AgentState) -> list[float]:
    """The bounds the state's FRT job is built from: one row of eight per mode in the set, flat
    (eight values for a single Gaussian or a set of one mode)."""
    if state.modes is None or len(state.modes["set"]) == 1:
        return state.control_bounds if state.modes is None else state.modes["bounds"][0]
    return [b for row in state.modes["bounds"] for b in row]
