"""Predictors' native messages (frt_client.adapters): Autoware's and Apollo's, offline and against
the live server.

Paths are made by rolling known controls through ``reach.dynamics`` (RK4, the controls held over
each step, the speed kept >= 0 as in the stop rule), so the recovered controls can be rolled back
through the same dynamics and compared with the path.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np
import pytest
from frt_client import FRTClient, ValidationError
from frt_client.adapters import (
    APOLLO_CLASSES,
    AUTOWARE_CLASSES,
    ApolloTrajectory,
    ApolloTrajectoryPoint,
    GaussianInfo,
    PathPoint,
    PerceptionObstacle,
    Pose,
    PoseWithCovariance,
    PredictedObject,
    PredictedObjectKinematics,
    PredictedPath,
    PredictionObstacle,
    Quaternion,
    Shape,
    Twist,
    TwistWithCovariance,
    Vector3,
    from_apollo,
    from_autoware,
    grown_covs,
    resample,
    shape_radius,
)
from frt_client.mixtures import from_trajectories
from frt_client.paths import path_controls, trajectory_controls

from reach.agent_classes import AGENT_CLASSES
from reach.dynamics import unicycle_derivative
from tests.conftest import LiveServer

START = (2.0, -1.0, 0.3, 8.0)


def roll(
    state: Sequence[float], controls: Sequence[Sequence[float]], dt: float, substeps: int = 20
) -> np.ndarray:
    """Positions (S + 1, 2) at every ``dt`` of the unicycle from ``state`` under ``controls``."""
    s = np.array(state, dtype=float)
    out = [s[:2].copy()]
    h = dt / substeps
    for u1, u2 in controls:

        def f(x: np.ndarray, u1: float = u1, u2: float = u2) -> np.ndarray:
            return np.array(unicycle_derivative(x[2], x[3], u1, u2))

        for _ in range(substeps):
            k1 = f(s)
            k2 = f(s + 0.5 * h * k1)
            k3 = f(s + 0.5 * h * k2)
            k4 = f(s + h * k3)
            s = s + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
            s[3] = max(s[3], 0.0)
        out.append(s[:2].copy())
    return np.array(out)


def swerving_path(fine: float = 0.01, horizon: float = 3.0) -> np.ndarray:
    """A car at 8 m/s steering |u1| <= 0.5 rad/s and braking/accelerating |u2| <= 2 m/s², the
    controls changing smoothly, every ``fine`` seconds."""
    n = round(horizon / fine)
    controls = [
        [0.4 * math.sin(1.3 * k * fine) + 0.1, 1.5 * math.cos(0.9 * k * fine) - 0.5]
        for k in range(n)
    ]
    return roll(START, controls, fine, substeps=1)


def roll_error(
    method: Callable[..., list[list[float]]], truth: np.ndarray, dt: float, fine: float = 0.01
) -> float:
    """Largest distance between the path sampled every ``dt`` and the roll of its controls."""
    points = truth[:: round(dt / fine)]
    controls = method(points.tolist(), dt, START[2], START[3])
    return float(np.linalg.norm(roll(START, controls, dt) - points, axis=1).max())


# ------------------------------------------------------------------ the method


def test_recovered_controls_roll_back_onto_the_path_to_second_order() -> None:
    truth = swerving_path()
    errors = {dt: roll_error(path_controls, truth, dt) for dt in (0.4, 0.2, 0.1, 0.05)}
    # second order: halving the step divides the error by about 4 (first order: by 2)
    for dt in (0.4, 0.2, 0.1):
        assert errors[dt] / errors[dt / 2] > 3.0, errors
    # at the 0.1 s step of Apollo's paths, within 2 cm over 3 s (measured 0.96 cm: a regression
    # by a factor of two fails), and 30x closer than the first-order differences
    assert errors[0.1] < 0.02
    assert errors[0.1] < roll_error(trajectory_controls, truth, 0.1) / 30


def test_where_the_method_is_exact() -> None:
    dt = 0.5
    # constant velocity from the matching state: no control
    straight = [[1.0 + 6.0 * k * dt, 2.0] for k in range(7)]
    np.testing.assert_allclose(path_controls(straight, dt, 0.0, 6.0), np.zeros((6, 2)), atol=1e-12)
    # constant acceleration: central differences are exact but at the last point (a segment)
    accel = [[5.0 * t + 0.75 * t * t, 0.0] for t in np.arange(7) * dt]
    controls = path_controls(accel, dt, 0.0, 5.0)
    assert [u2 for _, u2 in controls[:-1]] == pytest.approx([1.5] * 5)
    assert all(u1 == 0.0 for u1, _ in controls)
    # a stopped human keeps its heading and speed
    assert path_controls([[3.0, 4.0]] * 4, dt, 0.7, 0.0) == [[0.0, 0.0]] * 3


def test_headings_through_plus_minus_pi_turn_the_short_way() -> None:
    dt = 0.1
    # a circle anticlockwise crossing heading +pi: the steering rate stays v / R
    radius, v = 10.0, 5.0
    w = v / radius
    points = [
        [radius * math.cos(a), radius * math.sin(a)]
        for a in (math.pi / 2 + 0.4 + w * k * dt for k in range(31))
    ]
    controls = path_controls(points, dt, math.pi / 2 + 0.4 + math.pi / 2, v)
    assert [u1 for u1, _ in controls[1:-1]] == pytest.approx([w] * 28, rel=1e-9)


def test_resampling_keeps_the_given_points_and_cuts_at_the_horizon() -> None:
    truth = swerving_path(fine=0.1, horizon=8.0)
    times = [0.1 * k for k in range(len(truth))]
    coarse = resample(times, truth.tolist(), 0.5)
    assert len(coarse) == 7  # 0, 0.5, ..., 3.0: the horizon, not the 8 s of the path
    np.testing.assert_allclose(coarse, truth[:31:5], atol=1e-9)
    # up from 0.5 s to 0.1 s: exact for a constant acceleration ...
    t = np.arange(7) * 0.5
    accel = np.stack([5.0 * t + 0.75 * t * t, 0.2 * t * t], axis=1)
    fine_t = np.arange(31) * 0.1
    expected = np.stack([5.0 * fine_t + 0.75 * fine_t**2, 0.2 * fine_t**2], axis=1)
    np.testing.assert_allclose(resample(t.tolist(), accel.tolist(), 0.1), expected, atol=1e-12)
    # ... and for the swerving car 3x closer to the path between the points than straight lines
    fine = np.array(resample(times[::5], truth[::5].tolist(), 0.1))
    assert len(fine) == 31
    straight = np.stack([np.interp(fine_t, t, truth[:31:5, i]) for i in (0, 1)], axis=1)
    hermite_error = np.linalg.norm(fine - truth[:31], axis=1).max()
    assert hermite_error < np.linalg.norm(straight - truth[:31], axis=1).max() / 3


# ------------------------------------------------------------------ Autoware


def autoware_message(paths: list[tuple[np.ndarray, float]], step: float = 0.5) -> dict:
    """A PredictedObject dump (``ros2 topic echo``'s shape) of a walking pedestrian."""
    return {
        "object_id": {"uuid": list(range(16))},
        "existence_probability": 0.9,
        "classification": [{"label": 1, "probability": 0.1}, {"label": 7, "probability": 0.9}],
        "kinematics": {
            "initial_pose_with_covariance": {
                "pose": {
                    "position": {"x": 10.0, "y": 5.0, "z": 0.0},
                    "orientation": dataclasses.asdict(Quaternion.from_yaw(0.5)),
                },
                "covariance": [0.0] * 36,
            },
            "initial_twist_with_covariance": {
                "twist": {"linear": {"x": 1.4, "y": 0.0, "z": 0.0}},
            },
            "predicted_paths": [
                {
                    "path": [{"position": {"x": x, "y": y, "z": 0.0}} for x, y in points],
                    "time_step": {"sec": int(step), "nanosec": round((step % 1) * 1e9)},
                    "confidence": confidence,
                }
                for points, confidence in paths
            ],
        },
        "shape": {"type": 0, "dimensions": {"x": 0.6, "y": 0.8, "z": 1.7}},
    }


def walk(heading: float, speed: float, turn: float = 0.0, n: int = 9, dt: float = 0.5):
    state = (10.0, 5.0, heading, speed)
    return roll(state, [[turn, 0.0]] * (n - 1), dt)


def test_autoware_object_becomes_an_observation_piece() -> None:
    ahead, left = walk(0.5, 1.4), walk(0.5, 1.4, turn=0.4)
    piece = from_autoware(autoware_message([(ahead, 0.6), (left, 0.2)]), radius_from_shape=True)
    assert piece["agent_id"] == bytes(range(16)).hex()
    assert piece["agent_class"] == "pedestrian"
    assert piece["state"] == pytest.approx({"x": 10.0, "y": 5.0, "heading": 0.5, "speed": 1.4})
    assert piece["config"] == {"collision_radius": pytest.approx(0.5)}
    prediction = piece["prediction"]
    assert prediction["dt"] == 0.5
    weights = [m["weight"] for m in prediction["modes"]]
    assert weights == pytest.approx([0.75, 0.25]) and sum(weights) == pytest.approx(1.0)
    # the paths' own time step and horizon: 6 steps; the turn recovered (0.4 rad/s inside)
    assert [len(m["mean"]) for m in prediction["modes"]] == [6, 6]
    np.testing.assert_allclose(prediction["modes"][0]["mean"], np.zeros((6, 2)), atol=1e-9)
    assert [u1 for u1, _ in prediction["modes"][1]["mean"][1:-1]] == pytest.approx(
        [0.4] * 4, rel=0.01
    )
    # no covariance in the message: the rule of from_trajectories
    reference = from_trajectories([ahead[:7].tolist()], [1.0], 0.5, 0.5, 1.4)["modes"][0]["cov"]
    assert prediction["modes"][0]["cov"] == reference == grown_covs(6, (0.1, 0.5), 0.25)


def test_autoware_dataclasses_read_as_their_dump() -> None:
    ahead = walk(0.5, 1.4)
    obj = PredictedObject(
        object_id="ped-1",
        classification=[],
        kinematics=PredictedObjectKinematics(
            initial_pose_with_covariance=PoseWithCovariance(
                pose=Pose(Vector3(10.0, 5.0), Quaternion.from_yaw(0.5))
            ),
            initial_twist_with_covariance=TwistWithCovariance(Twist(linear=Vector3(1.4))),
            predicted_paths=[
                PredictedPath(
                    path=[Pose(Vector3(x, y)) for x, y in ahead], time_step=0.5, confidence=0.7
                )
            ],
        ),
        shape=Shape(type=1, dimensions=Vector3(0.8, 0.8, 1.7)),
    )
    piece = from_autoware(obj, dt=0.1, radius_from_shape=True)
    dumped = from_autoware(dataclasses.asdict(obj), dt=0.1, radius_from_shape=True)
    assert piece == dumped
    assert piece["agent_id"] == "ped-1" and piece["agent_class"] == "car"  # no classification
    assert piece["config"]["collision_radius"] == pytest.approx(0.4)  # the cylinder's
    mode = piece["prediction"]["modes"][0]
    assert piece["prediction"]["dt"] == 0.1 and len(mode["mean"]) == 30  # resampled to 0.1 s
    np.testing.assert_allclose(mode["mean"], np.zeros((30, 2)), atol=1e-9)


def test_autoware_twist_is_in_the_objects_frame() -> None:
    msg = autoware_message([(walk(0.5, 1.4), 1.0)])
    msg["kinematics"]["initial_twist_with_covariance"]["twist"]["linear"] = {"x": 0.0, "y": 1.0}
    state = from_autoware(msg)["state"]
    assert state["heading"] == pytest.approx(0.5 + math.pi / 2) and state["speed"] == 1.0
    # too slow for the velocity's direction to mean anything: the yaw
    msg["kinematics"]["initial_twist_with_covariance"]["twist"]["linear"] = {"x": -0.1, "y": 0.0}
    assert from_autoware(msg)["state"]["heading"] == pytest.approx(0.5)


@pytest.mark.parametrize(
    ("label", "expected"),
    [
        (0, "car"),
        (1, "car"),
        (2, "car"),
        (3, "car"),
        (4, "car"),
        (5, "car"),
        (6, "cyclist"),
        (7, "pedestrian"),
        ("BICYCLE", "cyclist"),
        ("pedestrian", "pedestrian"),
        (99, "car"),
    ],
)
def test_autoware_labels_map_to_agent_classes(label: int | str, expected: str) -> None:
    msg = autoware_message([(walk(0.5, 1.4), 1.0)])
    msg["classification"] = [{"label": label, "probability": 1.0}]
    assert from_autoware(msg)["agent_class"] == expected


def test_classes_can_be_mapped_otherwise() -> None:
    msg = autoware_message([(walk(0.5, 1.4), 1.0)])
    msg["classification"] = [{"label": 5, "probability": 1.0}]
    classes = {**AUTOWARE_CLASSES, "MOTORCYCLE": "cyclist"}
    assert from_autoware(msg, classes=classes)["agent_class"] == "cyclist"


def test_autoware_classes_fit_the_service_classes() -> None:
    assert set(AUTOWARE_CLASSES.values()) | set(APOLLO_CLASSES.values()) <= set(AGENT_CLASSES)


def test_paths_of_different_lengths_and_zero_confidence() -> None:
    long, short = walk(0.5, 1.4), walk(0.5, 1.4, turn=0.3, n=4)
    msg = autoware_message([(long, 2.0), (short, 1.0), (walk(0.5, 1.4, turn=-0.3), 0.0)])
    modes = from_autoware(msg)["prediction"]["modes"]
    assert len(modes) == 2  # the path of confidence 0 is dropped
    assert [m["weight"] for m in modes] == pytest.approx([2 / 3, 1 / 3])
    assert len(modes[1]["mean"]) == len(modes[1]["cov"]) == 6
    assert modes[1]["mean"][3:] == [modes[1]["mean"][2]] * 3  # the last step held
    assert modes[1]["cov"][3:] == [modes[1]["cov"][2]] * 3


# ------------------------------------------------------------------ Apollo


def apollo_message(
    trajectories: list[tuple[np.ndarray, float]],
    step: float = 0.1,
    sigma: Callable[[float], tuple[float, float, float]] | None = None,
    camel: bool = False,
) -> dict:
    """A PredictionObstacle as protobuf's MessageToDict gives it (``camel``: its default keys)."""

    def point(x: float, y: float, t: float) -> dict:
        out: dict = {"path_point": {"x": x, "y": y, "theta": 0.0}, "v": 0.0, "relative_time": t}
        if sigma is not None:
            sx, sy, rho = sigma(t)
            out["gaussian_info"] = {"sigma_x": sx, "sigma_y": sy, "correlation": rho}
        return out

    msg = {
        "perception_obstacle": {
            "id": 42,
            "position": {"x": START[0], "y": START[1], "z": 0.0},
            "theta": START[2],
            "velocity": {"x": START[3] * math.cos(START[2]), "y": START[3] * math.sin(START[2])},
            "length": 4.5,
            "width": 1.9,
            "type": "VEHICLE",
        },
        "trajectory": [
            {
                "probability": p,
                "trajectory_point": [point(x, y, k * step) for k, (x, y) in enumerate(points)],
            }
            for points, p in trajectories
        ],
    }
    return _camel_keys(msg) if camel else msg


def _camel_keys(node: object) -> object:
    if isinstance(node, dict):
        return {
            k.split("_")[0] + "".join(w.title() for w in k.split("_")[1:]): _camel_keys(v)
            for k, v in node.items()
        }
    if isinstance(node, list):
        return [_camel_keys(v) for v in node]
    return node


def test_apollo_obstacle_becomes_an_observation_piece() -> None:
    truth = swerving_path(fine=0.1, horizon=8.0)  # Apollo: 8 s at 0.1 s
    msg = apollo_message([(truth, 0.3), (truth, 0.1)])
    piece = from_apollo(msg, radius_from_shape=True)
    assert piece["agent_id"] == "42" and piece["agent_class"] == "car"
    assert piece["config"]["collision_radius"] == pytest.approx(shape_radius(4.5, 1.9))
    prediction = piece["prediction"]
    assert prediction["dt"] == pytest.approx(0.1)
    assert [m["weight"] for m in prediction["modes"]] == pytest.approx([0.75, 0.25])
    mean = prediction["modes"][0]["mean"]
    assert len(mean) == 30  # cut at the 3 s horizon
    np.testing.assert_allclose(
        mean, path_controls(truth[:31].tolist(), 0.1, START[2], START[3]), atol=1e-12
    )
    rolled = roll(START, mean, 0.1)
    assert np.linalg.norm(rolled - truth[:31], axis=1).max() < 0.02
    # without gaussian_info: the rule of from_trajectories
    assert prediction["modes"][0]["cov"] == grown_covs(30, (0.1, 0.5), 0.25)
    assert from_apollo(apollo_message([(truth, 1.0)], camel=True)) == from_apollo(
        apollo_message([(truth, 1.0)])
    )


def test_apollo_resampled_to_the_services_step() -> None:
    truth = swerving_path(fine=0.1, horizon=8.0)
    prediction = from_apollo(apollo_message([(truth, 1.0)]), dt=0.5)["prediction"]
    mean = prediction["modes"][0]["mean"]
    assert prediction["dt"] == 0.5 and len(mean) == 6
    expected = path_controls(truth[:31:5].tolist(), 0.5, START[2], START[3])
    np.testing.assert_allclose(mean, expected, atol=1e-9)


def test_apollo_gaussian_info_is_the_spread_of_held_controls() -> None:
    # positions whose spread is exactly that of an acceleration error of 0.4 m/s² along +x and of
    # a heading-rate error of 0.05 rad/s across, held since time 0, on a straight path at 8 m/s
    a_sd, w_sd, v = 0.4, 0.05, 8.0
    truth = np.array([[START[0] + v * t, START[1]] for t in np.arange(31) * 0.1])
    msg = apollo_message(
        [(truth, 1.0)], sigma=lambda t: (0.3 + a_sd * t * t / 2, 0.3 + w_sd * v * t * t / 2, 0.0)
    )
    msg["perception_obstacle"]["theta"] = 0.0
    msg["perception_obstacle"]["velocity"] = {"x": v, "y": 0.0}
    floor = (1e-6, 1e-6)
    covs = from_apollo(msg, floor=floor)["prediction"]["modes"][0]["cov"]
    # the growth since time 0 of a sigma 0.3 + s(t): sqrt((0.3 + s)^2 - 0.3^2), not s; the
    # method inverts that growth, so compare with it
    for k, cov in enumerate(covs):
        t = 0.1 * (k + 1)
        along = math.sqrt((0.3 + a_sd * t * t / 2) ** 2 - 0.09)
        across = math.sqrt((0.3 + w_sd * v * t * t / 2) ** 2 - 0.09)
        assert cov[1][1] == pytest.approx((along / (t * t / 2)) ** 2, rel=1e-6)
        assert cov[0][0] == pytest.approx((across / (v * t * t / 2)) ** 2, rel=1e-6)
        assert cov[0][1] == pytest.approx(0.0, abs=1e-12)
    # the growth exactly quadratic: the held errors themselves
    msg = apollo_message(
        [(truth, 1.0)], sigma=lambda t: (a_sd * t * t / 2, w_sd * v * t * t / 2, 0.0)
    )
    msg["perception_obstacle"]["theta"] = 0.0
    msg["perception_obstacle"]["velocity"] = {"x": v, "y": 0.0}
    covs = from_apollo(msg, floor=floor)["prediction"]["modes"][0]["cov"]
    np.testing.assert_allclose(np.sqrt([c[1][1] for c in covs]), a_sd, rtol=1e-6)
    np.testing.assert_allclose(np.sqrt([c[0][0] for c in covs]), w_sd, rtol=1e-6)


def test_apollo_covariances_are_positive_definite() -> None:
    truth = swerving_path(fine=0.1, horizon=8.0)

    def sigma(t: float) -> tuple[float, float, float]:
        return 0.2 + 0.3 * t, 0.2 + 0.1 * t * t, 0.9 * math.sin(t)

    for dt in (0.1, 0.5):
        piece = from_apollo(apollo_message([(truth, 1.0)], sigma=sigma), dt=dt)
        for cov in piece["prediction"]["modes"][0]["cov"]:
            m = np.array(cov)
            assert m[0, 1] == m[1, 0]
            assert np.linalg.eigvalsh(m).min() >= 0.02**2 * 0.999  # at least the floor
    # all zeros (protobuf's defaults when a predictor leaves gaussian_info empty): the rule
    zero = from_apollo(apollo_message([(truth, 1.0)], sigma=lambda t: (0.0, 0.0, 0.0)))
    assert zero["prediction"]["modes"][0]["cov"] == grown_covs(30, (0.1, 0.5), 0.25)


@pytest.mark.parametrize(
    ("kind", "sub_type", "expected"),
    [
        ("VEHICLE", None, "car"),
        (5, None, "car"),
        ("PEDESTRIAN", None, "pedestrian"),
        (3, None, "pedestrian"),
        ("BICYCLE", None, "cyclist"),
        ("BICYCLE", "ST_MOTORCYCLIST", "car"),
        (4, 8, "car"),
        ("UNKNOWN_MOVABLE", None, "car"),
        (0, None, "car"),
    ],
)
def test_apollo_types_map_to_agent_classes(
    kind: int | str, sub_type: int | str | None, expected: str
) -> None:
    msg = apollo_message([(swerving_path(fine=0.1), 1.0)])
    msg["perception_obstacle"]["type"] = kind
    if sub_type is not None:
        msg["perception_obstacle"]["sub_type"] = sub_type
    assert from_apollo(msg)["agent_class"] == expected


def test_apollo_trajectory_starting_after_time_zero_starts_at_the_obstacle() -> None:
    truth = swerving_path(fine=0.1)
    msg = apollo_message([(truth, 1.0)])
    points = msg["trajectory"][0]["trajectory_point"][1:]  # from 0.1 s
    msg["trajectory"][0]["trajectory_point"] = points
    mean = from_apollo(msg)["prediction"]["modes"][0]["mean"]
    expected = path_controls(truth.tolist(), 0.1, START[2], START[3])
    np.testing.assert_allclose(mean, expected, atol=1e-9)


def test_apollo_dataclasses_read_as_their_dump() -> None:
    truth = swerving_path(fine=0.1)
    obstacle = PredictionObstacle(
        perception_obstacle=PerceptionObstacle(
            id=7,
            position=Vector3(START[0], START[1]),
            theta=START[2],
            velocity=Vector3(START[3] * math.cos(START[2]), START[3] * math.sin(START[2])),
            length=1.8,
            width=0.6,
            type="BICYCLE",
        ),
        trajectory=[
            ApolloTrajectory(
                probability=1.0,
                trajectory_point=[
                    ApolloTrajectoryPoint(
                        path_point=PathPoint(x, y),
                        relative_time=0.1 * k,
                        gaussian_info=GaussianInfo(0.2 + 0.05 * k, 0.2 + 0.02 * k, 0.1),
                    )
                    for k, (x, y) in enumerate(truth)
                ],
            )
        ],
    )
    piece = from_apollo(obstacle, dt=0.5)
    assert piece == from_apollo(dataclasses.asdict(obstacle), dt=0.5)
    assert piece["agent_class"] == "cyclist" and piece["agent_id"] == "7"


# ------------------------------------------------------------------ bad input


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (lambda m: m["kinematics"].pop("initial_pose_with_covariance"),
         "kinematics.initial_pose_with_covariance"),
        (lambda m: m["kinematics"]["predicted_paths"][1]["path"][2]["position"].update(x="3"),
         "kinematics.predicted_paths.1.path.2.position.x"),
        (lambda m: m["kinematics"]["predicted_paths"][0].update(confidence=-0.5),
         "kinematics.predicted_paths.0.confidence"),
        (lambda m: m["kinematics"]["predicted_paths"][0].update(confidence=float("nan")),
         "kinematics.predicted_paths.0.confidence"),
        (lambda m: m["kinematics"]["predicted_paths"][0].update(time_step=0.0),
         "kinematics.predicted_paths.0.time_step"),
        (lambda m: m["kinematics"]["predicted_paths"][1].update(path=[]),
         "kinematics.predicted_paths.1.path"),
        (lambda m: m["kinematics"].update(predicted_paths=[]), "kinematics.predicted_paths"),
        (lambda m: m["classification"][0].update(label=[1]), "classification.0.label"),
        (lambda m: m["kinematics"]["initial_pose_with_covariance"]["pose"].update(
            orientation={"x": 0, "y": 0, "z": 0, "w": 0}),
         "kinematics.initial_pose_with_covariance.pose.orientation"),
    ],
)  # fmt: skip
def test_bad_autoware_input_names_the_field(edit: Callable[[dict], object], field: str) -> None:
    msg = autoware_message([(walk(0.5, 1.4), 0.6), (walk(0.5, 1.4, turn=0.4), 0.4)])
    edit(msg)
    with pytest.raises(ValidationError) as caught:
        from_autoware(msg)
    assert caught.value.field == field and caught.value.status is None


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (lambda m: m.pop("perception_obstacle"), "perception_obstacle"),
        (lambda m: m["perception_obstacle"]["position"].pop("y"), "perception_obstacle.position.y"),
        (lambda m: m["trajectory"][0]["trajectory_point"][5].update(relative_time=0.2),
         "trajectory.0.trajectory_point"),
        (lambda m: m["trajectory"][0]["trajectory_point"][3]["path_point"].update(x=math.inf),
         "trajectory.0.trajectory_point.3.path_point.x"),
        (lambda m: m["trajectory"][0]["trajectory_point"][3]["gaussian_info"].update(
            correlation=1.5), "trajectory.0.trajectory_point.3.gaussian_info"),
        (lambda m: m["trajectory"][0].update(probability="high"), "trajectory.0.probability"),
        (lambda m: m["trajectory"][0].update(trajectory_point=[]),
         "trajectory.0.trajectory_point"),
        (lambda m: m["trajectory"][0].update(
            trajectory_point=m["trajectory"][0]["trajectory_point"][:1]), "trajectory.0"),
        (lambda m: m["perception_obstacle"].update(type=2.5), "perception_obstacle.type"),
    ],
)  # fmt: skip
def test_bad_apollo_input_names_the_field(edit: Callable[[dict], object], field: str) -> None:
    msg = apollo_message([(swerving_path(fine=0.1), 1.0)], sigma=lambda t: (0.2 + t, 0.2 + t, 0.0))
    edit(msg)
    with pytest.raises(ValidationError) as caught:
        from_apollo(msg, dt=0.1)
    assert caught.value.field == field


def test_a_single_point_gives_no_step() -> None:
    msg = apollo_message([(swerving_path(fine=0.1)[:1], 1.0)])
    with pytest.raises(ValidationError) as caught:
        from_apollo(msg)
    assert caught.value.field == "trajectory.0"


def test_bad_step_and_shape() -> None:
    msg = autoware_message([(walk(0.5, 1.4), 1.0)])
    with pytest.raises(ValidationError) as caught:
        from_autoware(msg, dt=-0.5)
    assert caught.value.field == "dt"
    msg["shape"]["dimensions"]["x"] = 0.0
    with pytest.raises(ValidationError) as caught:
        from_autoware(msg, radius_from_shape=True)
    assert caught.value.field == "shape.dimensions.x"
    assert "collision_radius" not in from_autoware(msg).get("config", {})


# ------------------------------------------------------------------ through the service


def test_adapter_pieces_are_accepted_by_the_service(live_server: LiveServer) -> None:
    ahead, left = walk(0.5, 1.4), walk(0.5, 1.4, turn=0.4)
    walker = from_autoware(autoware_message([(ahead, 0.6), (left, 0.4)]), radius_from_shape=True)
    car = from_apollo(
        apollo_message(
            [(swerving_path(fine=0.1, horizon=8.0), 0.8), (swerving_path(fine=0.1), 0.2)],
            sigma=lambda t: (0.2 + 0.3 * t, 0.2 + 0.1 * t, 0.3),
        ),
        dt=0.5,
    )
    with FRTClient(live_server.url) as frt:
        first = frt.observe(timestamp=1.0, **walker)
        assert first.agent_id == walker["agent_id"]
        assert first.modes is not None and len(first.modes) == 2
        answer = frt.observe(timestamp=1.0, wait_frt_ms=5000, **car)
        assert answer.modes is not None and len(answer.modes) == 2
        agent = frt.get_agent(car["agent_id"])
        assert agent.agent_class == "car" and agent.config.collision_radius == 1.5
        assert frt.get_agent(walker["agent_id"]).config.collision_radius == pytest.approx(0.5)
        frame = frt.frame(timestamp=2.0, agents=[walker, car])
        assert frame.rejections() == []
