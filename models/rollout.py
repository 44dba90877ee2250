"""Rollouts of the true dynamics under admissible controls: the inner ground truth.

Written once over an array namespace (numpy for evaluation, torch for training supervision).
Controls switch a few times between the interpolated bounds: u(tau) = lo(tau) + alpha(tau) (hi - lo)
with alpha piecewise constant in [0, 1]; alpha in {0, 1} drives the boundary, random alpha the inside.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from models.contract import HORIZON_S, INITIAL_SET, InitialSet
from models.dynamics import interpolate_bounds, unicycle_derivative

Array = Any


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
        return u1_lo + a1 * (u1_hi - u1_lo), u2_lo + a2 * (u2_hi - u2_lo)

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


def sample_initial_states(
    v_start: np.ndarray,
    rng: np.random.Generator,
    initial_set: InitialSet = INITIAL_SET,
    spread: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """States spread over the initial set (``spread`` > 1 reaches outside it), numpy."""
    n = v_start.shape[0]
    m = initial_set
    radius = m.radius_m * spread * np.sqrt(rng.uniform(0, 1, n))
    angle = rng.uniform(-np.pi, np.pi, n)
    heading = m.heading_margin_rad * spread * rng.uniform(-1, 1, n)
    speed = np.clip(v_start + m.speed_margin_mps * spread * rng.uniform(-1, 1, n), 0.0, None)
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
