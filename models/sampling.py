"""Sampling of FRT parameters and of training points (numpy, seeded).

One parameter distribution serves training, calibration and evaluation: v_start, and for each
control a start and an end interval inside the hard limits, narrow (high confidence) to full width
(low confidence), with constant, independent, shrinking and growing bounds over the horizon.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.rollout import (
    rk4_rollout,
    sample_control_schedules,
    sample_initial_states,
    sample_reference_schedules,
)
from reach.contract import COL, HORIZON_S, N_INPUTS, U1_LIMIT, U2_LIMIT, V_START_MAX
from reach.dynamics import initial_set_value


def _interval(n: int, limit: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    centred = rng.uniform(0, 1, n) < 0.6
    center = np.where(centred, rng.normal(0, 0.15 * limit, n), rng.uniform(-limit, limit, n))
    half = limit * 10 ** rng.uniform(-2.3, 0.0, n)
    full = rng.uniform(0, 1, n) < 0.1
    lo = np.where(full, -limit, np.clip(center - half, -limit, limit))
    hi = np.where(full, limit, np.clip(center + half, -limit, limit))
    return lo, hi


def _start_end(n: int, limit: float, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """(lo_start, lo_end, hi_start, hi_end) with constant, independent, shrinking, growing pairs."""
    lo_s, hi_s = _interval(n, limit, rng)
    lo_i, hi_i = _interval(n, limit, rng)
    mode = rng.uniform(0, 1, n)
    center, half = 0.5 * (lo_s + hi_s), 0.5 * (hi_s - lo_s)
    factor = rng.uniform(0.05, 0.5, n)
    lo_shrink, hi_shrink = center - factor * half, center + factor * half
    lo_e = np.select([mode < 0.35, mode < 0.6, mode < 0.8], [lo_s, lo_i, lo_shrink], lo_s)
    hi_e = np.select([mode < 0.35, mode < 0.6, mode < 0.8], [hi_s, hi_i, hi_shrink], hi_s)
    grow = mode >= 0.8  # growing: the narrow pair is the start
    lo_s, lo_e = np.where(grow, lo_shrink, lo_s), np.where(grow, lo_s, lo_e)
    hi_s, hi_e = np.where(grow, hi_shrink, hi_s), np.where(grow, hi_s, hi_e)
    return lo_s, lo_e, hi_s, hi_e


def sample_parameters(n: int, rng: np.random.Generator) -> np.ndarray:
    """[n, 14] rows with v_start and the eight bound columns set (t and the state are zero)."""
    x = np.zeros((n, N_INPUTS))
    slow = rng.uniform(0, 1, n) < 0.15
    x[:, COL["v_start"]] = np.where(slow, rng.uniform(0, 1, n), rng.uniform(0, V_START_MAX, n))
    for dim, limit in (("u1", U1_LIMIT), ("u2", U2_LIMIT)):
        lo_s, lo_e, hi_s, hi_e = _start_end(n, limit, rng)
        x[:, COL[f"{dim}_min_start"]] = lo_s
        x[:, COL[f"{dim}_min_end"]] = lo_e
        x[:, COL[f"{dim}_max_start"]] = hi_s
        x[:, COL[f"{dim}_max_end"]] = hi_e
    return x


def _corner_interval(n: int, limit: float, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """Intervals at the edges of [-limit, limit]: full width, hard at one end, or wide."""
    mode = rng.uniform(0, 1, n)
    edge = rng.uniform(0.5, 1.0, n) * limit
    lo, hi = np.full(n, -limit), np.full(n, limit)  # full width: 40 %
    hard_high = (mode >= 0.4) & (mode < 0.6)  # [edge, limit]: 20 %
    lo[hard_high] = edge[hard_high]
    hard_low = (mode >= 0.6) & (mode < 0.8)  # [-limit, -edge]: 20 %
    hi[hard_low] = -edge[hard_low]
    wide = mode >= 0.8  # [< 0, > 0]: 20 %
    lo[wide] = rng.uniform(-limit, 0.0, int(wide.sum()))
    hi[wide] = rng.uniform(0.0, limit, int(wide.sum()))
    return lo, hi


def sample_corner_parameters(n: int, rng: np.random.Generator) -> np.ndarray:
    """[n, 14] settings near the corners of the ranges, where V's calibration tail sits: fast
    starts (v_start in [0.6, 1] V_START_MAX) with bounds at full width, hard at one end or wide;
    constant over the horizon for 60 %, else with an end interval drawn on its own."""
    x = np.zeros((n, N_INPUTS))
    x[:, COL["v_start"]] = rng.uniform(0.6 * V_START_MAX, V_START_MAX, n)
    for dim, limit in (("u1", U1_LIMIT), ("u2", U2_LIMIT)):
        lo_s, hi_s = _corner_interval(n, limit, rng)
        lo_e, hi_e = _corner_interval(n, limit, rng)
        constant = rng.uniform(0, 1, n) < 0.6
        x[:, COL[f"{dim}_min_start"]] = lo_s
        x[:, COL[f"{dim}_max_start"]] = hi_s
        x[:, COL[f"{dim}_min_end"]] = np.where(constant, lo_s, lo_e)
        x[:, COL[f"{dim}_max_end"]] = np.where(constant, hi_s, hi_e)
    return x


def sample_restart_parameters(n: int, rng: np.random.Generator) -> np.ndarray:
    """[n, 14] settings whose acceleration bounds go from braking to accelerating over the horizon
    (the car stops, waits at v = 0 while the bound is negative, then drives off: the stop rule's
    regime, where V's calibration maximum sits), from slow starts mostly; steering as usual."""
    x = sample_parameters(n, rng)
    slow = rng.uniform(0, 1, n) < 0.6
    x[:, COL["v_start"]] = np.where(
        slow, rng.uniform(0.0, 3.0, n), rng.uniform(0.0, V_START_MAX, n)
    )
    width = U2_LIMIT * 10 ** rng.uniform(-2.3, -0.5, n)
    start_mid = -rng.uniform(0.5, 1.0, n) * (U2_LIMIT - width)
    end_mid = rng.uniform(0.2, 1.0, n) * (U2_LIMIT - width)
    x[:, COL["u2_min_start"]] = start_mid - width / 2
    x[:, COL["u2_max_start"]] = start_mid + width / 2
    x[:, COL["u2_min_end"]] = end_mid - width / 2
    x[:, COL["u2_max_end"]] = end_mid + width / 2
    return x


def set_state(x: np.ndarray, t: np.ndarray, state: tuple[np.ndarray, ...]) -> np.ndarray:
    """Copy of ``x`` with the time and state columns replaced."""
    out = x.copy()
    out[:, COL["t"]] = t
    for name, value in zip(("px", "py", "heading", "speed"), state, strict=True):
        out[:, COL[name]] = value
    return out


@dataclass
class TrainingBatch:
    """Points for the PDE residual, plus rollout endpoints with their upper bound on V."""

    pde_points: np.ndarray  # [N, 14]
    rollout_points: np.ndarray  # [M, 14]
    rollout_upper_bound: np.ndarray  # [M]: V(t, xi(t)) <= l(xi(0))


def sample_training_batch(
    n_params: int,
    points_per_param: int,
    t_max: float,
    rng: np.random.Generator,
    rollout_steps: int = 24,
    horizon: float = HORIZON_S,
    extremal_share: float = 0.0,
    corner_share: float = 0.0,
    restart_share: float = 0.0,
) -> TrainingBatch:
    """A batch: rollout endpoints (exact reachable states), multi-scale perturbations of them, and
    uniform points over the region any in-range car can reach.

    With ``extremal_share`` > 0 that share of the rollouts follows the Pontryagin-shaped schedules
    of the evaluation and the calibration (``sample_reference_schedules``: turn hard, then drive
    straight), so that the upper bound V <= l(start) also holds V down on the front of the set,
    which switching between the bounds almost never reaches. 0 draws the original mix.
    ``corner_share`` of the parameter settings come from ``sample_corner_parameters``, the next
    ``restart_share`` from ``sample_restart_parameters``."""
    settings = sample_parameters(n_params, rng)
    k = round(n_params * corner_share) if corner_share > 0 else 0
    if k:
        settings[:k] = sample_corner_parameters(k, rng)
    r = round(n_params * restart_share) if restart_share > 0 else 0
    if r:
        settings[k : k + r] = sample_restart_parameters(r, rng)
    params = np.repeat(settings, points_per_param, axis=0)
    n = params.shape[0]
    t = rng.uniform(0, t_max, n)
    v_start = params[:, COL["v_start"]]

    start = sample_initial_states(v_start, rng, spread=2.0)
    if extremal_share > 0:
        a1, a2, switches = sample_reference_schedules(n, horizon, rng, extremal_share)
    else:
        a1, a2, switches = sample_control_schedules(n, horizon, rng)
    switches = switches * (t / horizon)[:, None]
    end, _ = rk4_rollout(start, params, t, a1, a2, switches, rollout_steps)
    rollout_points = set_state(params, t, end)
    upper = initial_set_value(*start, v_start)

    log_uniform = 10 ** rng.uniform(-1.3, 0.7, n)
    px = end[0] + rng.normal(0, 1, n) * log_uniform
    py = end[1] + rng.normal(0, 1, n) * log_uniform
    heading = end[2] + rng.normal(0, 1, n) * 10 ** rng.uniform(-2.3, -0.3, n)
    speed = np.clip(end[3] + rng.normal(0, 1, n) * 10 ** rng.uniform(-1.7, 0.3, n), 0.0, None)
    speed[rng.uniform(0, 1, n) < 0.05] = 0.0
    perturbed = set_state(params, t, (px, py, heading, speed))

    k = max(n // 8, 1)
    reach = 1.0 + (v_start[:k] + 10.0 * t[:k]) * t[:k]
    uniform = set_state(
        params[:k],
        t[:k],
        (
            rng.uniform(-1, 1, k) * reach,
            rng.uniform(-1, 1, k) * reach,
            rng.uniform(-np.pi, np.pi, k),
            rng.uniform(0, 1, k) * (v_start[:k] + 10.0 * t[:k] + 1.0),
        ),
    )
    return TrainingBatch(
        pde_points=np.concatenate([rollout_points, perturbed, uniform]),
        rollout_points=rollout_points,
        rollout_upper_bound=upper,
    )
