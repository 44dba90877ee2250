"""The assumption ``speed_limit``: a car keeps its speed at most v_cap, the lane speed limit times
a factor, and so travels no farther than a distance L(t) from where it started.

SPOT (Koschi & Althoff, *SPOT: A Tool for Set-Based Prediction of Traffic Participants*, IEEE IV
2017) bounds a vehicle's speed by the road's limit times a factor. Here:

* **v_cap** = factor × the highest speed limit among the lanes the car can reach within the box
  its set's region is read around (``reach.lanes.LaneGraph.speed_cap``: the lanes of the
  ``reachable_lanes`` assumption); there is none where a lane reached has no limit, the box
  reaches past the map's extent (a road the map does not know may be faster) or no start lane
  holds the car. A car observed faster than v_cap breaks the assumption already.
* **L(t)** = ∫₀ᵗ min(v̄(s), v_cap) ds, v̄ the speed bound of the dynamics under the set's
  acceleration bounds: the outer bound's (``reach.outer_bound``) on a grid of step h,
  w₀ = v_start + e_v, w_{k+1} = max(w_k + h·max(a_hi(s_k), a_hi(s_(k+1))), 0) (the stop rule;
  a_hi is linear in time, so h times its larger end bounds its integral over any part of the
  step), and v̄ = max(w_k, w_(k+1)) over step k (a part of the step gains at most what the whole
  step may, and a car that stops in it restarts from 0). A trajectory whose speed stays at most
  v_cap has speed at most min(v̄, v_cap) on each step, so its path from its start to time t is at
  most L(t), the sum of h·min(v̄_k, v_cap) over the steps up to t (L grows with t).
* The start lies within r₀ (the initial set's radius) of the observed position, so every position
  at time t lies in the disc of radius ρ(t) = r₀ + L(t) about it (the human frame's origin), and
  every position during [0, t] too (ρ grows). Tube j, slice j and interval j of a trajectory
  keeping the assumption lie in the disc of radius ρ(s_j): :class:`ReachDiscs` cuts them there
  (``reach.road_cut.CutSet``), each disc a polygon holding it (its inscribed circle has radius
  ρ(s_j), rounded outward).

With several modes (bounds [M, 8], a union of sets) ρ is the largest over the modes.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from reach.contract import INITIAL_SET, InitialSet
from reach.outer_bound import stop_rule_integral
from reach.road_map import cut_to

#: The label of this assumption in answers.
SPEED_LIMIT = "speed_limit"
#: v_cap = this × the lane speed limit, unless configured (``FRT_SPEED_LIMIT_FACTOR``).
DEFAULT_FACTOR = 1.2
#: Sides of the polygon standing for each disc (it holds the disc).
DISC_SIDES = 64
#: Grid steps of L(t) per slice.
SUBSTEPS = 16
#: ρ is rounded outward by this much, relative and absolute (m).
ROUND_REL = 1e-9
ROUND_ABS_M = 1e-6


def reach_radii(
    v_start: float,
    bounds: np.ndarray,
    v_cap: float,
    slice_dt: float,
    n_slices: int,
    horizon: float,
    initial_set: InitialSet = INITIAL_SET,
) -> np.ndarray:
    """ρ(s_j) = r₀ + L(s_j) for every slice j (see the module), the largest over the rows of
    ``bounds`` (8 contract columns each), rounded outward."""
    rows = np.asarray(bounds, dtype=np.float64).reshape(-1, 8)
    h = slice_dt / SUBSTEPS
    times = np.arange((n_slices - 1) * SUBSTEPS + 1) * h
    w_at = times / horizon
    # u2_max_start, u2_max_end: columns 5 and 7; the bounds are linear over [0, horizon].
    a_hi = (1.0 - w_at)[None, :] * rows[:, 5:6] + w_at[None, :] * rows[:, 7:8]
    gain = np.maximum(a_hi[:, :-1], a_hi[:, 1:]) * h
    # w_(k+1) = max(w_k + gain_k, 0), in closed form as the outer bound's speed.
    w = stop_rule_integral(np.full((len(rows), 1), v_start + initial_set.speed_margin_mps), gain)
    speed = np.minimum(np.maximum(w[:, :-1], w[:, 1:]), v_cap)
    path = np.concatenate([np.zeros((len(rows), 1)), np.cumsum(speed * h, axis=1)], axis=1)
    rho = initial_set.radius_m + path.max(axis=0)[::SUBSTEPS]
    return rho * (1.0 + ROUND_REL) + ROUND_ABS_M


def disc(radius: float) -> BaseGeometry:
    """A regular polygon about the origin holding the disc of ``radius`` (its inscribed circle's
    radius is at least ``radius``)."""
    outer = radius / math.cos(math.pi / DISC_SIDES) * (1.0 + ROUND_REL)
    angles = np.arange(DISC_SIDES) * (2.0 * math.pi / DISC_SIDES)
    return shapely.Polygon(np.stack([outer * np.cos(angles), outer * np.sin(angles)], axis=1))


class ReachDiscs:
    """The discs of radius ρ(s_j) (human frame) of one set under v_cap: tube, slice and interval
    j of a trajectory keeping the assumption lie in disc j (see the module)."""

    def __init__(self, v_cap: float, radii: np.ndarray) -> None:
        self.v_cap = float(v_cap)
        self.radii = np.asarray(radii, dtype=np.float64)
        self._discs: dict[int, BaseGeometry] = {}

    def disc(self, j: int) -> BaseGeometry:
        """Disc j as a polygon holding it, made on first use."""
        found = self._discs.get(j)
        if found is None:
            found = self._discs[j] = disc(float(self.radii[j]))
        return found

    def cut(self, geometry: BaseGeometry, j: int) -> BaseGeometry:
        """``geometry`` ∩ disc j; ``geometry`` itself where its bounding box's corners lie within
        ρ(s_j) (the box, and so the geometry, is inside the disc)."""
        if geometry.is_empty:
            return geometry
        x0, y0, x1, y1 = geometry.bounds
        far = math.hypot(max(abs(x0), abs(x1)), max(abs(y0), abs(y1)))
        if far <= self.radii[j]:
            return geometry
        return cut_to(geometry, self.disc(j))
