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
#: Rows of bounds whose rollouts' positions are kept (each ~16 kB): the latest 32-mode settings
#: of 32 agents.
CACHED_ROWS = 1024
#: Recorded positions per segment of a rollout that :func:`first_witnessed` bounds by a box.
SEGMENT = 8


@dataclass(frozen=True)
class Witnesses:
    """Positions ``xy`` [K, N, 2] (human frame) of K rollouts at the times ``times`` [N]."""

    times: np.ndarray
    xy: np.ndarray


def witnesses(v_start: float, bounds: np.ndarray, horizon: float = HORIZON_S) -> Witnesses:
    """The rollouts of each row of ``bounds`` ([8] or [M, 8], contract order) from speed
    ``v_start``, each row's kept for the latest :data:`CACHED_ROWS` rows."""
    rows = np.ascontiguousarray(bounds, dtype=np.float64).reshape(-1, 8)
    found = [_cached(float(v_start), row.tobytes(), float(horizon)) for row in rows]
    if len(found) == 1:
        return found[0]
    xy = np.concatenate([w.xy for w in found])
    xy.flags.writeable = False
    return Witnesses(found[0].times, xy)


@lru_cache(maxsize=CACHED_ROWS)
def _cached(v_start: float, row: bytes, horizon: float) -> Witnesses:
    bounds = np.frombuffer(row, dtype=np.float64)
    times = np.linspace(0.0, horizon, round(horizon / STEP_S) + 1)
    recorded = _rollouts(v_start, bounds, times)[:, ::RECORD_EVERY]
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


def first_witnessed(
    found: Witnesses, xy_human: np.ndarray, until: np.ndarray | None, radius: float
) -> int:
    """The first point (human frame, [P, 2]) that :func:`witnessed` holds witnessed, -1 if none:
    the same test, stopped at the first point it holds. Each rollout's positions are bounded by a
    box, and each :data:`SEGMENT` of them by one; a rollout or a segment whose box lies at least
    the reach from a point (the squared distance to the box is at most any of its positions':
    floating-point subtraction and sums of squares are monotone) holds no witness of it and is
    not searched."""
    xy = np.ascontiguousarray(xy_human, dtype=np.float64).reshape(-1, 2)
    limit = np.full(len(xy), np.inf) if until is None else np.asarray(until, dtype=np.float64)
    reach = radius - POSITION_ERROR_M
    if reach <= 0.0 or not len(xy):
        return -1
    return int(
        _first_witnessed(found.times, found.xy, xy, np.ascontiguousarray(limit), reach * reach)
    )


def compile_witness_kernel() -> None:
    """Compile (or load from numba's cache) the kernel checks search with
    (:func:`first_witnessed`) before a check needs it, for positions as :func:`witnesses` keeps
    them (read-only)."""
    xy = np.zeros((1, 2, 2))
    xy.flags.writeable = False
    first_witnessed(Witnesses(np.zeros(2), xy), np.zeros((1, 2)), None, 1.0)


@numba.njit(cache=True, nogil=True)
def _segment_boxes(xy):  # type: ignore[no-untyped-def]
    """Per rollout, the box of its positions (``[K, 0]``) and of each segment of
    :data:`SEGMENT` of them (``[K, 1 + g]``), as (x_lo, x_hi, y_lo, y_hi)."""
    rollouts, n = xy.shape[0], xy.shape[1]
    boxes = np.empty((rollouts, 1 + (n + SEGMENT - 1) // SEGMENT, 4))
    for k in range(rollouts):
        for g in range(boxes.shape[1]):
            start, end = (0, n) if g == 0 else ((g - 1) * SEGMENT, min(g * SEGMENT, n))
            boxes[k, g, 0] = xy[k, start:end, 0].min()
            boxes[k, g, 1] = xy[k, start:end, 0].max()
            boxes[k, g, 2] = xy[k, start:end, 1].min()
            boxes[k, g, 3] = xy[k, start:end, 1].max()
    return boxes


@numba.njit(cache=True, nogil=True, inline="always")
def _box_distance2(box, px, py):  # type: ignore[no-untyped-def]
    """The squared distance from a point to a box (0 inside)."""
    bx = max(box[0] - px, px - box[1], 0.0)
    by = max(box[2] - py, py - box[3], 0.0)
    return bx * bx + by * by


@numba.njit(cache=True, nogil=True)
def _first_witnessed(times, xy, points, until, reach2):  # type: ignore[no-untyped-def]
    """:func:`first_witnessed`: per point, rollout and segment, the boxes first."""
    boxes = _segment_boxes(xy)
    for p in range(len(points)):
        px, py = points[p, 0], points[p, 1]
        for k in range(xy.shape[0]):
            if _box_distance2(boxes[k, 0], px, py) >= reach2:
                continue
            for g in range(1, boxes.shape[1]):
                start = (g - 1) * SEGMENT
                if times[start] > until[p]:
                    break
                if _box_distance2(boxes[k, g], px, py) >= reach2:
                    continue
                for n in range(start, min(start + SEGMENT, len(times))):
                    if times[n] > until[p]:
                        break
                    dx = px - xy[k, n, 0]
                    dy = py - xy[k, n, 1]
                    if dx * dx + dy * dy < reach2:
                        return p
    return -1


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
