"""Controls that drive the extended unicycle along a predicted path.

The unicycle (x' = v cos θ, y' = v sin θ, θ' = u1, v' = u2) with controls held over each step
moves its heading and speed linearly between a path's points, so the controls are the changes of
heading and speed between consecutive points over ``dt``. What differs between the two methods
here is the state taken at each point:

- :func:`path_controls` (central differences): at point 0 the observation's state; at an inner
  point k the velocity ``(p[k+1] - p[k-1]) / (2 dt)``, the mean of the two segments' velocities; at
  the last point the last segment's velocity. Rolled through the dynamics, these controls meet a
  smooth path's points to second order in ``dt`` (halving ``dt`` quarters the error).
- :func:`trajectory_controls` (first-order differences): each segment's velocity as the state at
  its end, which lags half a step behind the path; kept to compare against.

A point whose velocity moves less than :data:`STOP_STEP_M` per step keeps the heading before it
(a stopped human has no direction). docs/client.md gives both methods' error on recorded tracks.
"""

from __future__ import annotations

import cmath
import itertools
import math
from collections.abc import Sequence

from frt_client.errors import ValidationError
from frt_client.inputs import plain

#: A point whose velocity moves less than this (m) per step keeps the heading before it.
STOP_STEP_M = 1e-3


def wrap(angle: float) -> float:
    """``angle`` in [-π, π)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def path_states(
    positions: Sequence[Sequence[float]], dt: float, heading: float, speed: float
) -> tuple[list[float], list[float]]:
    """The heading (continuous, rad) and speed (m/s) of the path at each of its points, from
    central differences (see the module)."""
    segments = [
        complex(x1 - x0, y1 - y0) / dt for (x0, y0), (x1, y1) in itertools.pairwise(positions)
    ]
    headings, speeds = [float(heading)], [float(speed)]
    last = len(positions) - 1
    for k in range(1, last + 1):
        velocity = 0.5 * (segments[k - 1] + segments[k]) if k < last else segments[k - 1]
        before = headings[-1]
        direction = cmath.phase(velocity) if abs(velocity) * dt >= STOP_STEP_M else before
        headings.append(before + wrap(direction - before))
        speeds.append(abs(velocity))
    return headings, speeds


def path_controls(
    positions: Sequence[Sequence[float]], dt: float, heading: float, speed: float
) -> list[list[float]]:
    """Controls (steering rate, acceleration) that drive the unicycle along a path.

    ``positions`` are the path's points ``(x, y)`` at ``0, dt, 2 dt, ...``, the first the human's
    position, whose heading (rad) and speed (m/s) are ``heading`` and ``speed``. Control k is the
    change of heading (wrapped) and of speed from point k to point k + 1 over ``dt``, with the
    state at each later point from central differences (see the module). ``len(positions) - 1``
    steps.
    """
    points = plain(positions)
    if not isinstance(points, list) or len(points) < 2:
        raise ValidationError("a path needs at least two points", field="positions")
    if not (math.isfinite(dt) and dt > 0):
        raise ValidationError(f"dt must be a positive number, got {dt!r}", field="dt")
    headings, speeds = path_states(points, dt, heading, speed)
    return [
        [(headings[k + 1] - headings[k]) / dt, (speeds[k + 1] - speeds[k]) / dt]
        for k in range(len(points) - 1)
    ]


def trajectory_controls(
    positions: Sequence[Sequence[float]], dt: float, heading: float, speed: float
) -> list[list[float]]:
    """Controls (steering rate, acceleration) along one path, by first-order finite differences.

    ``positions`` are the path's points ``(x, y)`` at ``0, dt, 2 dt, ...`` from the current
    position. Segment k (from point k to point k+1) has heading ``atan2(dy, dx)`` and speed
    ``|dp| / dt``; control k takes the human from the state before it (the current ``heading``
    and ``speed`` for k = 0, else segment k-1) to segment k in ``dt``: ``u1 = wrap(dtheta) / dt``,
    ``u2 = dv / dt``. A segment shorter than 1 mm keeps the heading before it. One control per
    segment: ``len(positions) - 1`` steps.
    """
    if len(positions) < 2:
        raise ValidationError("a path needs at least two points", field="positions")
    controls = []
    theta, v = float(heading), float(speed)
    for (x0, y0), (x1, y1) in itertools.pairwise(positions):
        dx, dy = x1 - x0, y1 - y0
        length = math.hypot(dx, dy)
        seg_theta = math.atan2(dy, dx) if length >= STOP_STEP_M else theta
        seg_v = length / dt
        controls.append([wrap(seg_theta - theta) / dt, (seg_v - v) / dt])
        theta, v = seg_theta, seg_v
    return controls
