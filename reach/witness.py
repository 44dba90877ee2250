"""Witnesses of a collision: positions the human reaches, which every exact set contains.

An exact set K contains every position the human reaches from its initial set under controls
within the bounds (the certified geometry's promise, tested against independent rollouts). A
position reached at time tau lies in every tube from tau on, so a check point within R_col of one
reached no later than the point's time is in C whatever K is drawn: a conservative "collision"
is then the exact set's verdict too.

The witnesses are rollouts of the extended unicycle (``reach.dynamics``) from the nominal state
(the origin of the human frame, heading 0, speed v_start), each under controls at fixed places in
the interpolated bounds, ``u_i(tau) = lo_i(tau) + f_i (hi_i(tau) - lo_i(tau))`` for every pair of
:data:`FRACTIONS` (within the bounds at every instant). The heading is integrated exactly
(theta' = u1 is linear in tau), the speed too up to the stop rule (v' = u2 while moving: the
reflection at 0 of ``X(tau) = v_start + int u2``, ``reach.outer_bound.stop_rule_integral``, its
minimum taken on the steps), and the position by the trapezoidal rule on :data:`STEP_S` steps;
:data:`POSITION_ERROR_M` bounds how far a recorded position may lie from the true one, and a
witness must be that much nearer than R_col.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np

from reach.contract import COL, HORIZON_S
from reach.dynamics import interpolate_bounds, unicycle_derivative
from reach.outer_bound import stop_rule_integral

#: Places of each control in its interval (0: the lower bound, 1: the upper one).
FRACTIONS = (0.0, 0.5, 1.0)
#: The integration step (s).
STEP_S = 0.01
#: Steps between recorded positions (a recorded position is a step's, not an interpolation).
RECORD_EVERY = 3
#: A bound of a recorded position's error: the trapezoidal rule's (T / 12) STEP_S^2 max|f''| per
#: coordinate of f = (v cos theta, v sin theta), |f''| <= |u2'| + 2 |u2| |u1| + v (|u1'| + u1^2):
#: at most 8 mm a coordinate (11 mm apart) for every class's limits at the speeds it is served at
#: (a car at 20 m/s turning and accelerating at its limits), plus the speed's minimum taken on the
#: steps (under 0.1 mm of position), with a margin.
POSITION_ERROR_M = 0.02
#: Rollouts' positions kept for the latest settings (each ~16 kB a row of bounds).
CACHED_SETTINGS = 256


@dataclass(frozen=True)
class Witnesses:
    """Positions ``xy`` [K, N, 2] (human frame) of K rollouts at the times ``times`` [N]."""

    times: np.ndarray
    xy: np.ndarray


def witnesses(v_start: float, bounds: np.ndarray, horizon: float = HORIZON_S) -> Witnesses:
    """The rollouts of each row of ``bounds`` ([8] or [M, 8], contract order) from speed
    ``v_start``, kept for the latest :data:`CACHED_SETTINGS` settings."""
    rows = np.ascontiguousarray(bounds, dtype=np.float64).reshape(-1, 8)
    return _cached(float(v_start), rows.tobytes(), float(horizon))


@lru_cache(maxsize=CACHED_SETTINGS)
def _cached(v_start: float, rows: bytes, horizon: float) -> Witnesses:
    bounds = np.frombuffer(rows, dtype=np.float64).reshape(-1, 8)
    times = np.linspace(0.0, horizon, round(horizon / STEP_S) + 1)
    xy = np.concatenate([_rollouts(v_start, row, times) for row in bounds])
    recorded = xy[:, ::RECORD_EVERY]
    recorded.flags.writeable = False
    return Witnesses(times[::RECORD_EVERY].copy(), recorded)


def _rollouts(v_start: float, row: np.ndarray, times: np.ndarray) -> np.ndarray:
    """[K, N, 2] positions of one row's rollouts at ``times``."""
    params = np.zeros(len(COL))
    params[6:] = row
    lo1, lo2, hi1, hi2 = interpolate_bounds(params, times, float(times[-1]))
    f1, f2 = (np.array(f)[:, None] for f in zip(*_pairs(), strict=True))
    u1 = lo1 + f1 * (hi1 - lo1)  # [K, N]
    u2 = lo2 + f2 * (hi2 - lo2)
    heading = _integral(u1, times)
    speed = stop_rule_integral(np.full((len(u2), 1), v_start), _steps(u2, times))
    dx, dy, _, _ = unicycle_derivative(heading, speed, u1, u2)
    return np.stack([_integral(dx, times), _integral(dy, times)], axis=-1)


def _pairs() -> list[tuple[float, float]]:
    return [(a, b) for a in FRACTIONS for b in FRACTIONS]


def _steps(values: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Each step's trapezoidal integral along the last axis."""
    return 0.5 * (values[..., 1:] + values[..., :-1]) * np.diff(times)


def _integral(values: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Cumulative trapezoidal integral along the last axis, from 0."""
    start = np.zeros((*values.shape[:-1], 1))
    return np.concatenate([start, np.cumsum(_steps(values, times), axis=-1)], axis=-1)


def witnessed(
    found: Witnesses, xy_human: np.ndarray, until: np.ndarray | None, radius: float
) -> np.ndarray:
    """Per point (human frame, [P, 2]), whether a witness position reached by ``until[p]``
    seconds (by the horizon: None) lies within ``radius`` less :data:`POSITION_ERROR_M` of it."""
    xy = np.ascontiguousarray(xy_human, dtype=np.float64).reshape(-1, 2)
    limit = np.full(len(xy), np.inf) if until is None else np.asarray(until, dtype=np.float64)
    reach = radius - POSITION_ERROR_M
    out = np.zeros(len(xy), dtype=np.bool_)
    if reach > 0.0:
        _witnessed(found.times, found.xy, xy, np.ascontiguousarray(limit), reach * reach, out)
    return out


def compile_witness_kernel() -> None:
    """Compile (or load from numba's cache) the kernel before a check needs it."""
    found = Witnesses(np.zeros(2), np.zeros((1, 2, 2)))
    witnessed(found, np.zeros((1, 2)), None, 1.0)


@numba.njit(cache=True, nogil=True)
def _witnessed(times, xy, points, until, reach2, out):
    for p in range(len(points)):
        for k in range(xy.shape[0]):
            for n in range(len(times)):
                if times[n] > until[p]:
                    break
                dx = points[p, 0] - xy[k, n, 0]
                dy = points[p, 1] - xy[k, n, 1]
                if dx * dx + dy * dy < reach2:
                    out[p] = True
                    break
            if out[p]:
                break
