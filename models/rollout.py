"""Rollouts of the true dynamics under admissible controls: the inner ground truth.

Written once over an array namespace (numpy for evaluation, torch for training supervision).
Controls switch a few times between the interpolated bounds: u(tau) = lo(tau) + alpha(tau) (hi - lo)
with alpha piecewise constant in [0, 1]; alpha in {0, 1} drives the boundary, random alpha the inside.
A phase may instead hold the control at the admissible value nearest zero (``ZERO_SEEKING``): the
singular arc of Pontryagin's principle for this system. For d . p(t) to be maximal, u2 is bang-bang
and u1 is bang-bang except on arcs where lambda_theta = 0, i.e. heading aligned with d, u1 = 0. So
the front of the reachable set is swept by "turn hard, then drive straight" schedules, which random
switching between the bounds almost never produces (``sample_extremal_schedules``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from reach.contract import HORIZON_S, INITIAL_SET, InitialSet
from reach.dynamics import interpolate_bounds, unicycle_derivative

Array = Any

#: Share of reference rollouts started on the edge of the initial set, where extreme paths start.
EDGE_SHARE = 0.5

#: Phase value meaning "hold the control at the admissible value nearest 0" (clip(0, lo, hi)).
ZERO_SEEKING = -1.0


def switching_control(alpha: Array, switch_times: Array, tau: Array) -> Array:
    """alpha(tau) for piecewise-constant schedules: alpha[:, 0] until switch_times[:, 0], and so on.

    ``alpha`` is [N, S + 1], ``switch_times`` is [N, S] sorted along axis 1, ``tau`` is [N].
    """
    value = alpha[:, 0]
    for j in range(switch_times.shape[1]):
        after = (tau >= switch_times[:, j]) * 1.0
        value = value * (1.0 - after) + alpha[:, j + 1] * after
    return value


def rk4_rollout(
    state0: tuple[Array, Array, Array, Array],
    params: Array,
    t_end: Array,
    alpha1: Array,
    alpha2: Array,
    switch_times: Array,
    steps: int,
    xp: Any = np,
    horizon: float = HORIZON_S,
    record: bool = False,
) -> tuple[tuple[Array, Array, Array, Array], list]:
    """Integrate the extended unicycle with RK4 from ``state0`` over [0, t_end] (per row).

    ``switch_times`` must be sorted along axis 1. Speed is clamped at 0 after every step (stop rule).
    Returns the final state and, when ``record``, the list of (tau, state) after each step.
    """
    px, py, th, v = state0
    h = t_end / steps
    trace = []

    def controls(tau: Array) -> tuple[Array, Array]:
        u1_lo, u2_lo, u1_hi, u2_hi = interpolate_bounds(params, tau, horizon)
        a1 = switching_control(alpha1, switch_times, tau)
        a2 = switching_control(alpha2, switch_times, tau)
        return _control(u1_lo, u1_hi, a1, xp), _control(u2_lo, u2_hi, a2, xp)

    tau = t_end * 0.0
    for _ in range(steps):
        # Controls are held over the step (zero-order hold at the step's midpoint).
        u1, u2 = controls(tau + 0.5 * h)
        k1 = unicycle_derivative(th, v, u1, u2, xp)
        k2 = unicycle_derivative(th + 0.5 * h * k1[2], v + 0.5 * h * k1[3], u1, u2, xp)
        k3 = unicycle_derivative(th + 0.5 * h * k2[2], v + 0.5 * h * k2[3], u1, u2, xp)
        k4 = unicycle_derivative(th + h * k3[2], v + h * k3[3], u1, u2, xp)
        px = px + h / 6.0 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        py = py + h / 6.0 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        th = th + h / 6.0 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
        v = xp.clip(v + h / 6.0 * (k1[3] + 2 * k2[3] + 2 * k3[3] + k4[3]), 0.0, None)
        tau = tau + h
        if record:
            trace.append((tau, (px, py, th, v)))
    return (px, py, th, v), trace


def _control(lo: Array, hi: Array, alpha: Array, xp: Any) -> Array:
    """lo + alpha (hi - lo), or clip(0, lo, hi) where alpha is ``ZERO_SEEKING``."""
    nearest_zero = xp.minimum(xp.maximum(lo * 0.0, lo), hi)
    return xp.where(alpha < 0, nearest_zero, lo + alpha * (hi - lo))


def sample_initial_states(
    v_start: np.ndarray,
    rng: np.random.Generator,
    initial_set: InitialSet = INITIAL_SET,
    spread: float = 1.0,
    on_boundary: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """States spread over the initial set (``spread`` > 1 reaches outside it), numpy.

    A share ``on_boundary`` of them sits on its edge (position on the disc's rim, heading and speed
    at their margins), where the extreme trajectories start.
    """
    n = v_start.shape[0]
    m = initial_set
    radius_unit = np.sqrt(rng.uniform(0, 1, n))
    angle = rng.uniform(-np.pi, np.pi, n)
    heading_unit = rng.uniform(-1, 1, n)
    speed_unit = rng.uniform(-1, 1, n)
    if on_boundary > 0:  # drawn after the others, so on_boundary = 0 keeps the seeded streams
        edge = rng.uniform(0, 1, n) < on_boundary
        radius_unit[edge] = 1.0
        heading_unit[edge] = np.sign(heading_unit[edge])
        speed_unit[edge] = np.sign(speed_unit[edge])
    radius = m.radius_m * spread * radius_unit
    heading = m.heading_margin_rad * spread * heading_unit
    speed = np.clip(v_start + m.speed_margin_mps * spread * speed_unit, 0.0, None)
    return radius * np.cos(angle), radius * np.sin(angle), heading, speed


def sample_control_schedules(
    n: int, horizon: float, rng: np.random.Generator, switches: int = 3
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mix of schedules: bang-bang switching, straight (mid-bound) driving and random values."""
    kind = rng.uniform(0, 1, n)
    alpha1 = rng.integers(0, 2, (n, switches + 1)).astype(float)
    alpha2 = rng.integers(0, 2, (n, switches + 1)).astype(float)
    random_rows = kind > 0.8
    alpha1[random_rows] = rng.uniform(0, 1, (random_rows.sum(), switches + 1))
    alpha2[random_rows] = rng.uniform(0, 1, (random_rows.sum(), switches + 1))
    straight = (kind > 0.7) & (kind <= 0.8)
    alpha1[straight] = 0.5
    switch_times = np.sort(rng.uniform(0, horizon, (n, switches)), axis=1)
    return alpha1, alpha2, switch_times


#: Share of extremal schedules that sweep the outer front (turn, then straight).
FRONT_SHARE = 0.5


def sample_extremal_schedules(
    n: int, horizon: float, rng: np.random.Generator, switches: int = 3
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pontryagin-shaped schedules: u1 per phase at a bound or zero-seeking (turn, drive straight,
    turn again), u2 per phase at a bound (mostly) or zero-seeking. Half of the rows draw their
    switch times skewed early, where short hard turns set the heading of a long straight run;
    ``FRONT_SHARE`` of them are the one-parameter family that sweeps the outer front."""
    alpha1 = rng.choice([0.0, 1.0, ZERO_SEEKING], size=(n, switches + 1))
    alpha2 = rng.choice([0.0, 1.0, ZERO_SEEKING], size=(n, switches + 1), p=[0.4, 0.4, 0.2])
    unit = rng.uniform(0, 1, (n, switches))
    early = rng.uniform(0, 1, n) < 0.5
    unit[early] = unit[early] ** 2
    switch_times = np.sort(unit * horizon, axis=1)
    # The outer front itself: one hard turn, then straight, at full throttle (or full brake), the
    # turn's length uniform so that the front is swept evenly.
    kind = rng.uniform(0, 1, n)
    front = kind < FRONT_SHARE
    alpha1[front, 0] = rng.integers(0, 2, int(front.sum()))
    alpha1[front, 1:] = ZERO_SEEKING
    alpha2[front] = (kind[front] < 0.75 * FRONT_SHARE)[:, None] * 1.0
    switch_times[front, 0] = rng.uniform(0, horizon, int(front.sum()))
    switch_times[front, 1:] = horizon
    return alpha1, alpha2, switch_times


def sample_reference_schedules(
    n: int, horizon: float, rng: np.random.Generator, extremal_share: float = 0.6
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The evaluation's mix: extremal schedules for the boundary, the switching/straight/random mix
    of ``sample_control_schedules`` for the inside."""
    k = round(n * extremal_share)
    ext = sample_extremal_schedules(k, horizon, rng)
    mix = sample_control_schedules(n - k, horizon, rng)
    return tuple(np.concatenate([a, b]) for a, b in zip(ext, mix, strict=True))  # type: ignore[return-value]
