"""Agent classes (reach.agent_classes): each class's set holds rollouts of its own limits, and a
pedestrian's set is a pedestrian's (it turns round, it stays small)."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from models.evaluate import simulate
from reach.agent_classes import AGENT_CLASSES, agent_class, engine_for_class
from reach.contract import PARAM_RANGES
from reach.engine import FRTEngine, OutOfRangeError
from reach.frames import Pose


def full_bounds(name: str) -> np.ndarray:
    """The class's whole control box, start and end: every physically possible control."""
    k = agent_class(name)
    return np.array([-k.u1_limit, -k.u2_limit] * 2 + [k.u1_limit, k.u2_limit] * 2)


def class_set(name: str, speed: float):
    engine = FRTEngine(ranges=agent_class(name).ranges())
    engine.validate(speed, full_bounds(name))
    return engine.exact(Pose(0.0, 0.0, 0.0), speed, full_bounds(name))


def test_the_car_is_the_contracts_setting() -> None:
    assert AGENT_CLASSES["car"].ranges() == PARAM_RANGES
    engine = FRTEngine()
    assert engine_for_class(engine, agent_class("car")) is engine


@pytest.mark.parametrize(
    ("name", "speed"), [("car", 8.0), ("cyclist", 6.0), ("pedestrian", 1.4), ("pedestrian", 0.0)]
)
def test_every_class_set_holds_rollouts_of_its_own_limits(name: str, speed: float) -> None:
    frt = class_set(name, speed)
    rollouts = simulate(speed, full_bounds(name), 4096, np.random.default_rng(11))
    for t in (0.5, 1.5, 3.0):
        tube = frt.geometry("tube", t).buffer(1e-6)
        upto = rollouts.times <= t + 1e-9
        xy = rollouts.states[upto][:, :, :2].reshape(-1, 2)
        inside = shapely.contains_xy(tube, xy[:, 0], xy[:, 1])
        assert inside.all(), f"{name} at t={t}: {int((~inside).sum())} rollout points outside"


def test_a_walking_pedestrian_turns_round_and_stays_far_smaller_than_a_car() -> None:
    walk = 1.4
    pedestrian = class_set("pedestrian", walk).geometry("tube", 3.0)
    car = class_set("car", walk).geometry("tube", 3.0)
    # Behind the pedestrian, beyond the initial disc (radius 0.5 m): it turns on the spot.
    assert pedestrian.contains(shapely.Point(-3.0, 0.0))
    assert pedestrian.area < 0.3 * car.area
    # Ahead it reaches no farther than walking (plus the initial set's speed margin, 0.25 m/s,
    # and disc, 0.5 m) and accelerating at its limit allow, plus the grid's half metre.
    ahead = (walk + 0.25) * 3.0 + 0.5 * agent_class("pedestrian").u2_limit * 9.0 + 0.5
    assert pedestrian.bounds[2] <= ahead + 0.5


def test_out_of_range_states_name_the_field() -> None:
    engine = engine_for_class(FRTEngine(), agent_class("pedestrian"))
    with pytest.raises(OutOfRangeError) as exc:
        engine.validate(6.0, full_bounds("pedestrian"))
    assert exc.value.field == "v_start"
    with pytest.raises(OutOfRangeError) as exc:
        engine.validate(1.0, full_bounds("pedestrian") * 1.01)
    assert exc.value.field.startswith("u1_min")
    # The car's ranges are untouched by the copies.
    FRTEngine().validate(6.0, full_bounds("car"))
