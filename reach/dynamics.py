"""Dynamics, control bounds, initial set and optimal Hamiltonian of the extended unicycle.

Every function is written once over an array namespace ``xp`` (``numpy`` or ``torch``), so the
training loss, the rollouts of the ground truth and the service use the same maths.

Paper references: "Running example" (extended unicycle), "Collision Set Update" (linear
interpolation of the control bounds, l(x)), "Overview: HJ reachability" (Hamiltonian, eq. hamiltonian).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from reach.contract import COL, HORIZON_S, INITIAL_SET, InitialSet

Array = Any  # numpy.ndarray or torch.Tensor


def wrap_angle(angle: Array, xp: Any = np) -> Array:
    """Wrap an angle into [-pi, pi)."""
    two_pi = 2.0 * math.pi
    return angle - two_pi * xp.floor((angle + math.pi) / two_pi)


def interpolate_bounds(params: Array, tau: Array, horizon: float = HORIZON_S) -> tuple[Array, ...]:
    """Control bounds at time ``tau``: the paper's linear interpolation (eq. for u~_min^tau).

    ``params`` holds the 14-column layout (only columns 6..13 are read); ``tau`` broadcasts against
    ``params[..., 0]``. Returns ``(u1_lo, u2_lo, u1_hi, u2_hi)``.
    """
    w = tau / horizon

    def lerp(start: str, end: str) -> Array:
        return (1.0 - w) * params[..., COL[start]] + w * params[..., COL[end]]

    return (
        lerp("u1_min_start", "u1_min_end"),
        lerp("u2_min_start", "u2_min_end"),
        lerp("u1_max_start", "u1_max_end"),
        lerp("u2_max_start", "u2_max_end"),
    )


def acceleration_with_stop(speed: Array, u2: Array, xp: Any = np) -> Array:
    """v' = u2 while moving; at v = 0 the car stays stopped unless it accelerates (API.md)."""
    return xp.where(speed > 0, u2, xp.clip(u2, 0.0, None))


def unicycle_derivative(
    heading: Array, speed: Array, u1: Array, u2: Array, xp: Any = np
) -> tuple[Array, Array, Array, Array]:
    """f(x, u) of the extended unicycle: (v cos th, v sin th, u1, u2) with the stop rule."""
    return (
        speed * xp.cos(heading),
        speed * xp.sin(heading),
        u1,
        acceleration_with_stop(speed, u2, xp),
    )


def initial_set_value(
    px: Array,
    py: Array,
    heading: Array,
    speed: Array,
    v_start: Array,
    xp: Any = np,
    initial_set: InitialSet = INITIAL_SET,
) -> Array:
    """l(x), whose zero sub-level set is the initial set (paper, eq. for l(x)), in metres."""
    s = initial_set
    position = xp.sqrt(px * px + py * py) - s.radius_m
    speed_term = (xp.abs(speed - v_start) - s.speed_margin_mps) * s.speed_weight
    heading_term = (xp.abs(wrap_angle(heading, xp)) - s.heading_margin_rad) * s.heading_weight
    return xp.maximum(position, xp.maximum(speed_term, heading_term))


def optimal_hamiltonian(
    grad: tuple[Array, Array, Array, Array],
    heading: Array,
    speed: Array,
    bounds: tuple[Array, Array, Array, Array],
    xp: Any = np,
) -> Array:
    """H(x, tau, p) = max_{u in U(tau)} p . f(x, u) in closed form (paper, eq. hamiltonian).

    f is control-affine and U(tau) a box, so each control sits at the bound that maximises its term:
    ``max(p_th u1_lo, p_th u1_hi) + max(p_v a(u2_lo), p_v a(u2_hi))`` with ``a`` the stop rule.
    """
    p_x, p_y, p_th, p_v = grad
    u1_lo, u2_lo, u1_hi, u2_hi = bounds
    drift = p_x * speed * xp.cos(heading) + p_y * speed * xp.sin(heading)
    steer = xp.maximum(p_th * u1_lo, p_th * u1_hi)
    accel = xp.maximum(
        p_v * acceleration_with_stop(speed, u2_lo, xp),
        p_v * acceleration_with_stop(speed, u2_hi, xp),
    )
    return drift + steer + accel


def heading_interval(params: Array, t: Array, horizon: float = HORIZON_S) -> tuple[Array, Array]:
    """Exact range of the heading change over [0, t]: integrals of the interpolated u1 bounds.

    theta' = u1 does not depend on the state, so these are exact (up to the initial margin).
    """
    lo_s, lo_e = params[..., COL["u1_min_start"]], params[..., COL["u1_min_end"]]
    hi_s, hi_e = params[..., COL["u1_max_start"]], params[..., COL["u1_max_end"]]
    quad = t * t / (2.0 * horizon)
    return lo_s * t + (lo_e - lo_s) * quad, hi_s * t + (hi_e - hi_s) * quad


def speed_change_interval(
    params: Array, t: Array, horizon: float = HORIZON_S
) -> tuple[Array, Array]:
    """Integrals of the interpolated u2 bounds over [0, t] (speed change before the stop rule)."""
    lo_s, lo_e = params[..., COL["u2_min_start"]], params[..., COL["u2_min_end"]]
    hi_s, hi_e = params[..., COL["u2_max_start"]], params[..., COL["u2_max_end"]]
    quad = t * t / (2.0 * horizon)
    return lo_s * t + (lo_e - lo_s) * quad, hi_s * t + (hi_e - hi_s) * quad
