"""A cheap guaranteed outer bound of the reachable set, by interval propagation of the dynamics.

theta' = u1 does not depend on the state, so the heading interval is exact: [int u1_lo, int u1_hi]
widened by the initial margin. The speed obeys a scalar ODE that is monotone in u2 (comparison
principle), so the stop-rule integrations of u2_lo and u2_hi bound it from below and above. The
position derivative (v cos th, v sin th) is then bounded by interval arithmetic over each
sub-interval and integrated outward, starting from the box around the initial disc; a disc of radius
r + int v_max bounds it too. Every rounding goes outward: whatever the controls, the state stays in.

Used as the outer half of the ground-truth sandwich (models/evaluate.py) and as the service's
conservative fallback (``reach.sets.BoxTubeSet``), whose sweep boxes :func:`outer_boxes` gives for
many settings at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from reach.contract import HORIZON_S, INITIAL_SET, InitialSet
from reach.polygons import half_plane_polygon, half_plane_polygons
from reach.sweep_boxes import sweep_boxes


def _lerp(start: float, end: float, tau: np.ndarray, horizon: float) -> np.ndarray:
    return start + (end - start) * tau / horizon


def _integral(start: float, end: float, tau: np.ndarray, horizon: float) -> np.ndarray:
    return start * tau + (end - start) * tau * tau / (2.0 * horizon)


def cos_range(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact range of cos over each interval [lo, hi]."""
    cos_lo, cos_hi = np.cos(lo), np.cos(hi)
    c_lo = np.minimum(cos_lo, cos_hi)
    c_hi = np.maximum(cos_lo, cos_hi)
    has_max = np.floor(hi / (2 * math.pi)) >= np.ceil(lo / (2 * math.pi))
    has_min = np.floor((hi - math.pi) / (2 * math.pi)) >= np.ceil((lo - math.pi) / (2 * math.pi))
    return np.where(has_min, -1.0, c_lo), np.where(has_max, 1.0, c_hi)


def cos_max_towards(lo: np.ndarray, hi: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """max over theta in [lo, hi] of cos(theta - phi_m), for intervals [...] and directions [M]:
    [..., M]. 1 where the interval holds phi_m + 2 pi k, else the larger end; the ends' cosines
    by the angle-addition formula (the transcendental functions on the intervals only, not on every
    interval-direction pair as ``cos_range(lo - phi, hi - phi)`` computes them)."""
    lo, hi = np.asarray(lo, dtype=float)[..., None], np.asarray(hi, dtype=float)[..., None]
    c, s = np.cos(directions), np.sin(directions)
    ends = np.maximum(np.cos(lo) * c + np.sin(lo) * s, np.cos(hi) * c + np.sin(hi) * s)
    holds = np.mod(directions - lo, 2 * math.pi) <= hi - lo
    return np.where(holds, 1.0, ends)


def sin_range(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact range of sin over each interval [lo, hi] (sin x = cos(x - pi/2))."""
    return cos_range(lo - math.pi / 2, hi - math.pi / 2)


def _interval_product(
    a_lo: np.ndarray, a_hi: np.ndarray, b_lo: np.ndarray, b_hi: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    p, q, r, s = a_lo * b_lo, a_lo * b_hi, a_hi * b_lo, a_hi * b_hi
    return np.minimum(np.minimum(p, q), np.minimum(r, s)), np.maximum(
        np.maximum(p, q), np.maximum(r, s)
    )


SUPPORT_DIRECTIONS = 16


def box_scale(box: np.ndarray) -> np.ndarray:
    """Size of a reachable set for calibration: sqrt of the area of its outer box(es) [..., 4]
    (x_lo, x_hi, y_lo, y_hi). The distilled projection's errors grow with the set; its level is
    calibrated per unit of this scale (models/projection.py) and applied so by the engine."""
    box = np.asarray(box, dtype=float)
    return np.sqrt((box[..., 1] - box[..., 0]) * (box[..., 3] - box[..., 2]))


def stop_rule_integral(v0: np.ndarray, increments: np.ndarray) -> np.ndarray:
    """Per row (v0 [B, 1], increments [B, n]): v[i+1] = max(v[i] + increments[i], 0), vectorised
    (Lindley's recursion): v[n] = S[n] - min(-v0, min_{k<=n} S[k]) with S the cumulative sum of
    the increments."""
    zero = np.zeros((len(increments), 1))
    cumulative = np.concatenate([zero, np.cumsum(increments, axis=1)], axis=1)
    return cumulative - np.minimum(-v0, np.minimum.accumulate(cumulative, axis=1))


@dataclass(frozen=True)
class OuterBound:
    """Boxes (human frame) that contain every reachable position.

    ``times`` has n + 1 entries; ``box_at[k]`` = (x_lo, x_hi, y_lo, y_hi) at ``times[k]``;
    ``sweep[k]`` contains every position during [times[k], times[k + 1]]; ``radius[k]`` bounds the
    distance from the origin at ``times[k]``.
    """

    times: np.ndarray
    box_at: np.ndarray  # [n + 1, 4]
    sweep: np.ndarray  # [n, 4]
    radius: np.ndarray  # [n + 1]
    heading: np.ndarray  # [n + 1, 2]
    speed: np.ndarray  # [n + 1, 2]
    directions: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [M] angles
    sweep_support: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # [n, M]
    support_at: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # [n + 1, M]
    sweep_speed_max: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [n]

    def polygons_at(self, rows: np.ndarray | list[int]) -> list[np.ndarray]:
        """Convex polygons containing every position reachable at exactly ``times[k]``, k in rows."""
        return half_plane_polygons(self.directions, self.support_at[np.asarray(rows, dtype=int)])

    def sweep_polygon(self, k: int) -> np.ndarray:
        """Vertices of a convex polygon containing every position during sweep k (⊆ its box)."""
        return half_plane_polygon(self.directions, self.sweep_support[k])

    def sweep_polygons(self) -> list[np.ndarray]:
        """sweep_polygon(k) for every sweep, computed together."""
        return half_plane_polygons(self.directions, self.sweep_support)

    def nearest_row(self, t: float) -> int:
        """Index k of the instant ``times[k]`` nearest to t (of ``box_at``, ``support_at``, ...)."""
        return int(np.argmin(np.abs(self.times - t)))

    def slice_index(self, t: float) -> int:
        """Index k of the sub-interval [times[k], times[k+1]] that contains t (clipped)."""
        k = int(np.searchsorted(self.times, t, side="right")) - 1
        return min(max(k, 0), len(self.sweep) - 1)

    def box_containing_slice(self, t: float) -> np.ndarray:
        """A box that contains every position reachable at exactly time t."""
        return self.sweep[self.slice_index(t)]

    def sweeps_until(self, t: float) -> np.ndarray:
        """Boxes whose union contains every position reachable at some time in [0, t]."""
        return self.sweep[: self.slice_index(t) + 1]


@dataclass(frozen=True)
class _Propagation:
    """The interval propagation of ``B`` settings on the fine grid (``fine``, F points, spacing
    ``h``): heading and speed bounds at the points [B, F], over each fine step [B, F - 1], and the
    position box at the points [B, F]."""

    fine: np.ndarray
    h: float
    theta: tuple[np.ndarray, np.ndarray]
    v: tuple[np.ndarray, np.ndarray]
    th: tuple[np.ndarray, np.ndarray]
    sp: tuple[np.ndarray, np.ndarray]
    x: tuple[np.ndarray, np.ndarray]
    y: tuple[np.ndarray, np.ndarray]


def _integrated(rate: np.ndarray, at0: np.ndarray, h: float) -> np.ndarray:
    """``at0`` [B, 1] followed by ``at0`` plus the running sum of ``rate * h`` [B, F - 1]."""
    return np.concatenate([at0, at0 + np.cumsum(rate * h, axis=1)], axis=1)


def _propagate(
    v_start: np.ndarray, bounds: np.ndarray, horizon: float, n_fine: int, m: InitialSet
) -> _Propagation:
    """The propagation of each row (v_start [B], bounds [B, 8] in contract order) over
    ``n_fine`` fine steps of [0, horizon], on arrays [B, F]; ``reach.sweep_boxes`` does the same
    operations step by step for the sweep boxes."""
    col = [bounds[:, k : k + 1] for k in range(8)]  # [B, 1] each
    u1_lo_s, u2_lo_s, u1_lo_e, u2_lo_e, u1_hi_s, u2_hi_s, u1_hi_e, u2_hi_e = col
    fine = np.linspace(0.0, horizon, n_fine + 1)
    h = horizon / n_fine
    v0 = v_start[:, None]

    theta_lo = _integral(u1_lo_s, u1_lo_e, fine, horizon) - m.heading_margin_rad
    theta_hi = _integral(u1_hi_s, u1_hi_e, fine, horizon) + m.heading_margin_rad

    # Speed: Euler with the extreme acceleration over each fine step, clamped at zero (stop rule).
    a_lo = _lerp(u2_lo_s, u2_lo_e, fine, horizon)
    a_hi = _lerp(u2_hi_s, u2_hi_e, fine, horizon)
    step_lo = np.minimum(a_lo[:, :-1], a_lo[:, 1:]) * h
    step_hi = np.maximum(a_hi[:, :-1], a_hi[:, 1:]) * h
    v_lo = stop_rule_integral(np.maximum(v0 - m.speed_margin_mps, 0.0), step_lo)
    v_hi = stop_rule_integral(v0 + m.speed_margin_mps, step_hi)

    # Over each fine step: heading in the hull of both ends (theta bounds are quadratics: pad by
    # the largest possible bulge |u1 change| h^2 / 8), speed in [min v_lo, max v_hi].
    bulge = (np.abs(u1_lo_e - u1_lo_s) + np.abs(u1_hi_e - u1_hi_s)) / horizon * h * h / 8 + 1e-12
    th_lo = np.minimum(theta_lo[:, :-1], theta_lo[:, 1:]) - bulge
    th_hi = np.maximum(theta_hi[:, :-1], theta_hi[:, 1:]) + bulge
    sp_lo = np.minimum(v_lo[:, :-1], v_lo[:, 1:])
    sp_hi = np.maximum(v_hi[:, :-1], v_hi[:, 1:])
    c_lo, c_hi = cos_range(th_lo, th_hi)
    s_lo, s_hi = sin_range(th_lo, th_hi)
    vx_lo, vx_hi = _interval_product(sp_lo, sp_hi, c_lo, c_hi)
    vy_lo, vy_hi = _interval_product(sp_lo, sp_hi, s_lo, s_hi)

    r = np.full((len(bounds), 1), m.radius_m)
    return _Propagation(
        fine=fine,
        h=h,
        theta=(theta_lo, theta_hi),
        v=(v_lo, v_hi),
        th=(th_lo, th_hi),
        sp=(sp_lo, sp_hi),
        x=(_integrated(vx_lo, -r, h), _integrated(vx_hi, r, h)),
        y=(_integrated(vy_lo, -r, h), _integrated(vy_hi, r, h)),
    )


def outer_boxes(
    v_start: np.ndarray,
    bounds: np.ndarray,
    horizon: float = HORIZON_S,
    steps: int = 60,
    substeps: int = 8,
    initial_set: InitialSet = INITIAL_SET,
) -> np.ndarray:
    """The sweep boxes (:attr:`OuterBound.sweep`) of each row of ``v_start`` [B] and ``bounds``
    [B, 8], [B, steps, 4]: the box of every position during each sweep, the fine points' boxes
    of the propagation reduced over the sweep's substeps and its end point; compiled
    (``reach.sweep_boxes``: the propagation's operations step by step, bit for bit)."""
    v = np.asarray(v_start, dtype=np.float64).reshape(-1)
    b = np.asarray(bounds, dtype=np.float64).reshape(len(v), 8)
    m = initial_set
    margins = (m.heading_margin_rad, m.speed_margin_mps, m.radius_m)
    return sweep_boxes(v, b, horizon, steps, substeps, margins)


def outer_bound(
    v_start: float,
    bounds: np.ndarray,
    horizon: float = HORIZON_S,
    steps: int = 60,
    substeps: int = 8,
    initial_set: InitialSet = INITIAL_SET,
    support_directions: int = SUPPORT_DIRECTIONS,
) -> OuterBound:
    """Interval propagation over ``steps`` sub-intervals of [0, horizon].

    ``bounds`` are the 8 bound columns in contract order (reach.contract.BOUND_COLUMNS).
    ``support_directions=0`` skips the support functions (boxes only: the service's conservative
    set needs nothing else, and the directions are two thirds of the work).
    """
    v = np.array([float(v_start)])
    p = _propagate(
        v, np.asarray(bounds, float).reshape(1, 8), horizon, steps * substeps, initial_set
    )
    th_lo, th_hi = p.th[0][0], p.th[1][0]
    sp_lo, sp_hi = p.sp[0][0], p.sp[1][0]
    v_hi = p.v[1][0]
    r = initial_set.radius_m
    radius = _integrated(p.sp[1], np.full((1, 1), r), p.h)[0]

    # Support functions in M directions: h(phi) bounds p . (cos phi, sin phi) by the same interval
    # arithmetic as the box (which is the special case of the four axis directions).
    directions = np.arange(support_directions) * (2 * math.pi / max(support_directions, 1))
    support = np.full((len(p.fine), len(directions)), r)
    if support_directions:
        c_hi = cos_max_towards(th_lo, th_hi, directions)
        rate = np.where(c_hi >= 0, sp_hi[:, None] * c_hi, sp_lo[:, None] * c_hi)
        support[1:] += np.cumsum(rate * p.h, axis=0)

    idx = np.arange(0, steps + 1) * substeps
    box_at = np.stack([p.x[0][0, idx], p.x[1][0, idx], p.y[0][0, idx], p.y[1][0, idx]], axis=1)
    sweep_support = np.maximum(
        support[:-1].reshape(steps, substeps, -1).max(axis=1), support[idx[1:]]
    )
    # The speed bound is piecewise linear between fine nodes: its maximum over a sweep is at a node.
    sweep_speed_max = np.maximum(v_hi[:-1].reshape(steps, substeps).max(axis=1), v_hi[idx[1:]])
    return OuterBound(
        times=p.fine[idx],
        box_at=box_at,
        sweep=outer_boxes(v, bounds, horizon, steps, substeps, initial_set)[0],
        radius=radius[idx],
        heading=np.stack([p.theta[0][0, idx], p.theta[1][0, idx]], axis=1),
        speed=np.stack([p.v[0][0, idx], v_hi[idx]], axis=1),
        directions=directions,
        sweep_support=sweep_support,
        support_at=support[idx],
        sweep_speed_max=sweep_speed_max,
    )
