"""The paper's ego planner: constant speed; on a predicted conflict, stop before the line or brake.

Paper, section "Case Studies": "the ego vehicle nominally moves in its lane at a constant speed.
If its current nominal trajectory intersects with C over the planning horizon (3 seconds), it
decelerates to stop before the intersection if possible; otherwise, it decelerates maximally until
it stops."

Choices the paper leaves open, made here:

- distances to the stop line are measured from the ego's front bumper (half a car length ahead of
  its centre), so "stops before the stop line" means no part of the car crosses it;
- "stop before the intersection if possible" is the constant deceleration ``v^2 / (2 d)`` that
  stops the front bumper exactly on the line; it is possible when it is at most the maximal
  deceleration (10 m/s^2, the paper's hard limit on accelerations), else the ego brakes at 10 m/s^2;
- the first detection commits the ego to its braking (no re-planning, as in the paper's runs);
- the nominal trajectory is the ego's centre at constant speed, one point every 0.1 s over 3 s,
  checked against the whole-horizon unsafe set (API.md collision-check ``mode: "tube"``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from experiments.scenes import CAR_LENGTH_M

MAX_DECEL_MPS2 = 10.0
HORIZON_S = 3.0
PLAN_DT_S = 0.1


@dataclass(frozen=True)
class Detection:
    """The moment the planner first saw its nominal trajectory meet C, and what it chose."""

    time_s: float
    distance_to_stop_line_m: float
    deceleration_mps2: float
    stop_time_s: float
    can_stop_before_line: bool


@dataclass
class EgoCar:
    """The ego car driving east along ``y``, planned by the paper's rule.

    ``x`` is the centre of the car; ``stop_line_x`` the ego's stop line.
    """

    x: float
    y: float
    speed: float
    stop_line_x: float
    decel: float = 0.0
    detection: Detection | None = None
    stopped_at_s: float | None = None

    @property
    def front_x(self) -> float:
        return self.x + CAR_LENGTH_M / 2

    @property
    def distance_to_stop_line(self) -> float:
        """Front bumper to the stop line (m), negative once past it."""
        return self.stop_line_x - self.front_x

    def nominal_trajectory(self, t: float) -> np.ndarray:
        """(t, x, y) rows of the constant-speed plan over the next 3 s (paper's horizon)."""
        times = t + np.arange(0.0, HORIZON_S + 1e-9, PLAN_DT_S)
        xs = self.x + self.speed * (times - t)
        return np.stack([times, xs, np.full_like(times, self.y)], axis=1)

    def on_conflict(self, t: float) -> Detection:
        """Commit to a stop: at the line if a deceleration <= 10 m/s^2 does it, else brake at 10."""
        d = self.distance_to_stop_line
        needed = self.speed**2 / (2.0 * d) if d > 0.0 else np.inf
        feasible = bool(needed <= MAX_DECEL_MPS2)
        self.decel = float(needed) if feasible else MAX_DECEL_MPS2
        self.detection = Detection(
            time_s=t,
            distance_to_stop_line_m=d,
            deceleration_mps2=-self.decel,
            stop_time_s=self.speed / self.decel,
            can_stop_before_line=feasible,
        )
        return self.detection

    def advance(self, t: float, dt: float) -> None:
        """Move by ``dt`` (exact for constant deceleration, stopping at speed 0)."""
        if self.decel <= 0.0 or self.speed <= 0.0:
            self.x += self.speed * dt
            return
        t_stop = self.speed / self.decel
        step = min(dt, t_stop)
        self.x += self.speed * step - 0.5 * self.decel * step * step
        self.speed = max(self.speed - self.decel * step, 0.0)
        if self.speed == 0.0 and self.stopped_at_s is None:
            self.stopped_at_s = t + step
