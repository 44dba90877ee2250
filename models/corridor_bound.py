"""A sound lower bound on the value function from heading and speed corridors.

V(t, x) > c exactly when no trajectory from the sub-level set {l <= c} of the initial set reaches
x at time t (set semantics, docs/model.md). This module proves that for given states, which gives
training a signal the PDE residual alone conveys slowly: *where the network must be high*.

Why it cuts what the interval outer bound (models/outer_bound.py) cannot: a state fixes the final
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
import shapely

from models.contract import BOUND_COLUMNS, COL, HORIZON_S, INITIAL_SET, InitialSet
from models.dynamics import heading_interval, interpolate_bounds, speed_change_interval
from models.outer_bound import convex_polygons, cos_max_towards, outer_bound

#: Support directions of the per-state position polygon.
DIRECTIONS = np.arange(16) * (2 * math.pi / 16)

#: Where in [0, t] a partition's waypoint bins pin the heading (``partition_supports``): early,
#: where wide steering bounds let the car turn hard and the notch's walls are made.
WAYPOINT_AT = 0.2


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
        (``models.speed_lp``, a linear programme per row and direction, solved together) instead
        of taking either end of its interval at every instant independently."""
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
            from models.speed_lp import corridor_gain

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


def sample_bounded_states(
    n_params: int, per_param: int, rng: np.random.Generator, horizon: float = HORIZON_S
) -> tuple[np.ndarray, np.ndarray]:
    """States near and around the reachable set with their proven lower bound on V, for
    training: rollout endpoints (reachable positions) moved 0.5-20 m in a random direction,
    with the heading and speed of another rollout of the same setting. Returns (x [N, 14], lower
    bound [N]), keeping only the states the bound excludes (bound >= 0)."""
    from models.rollout import rk4_rollout, sample_control_schedules, sample_initial_states
    from models.sampling import sample_parameters, set_state

    params = np.repeat(sample_parameters(n_params, rng), per_param, axis=0)
    n = len(params)
    t = np.repeat(rng.uniform(0.3, horizon, n_params), per_param)
    start = sample_initial_states(params[:, COL["v_start"]], rng)
    a1, a2, switches = sample_control_schedules(n, horizon, rng)
    end, _ = rk4_rollout(start, params, t, a1, a2, switches * (t / horizon)[:, None], 24)
    other = (np.arange(n) // per_param) * per_param + rng.integers(0, per_param, n)
    distance = 10 ** rng.uniform(math.log10(0.5), math.log10(20.0), n)
    angle = rng.uniform(-math.pi, math.pi, n)
    heading = (end[2][other] + math.pi) % (2 * math.pi) - math.pi
    x = set_state(
        params,
        t,
        (
            end[0] + distance * np.cos(angle),
            end[1] + distance * np.sin(angle),
            heading,
            end[3][other],
        ),
    )
    bound = value_lower_bound(x)
    keep = bound >= 0
    return x[keep], bound[keep]


def bins_union(support: np.ndarray, empty: np.ndarray, directions: np.ndarray) -> shapely.Geometry:
    """The union of one instant's bin polygons (supports [B, M] in ``directions``, [B] empty bins
    skipped): every position reachable then (:func:`partition_supports`)."""
    return shapely.union_all(convex_polygons(directions, support[~empty]))


def grown_to_hold(
    geometry: shapely.Geometry, distance: float, quad_segs: int = 16
) -> shapely.Geometry:
    """``geometry`` buffered so that it holds every point within ``distance`` of it: shapely
    inscribes its arcs (``quad_segs`` segments a quarter circle), so the radius is divided by the
    cosine of half a segment's angle."""
    return geometry.buffer(distance / math.cos(math.pi / (4 * quad_segs)) + 1e-6, quad_segs)


def partition_tubes(
    v_start: float,
    bounds: np.ndarray,
    t_ends: tuple[float, ...],
    speed_max: float,
    heading_bins: int = 16,
    speed_bins: int = 1,
    coupled_speed: bool = True,
    steps: int = 60,
    instant_s: float = 0.1,
    initial_set: InitialSet = INITIAL_SET,
    partitioned_from_s: float = 0.0,
    directions: np.ndarray = DIRECTIONS,
    waypoint_bins: int | Sequence[int] = 1,
    waypoint_at: float | Sequence[float] = WAYPOINT_AT,
) -> list[shapely.Geometry]:
    """Regions that contain every position reached during [0, t] for each t of ``t_ends``: the
    union over instants ``instant_s`` apart of their bin polygons (:func:`partition_supports`),
    each swept along its headings by ``speed_max * instant_s / 2`` (:func:`swept_supports`: the
    farthest a car moves to the nearest instant; ``speed_max`` must bound the speed over the
    horizon; the last instant before t only, since nothing after t belongs to the tube), and the
    initial disc grown by as much for the times before the first instant. Sound
    (tests/test_corridor_bound.py), not convex: with the speed coupled it cuts most of the notch
    behind a car that can turn round.
    ``partitioned_from_s``: instants before it take the interval outer bound's convex polygon
    instead (early sets have no notch; the partition's cost is in the instants it runs on)."""
    instants = np.arange(1, round(max(t_ends) / instant_s) + 1) * instant_s
    partitioned = instants >= partitioned_from_s - 1e-9
    support, empty = partition_supports(
        v_start,
        bounds,
        instants[partitioned],
        heading_bins,
        speed_bins,
        steps=steps,
        initial_set=initial_set,
        coupled_speed=coupled_speed,
        directions=directions,
        waypoint_bins=waypoint_bins,
        waypoint_at=waypoint_at,
    )
    convex = (
        outer_bound(v_start, bounds, initial_set=initial_set) if not partitioned.all() else None
    )
    grow = speed_max * instant_s / 2
    turn = max_turn_rate(bounds) * instant_s / 2
    headings = bin_headings(
        bounds, instants[partitioned], heading_bins, waypoint_bins, speed_bins,
        initial_set=initial_set,
    )  # fmt: skip
    parts = [grown_to_hold(shapely.Point(0.0, 0.0), initial_set.radius_m + grow)]
    #: Per instant, its region for a tube that ends there: nothing after the instant.
    ends = [parts[0]]
    j = 0
    for s in instants:
        if convex is not None and s < partitioned_from_s - 1e-9:
            region = shapely.Polygon(convex.polygons_at([convex.nearest_row(s)])[0])
            parts.append(grown_to_hold(region, grow))
            ends.append(parts[-1])
            continue
        swept = swept_supports(support[j], headings[j], grow, turn, directions)
        parts.append(bins_union(swept, empty[j], directions))
        before = swept_supports(support[j], headings[j], grow, turn, directions, after=False)
        ends.append(bins_union(before, empty[j], directions))
        j += 1
    last = [round(t / instant_s) for t in t_ends]
    return [shapely.union_all([*parts[:k], ends[k]]) for k in last]


def main() -> None:
    import argparse
    from pathlib import Path

    from tqdm import tqdm

    parser = argparse.ArgumentParser(description="States with a proven lower bound on V.")
    parser.add_argument("--out", type=Path, required=True, help=".npz with x and lower_bound")
    parser.add_argument("--params", type=int, default=4000)
    parser.add_argument("--per-param", type=int, default=32)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    xs, bounds = [], []
    for _ in tqdm(range(0, args.params, 100), desc="lower bounds", unit="100 settings"):
        x, bound = sample_bounded_states(100, args.per_param, rng)
        xs.append(x)
        bounds.append(bound)
    x, bound = np.concatenate(xs), np.concatenate(bounds)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, x=x.astype(np.float32), lower_bound=bound.astype(np.float32))
    print(f"{len(x)} states, lower bound median {np.median(bound):.2f}, wrote {args.out}")


if __name__ == "__main__":
    main()


def final_heading_bins(
    bounds: np.ndarray,
    times: np.ndarray,
    heading_bins: int,
    horizon: float = HORIZON_S,
    initial_set: InitialSet = INITIAL_SET,
) -> np.ndarray:
    """The final (unwrapped) heading interval of each bin of :func:`partition_supports` at each of
    ``times`` [J]: [J, B, 2]. The bins split the forward heading interval evenly."""
    params = np.zeros(len(COL))
    params[6:] = np.asarray(bounds, dtype=float)
    lo, hi = heading_interval(params, np.asarray(times, dtype=float), horizon)
    lo, hi = lo - initial_set.heading_margin_rad, hi + initial_set.heading_margin_rad
    edges = np.arange(heading_bins + 1) / heading_bins
    at = lo[:, None] + (hi - lo)[:, None] * edges[None, :]
    return np.stack([at[:, :-1], at[:, 1:]], axis=-1)


def bin_headings(
    bounds: np.ndarray,
    times: np.ndarray,
    heading_bins: int,
    waypoint_bins: int | Sequence[int] = 1,
    speed_bins: int = 1,
    horizon: float = HORIZON_S,
    initial_set: InitialSet = INITIAL_SET,
) -> np.ndarray:
    """The final heading interval of every bin of :func:`partition_supports`, in its order:
    [J, heading_bins x waypoint_bins x speed_bins, 2]."""
    final = final_heading_bins(bounds, times, heading_bins, horizon, initial_set)
    return np.repeat(final, int(np.prod(waypoint_bins)) * speed_bins, axis=1)


def max_turn_rate(bounds: np.ndarray) -> float:
    """The largest |u1| the bounds allow at any time (the interpolation stays between its ends)."""
    named = dict(zip(BOUND_COLUMNS, np.asarray(bounds, dtype=float), strict=True))
    return max(abs(v) for name, v in named.items() if name.startswith("u1_"))


def swept_supports(
    support: np.ndarray,
    headings: np.ndarray,
    reach_m: float,
    turn_rad: float,
    directions: np.ndarray = DIRECTIONS,
    before: bool = True,
    after: bool = True,
) -> np.ndarray:
    """Supports [B, M] of regions that hold every position within ``reach_m`` of travel, before or
    after, of one at a bin's instant: each bin's polygon (``support`` [B, M]) plus the hull of
    the double sector of radius ``reach_m`` along its headings (``headings`` [B, 2], widened by
    ``turn_rad``, how far the heading turns meanwhile). ``before`` / ``after`` False leaves that
    half out: a tube that ends at the instant needs no position after it (``after=False``: only
    the backward sector, thinner where the car heads away from the set), an instant's own set
    neither.

    A car in bin b at instant s whose speed stays below V moves, during [s - D, s + D], by the
    integral of v (cos theta, sin theta) with theta inside the widened bin and |v| <= V: a vector
    of the cone of those headings no longer than V D, forwards after s, backwards before. So the
    displacement lies in the hull of the two opposite sectors of radius V D = ``reach_m``, whose
    support in direction phi is reach_m max(0, max cos(theta - phi), max cos(theta + pi - phi)):
    thinner than the disc of that radius across a bin's headings, where the notch's walls are."""
    lo, hi = headings[:, 0] - turn_rad, headings[:, 1] + turn_rad
    sweep = np.zeros_like(support)
    if after:
        sweep = np.maximum(sweep, cos_max_towards(lo, hi, directions))
    if before:
        sweep = np.maximum(sweep, cos_max_towards(lo + math.pi, hi + math.pi, directions))
    return support + reach_m * sweep


def partition_supports(
    v_start: float,
    bounds: np.ndarray,
    times: np.ndarray,
    heading_bins: int,
    speed_bins: int,
    steps: int = 24,
    horizon: float = HORIZON_S,
    initial_set: InitialSet = INITIAL_SET,
    coupled_speed: bool = False,
    directions: np.ndarray = DIRECTIONS,
    waypoint_bins: int | Sequence[int] = 1,
    waypoint_at: float | Sequence[float] = WAYPOINT_AT,
) -> tuple[np.ndarray, np.ndarray]:
    """Outer polygons of the positions reachable at exactly each of ``times`` [J], one per final
    heading x waypoint heading(s) x final speed bin: supports [J, B, M] in ``directions`` (B =
    heading_bins x the waypoint bins x speed_bins, in that order of nesting) and [J, B] True for
    bins no trajectory reaches.

    The bins split the forward intervals of the final (unwrapped) heading and speed, which every
    trajectory's final values lie in, so the union of a time's polygons contains every position
    reachable then; unlike one convex polygon, it has the notch behind a car that can turn round.
    ``waypoint_bins`` (one count per ``waypoint_at``, a fraction of t) splits each bin again, in
    turn, by the heading at the sub-interval node nearest that fraction: evenly over the interval
    that node's heading lies in *for that bin's trajectories* (``_Corridors.heading_nodes``: the
    final heading bin and the waypoints before it narrow it), which covers them, so no split is
    spent where the bin cannot go (splitting the whole forward interval left a sixth of the bins
    empty and `fast_wide_limits` t = 2 s at 1.82 against 1.68 m, one-off, 32 x 8 bins).
    ``coupled_speed``: see ``_Corridors.supports`` (a linear programme per bin and direction).
    """
    times = np.asarray(times, dtype=float)
    counts = np.atleast_1d(np.asarray(waypoint_bins, dtype=int))
    fractions = np.broadcast_to(np.asarray(waypoint_at, dtype=float), counts.shape)
    n_bins = heading_bins * int(np.prod(counts)) * speed_bins
    x = np.zeros((len(times) * heading_bins, len(COL)))
    x[:, COL["t"]] = np.repeat(times, heading_bins)
    x[:, COL["v_start"]] = v_start
    x[:, 6:] = np.asarray(bounds, dtype=float)
    corridors = _Corridors(x, steps, horizon)
    m = initial_set
    theta = final_heading_bins(bounds, times, heading_bins, horizon, initial_set).reshape(-1, 2)
    eps_th = np.full((1, 1), m.heading_margin_rad)
    waypoints: list[tuple[int, np.ndarray, np.ndarray]] = []
    for count, fraction in zip(counts.tolist(), fractions.tolist(), strict=True):
        if count <= 1:
            continue
        node = min(max(round(steps * fraction), 1), steps - 1)
        node_lo, node_hi = corridors.heading_nodes(eps_th, (theta[:, 0], theta[:, 1]), waypoints)
        lo, hi = node_lo[:, node], np.maximum(node_hi[:, node], node_lo[:, node])
        rows = np.repeat(np.arange(corridors.n), count)
        part = np.tile(np.arange(count), corridors.n)
        width = (hi - lo)[rows] / count
        corridors, theta = corridors.subset(rows), theta[rows]
        waypoints = [(k, w_lo[rows], w_hi[rows]) for k, w_lo, w_hi in waypoints]
        waypoints.append((node, lo[rows] + part * width, lo[rows] + (part + 1) * width))
    if speed_bins > 1:
        rows = np.repeat(np.arange(corridors.n), speed_bins)
        corridors, theta = corridors.subset(rows), theta[rows]
        waypoints = [(k, w_lo[rows], w_hi[rows]) for k, w_lo, w_hi in waypoints]
    sp_lo = _stop_rule_paths(
        np.maximum(corridors.v_start - m.speed_margin_mps, 0.0), corridors.step_lo
    )[:, -1]
    sp_hi = _stop_rule_paths(corridors.v_start + m.speed_margin_mps, corridors.step_hi)[:, -1]
    s_edges = np.tile(np.arange(speed_bins), corridors.n // speed_bins)[:, None] + np.array(
        [0.0, 1.0]
    )
    speed = sp_lo[:, None] + (sp_hi - sp_lo)[:, None] * s_edges / speed_bins
    support, empty = corridors.supports(
        np.zeros(corridors.n),
        (theta[:, 0], theta[:, 1]),
        (speed[:, 0], speed[:, 1]),
        initial_set,
        coupled_speed=coupled_speed,
        directions=directions,
        waypoints=waypoints,
    )
    return (
        support.reshape(len(times), n_bins, len(directions)),
        empty.reshape(len(times), n_bins),
    )
