"""Agents' next states from their last ones and one observation each: the one path every
observation takes, alone (:func:`next_state`) or with the other agents of its frame
(:func:`next_states`), each step done for all of them at once on arrays whose every row is
computed by the same operations whatever the other rows, so an agent gets bit for bit the same
state either way.

Every prediction is a mixture; a single Gaussian is a mixture of one mode, and for it each step
below is the paper's single-Gaussian filter exactly (``tests/test_next_state.py`` holds them equal,
bit for bit, against ``service.flows.confidence.update_belief`` and the paper's bounds):

1. the belief over (mode, beta) of the last state is updated by the observed action, scored
   against the first step of every mode of the last prediction (``service.flows.beliefs``, on
   ``service.flows.modes``: the epsilon-static transition, then Bayes; paper, eq. ``beta``) and
   carried to the new prediction;
2. the modes the served set holds are the most probable ones (``select_modes``);
3. each of them gets control bounds from its own beta under the agent's confidence-to-bounds rule
   (``service.flows.bounds``, paper, "Collision Set Update"), within its class's limits, and the
   bounds and the speed are checked against the class's ranges (one check, from the class); an
   agent whose modes fail either is refused with the error of its first such mode;
4. the state stores the marginal belief over beta, the first step of the most probable mode's
   prediction (what the next action is scored against) and its bounds, and, for several modes, the joint belief and the set's modes (:class:`ModeSet`). The
   job of a state (``AgentState.set_bounds``) has one row of bounds per mode in the set; its set
   is their union (``reach.union``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from reach.agent_classes import DEFAULT_CLASS, AgentClass, agent_class, engine_for_class
from reach.contract import BOUND_COLUMNS
from reach.engine import FRTEngine, OutOfRangeError
from service.flows.agent_config import AgentConfig
from service.flows.beliefs import BeliefStep, Joint, groups, summarised, updated_joints
from service.flows.bounds import (
    PredictionError,
    TrimRows,
    control_bounds_rows,
    validate_predictions,
)
from service.flows.confidence import Belief, hypotheses
from service.flows.modes import MODE_FLOOR, MODE_MASS, Mixture, select_modes, validate_mixture
from service.runtime.settings import Settings
from service.runtime.stores import AgentState
from service.wire.errors import AgentClassChangedError, APIError, FieldError
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
        return {name: getattr(self, name) for name in _MODE_SET_FIELDS}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModeSet:
        return cls(**data)


#: ModeSet's fields in order (``dataclasses.asdict`` deep-copies what is built afresh anyway).
_MODE_SET_FIELDS = tuple(f.name for f in fields(ModeSet))


def observed_prediction(
    prediction: ObservationPrediction | Prediction, settings: RequestLimits
) -> ObservedPrediction:
    """An observation's prediction validated once (422 naming the field): one Gaussian, or a
    list of modes (a list of one is that Gaussian, named as one)."""
    (result,) = observed_predictions([prediction], settings)
    if isinstance(result, APIError):
        raise result
    return result


def observed_predictions(
    predictions: Sequence[ObservationPrediction | Prediction], settings: RequestLimits
) -> list[ObservedPrediction | APIError]:
    """:func:`observed_prediction` of each prediction of a frame: every Gaussian of every
    prediction (the single ones and each mode of the mixtures) validated together
    (``validate_predictions``)."""
    out: list[ObservedPrediction | APIError | None] = [None] * len(predictions)
    gaussians: list[tuple[Any, Any, Any]] = []  # every Gaussian to validate
    first: list[int] = []  # per prediction, where its Gaussians start in ``gaussians``
    for i, prediction in enumerate(predictions):
        first.append(len(gaussians))
        modes = getattr(prediction, "modes", None)
        try:
            if modes is not None and len(modes) > 1:
                for m, mode in enumerate(modes[:MAX_MODES]):
                    check_prediction_steps(f"prediction.modes.{m}", mode.mean, settings)
                gaussians += [(mode.mean, mode.cov, prediction.dt) for mode in modes[:MAX_MODES]]
                continue
            mean, cov = (prediction.mean, prediction.cov) if modes is None else _one(modes)
            check_prediction_steps("prediction", mean, settings)
        except APIError as exc:
            out[i] = exc
            continue
        gaussians.append((mean, cov, prediction.dt))
    checked = validate_predictions(gaussians, settings.max_prediction_steps)
    for i, prediction in enumerate(predictions):
        if out[i] is None:
            out[i] = _observed(prediction, checked[first[i] :], settings)
    return out  # type: ignore[return-value]


def _one(modes: list[Any]) -> tuple[Any, Any]:
    return modes[0].mean, modes[0].cov


def _observed(
    prediction: ObservationPrediction | Prediction,
    checked: list[tuple[np.ndarray, np.ndarray] | PredictionError],
    settings: RequestLimits,
) -> ObservedPrediction | APIError:
    """The prediction from its Gaussians' checks (``checked`` starts with them): one Gaussian,
    or a mixture (a 422 naming the field where a check failed)."""
    modes = getattr(prediction, "modes", None)
    if modes is None or len(modes) == 1:
        result = checked[0]
        if isinstance(result, PredictionError):
            return _field_error(result)
        mean, cov = result
        return ObservedPrediction(Mixture(prediction.dt, np.ones(1), mean[None], cov[None]), False)
    count = min(len(modes), MAX_MODES)
    try:
        mixture = validate_mixture(
            modes, prediction.dt, settings.max_prediction_steps, MAX_MODES, checked[:count]
        )
    except PredictionError as exc:
        return _field_error(exc)
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


@dataclass(frozen=True)
class BoundsRow:
    """One mode's bounds to fit: the prediction, the mode, its beta, the agent's config and its
    class's hard limits."""

    prediction: ObservedPrediction
    m: int
    beta: float
    config: AgentConfig
    limits: tuple[float, float]


def bounds_of_rows(rows: Sequence[BoundsRow], settings: Settings) -> list[list[float] | APIError]:
    """Step 3's bounds of every row (eight, contract order), or the error naming the mode's
    prediction: the rows with the same steps and fit computed together (``control_bounds_rows``),
    one by one where that raises, so that each row gets its own error."""
    out: list[list[float] | APIError | None] = [None] * len(rows)
    keys = [
        (r.prediction.mixture.means.shape[1:], r.prediction.mixture.dt, r.config.bounds_fit)
        for r in rows
    ]
    for _, members in groups(keys).items():
        try:
            fitted = _fit([rows[i] for i in members], settings)
        except ValueError:  # a PredictionError too: the rows one by one name theirs
            for i in members:
                try:
                    out[i] = _fit([rows[i]], settings)[0]
                except PredictionError as exc:
                    prediction = rows[i].prediction
                    if prediction.as_modes:
                        out[i] = FieldError(prediction.field(rows[i].m), str(exc))
                    else:
                        out[i] = _field_error(exc)
                except ValueError as exc:
                    out[i] = FieldError(rows[i].prediction.field(rows[i].m), str(exc))
            continue
        for i, bounds in zip(members, fitted, strict=True):
            out[i] = bounds
    return out  # type: ignore[return-value]


def _fit(rows: list[BoundsRow], settings: Settings) -> list[list[float]]:
    """The bounds of rows with the same steps and fit, together."""
    first = rows[0]
    trim = TrimRows(
        betas=np.array([r.beta for r in rows], dtype=np.float64),
        gammas=np.array([r.config.gamma for r in rows], dtype=np.float64),
        rules=tuple(r.config.bounds_rule for r in rows),  # type: ignore[misc]
        onsets=np.array([r.config.rescue_onset for r in rows], dtype=np.float64),
        limits=np.array([r.limits for r in rows], dtype=np.float64),
    )
    means = np.array([r.prediction.mixture.means[r.m] for r in rows])
    covs = np.array([r.prediction.mixture.covs[r.m] for r in rows])
    bounds = control_bounds_rows(
        means,
        covs,
        first.prediction.mixture.dt,
        trim,
        horizon=settings.horizon_s,
        method=first.config.bounds_fit,  # type: ignore[arg-type]
    )
    return bounds.tolist()  # type: ignore[no-any-return]


def mode_bounds(
    prediction: ObservedPrediction,
    m: int,
    beta: float,
    config: AgentConfig,
    settings: Settings,
    limits: tuple[float, float],
) -> list[float]:
    """Step 3: mode m's eight control bounds (contract order) for ``beta``."""
    (bounds,) = bounds_of_rows([BoundsRow(prediction, m, beta, config, limits)], settings)
    if isinstance(bounds, APIError):
        raise bounds
    return bounds


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

    def belief_step(self, prior: AgentState | None) -> BeliefStep:
        """What step 1 needs of this observation: the action is scored if there is a prior."""
        action = self.request.observed_action
        observed = None
        if action is not None and prior is not None:
            observed = np.array([action.steering_rate, action.acceleration], dtype=np.float64)
        betas = hypotheses(self.config.beta_low)
        weights = self.prediction.mixture.weights
        return BeliefStep(prior, betas, self.config.epsilon, observed, weights)

    def chosen_modes(self, posterior: np.ndarray) -> list[int]:
        """Step 2: the modes the served set holds."""
        mass = float(self.overrides.get("mode_mass") or MODE_MASS)
        floor = self.overrides.get("mode_floor")
        return select_modes(posterior, mass, MODE_FLOOR if floor is None else float(floor))


def next_state(
    prior: AgentState | None, inputs: StateInputs, settings: Settings, engine: FRTEngine
) -> tuple[AgentState, Belief]:
    """The agent's next state (see the module) and its marginal belief over beta: the agent
    alone through :func:`next_states`."""
    (result,) = next_states([prior], [inputs], settings, engine)
    if isinstance(result, APIError):
        raise result
    return result


def next_states(
    priors: Sequence[AgentState | None],
    inputs: Sequence[StateInputs],
    settings: Settings,
    engine: FRTEngine,
) -> list[tuple[AgentState, Belief] | APIError]:
    """Each agent's next state from its prior (see the module) and its marginal belief over beta,
    or the error that refuses it (its first mode whose bounds or ranges fail); the steps are done
    for all agents together."""
    steps = [i.belief_step(p) for p, i in zip(priors, inputs, strict=True)]
    joints = summarised(updated_joints(steps))
    chosen = [i.chosen_modes(j.posterior) for i, j in zip(inputs, joints, strict=True)]  # type: ignore[arg-type]
    rows = [
        BoundsRow(
            inputs[a].prediction,
            m,
            float(joints[a].mode_betas[m]),  # type: ignore[index]
            inputs[a].config,
            class_limits(inputs[a].klass, settings),
        )
        for a in range(len(inputs))
        for m in chosen[a]
    ]
    fitted = bounds_of_rows(rows, settings)
    speeds = [inputs[a].request.state.speed for a in range(len(inputs)) for _ in chosen[a]]
    classes = [inputs[a].klass for a in range(len(inputs)) for _ in chosen[a]]
    outside = iter(out_of_ranges(engine, classes, speeds, fitted))
    fitted_rows = iter(fitted)
    results: list[tuple[AgentState, Belief] | APIError] = []
    for prior, agent, joint, modes in zip(priors, inputs, joints, chosen, strict=True):
        bounds = {m: (next(fitted_rows), next(outside)) for m in modes}
        refused = _first_refusal(engine, agent, bounds)
        if refused is not None:
            results.append(refused)
            continue
        kept = {m: row for m, (row, _) in bounds.items()}
        results.append(_assembled(prior, agent, joint, modes, kept))  # type: ignore[arg-type]
    return results


def out_of_ranges(
    engine: FRTEngine,
    classes: Sequence[AgentClass],
    speeds: Sequence[float],
    rows: Sequence[list[float] | APIError],
) -> list[bool]:
    """Per row of bounds, whether :func:`check_ranges` may refuse it (the speed and the bounds
    outside the class's ranges, or a lower bound above its upper), for all rows at once with
    ``FRTEngine.validate``'s comparisons on its table of ranges; an engine validating otherwise,
    and a row that is an error, say True (such rows are checked, or answered, one by one)."""
    out = [True] * len(rows)
    engines = [engine_for_class(engine, k) for k in classes]
    table = [e.ranges if type(e).validate is FRTEngine.validate else None for e in engines]
    checked = [
        i for i, r in enumerate(rows) if table[i] is not None and not isinstance(r, APIError)
    ]
    if not checked:
        return out
    names = ("v_start", *BOUND_COLUMNS)
    values = np.array([[speeds[i], *rows[i]] for i in checked], dtype=np.float64)  # type: ignore[misc]
    limits = np.array([[table[i][name] for name in names] for i in checked], dtype=np.float64)  # type: ignore[index]
    inside = (
        np.isfinite(values)
        & (limits[:, :, 0] - 1e-9 <= values)
        & (values <= limits[:, :, 1] + 1e-9)
    )
    ordered = ~(values[:, 1:5] > values[:, 5:9] + 1e-9)  # each lower bound at most its upper
    ok = inside.all(axis=1) & ordered.all(axis=1)
    for i, fine in zip(checked, ok.tolist(), strict=True):
        out[i] = not fine
    return out


def _first_refusal(
    engine: FRTEngine,
    inputs: StateInputs,
    bounds: dict[int, tuple[list[float] | APIError, bool]],
) -> APIError | None:
    """The error of the agent's first mode whose bounds failed or fall outside its class's
    ranges (checked on their own where :func:`out_of_ranges` says they may), if any."""
    for row, outside in bounds.values():
        if isinstance(row, APIError):
            return row
        if not outside:
            continue
        try:
            check_ranges(engine, inputs.klass, inputs.request.state.speed, row)
        except FieldError as exc:
            return exc
    return None


def _assembled(
    prior: AgentState | None,
    inputs: StateInputs,
    joint: Joint,
    chosen: list[int],
    bounds: dict[int, list[float]],
) -> tuple[AgentState, Belief]:
    """Step 4: the state (see the module) and the marginal belief over beta."""
    mixture = inputs.prediction.mixture
    posterior, mode_betas = joint.posterior, joint.mode_betas
    main = int(np.argmax(posterior))  # type: ignore[arg-type]
    belief = joint.marginal
    modes = None
    if len(mixture.weights) > 1:
        modes = ModeSet(
            belief=joint.to_dict(),
            first_mean=mixture.means[:, 0].tolist(),
            first_cov=mixture.covs[:, 0].tolist(),
            posterior=posterior.tolist(),  # type: ignore[union-attr]
            beta=mode_betas.tolist(),  # type: ignore[union-attr]
            set=chosen,
            bounds=[bounds[m] for m in chosen],
            mode_mass=float(inputs.overrides.get("mode_mass") or MODE_MASS),
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
        prediction={  # its first step: what the next observation's action is scored against
            "dt": mixture.dt,
            "mean": mixture.means[main, :1].tolist(),
            "cov": mixture.covs[main, :1].tolist(),
        },
        control_bounds=bounds[main],
        config=inputs.overrides,
        frt_version=(prior.frt_version + 1) if prior else 1,
        modes=modes,
        gamma_state=inputs.gamma_state,
    )
    return state, belief  # type: ignore[return-value]


def modes_fields(modes: dict[str, Any] | None) -> list[dict[str, Any]] | None:
    """The ``modes`` of a response as the fields of each ``ModeOut``: per mode, in the order
    given, its weight, posterior, beta and whether (with which bounds) the served set holds it;
    None for a single Gaussian."""
    if modes is None:
        return None
    mode_set = ModeSet.from_dict(modes)
    bounds = dict(zip(mode_set.set, mode_set.bounds, strict=True))
    weights = mode_set.belief["weights"]
    return [
        {
            "weight": float(weights[m]),
            "posterior": float(p),
            "beta": float(mode_set.beta[m]),
            "in_set": m in bounds,
            "control_bounds": ControlBoundsOut.fields_of(bounds[m]) if m in bounds else None,
        }
        for m, p in enumerate(mode_set.posterior)
    ]


def modes_out(modes: dict[str, Any] | None) -> list[ModeOut] | None:
    """:func:`modes_fields` as models."""
    fields = modes_fields(modes)
    return None if fields is None else [ModeOut.model_validate(f) for f in fields]
