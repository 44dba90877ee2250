"""Convex pieces whose union contains C = K ⊕ B_r at one time, as half-spaces ``A x ≤ b``: the
constraints a planner's MPC can take per time step.

Containment. K is split into sub-sets K_1 … K_p whose union is K (below). For a unit normal n let
h_i(n) = max over K_i of n·v, the support function of K_i: for a polygonal K_i the maximum over its
vertices, which are the served geometry's own coordinates. Every x = k + u of K_i ⊕ B_r (k in K_i,
|u| ≤ r) has n·x = n·k + n·u ≤ h_i(n) + r. So for *any* finite set of unit normals the polygon

    P_i = ∩_n {x : n·x ≤ h_i(n) + r}

contains K_i ⊕ B_r, and P_1 ∪ … ∪ P_p contains ∪ (K_i ⊕ B_r) = (∪ K_i) ⊕ B_r = C. The choice of
normals and of the split only decides how tight the pieces are, never whether they contain C. Each
b is moved outwards by ``ROUND_OUT_M`` in the set's frame and again in the world frame, so the
float arithmetic of the support and of the rotation cannot move a half-space's line inwards.

The split. The parts of K are its connected polygons (and any lower-dimensional component, kept as
its own part). While there are more than ``max_pieces``, the two whose common convex hull adds the
least area to C's pieces are replaced by that hull. While there are fewer, the part whose best cut
shrinks the pieces most is cut by a line into two halves, each taking ``CUT_OVERLAP_M`` past the
line, so the halves' union is the part even where the clipping rounds. Convex parts are never cut:
cutting a convex set only adds area. The area of a piece is measured as that of its hull ⊕ B_r,
hull area + perimeter · r + π r² (Steiner's formula for convex sets).

The normals of a piece. Its hull's own edge normals, thinned to ``max_sides`` by dropping, one at a
time, the edge whose removal adds the least area (the triangle its two neighbours' lines close
over it; never one whose neighbours' normals are half a turn or more apart, which would open the
polygon); or ``max_sides`` normals evenly spaced from the heading (+x of the human frame). The
smaller polygon of the two is served.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry
from shapely.geometry.polygon import orient

from reach.frames import Pose
from reach.sets import FRTSet

#: Each half of a cut part reaches this far past the cutting line (m).
CUT_OVERLAP_M = 1e-6
#: Every b is moved outwards by this much in the set's frame and again in the world frame (m).
ROUND_OUT_M = 1e-6
#: Normals closer than this (rad) are one normal: the pieces' corners stay well conditioned.
SAME_NORMAL_RAD = 1e-6
#: More connected parts than this are served as one hull before splitting (a set in hundreds of
#: crumbs would make the pairwise merging quadratic for nothing).
MAX_PARTS = 32
#: Directions (over half a turn) and positions (shares of the part's extent) of the candidate cuts.
CUT_DIRECTIONS = 8
CUT_POSITIONS = (0.25, 0.5, 0.75)
#: A cut is made only if it shrinks the part's piece by more than this share of its area.
MIN_CUT_GAIN = 0.02
#: The defaults and bounds of ``max_sides`` and ``max_pieces``.
DEFAULT_SIDES, SIDES_RANGE = 16, (3, 64)
DEFAULT_PIECES, PIECES_RANGE = 4, (1, 16)


@dataclass(frozen=True)
class ConvexPiece:
    """``{x : normals @ x <= offsets}``: unit normals [m, 2], offsets [m], and the polygon's corners
    [m, 2] counter-clockwise (corner i where the lines of normals i and i + 1 meet; a corner may
    repeat where a side has no length)."""

    normals: np.ndarray
    offsets: np.ndarray
    corners: np.ndarray

    def contains(self, xy: np.ndarray, tolerance: float = 0.0) -> np.ndarray:
        """Whether each point [N, 2] meets every half-space (within ``tolerance`` metres)."""
        slack = np.asarray(xy, dtype=float).reshape(-1, 2) @ self.normals.T - self.offsets
        return np.all(slack <= tolerance, axis=1)

    def area(self) -> float:
        x, y = self.corners[:, 0], self.corners[:, 1]
        return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))

    def in_world(self, pose: Pose) -> ConvexPiece:
        """The piece in the world frame (p_world = R p + (x, y)): n_w = R n, b_w = b + n_w·(x, y),
        each b then moved out by ``ROUND_OUT_M``. Each corner moves with its two lines: by
        ε (n_i + n_(i+1)) / (1 + n_i·n_(i+1)), which meets both moved lines, computed from the
        moved corner rather than by intersecting lines far from the origin."""
        c, s = math.cos(pose.heading), math.sin(pose.heading)
        rotation = np.array([[c, -s], [s, c]])
        shift = np.array([pose.x, pose.y])
        normals = self.normals @ rotation.T
        offsets = self.offsets + normals @ shift + ROUND_OUT_M
        following = np.roll(normals, -1, axis=0)
        cosine = np.sum(normals * following, axis=1, keepdims=True)
        out = ROUND_OUT_M * (normals + following) / (1.0 + cosine)
        return ConvexPiece(normals, offsets, self.corners @ rotation.T + shift + out)


def slice_pieces(
    frt: FRTSet,
    t: float,
    radius: float,
    max_sides: int = DEFAULT_SIDES,
    max_pieces: int = DEFAULT_PIECES,
) -> list[ConvexPiece]:
    """Convex pieces in the world frame whose union contains C = K(t) ⊕ B_radius, K(t) the set
    ``frt.geometry("slice", t)`` (which holds every position reachable at t)."""
    pieces = outer_pieces(frt.geometry("slice", t), radius, max_sides, max_pieces)
    return [piece.in_world(frt.pose) for piece in pieces]


def outer_pieces(
    k_set: BaseGeometry,
    radius: float,
    max_sides: int = DEFAULT_SIDES,
    max_pieces: int = DEFAULT_PIECES,
) -> list[ConvexPiece]:
    """At most ``max_pieces`` convex pieces of at most ``max_sides`` sides each, in ``k_set``'s
    frame, whose union contains ``k_set`` ⊕ B_radius (none for an empty set)."""
    if not SIDES_RANGE[0] <= max_sides <= SIDES_RANGE[1]:
        raise ValueError(f"max_sides must be in {SIDES_RANGE}")
    if not PIECES_RANGE[0] <= max_pieces <= PIECES_RANGE[1]:
        raise ValueError(f"max_pieces must be in {PIECES_RANGE}")
    parts = _parts(k_set)
    if not parts:
        return []
    if len(parts) > MAX_PARTS:
        parts = [k_set.convex_hull]
    parts = _merged(parts, radius, max_pieces)
    parts = _cut(parts, radius, max_pieces)
    return [_piece(part, radius, max_sides) for part in parts]


# ----------------------------------------------------------------------------- parts and cuts


def _parts(geometry: BaseGeometry) -> list[BaseGeometry]:
    """The components of ``geometry`` (each polygon of a multi-polygon, each member of a
    collection), none of them empty."""
    parts = shapely.get_parts(geometry)
    out: list[BaseGeometry] = []
    for part in parts:
        if part.is_empty:
            continue
        if isinstance(part, Polygon) or not hasattr(part, "geoms"):
            out.append(part)
        else:
            out.extend(_parts(part))
    return out


def _c_areas(parts: np.ndarray | list[BaseGeometry], radius: float) -> np.ndarray:
    """Area of each part's convex hull ⊕ B_radius (Steiner: area + perimeter r + π r²; a segment's
    perimeter is twice its length)."""
    hulls = shapely.convex_hull(np.asarray(parts, dtype=object))
    area = shapely.area(hulls)
    perimeter = np.where(area > 0.0, shapely.length(hulls), 2.0 * shapely.length(hulls))
    return area + perimeter * radius + math.pi * radius**2


def _merged(parts: list[BaseGeometry], radius: float, limit: int) -> list[BaseGeometry]:
    """Parts merged pairwise into their common hull, the cheapest pair first, while there are more
    than ``limit`` or a merge adds no area (two pieces that overlap more than their hull's extra)."""
    parts = list(parts)
    while len(parts) > 1:
        own = _c_areas(parts, radius)
        pairs = [(i, j) for i in range(len(parts)) for j in range(i + 1, len(parts))]
        hulls = [shapely.MultiPoint(_coordinates(parts[i], parts[j])).convex_hull for i, j in pairs]
        added = _c_areas(hulls, radius) - np.array([own[i] + own[j] for i, j in pairs])
        best = int(np.argmin(added))
        if len(parts) <= limit and added[best] > 0.0:
            break
        i, j = pairs[best]
        parts = [p for k, p in enumerate(parts) if k not in (i, j)] + [hulls[best]]
    return parts


def _coordinates(*geometries: BaseGeometry) -> np.ndarray:
    return np.concatenate([shapely.get_coordinates(g) for g in geometries])


def _cut(parts: list[BaseGeometry], radius: float, limit: int) -> list[BaseGeometry]:
    """Parts cut in two, the best cut first, while there are fewer than ``limit`` and a cut
    shrinks its part's piece by more than ``MIN_CUT_GAIN`` of it."""
    if len(parts) >= limit:
        return parts
    cuts = [(part, _best_cut(part, radius)) for part in parts]
    while len(cuts) < limit:
        i = int(np.argmax([gain for _, (gain, _) in cuts]))
        halves = cuts[i][1][1]
        if halves is None:
            break
        cuts = cuts[:i] + cuts[i + 1 :] + [(half, _best_cut(half, radius)) for half in halves]
    return [part for part, _ in cuts]


def _best_cut(
    part: BaseGeometry, radius: float
) -> tuple[float, tuple[BaseGeometry, BaseGeometry] | None]:
    """(gain, the two halves) of the cut that shrinks ``part``'s piece most; (0, None) if none
    shrinks it by more than ``MIN_CUT_GAIN`` (always for a convex part)."""
    hull = part.convex_hull
    if part.area <= 0.0 or part.area >= hull.area * (1.0 - 1e-9):
        return 0.0, None
    whole = float(_c_areas([part], radius)[0])
    # The halves' pieces cover part ⊕ B_r, so no cut gains more than the hull's excess over it
    # (over the buffer's polygon, which lies inside it: a bound at least as large).
    if whole - part.buffer(radius, quad_segs=8).area <= MIN_CUT_GAIN * whole:
        return 0.0, None
    xy = shapely.get_coordinates(hull)
    angles = math.pi * np.arange(CUT_DIRECTIONS) / CUT_DIRECTIONS
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)  # [D, 2] cut normals
    w = np.stack([-d[:, 1], d[:, 0]], axis=1)  # along each cut
    along, across = d @ xy.T, w @ xy.T  # [D, V]
    lo, hi = along.min(axis=1), along.max(axis=1)
    reach = np.abs(across).max(axis=1) + 1.0
    c = lo[:, None] + np.array(CUT_POSITIONS)[None, :] * (hi - lo)[:, None]  # [D, P]
    shape = c.shape
    lower = _bands(d, w, np.broadcast_to(lo[:, None] - 1.0, shape), c + CUT_OVERLAP_M, reach)
    upper = _bands(d, w, c - CUT_OVERLAP_M, np.broadcast_to(hi[:, None] + 1.0, shape), reach)
    below, above = shapely.intersection(part, lower), shapely.intersection(part, upper)
    cost = _c_areas(below, radius) + _c_areas(above, radius)
    cost[(shapely.area(below) <= 0.0) | (shapely.area(above) <= 0.0)] = np.inf  # no cut
    k = int(np.argmin(cost))
    gain = whole - float(cost[k])
    if not gain > MIN_CUT_GAIN * whole:
        return 0.0, None
    return gain, (_polygonal(below[k]), _polygonal(above[k]))


def _bands(d: np.ndarray, w: np.ndarray, lo: np.ndarray, hi: np.ndarray, reach: np.ndarray):
    """Per direction k and position j the rectangle lo[k, j] ≤ d[k]·x ≤ hi[k, j],
    |w[k]·x| ≤ reach[k] (d[k], w[k] orthonormal), flattened."""
    dk, wk, rk = d[:, None, None, :], w[:, None, None, :], reach[:, None, None, None]
    ends = np.stack([lo, hi, hi, lo], axis=-1)[..., None]  # [D, P, 4, 1]
    sides = np.array([-1.0, -1.0, 1.0, 1.0])[None, None, :, None]
    return shapely.polygons((ends * dk + sides * rk * wk).reshape(-1, 4, 2))


def _polygonal(geometry: BaseGeometry) -> BaseGeometry:
    """The polygons of a clipped half. Lower-dimensional bits of a clip lie on the half's own
    edge, a band's width inside the other half, which holds them."""
    polygons = [p for p in _parts(geometry) if isinstance(p, Polygon)]
    return polygons[0] if len(polygons) == 1 else shapely.MultiPolygon(polygons)


# ---------------------------------------------------------------------------------- one piece


def _piece(part: BaseGeometry, radius: float, max_sides: int) -> ConvexPiece:
    """The smaller of the two outer polygons of ``part`` ⊕ B_radius (module docstring)."""
    xy = shapely.get_coordinates(part)
    candidates = [_polygon(_even_normals(max_sides), xy, radius)]
    edges = _hull_normals(part)
    if edges is not None:
        lines = _polygon(edges, xy, radius)
        if len(edges) <= max_sides:
            candidates.append(lines)
        else:
            kept = _thinned(lines, max_sides)
            if kept is not None:
                candidates.append(_polygon(lines.normals[kept], xy, radius))
    return min(candidates, key=ConvexPiece.area)


def _even_normals(count: int) -> np.ndarray:
    angles = 2.0 * math.pi * np.arange(count) / count
    return np.stack([np.cos(angles), np.sin(angles)], axis=1)


def _hull_normals(part: BaseGeometry) -> np.ndarray | None:
    """Outward unit normals of the part's hull's edges, by angle, near-parallel ones as one;
    None if the hull has no area."""
    hull = part.convex_hull
    if not isinstance(hull, Polygon) or hull.area <= 0.0:
        return None
    ring = np.asarray(orient(hull, 1.0).exterior.coords)
    edges = np.diff(ring, axis=0)
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    edges = edges[lengths > 0.0] / lengths[lengths > 0.0, None]
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
    angles = np.arctan2(normals[:, 1], normals[:, 0])
    normals, angles = normals[np.argsort(angles)], np.sort(angles)
    gaps = np.diff(angles, append=angles[0] + 2.0 * math.pi)
    distinct = np.concatenate([[True], gaps[:-1] > SAME_NORMAL_RAD])
    if gaps[-1] <= SAME_NORMAL_RAD:
        distinct[-1] = False
    normals = normals[distinct]
    return normals if len(normals) >= 3 else None


def _polygon(normals: np.ndarray, xy: np.ndarray, radius: float) -> ConvexPiece:
    """{x : n·x ≤ h(n) + radius} over ``normals`` (by angle, consecutive ones less than half a
    turn apart), h the support function of the points ``xy``."""
    offsets = (xy @ normals.T).max(axis=0) + radius + ROUND_OUT_M
    return ConvexPiece(normals, offsets, _corners(normals, offsets))


def _corners(normals: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Where the line of each normal meets the next one's."""
    return _meet((normals, np.roll(normals, -1, axis=0)), (offsets, np.roll(offsets, -1)))


def _thinned(piece: ConvexPiece, max_sides: int) -> np.ndarray | None:
    """Indices of at most ``max_sides`` of the piece's lines, dropped one at a time, the one whose
    removal adds the least area first; None if no line can be dropped without opening the
    polygon while more than ``max_sides`` remain."""
    normals, offsets = piece.normals, piece.offsets
    m = len(normals)
    prev, succ = np.roll(np.arange(m), 1), np.roll(np.arange(m), -1)
    alive = np.ones(m, dtype=bool)
    cost = _removal_areas(normals, offsets, prev, np.arange(m), succ)
    for _ in range(m - max_sides):
        i = int(np.argmin(np.where(alive, cost, np.inf)))
        if not np.isfinite(cost[i]):
            return None
        alive[i] = False
        p, q = prev[i], succ[i]
        succ[p], prev[q] = q, p
        both = np.array([p, q])
        cost[both] = _removal_areas(normals, offsets, prev[both], both, succ[both])
    return np.flatnonzero(alive)


def _removal_areas(
    normals: np.ndarray, offsets: np.ndarray, p: np.ndarray, i: np.ndarray, q: np.ndarray
) -> np.ndarray:
    """Per k, the area the polygon gains when line i[k] goes and its neighbours p[k] and q[k]
    meet: the triangle of the three lines; inf where p's and q's normals are half a turn or more
    apart counter-clockwise (the polygon would open)."""
    angles = np.arctan2(normals[:, 1], normals[:, 0])
    gap = (angles[q] - angles[p]) % (2.0 * math.pi)
    corner_pi = _meet((normals[p], normals[i]), (offsets[p], offsets[i]))
    corner_iq = _meet((normals[i], normals[q]), (offsets[i], offsets[q]))
    with np.errstate(divide="ignore", invalid="ignore"):
        corner_pq = _meet((normals[p], normals[q]), (offsets[p], offsets[q]))
    u, v = corner_iq - corner_pi, corner_pq - corner_pi
    area = 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    return np.where(gap < math.pi - 1e-9, area, np.inf)


def _meet(n: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Where line n[0][k]·x = b[0][k] meets n[1][k]·x = b[1][k], for each k."""
    (n1, n2), (b1, b2) = n, b
    det = n1[:, 0] * n2[:, 1] - n1[:, 1] * n2[:, 0]
    x = (b1 * n2[:, 1] - b2 * n1[:, 1]) / det
    y = (n1[:, 0] * b2 - n2[:, 0] * b1) / det
    return np.stack([x, y], axis=1)
