"""The client SDK's mixture helpers (frt_client.mixtures), offline and against the live server."""

from __future__ import annotations

import math

import numpy as np
import pytest
from frt_client import FRTClient, ValidationError, from_mixture, from_trajectories
from frt_client.paths import trajectory_controls

from tests.conftest import LiveServer


def straight_segments(thetas: list[float], speeds: list[float], dt: float) -> list[list[float]]:
    """Points of a path whose segment k has heading thetas[k] and speed speeds[k]."""
    points = [[1.0, 2.0]]
    for theta, v in zip(thetas, speeds, strict=True):
        x, y = points[-1]
        points.append([x + v * dt * math.cos(theta), y + v * dt * math.sin(theta)])
    return points


def test_finite_differences_recover_the_controls_of_a_path() -> None:
    dt = 0.1
    thetas = [0.1, 0.3, 0.6, 1.0, 1.5, 2.2, 3.0, -2.9]  # through +-pi: wrapped
    speeds = [5.0, 4.8, 4.4, 4.0, 3.9, 3.9, 4.2, 4.5]
    controls = trajectory_controls(straight_segments(thetas, speeds, dt), dt, 0.0, 5.2)
    heading = [0.0, *thetas]
    speed = [5.2, *speeds]
    for k, (u1, u2) in enumerate(controls):
        turn = (heading[k + 1] - heading[k] + math.pi) % (2 * math.pi) - math.pi
        assert u1 == pytest.approx(turn / dt, abs=1e-9)
        assert u2 == pytest.approx((speed[k + 1] - speed[k]) / dt, abs=1e-9)


def test_a_stopped_path_keeps_its_heading() -> None:
    controls = trajectory_controls([[0.0, 0.0]] * 4, 0.5, 0.7, 0.0)
    assert controls == [[0.0, 0.0]] * 3


def test_trajectories_become_modes_with_the_stated_covariance() -> None:
    dt = 0.5
    straight = straight_segments([0.0] * 6, [5.0] * 6, dt)
    turn = straight_segments([0.2 * k for k in range(1, 7)], [4.0] * 6, dt)
    pred = from_trajectories(np.array([straight, turn]), np.array([3.0, 1.0]), dt, 0.0, 5.0)
    assert pred["dt"] == dt and [m["weight"] for m in pred["modes"]] == [0.75, 0.25]
    for mode in pred["modes"]:
        assert len(mode["mean"]) == 6
        for k, cov in enumerate(mode["cov"]):
            s = 1.0 + 0.25 * k
            np.testing.assert_allclose(cov, [[(0.1 * s) ** 2, 0.0], [0.0, (0.5 * s) ** 2]])
    assert pred["modes"][1]["mean"][1][0] == pytest.approx(0.2 / dt)
    with pytest.raises(ValidationError):
        from_trajectories([straight], [0.0], dt, 0.0, 5.0)


def test_a_mixture_is_soft_maxed_and_cut_to_the_most_probable_modes() -> None:
    rng = np.random.default_rng(1)
    logs = rng.normal(size=40) + 1000.0  # any offset
    means = rng.normal(size=(40, 6, 2))
    covs = np.tile(np.diag([0.01, 0.25]), (40, 6, 1, 1))
    pred = from_mixture(logs, means, covs, 0.5)
    assert len(pred["modes"]) == 32
    weights = np.exp(logs - logs.max())
    weights /= weights.sum()
    kept = sorted(np.argsort(-weights)[:32])
    assert [m["weight"] for m in pred["modes"]] == pytest.approx(weights[kept].tolist())
    assert pred["modes"][0]["mean"] == means[kept[0]].tolist()
    one = from_mixture([0.0], means[:1], covs[:1], 0.5)
    assert one["modes"][0]["weight"] == 1.0
    with pytest.raises(ValidationError):
        from_mixture([0.0, float("nan")], means[:2], covs[:2], 0.5)


def test_a_mixture_observed_through_the_client(live_server: LiveServer) -> None:
    means = np.array([np.zeros((6, 2)), np.tile([0.5, -1.0], (6, 1))])
    covs = np.tile(np.diag([0.01, 0.25]), (2, 6, 1, 1))
    pred = from_mixture(np.log([0.9, 0.1]), means, covs, 0.5)
    with FRTClient(live_server.url) as frt:
        first = frt.observe("sdk-mix", timestamp=1.0, state=(0, 0, 0, 5), prediction=pred)
        assert first.modes is not None and [m.in_set for m in first.modes] == [True, True]
        nxt = frt.observe(
            "sdk-mix",
            timestamp=2.0,
            state=(2.5, 0, 0, 5),
            prediction=pred,
            observed_action=(0.5, -1.0),
            agent_class="car",
        )
        assert nxt.modes[1].posterior > first.modes[1].posterior
        agent = frt.get_agent("sdk-mix")
        assert agent.agent_class == "car" and agent.modes == nxt.modes
        walker = frt.observe(
            "sdk-walker",
            timestamp=1.0,
            state=(0, 0, 0, 1.4),
            prediction={"dt": 0.5, "mean": means[0], "cov": covs[0]},
            agent_class="pedestrian",
        )
        assert walker.modes is None
        assert frt.get_agent("sdk-walker").agent_class == "pedestrian"
