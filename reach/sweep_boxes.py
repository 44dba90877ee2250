"""The sweep boxes of the interval outer bound (``reach.outer_bound``), compiled: for each setting
one pass over the fine grid doing, step by step, the operations its propagation does on arrays
(heading and speed bounds, the stop rule, the ranges of cos and sin over each step's heading
interval, the interval products, the position sums), so each box is bit for bit the one the
array propagation gives (``tests/test_box_tubes.py``); no temporary arrays, so a frame's hundred
settings cost a fraction of the array version's passes over [settings, fine points]. It runs
without the GIL: a thread may propagate a frame's settings while the event loop goes on.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_TWO_PI = 2 * math.pi
_HALF_PI = math.pi / 2


@numba.njit(cache=True)
def _cos_bounds(lo: float, hi: float) -> tuple[float, float]:
    """The range of cos over [lo, hi] (``reach.outer_bound.cos_range`` of one interval)."""
    cos_lo, cos_hi = math.cos(lo), math.cos(hi)
    c_lo, c_hi = min(cos_lo, cos_hi), max(cos_lo, cos_hi)
    if math.floor((hi - math.pi) / _TWO_PI) >= math.ceil((lo - math.pi) / _TWO_PI):
        c_lo = -1.0
    if math.floor(hi / _TWO_PI) >= math.ceil(lo / _TWO_PI):
        c_hi = 1.0
    return c_lo, c_hi


@numba.njit(cache=True)
def _product_bounds(a_lo: float, a_hi: float, b_lo: float, b_hi: float) -> tuple[float, float]:
    """The range of a * b over the two intervals."""
    p, q, r, s = a_lo * b_lo, a_lo * b_hi, a_hi * b_lo, a_hi * b_hi
    return min(min(p, q), min(r, s)), max(max(p, q), max(r, s))


@numba.njit(cache=True)
def _row(
    fine: np.ndarray,
    grid: np.ndarray,
    v_start: float,
    u: np.ndarray,
    substeps: int,
    out: np.ndarray,
) -> None:
    """One setting's sweep boxes into ``out`` [steps, 4] (x_lo, x_hi, y_lo, y_hi); ``u`` its
    eight bounds in contract order, ``grid`` (horizon, fine step, the initial set's heading,
    speed and radius margins)."""
    horizon, h, heading, speed, r = grid[0], grid[1], grid[2], grid[3], grid[4]
    bulge = (abs(u[2] - u[0]) + abs(u[6] - u[4])) / horizon * h * h / 8 + 1e-12
    v0_lo, v0_hi = max(v_start - speed, 0.0), v_start + speed
    tau = fine[0]
    theta_lo = u[0] * tau + (u[2] - u[0]) * tau * tau / (2.0 * horizon) - heading
    theta_hi = u[4] * tau + (u[6] - u[4]) * tau * tau / (2.0 * horizon) + heading
    a_lo, a_hi = u[1] + (u[3] - u[1]) * tau / horizon, u[5] + (u[7] - u[5]) * tau / horizon
    s_lo = s_hi = least_lo = least_hi = 0.0  # the stop rule's sums and their running minima
    v_lo, v_hi = 0.0 - min(-v0_lo, 0.0), 0.0 - min(-v0_hi, 0.0)
    x_lo, x_hi, y_lo, y_hi = -r, r, -r, r  # the position box at the fine point
    sx_lo = sx_hi = sy_lo = sy_hi = 0.0  # the sums its sides move by
    for k in range(len(fine) - 1):
        tau = fine[k + 1]
        next_lo = u[0] * tau + (u[2] - u[0]) * tau * tau / (2.0 * horizon) - heading
        next_hi = u[4] * tau + (u[6] - u[4]) * tau * tau / (2.0 * horizon) + heading
        next_a_lo = u[1] + (u[3] - u[1]) * tau / horizon
        next_a_hi = u[5] + (u[7] - u[5]) * tau / horizon
        s_lo, s_hi = s_lo + min(a_lo, next_a_lo) * h, s_hi + max(a_hi, next_a_hi) * h
        least_lo, least_hi = min(least_lo, s_lo), min(least_hi, s_hi)
        next_v_lo, next_v_hi = s_lo - min(-v0_lo, least_lo), s_hi - min(-v0_hi, least_hi)
        th_lo, th_hi = min(theta_lo, next_lo) - bulge, max(theta_hi, next_hi) + bulge
        sp_lo, sp_hi = min(v_lo, next_v_lo), max(v_hi, next_v_hi)
        c_lo, c_hi = _cos_bounds(th_lo, th_hi)
        n_lo, n_hi = _cos_bounds(th_lo - _HALF_PI, th_hi - _HALF_PI)  # sin x = cos(x - pi/2)
        vx_lo, vx_hi = _product_bounds(sp_lo, sp_hi, c_lo, c_hi)
        vy_lo, vy_hi = _product_bounds(sp_lo, sp_hi, n_lo, n_hi)
        sx_lo, sx_hi = sx_lo + vx_lo * h, sx_hi + vx_hi * h
        sy_lo, sy_hi = sy_lo + vy_lo * h, sy_hi + vy_hi * h
        _widen(out[k // substeps], x_lo, x_hi, y_lo, y_hi, k % substeps == 0)
        x_lo, x_hi, y_lo, y_hi = -r + sx_lo, r + sx_hi, -r + sy_lo, r + sy_hi
        if k % substeps == substeps - 1:
            _widen(out[k // substeps], x_lo, x_hi, y_lo, y_hi, False)
        theta_lo, theta_hi, a_lo, a_hi = next_lo, next_hi, next_a_lo, next_a_hi
        v_lo, v_hi = next_v_lo, next_v_hi


@numba.njit(cache=True)
def _widen(
    sweep: np.ndarray, x_lo: float, x_hi: float, y_lo: float, y_hi: float, first: bool
) -> None:
    """The sweep's box made to hold the point's box (or set to it, for its first point)."""
    if first:
        sweep[0], sweep[1], sweep[2], sweep[3] = x_lo, x_hi, y_lo, y_hi
        return
    sweep[0], sweep[1] = min(sweep[0], x_lo), max(sweep[1], x_hi)
    sweep[2], sweep[3] = min(sweep[2], y_lo), max(sweep[3], y_hi)


@numba.njit(cache=True, nogil=True)
def _rows(
    fine: np.ndarray,
    grid: np.ndarray,
    v_start: np.ndarray,
    bounds: np.ndarray,
    substeps: int,
    out: np.ndarray,
) -> None:
    for b in range(len(v_start)):
        _row(fine, grid, v_start[b], bounds[b], substeps, out[b])


def sweep_boxes(
    v_start: np.ndarray,
    bounds: np.ndarray,
    horizon: float,
    steps: int,
    substeps: int,
    margins: tuple[float, float, float],
) -> np.ndarray:
    """The sweep boxes [B, steps, 4] of each setting (v_start [B], bounds [B, 8]) over
    ``steps`` sweeps of ``substeps`` fine steps each on [0, horizon], from the initial set's
    ``margins`` (heading, speed, radius)."""
    n_fine = steps * substeps
    fine = np.linspace(0.0, horizon, n_fine + 1)
    grid = np.array([horizon, horizon / n_fine, *margins], dtype=np.float64)
    out = np.empty((len(v_start), steps, 4))
    v = np.ascontiguousarray(v_start, dtype=np.float64)
    _rows(fine, grid, v, np.ascontiguousarray(bounds, dtype=np.float64), substeps, out)
    return out


def compile_sweep_kernels() -> None:
    """Compile (or load from numba's cache) the kernels before an observation's conservative set
    needs them (a first call takes a few hundred milliseconds)."""
    bounds = np.array([[-0.1, -1.0, -0.1, -1.0, 0.1, 1.0, 0.1, 1.0]])
    sweep_boxes(np.array([5.0]), bounds, 1.0, 2, 2, (0.0, 0.0, 0.0))
