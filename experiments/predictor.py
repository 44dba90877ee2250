"""A stand-in for Trajectron++ that is confidently wrong the way it was in the paper's scenes.

Paper, "Human Prediction Model" (eq. ``pred``): at each time step the robot has a Gaussian over
the human's controls (steering rate, acceleration) for every step of the horizon. Section "Case
Studies": in the U-turn Trajectron++ "makes incorrect predictions the human will remain at
rest/proceed slowly", then, "as more of the manoeuvre is completed, generates more accurate
predictions"; at the stop sign it believes the human "will also stop" like the cars around it,
until it "determines the intent of the human".

:class:`StopPredictor` reproduces exactly that, without any learning:

- *until the manoeuvre is evident* it predicts that the human stays in its lane (mean steering
  rate 0) and stops: at rest it stays at rest; moving, it brakes to stop at its stop line if that
  line is ahead, else within ``stop_time_s``;
- *once the manoeuvre is evident* (the heading has changed by ``catch_on_heading_rad`` or the car
  has moved ``catch_on_distance_m`` since it was first seen) it predicts that the last observed
  action continues (constant steering rate and acceleration): accurate, but late.

The covariance is diagonal with standard deviations ``sigma * (1 + growth k)`` at step k
(defaults: 0.2 rad/s and 0.5 m/s^2 for the first 0.5 s, growing to 11 times that at the last step,
as a learned predictor is sure about the next half second and unsure about the third). That is
*confidently* wrong in the paper's sense: the action scored by the filter is several first-step
standard deviations from the mean, and with beta = 1 and gamma = 0.075 the control bounds are the
mean +- 0.094 sigma (z_gamma = 0.094), so the FRT without confidence is a thin tube around the
wrong mean. With beta = beta_low = 0.03 the bounds widen by 1 / sqrt(beta_low) = 5.8 to
+- 0.54 sigma: still not the true action, but a set wide enough to reach the ego's lane.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from experiments.scenes import CAR_LENGTH_M
from reach.dynamics import wrap_angle

#: The paper's prediction format: 0.5 s steps over a 3 s horizon (nuScenes is annotated at 2 Hz).
STEP_S = 0.5
STEPS = 6


@dataclass(frozen=True)
class Observation:
    """An observed human state at time ``t`` (world frame, heading continuous)."""

    t: float
    x: float
    y: float
    heading: float
    speed: float

    @property
    def state(self) -> tuple[float, float, float, float]:
        """``(x, y, heading, speed)`` with the heading wrapped into [-pi, pi)."""
        return (self.x, self.y, float(wrap_angle(self.heading)), self.speed)


def observed_action(previous: Observation, current: Observation) -> tuple[float, float]:
    """The action taken between two observations: mean steering rate and acceleration.

    Paper, "Confidence estimation and update": the robot observes the true action in hindsight;
    here it is recovered from the two states by finite differences (heading unwrapped).
    """
    dt = current.t - previous.t
    dheading = float(wrap_angle(current.heading - previous.heading))
    return dheading / dt, (current.speed - previous.speed) / dt


@dataclass(frozen=True)
class GaussianPrediction:
    """Per-step Gaussian over the controls: ``mean`` (S, 2), ``cov`` (S, 2, 2), step ``dt``."""

    dt: float
    mean: np.ndarray
    cov: np.ndarray
    #: Which hypothesis produced it: "stop" (wrong) or "continue" (caught on).
    mode: str = "stop"

    def payload(self) -> dict[str, Any]:
        """The ``prediction`` object of API.md."""
        return {"dt": self.dt, "mean": self.mean.tolist(), "cov": self.cov.tolist()}


@dataclass(frozen=True)
class StopPredictor:
    """Predicts "stays in lane and stops" until the manoeuvre is evident, then "continues".

    Args:
        sigma_u1: standard deviation of the steering rate at the first step (rad/s).
        sigma_u2: standard deviation of the acceleration at the first step (m/s^2).
        growth: per-step relative growth of the standard deviations.
        stop_time_s: time to stop of the predicted stop when no stop line lies ahead.
        stop_line: the human's stop line ``(x, y, heading)`` (``Scene.human_stop_line``).
        catch_on_heading_rad: heading change since the first observation that reveals a turn.
        catch_on_distance_m: distance since the first observation that reveals the car goes.
    """

    sigma_u1: float = 0.2
    sigma_u2: float = 0.5
    growth: float = 2.0
    stop_time_s: float = 1.5
    stop_line: tuple[float, float, float] | None = None
    catch_on_heading_rad: float = math.inf
    catch_on_distance_m: float = math.inf
    dt: float = STEP_S
    steps: int = STEPS
    max_decel_mps2: float = 10.0

    def covariance(self) -> np.ndarray:
        """Diagonal covariances (S, 2, 2), growing with the step index."""
        scale = 1.0 + self.growth * np.arange(self.steps)
        cov = np.zeros((self.steps, 2, 2))
        cov[:, 0, 0] = (self.sigma_u1 * scale) ** 2
        cov[:, 1, 1] = (self.sigma_u2 * scale) ** 2
        return cov

    def caught_on(self, history: Sequence[Observation]) -> bool:
        """Whether the manoeuvre is evident in the observed history."""
        first, last = history[0], history[-1]
        turned = abs(last.heading - first.heading) >= self.catch_on_heading_rad
        moved = math.hypot(last.x - first.x, last.y - first.y) >= self.catch_on_distance_m
        return turned or moved

    def stop_means(self, current: Observation) -> np.ndarray:
        """Mean controls of "stays in lane and stops": steering rate 0, one constant deceleration.

        The deceleration stops the front bumper at the stop line if the line is ahead, else
        within ``stop_time_s``; it is held over the whole horizon (the stop rule of the dynamics
        keeps a stopped car stopped), so the mean is linear in time like the FRT's bounds.
        """
        speed = current.speed
        decel = speed / self.stop_time_s
        if self.stop_line is not None:
            lx, ly, lh = self.stop_line
            ahead = (lx - current.x) * math.cos(lh) + (ly - current.y) * math.sin(lh)
            ahead -= CAR_LENGTH_M / 2
            if ahead > 0.5:  # the stop line is ahead of the bumper: stop at it
                decel = speed**2 / (2.0 * ahead)
        mean = np.zeros((self.steps, 2))
        mean[:, 1] = -min(decel, self.max_decel_mps2)
        return mean

    def predict(self, history: Sequence[Observation]) -> GaussianPrediction:
        """The prediction at the last observation of ``history`` (oldest first)."""
        if not history:
            raise ValueError("need at least one observation")
        current = history[-1]
        if len(history) >= 2 and self.caught_on(history):
            u1, u2 = observed_action(history[-2], current)
            mean = np.tile([u1, u2], (self.steps, 1))
            mode = "continue"
        else:
            mean = self.stop_means(current)
            mode = "stop"
        return GaussianPrediction(self.dt, mean, self.covariance(), mode)


@dataclass(frozen=True)
class MixturePrediction:
    """A multi-modal prediction: per mode a weight and a :class:`GaussianPrediction`."""

    weights: tuple[float, ...]
    modes: tuple[GaussianPrediction, ...]
    mode: str = "bimodal"

    def payload(self) -> dict[str, Any]:
        """The multi-modal ``prediction`` object of API.md."""
        return {
            "dt": self.modes[0].dt,
            "modes": [
                {"weight": w, "mean": g.mean.tolist(), "cov": g.cov.tolist()}
                for w, g in zip(self.weights, self.modes, strict=True)
            ],
        }


@dataclass(frozen=True)
class BimodalPredictor:
    """A stand-in for a multi-modal predictor at the U-turn: "keeps going straight" (the
    single-Gaussian stand-in's prediction, ``base``) with weight ``w_straight``, and "U-turn"
    (left on ``turn_radius_m`` at ``turn_speed_mps``, accelerating to it at ``accel_mps2``) with
    the rest, both with ``base``'s covariances. The weights stay fixed: what the service learns
    about the modes comes from the observed actions alone."""

    base: StopPredictor
    turn_radius_m: float
    turn_speed_mps: float = 2.0
    accel_mps2: float = 2.0
    w_straight: float = 0.9

    def uturn_means(self, current: Observation) -> np.ndarray:
        """u1 = v / R (the yaw rate on the circle, left), u2 up to the turning speed."""
        steps, dt = self.base.steps, self.base.dt
        mean = np.zeros((steps, 2))
        mean[:, 0] = self.turn_speed_mps / self.turn_radius_m
        speed = current.speed
        for k in range(steps):
            u2 = min(self.accel_mps2, max(0.0, (self.turn_speed_mps - speed) / dt))
            mean[k, 1] = u2
            speed += u2 * dt
        return mean

    def predict(self, history: Sequence[Observation]) -> MixturePrediction:
        straight = self.base.predict(history)
        uturn = GaussianPrediction(
            straight.dt, self.uturn_means(history[-1]), straight.cov, "uturn"
        )
        return MixturePrediction((self.w_straight, 1.0 - self.w_straight), (straight, uturn))
