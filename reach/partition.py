"""The speed-coupled partition of the reachable set: a union of convex polygons per instant.

Trajectories are split into bins by their final heading (and, optionally, by their heading at
waypoints early in [0, t]); each bin's heading corridor and coupled speed programme
(``reach.corridors``, ``reach.speed_programme``) bound its positions by a convex polygon. The union
over bins holds every position reachable at t and, unlike any single convex bound, keeps the notch
behind a car that can turn round (a car ending backwards must have turned while moving forwards).
Sweeping each bin's polygon along its headings by how far a car moves in half an instant gives the
region reached between instants, and their union over [0, t] the tube (``partition_tubes``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import shapely

from reach.contract import BOUND_COLUMNS, COL, HORIZON_S, INITIAL_SET, InitialSet
from reach.corridors import DIRECTIONS, _Corridors, _stop_rule_paths
from reach.dynamics import heading_interval
from reach.outer_bound import cos_max_towards, outer_bound
from reach.polygons import convex_polygons

#: Where in [0, t] a partition's waypoint bins pin the heading (``partition_supports``): early,
#: where wide steering bounds let the car turn hard and the notch's walls are made.
WAYPOINT_AT = 0.2


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
    instead (early sets have no notch; the partition's cost is in the instants it runs on).

    A numeric kernel kept whole so its maths reads in one place."""
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
    spent where the bin cannot go (a split of the whole forward interval leaves bins empty).
    ``coupled_speed``: see ``_Corridors.supports`` (a linear programme per bin and direction).

    A numeric kernel kept whole so its maths reads in one place.
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
