"""The one observation path (``service.flows.next_state``): a single Gaussian is a mixture of one
mode, and on it the path is the paper's single-Gaussian filter bit for bit.

The reference is written here from the paper's pieces only: the beta filter of
``service.flows.confidence`` (prior 1/n, epsilon-static transition, Bayes with N(mu, Sigma/beta)),
its point estimate, and the bounds of ``service.flows.bounds.control_bounds`` at that beta.
"""

from __future__ import annotations

import numpy as np
import pytest

from service.flows.agent_config import AgentConfig
from service.flows.bounds import control_bounds
from service.flows.confidence import hypotheses, prior_belief, update_belief
from service.flows.next_state import (
    ModeSet,
    StateInputs,
    check_ranges,
    next_state,
    observed_prediction,
    resolve_class,
)
from service.runtime.settings import Settings
from service.runtime.stores import AgentState
from service.wire.errors import AgentClassChangedError, FieldError
from service.wire.schemas import ObservationRequest

STEPS = 6
DT = 0.5


class _AnyRange:
    """An engine whose ranges hold everything: the range check is not what is compared here."""

    def validate(self, v_start: float, bounds: np.ndarray) -> None:
        return None


def _prediction(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    mean = rng.normal(0.0, [0.2, 1.0], size=(STEPS, 2))
    a = rng.normal(0.0, 0.3, size=(STEPS, 2, 2))
    cov = a @ a.transpose(0, 2, 1) + np.diag([0.01, 0.05])
    return mean, cov


def _request(t: float, mean, cov, action, modes: bool, rng) -> ObservationRequest:
    pred = {"dt": DT, "mean": mean.tolist(), "cov": cov.tolist()}
    if modes:  # the same Gaussian as a list of one mode
        pred = {"dt": DT, "modes": [{"weight": 0.7, "mean": pred["mean"], "cov": pred["cov"]}]}
    return ObservationRequest.model_validate(
        {
            "timestamp": t,
            "state": {"x": 0.0, "y": 0.0, "heading": 0.1, "speed": float(rng.uniform(2, 10))},
            "observed_action": None
            if action is None
            else {"steering_rate": float(action[0]), "acceleration": float(action[1])},
            "prediction": pred,
        }
    )


def _step(prior, request, settings, overrides):
    prediction = observed_prediction(request.prediction, settings)
    klass, overrides = resolve_class("a", request.agent_class, prior, overrides)
    config = AgentConfig.of(settings, overrides)
    inputs = StateInputs("a", request, prediction, overrides, config, klass, None)
    return next_state(prior, inputs, settings, _AnyRange())  # type: ignore[arg-type]


@pytest.mark.parametrize("rule", ["paper", "uniform_mixture", "mass_ramp"])
@pytest.mark.parametrize("seed", range(6))
def test_a_single_gaussian_is_the_papers_filter_bit_for_bit(seed: int, rule: str) -> None:
    rng = np.random.default_rng(seed)
    settings = Settings()
    beta_low = float(rng.choice([0.03, 0.1, 0.3]))
    epsilon = float(rng.choice([0.0, 0.02, 0.2]))
    overrides = {"beta_low": beta_low, "epsilon": epsilon, "bounds_rule": rule}
    reference = prior_belief(hypotheses(beta_low))
    prior: AgentState | None = None
    prev_mean = prev_cov = None
    for k in range(8):
        mean, cov = _prediction(rng)
        # Sometimes on the prediction, sometimes far off it: beta moves both ways.
        action = None if k == 0 else prev_mean[0] + rng.normal(0, 1 + 5 * (k % 3 == 0), 2)
        request = _request(1.0 + k, mean, cov, action, modes=bool(k % 2), rng=rng)
        state, belief = _step(prior, request, settings, overrides)
        if action is not None:
            reference = update_belief(reference, action, prev_mean[0], prev_cov[0], epsilon)
        sym = 0.5 * (cov + cov.transpose(0, 2, 1))
        bounds = control_bounds(
            mean, sym, DT, reference.beta, settings.gamma,
            horizon=settings.horizon_s, method=settings.bounds_fit,
            limits=(settings.u1_limit, settings.u2_limit), rule=rule, onset=settings.rescue_onset,
        ).as_array()  # fmt: skip
        assert state.belief == reference.to_dict()
        assert belief == reference and belief.beta == reference.beta
        assert state.control_bounds == [float(b) for b in bounds]
        assert state.modes is None and state.frt_version == k + 1
        assert state.set_bounds() == state.control_bounds
        prior, prev_mean, prev_cov = state, mean, sym


def test_a_state_keeps_its_predictions_first_step_and_one_with_every_step_reads_alike() -> None:
    """The next action is scored against the last prediction's first step, so a state keeps that
    step alone; a state stored with every step (written before) gives the same next state."""
    rng = np.random.default_rng(3)
    settings, overrides = Settings(), {}
    mean, cov = _prediction(rng)
    first, _ = _step(None, _request(1.0, mean, cov, None, False, rng), settings, overrides)
    sym = 0.5 * (cov + cov.transpose(0, 2, 1))
    assert first.prediction == {"dt": DT, "mean": mean[:1].tolist(), "cov": sym[:1].tolist()}
    every = AgentState.from_dict(
        {**first.to_dict(), "prediction": {"dt": DT, "mean": mean.tolist(), "cov": sym.tolist()}}
    )
    action = mean[0] + rng.normal(0.0, 2.0, 2)
    later = _request(2.0, *_prediction(rng), action, False, rng)
    assert _step(first, later, settings, overrides) == _step(every, later, settings, overrides)


def test_several_modes_keep_their_set_and_one_row_of_bounds_each() -> None:
    rng = np.random.default_rng(3)
    settings = Settings()
    means = [_prediction(rng) for _ in range(3)]
    pred = {
        "dt": DT,
        "modes": [
            {"weight": w, "mean": m.tolist(), "cov": c.tolist()}
            for w, (m, c) in zip([0.5, 0.3, 0.2], means, strict=True)
        ],
    }
    request = ObservationRequest.model_validate(
        {"timestamp": 1.0, "state": {"x": 0, "y": 0, "heading": 0, "speed": 5.0},
         "prediction": pred}
    )  # fmt: skip
    state, _ = _step(None, request, settings, {})
    modes = ModeSet.from_dict(state.modes)
    assert modes.set == [0, 1, 2] and len(modes.bounds) == 3
    assert state.set_bounds() == [b for row in modes.bounds for b in row]
    assert abs(sum(modes.posterior) - 1.0) < 1e-12
    assert state.control_bounds == modes.bounds[0]  # the most probable mode's


def test_the_class_is_fixed_and_brings_its_radius() -> None:
    klass, overrides = resolve_class("a", "pedestrian", None, {})
    assert klass.name == "pedestrian"
    assert overrides["collision_radius"] == klass.collision_radius_m
    prior = AgentState("a", 0, 0, 0, 0, 1, {}, {}, [0.0] * 8, config=overrides)
    with pytest.raises(AgentClassChangedError):
        resolve_class("a", "car", prior, {})


def test_one_range_check_names_the_speed_or_the_prediction() -> None:
    from reach.agent_classes import agent_class
    from reach.engine import OutOfRangeError

    class Narrow:
        def validate(self, v_start: float, bounds: np.ndarray) -> None:
            if v_start > 1.0:
                raise OutOfRangeError("v_start", v_start, 0.0, 1.0)
            raise OutOfRangeError("u1_min", 2.0, -1.0, 1.0)

    car = agent_class("car")
    with pytest.raises(FieldError) as exc:
        check_ranges(Narrow(), car, 5.0, np.zeros(8))  # type: ignore[arg-type]
    assert exc.value.field == "state.speed"
    with pytest.raises(FieldError) as exc:
        check_ranges(Narrow(), car, 0.5, np.zeros(8))  # type: ignore[arg-type]
    assert exc.value.field == "prediction"
    with pytest.raises(FieldError) as exc:
        check_ranges(Narrow(), car, 0.5, np.zeros(8), "control_bounds")  # type: ignore[arg-type]
    assert exc.value.field == "control_bounds.u1_min"


def test_config_is_frozen_and_adaptive_gamma_makes_a_new_one() -> None:
    config = AgentConfig.of(Settings(), {"gamma": 0.2, "unknown": 1, "epsilon": None})
    assert config.gamma == 0.2 and config.epsilon == Settings().epsilon
    served = config.with_gamma(0.5)
    assert served.gamma == 0.5 and config.gamma == 0.2
    with pytest.raises(AttributeError):
        config.gamma = 0.3  # type: ignore[misc]


@pytest.mark.parametrize(
    ("overrides", "radius", "gamma"),
    [
        ({}, 2.0, 0.4),
        ({"collision_radius": 0.75}, 0.75, 0.4),
        ({"collision_radius": None, "gamma": 0.3}, 2.0, 0.3),
        ({"beta_low": 0.1, "unknown": 1}, 2.0, 0.4),
    ],
)
def test_an_override_wins_unless_it_is_null(overrides: dict, radius: float, gamma: float) -> None:
    settings = Settings(collision_radius=2.0, gamma=0.4)
    whole = AgentConfig.of(settings, overrides)
    assert (whole.collision_radius, whole.gamma) == (radius, gamma)
    assert AgentConfig.value_of(settings, overrides, "collision_radius") == radius
    assert whole.beta_low == overrides.get("beta_low", settings.beta_low)


def test_effective_config_fields_are_the_schemas() -> None:
    from service.wire.schemas import EffectiveConfig

    assert set(AgentConfig.of(Settings(), {}).as_dict()) == set(EffectiveConfig.model_fields) - {
        "beta_high"
    }


def test_the_ranges_checked_together_refuse_what_the_engine_refuses() -> None:
    """``out_of_ranges`` flags every row ``FRTEngine.validate`` refuses (the flagged ones are then
    checked on their own), for each class, at and around the ranges' ends."""
    from reach.agent_classes import agent_class, engine_for_class
    from reach.contract import BOUND_COLUMNS
    from reach.engine import FRTEngine, OutOfRangeError
    from service.flows.next_state import out_of_ranges

    engine = FRTEngine()
    rng = np.random.default_rng(7)
    classes, speeds, rows, refused = [], [], [], []
    for _ in range(3000):
        klass = agent_class(str(rng.choice(["car", "pedestrian", "cyclist"])))
        ranges = engine_for_class(engine, klass).ranges
        ends = np.array([ranges[name] for name in ("v_start", *BOUND_COLUMNS)])
        # Mostly inside, some at an end, some just beyond one by more or less than the slack.
        values = rng.uniform(ends[:, 0], ends[:, 1])
        k = int(rng.integers(0, 9))
        values[k] = ends[k, int(rng.integers(0, 2))] + float(
            rng.choice([0.0, 5e-10, -5e-10, 2e-9, -2e-9, 0.1, -0.1])
        )
        if rng.random() < 0.05:
            values[int(rng.integers(0, 9))] = float(rng.choice([np.nan, np.inf]))
        try:
            engine_for_class(engine, klass).validate(values[0], values[1:])
            refused.append(False)
        except OutOfRangeError:
            refused.append(True)
        classes.append(klass)
        speeds.append(float(values[0]))
        rows.append(values[1:].tolist())
    flagged = out_of_ranges(engine, classes, speeds, rows)
    assert [f for f, r in zip(flagged, refused, strict=True) if r] == [True] * sum(refused)
    assert flagged == refused  # and nothing more: the same comparisons
    assert sum(refused) > 300
