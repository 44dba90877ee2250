"""A sound lower bound on the value function from heading and speed corridors.

V(t, x) > c exactly when no trajectory from the sub-level set {l <= c} of the initial set reaches
x at time t (set semantics, docs/model.md). This module proves that for given states, which gives
training a signal the PDE residual alone conveys slowly: *where the network must be high*.

Why it cuts what the interval outer bound (``reach.outer_bound``) cannot: a state fixes the final
heading theta_f and speed v_f. theta' = u1 and v' = u2 do not depend on the position, so every
trajectory that ends there has, at every s <= t, a heading inside the *corridor*

    [max(-eps_c + U1_lo(s), theta_f - (U1_hi(t) - U1_hi(s))),
     min( eps_c + U1_hi(s), theta_f - (U1_lo(t) - U1_lo(s)))]

(U1_lo, U1_hi the integrals of the interpolated u1 bounds, eps_c the heading margin of {l <= c})
and likewise a speed inside the intersection of the forward stop-rule interval and the backward
one. The position is p(t) = p(0) + integral of v (cos theta, sin theta), so in any direction d its
component is at most r + c + integral of max over the corridors of v cos(theta - phi_d): a convex
polygon *per final heading and speed*. A car that ends heading backwards must have turned while it
moved forwards, so the union over headings has the notch behind the car that no single convex
bound has (docs/model.md, "What it buys").

Every bound is taken outward: corridors are hulls over each sub-interval padded by the largest
bulge of their quadratic ends, the speed's backward lower bound ignores braking, an unwrapped final
heading is tried at every 2 pi shift. States the bound cannot exclude even at c = 0 get -inf.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from reach.contract import COL, HORIZON_S, INITIAL_SET, InitialSet
from reach.dynamics import heading_interval, interpolate_bounds, speed_change_interval
from reach.outer_bound import cos_max_towards

#: Support directions of the per-state position polygon.
DIRECTIONS = np.arange(16) * (2 * math.pi / 16)


def _hull(ends: np.ndarray, pad: np.ndarray, upper: bool) -> np.ndarray:
    """Outward hull over each sub-interval of a function known at its nodes [N, S + 1], with
    curvature padding ``pad`` [N, 1] (a quadratic bulges by at most |f''| h^2 / 8 between nodes)."""
    if upper:
        return np.maximum(ends[:, :-1], ends[:, 1:]) + pad
    return np.minimum(ends[:, :-1], ends[:, 1:]) - pad


def _stop_rule_paths(v0: np.ndarray, increments: np.ndarray) -> np.ndarray:
    """Rows of v[k+1] = max(v[k] + increments[k], 0) from v0 [N] (Lindley's recursion)."""
    cumulative = np.concatenate([np.zeros((len(v0), 1)), np.cumsum(increments, axis=1)], axis=1)
    return cumulative - np.minimum(-v0[:, None], np.minimum.accumulate(cumulative, axis=1))


class _Corridors:
    """The c-independent parts of the corridors of N states on S sub-intervals of [0, t]."""

    def __init__(self, x: np.ndarray, steps: int, horizon: float) -> None:
        t = x[:, COL["t"]].astype(float)
        self.n = len(x)
        self.s = t[:, None] * np.linspace(0.0, 1.0, steps + 1)[None, :]  # [N, S + 1]
        self.h = t / steps  # [N]
        params = x.astype(float)[:, None, :]
        u1_lo_cum, u1_hi_cum = heading_interval(params, self.s, horizon)
        u2_lo_cum, _ = speed_change_interval(params, self.s, horizon)
        self.u1_lo_cum, self.u1_hi_cum = u1_lo_cum, u1_hi_cum
        h2 = (self.h * self.h / 8.0)[:, None]

        def curvature(start: str, end: str) -> np.ndarray:
            """|second derivative| of the integral of the bound interpolated start -> end."""
            return np.abs(x[:, COL[end]] - x[:, COL[start]])[:, None] / horizon

        self.pad_u1_lo = curvature("u1_min_start", "u1_min_end") * h2 + 1e-12
        self.pad_u1_hi = curvature("u1_max_start", "u1_max_end") * h2 + 1e-12
        pad_u2_lo = curvature("u2_min_start", "u2_min_end") * h2 + 1e-12

        _, a_lo, _, a_hi = interpolate_bounds(params, self.s, horizon)
        self.step_lo = np.minimum(a_lo[:, :-1], a_lo[:, 1:]) * self.h[:, None]
        self.step_hi = np.maximum(a_hi[:, :-1], a_hi[:, 1:]) * self.h[:, None]
        self.v_start = x[:, COL["v_start"]].astype(float)

        # Backward speed corridor from a final speed in [v_lo, v_hi]: v(s) <= v_hi - (U2_lo(t) -
        # U2_lo(s)) (braking from v(s) ends no lower than that, the stop rule only raises it) and
        # v(s) >= v_lo - integral over [s, t] of max(u2_hi, 0) (no faster growth is possible).
        # Stored as offsets from the final speed.
        self.brake_after = u2_lo_cum[:, -1:] - u2_lo_cum
        gain = np.maximum(self.step_hi, 0.0)
        self.gain_after = np.concatenate(
            [np.cumsum(gain[:, ::-1], axis=1)[:, ::-1], np.zeros((self.n, 1))], axis=1
        )
        self.pad_u2_lo = pad_u2_lo
        self.position = x[:, [COL["px"], COL["py"]]].astype(float)
        self.final_speed = x[:, COL["speed"]].astype(float)

    def subset(self, rows: np.ndarray) -> _Corridors:
        """The corridors of some of the states."""
        part = object.__new__(_Corridors)
        for name, value in vars(self).items():
            if isinstance(value, tuple):
                value = tuple(v[rows] for v in value)
            elif isinstance(value, np.ndarray) and value.ndim >= 1 and len(value) == self.n:
                value = value[rows]
            setattr(part, name, value)
        part.n = len(rows)
        return part

    def waypoint_envelope(
        self, k: int, w_lo: np.ndarray, w_hi: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Node-wise bounds [N, S + 1] of the heading of every trajectory whose heading at node k
        lies in [w_lo, w_hi] [N]: theta' = u1 bounds it on either side, theta(s) in
        [lo - (U1_hi(s_k) - U1_hi(s)), hi - (U1_lo(s_k) - U1_lo(s))] before s_k and
        [lo + U1_lo(s) - U1_lo(s_k), hi + U1_hi(s) - U1_hi(s_k)] after."""
        nodes = np.arange(self.u1_lo_cum.shape[1])[None, :]
        lo_at, hi_at = self.u1_lo_cum[:, k : k + 1], self.u1_hi_cum[:, k : k + 1]
        before = nodes <= k
        p_lo = np.where(
            before,
            w_lo[:, None] - (hi_at - self.u1_hi_cum),
            w_lo[:, None] + self.u1_lo_cum - lo_at,
        )
        p_hi = np.where(
            before,
            w_hi[:, None] - (lo_at - self.u1_lo_cum),
            w_hi[:, None] + self.u1_hi_cum - hi_at,
        )
        return p_lo, p_hi

    def _end_envelopes(
        self, eps_th: np.ndarray, theta_f: tuple[np.ndarray, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Node-wise heading bounds [N, S + 1] forwards from the initial heading (within
        ``eps_th`` of 0) and backwards from the final one (in ``theta_f``): f_lo, f_hi, b_lo,
        b_hi."""
        f_lo, f_hi = self.u1_lo_cum - eps_th, self.u1_hi_cum + eps_th
        b_lo = theta_f[0][:, None] - (self.u1_hi_cum[:, -1:] - self.u1_hi_cum)
        b_hi = theta_f[1][:, None] - (self.u1_lo_cum[:, -1:] - self.u1_lo_cum)
        return f_lo, f_hi, b_lo, b_hi

    def heading_nodes(
        self,
        eps_th: np.ndarray,
        theta_f: tuple[np.ndarray, np.ndarray],
        waypoints: Sequence[tuple[int, np.ndarray, np.ndarray]] = (),
    ) -> tuple[np.ndarray, np.ndarray]:
        """Node-wise bounds [N, S + 1] of the heading of every trajectory from an initial heading
        within ``eps_th`` [N, 1] of 0 whose final heading lies in ``theta_f`` and whose heading at
        each waypoint lies in its interval (lo > hi somewhere: no such trajectory)."""
        f_lo, f_hi, b_lo, b_hi = self._end_envelopes(eps_th, theta_f)
        lo, hi = np.maximum(f_lo, b_lo), np.minimum(f_hi, b_hi)
        for k, w_lo, w_hi in waypoints:
            p_lo, p_hi = self.waypoint_envelope(k, w_lo, w_hi)
            lo, hi = np.maximum(lo, p_lo), np.minimum(hi, p_hi)
        return lo, hi

    def supports(
        self,
        c: np.ndarray,
        theta_f: tuple[np.ndarray, np.ndarray],
        speed_f: tuple[np.ndarray, np.ndarray],
        initial_set: InitialSet,
        coupled_speed: bool = False,
        directions: np.ndarray = DIRECTIONS,
        waypoints: Sequence[tuple[int, np.ndarray, np.ndarray]] = (),
    ) -> tuple[np.ndarray, np.ndarray]:
        """Support values [N, M] in ``directions`` of a convex polygon that contains every position
        at time t of a trajectory from {l <= c} [N] whose final (unwrapped) heading lies in
        ``theta_f`` = (lo, hi) [N] and final speed in ``speed_f`` = (lo, hi) [N]; and [N] True where
        no such trajectory exists (the corridors are empty somewhere).

        ``waypoints``, each (node k, lo [N], hi [N]): only trajectories whose (unwrapped) heading
        at node k lies in [lo, hi] (``waypoint_envelope`` bounds the heading on either side of
        it). A heading corridor pinned in the middle as well as at its ends: the paths that turn
        early and those that turn late fall in different bins, whose convex polygons no longer
        span the curved wall of the notch between them.

        ``coupled_speed``: the speed along the corridor is a profile with bounded rates
        (``reach.speed_programme``, a linear programme per row and direction, solved together) instead
        of taking either end of its interval at every instant independently.

        A numeric kernel kept whole so its maths reads in one place."""
        m = initial_set
        grow = 1.0 + c / m.radius_m
        eps_th = (m.heading_margin_rad * grow)[:, None]
        eps_v = m.speed_margin_mps * grow

        node_lo, node_hi = self.heading_nodes(eps_th, theta_f, waypoints)
        empty = np.any(node_lo > node_hi + 1e-9, axis=1)
        f_lo, f_hi, b_lo, b_hi = self._end_envelopes(eps_th, theta_f)
        th_lo = np.maximum(
            _hull(f_lo, self.pad_u1_lo, upper=False), _hull(b_lo, self.pad_u1_hi, upper=False)
        )
        th_hi = np.minimum(
            _hull(f_hi, self.pad_u1_hi, upper=True), _hull(b_hi, self.pad_u1_lo, upper=True)
        )
        nodes = np.arange(self.u1_lo_cum.shape[1])[None, :]
        for k, w_lo, w_hi in waypoints:
            p_lo, p_hi = self.waypoint_envelope(k, w_lo, w_hi)
            sub_before = nodes[:, :-1] < k  # sub-interval i spans nodes i and i + 1
            # Before the waypoint p_lo follows U1_hi and p_hi U1_lo; after it the other way round.
            pad_lo = np.where(sub_before, self.pad_u1_hi, self.pad_u1_lo)
            pad_hi = np.where(sub_before, self.pad_u1_lo, self.pad_u1_hi)
            th_lo = np.maximum(th_lo, _hull(p_lo, pad_lo, upper=False))
            th_hi = np.minimum(th_hi, _hull(p_hi, pad_hi, upper=True))

        v_lo_f = _stop_rule_paths(np.maximum(self.v_start - eps_v, 0.0), self.step_lo)
        v_hi_f = _stop_rule_paths(self.v_start + eps_v, self.step_hi)
        back_lo_nodes = speed_f[0][:, None] - self.gain_after
        back_hi_nodes = speed_f[1][:, None] - self.brake_after
        empty |= np.any((v_lo_f > back_hi_nodes + 1e-9) | (back_lo_nodes > v_hi_f + 1e-9), axis=1)
        th_hi = np.maximum(th_hi, th_lo)

        if coupled_speed:
            from reach.speed_programme import corridor_gain

            gain = np.full((self.n, len(directions)), -np.inf)
            live = np.flatnonzero(~empty)
            node_lo = np.maximum(v_lo_f, back_lo_nodes)
            node_hi = np.minimum(v_hi_f, back_hi_nodes)
            gain[live], lp_empty = corridor_gain(
                th_lo[live],
                th_hi[live],
                directions,
                self.h[live],
                node_lo[live] - 1e-9,
                node_hi[live] + 1e-9,
                self.step_lo[live],
                self.step_hi[live],
            )
            empty[live] |= lp_empty
            return m.radius_m + c[:, None] + gain, empty

        sp_lo = np.maximum(
            np.maximum(_hull(v_lo_f, 0.0, upper=False), _hull(back_lo_nodes, 0.0, upper=False)),
            0.0,
        )
        sp_hi = np.minimum(
            _hull(v_hi_f, 0.0, upper=True), _hull(back_hi_nodes, self.pad_u2_lo, upper=True)
        )
        sp_hi = np.maximum(sp_hi, sp_lo)  # an empty sub-interval is caught at the nodes above
        c_hi = cos_max_towards(th_lo, th_hi, directions)
        rate = np.where(c_hi >= 0, sp_hi[:, :, None] * c_hi, sp_lo[:, :, None] * c_hi)
        support = m.radius_m + c[:, None] + rate.sum(axis=1) * self.h[:, None]  # [N, M]
        return support, empty

    def excluded(self, c: np.ndarray, theta_f: np.ndarray, initial_set: InitialSet) -> np.ndarray:
        """True where no trajectory from {l <= c} [N] ends at the states with final (unwrapped)
        heading theta_f [N]."""
        speed = self.final_speed
        support, empty = self.supports(c, (theta_f, theta_f), (speed, speed), initial_set)
        reach = self.position @ np.stack([np.cos(DIRECTIONS), np.sin(DIRECTIONS)])
        return empty | np.any(reach > support + 1e-9, axis=1)


def value_lower_bound(
    x: np.ndarray,
    steps: int = 40,
    iterations: int = 6,
    c_max: float = 8.0,
    horizon: float = HORIZON_S,
    initial_set: InitialSet = INITIAL_SET,
    chunk: int = 4096,
) -> np.ndarray:
    """A proven lower bound on V at the 14-column inputs ``x`` [N, 14]: the largest c found by
    bisection on [0, c_max] (to c_max / 2^iterations) with V > c; -inf where even c = 0 cannot be
    excluded (the state may be reachable)."""
    x = np.asarray(x, dtype=float)
    out = np.empty(len(x))
    for a in range(0, len(x), chunk):
        out[a : a + chunk] = _lower_bound_chunk(
            x[a : a + chunk], steps, iterations, c_max, horizon, initial_set
        )
    return out


def _lower_bound_chunk(
    x: np.ndarray,
    steps: int,
    iterations: int,
    c_max: float,
    horizon: float,
    initial_set: InitialSet,
) -> np.ndarray:
    """Per unwrapped final heading (theta_f + 2 pi k, |k| <= 1 covers every heading change within
    the limits): rows reachable at c = 0 are done (-inf); the others are bisected on c."""
    best = np.full(len(x), np.inf)
    for shift in (0.0, -2 * math.pi, 2 * math.pi):
        rows = np.flatnonzero(best > -np.inf)
        if len(rows) == 0:
            break
        corridors = _Corridors(x[rows], steps, horizon)
        theta_f = x[rows, COL["heading"]] + shift
        zero = corridors.excluded(np.zeros(len(rows)), theta_f, initial_set)
        bound = np.full(len(rows), -np.inf)
        live = np.flatnonzero(zero)
        if len(live):
            part = corridors.subset(live)
            theta = theta_f[live]
            lo, hi = np.zeros(len(live)), np.full(len(live), c_max)
            at_max = part.excluded(hi, theta, initial_set)
            for _ in range(iterations):
                mid = (lo + hi) / 2
                out = part.excluded(mid, theta, initial_set)
                lo = np.where(out, mid, lo)
                hi = np.where(out, hi, mid)
            bound[live] = np.where(at_max, c_max, lo)
        best[rows] = np.minimum(best[rows], bound)
    return best
