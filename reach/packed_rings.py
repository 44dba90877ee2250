"""Signed distances to polygons by a compiled kernel, reduced per trajectory where that suffices.

A polygon (or a multipolygon, with holes) is packed as the segments of its rings; the signed
distance of a point is the least distance to a segment, negative where a ray from the point
crosses the rings an odd number of times (inside): the same quantity as
``reach.distances.signed_distance`` (GEOS), computed without a geometry object per point. The
kernels take world points and the human's pose and move each point to the human frame by the
arithmetic of ``reach.frames.human_frames`` (the same products and sums in the same order: the same
values). They release the GIL: several polygons' packs can be measured on threads at once.

Two lower bounds of the signed distance d(p) to a polygon K cost a few operations each:

- the *box bound*, the signed distance to K's bounding box (K lies in its box: outside, the box is
  nearer; inside, p is at most as deep in K as in the box);
- the *support bound* max_n (n . p - h(n)) over the unit vectors n of :data:`SUPPORT_DIRECTIONS`
  directions, h(n) = max over K's vertices of n . q. Every q in K has n . q <= h(n). Outside K,
  d(p) = |p - q*| for the nearest q* in K, and |p - q*| >= n . (p - q*) >= n . p - h(n). Inside,
  moving from p along n by h(n) - n . p + e (any e > 0) reaches n . x > h(n), outside K, so the
  boundary is within h(n) - n . p of p and d(p) >= n . p - h(n). Both sides of the inequality are
  widened by a margin far above their rounding (:data:`SUPPORT_MARGIN`).

A batch check needs per trajectory only its least clearance and its first colliding point, not
every point's distance. :func:`trajectory_surrogates` returns per point a *surrogate* s_i: the
exact d_i where it evaluated it, else a lower bound of it (the larger of the two bounds where it
took the support bound, else the box bound). Per trajectory it evaluates the point of least box
bound, then visits the points in order: a point whose bound is below the least distance found so
far takes its support bound and is evaluated if that is still below it. The least distance found
only decreases, so every point left has d_i >= s_i >= min_j d_j: ``min s = min d``. If that is
below the threshold it visits the points in order again: a point whose value is below the
threshold takes its support bound and is evaluated if that is still below, until the first whose
distance is; every point before it has s_i >= threshold (a bound, so d_i too) or s_i = d_i, so
the first s_i below the threshold is the first d_i below it. Reductions of s by minimum and by
first index below the threshold are therefore those of d. A point evaluated with a positive
bound is outside K: its distance is the nearest segment's, found without counting the rings'
crossings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import shapely
from shapely.geometry import box
from shapely.geometry.base import BaseGeometry

#: Segments per chunk: a chunk's bounding box lets a point skip its segments together.
CHUNK = 8
#: Directions of the support bound (see the module docstring), evenly spaced.
SUPPORT_DIRECTIONS = 16
#: The support bound's margin per metre of coordinate magnitude (and per polygon, at least this):
#: far above the rounding of a dot product, far below a distance a check reports.
SUPPORT_MARGIN = 1e-9
_ANGLES = 2.0 * np.pi * np.arange(SUPPORT_DIRECTIONS) / SUPPORT_DIRECTIONS
#: The unit vectors n of the support bound ``[SUPPORT_DIRECTIONS, 2]``.
DIRECTIONS = np.ascontiguousarray(np.stack([np.cos(_ANGLES), np.sin(_ANGLES)], axis=1))
#: No change of frame: points already in the polygons' frame.
IDENTITY = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class PackedRings:
    """Polygons' ring segments ``[E, 4]`` as (x0, y0, x1, y1), in chunks of at most
    :data:`CHUNK` consecutive segments of one polygon with their bounding boxes ``[C, 4]`` (x_lo,
    y_lo, x_hi, y_hi); polygon g's chunks are ``chunk_starts[g]:chunk_starts[g + 1]``, chunk c's
    segments ``segment_starts[c]:segment_starts[c + 1]``; ``boxes[g]`` polygon g's bounding
    box, ``supports[g]`` its support values h(n) along :data:`DIRECTIONS`, widened by the margin
    (``-inf`` for an empty polygon)."""

    segments: np.ndarray
    segment_starts: np.ndarray
    chunk_boxes: np.ndarray
    chunk_starts: np.ndarray
    boxes: np.ndarray
    supports: np.ndarray


def pack_rings(geometries: list[BaseGeometry]) -> PackedRings:
    """The ring segments, bounding boxes and support values of ``geometries`` (polygons or
    multipolygons; an empty one has no segments and an empty box, every point infinitely far from
    it)."""
    array = np.empty(len(geometries), dtype=object)
    array[:] = geometries
    parts, part_of = shapely.get_parts(array, return_index=True)
    rings, ring_part = shapely.get_rings(parts, return_index=True)
    xy, ring_of = shapely.get_coordinates(rings, return_index=True)
    follows = ring_of[1:] == ring_of[:-1]  # consecutive vertices of one ring: a segment
    segments = np.concatenate([xy[:-1], xy[1:]], axis=1)[follows]
    owner = part_of[ring_part[ring_of[:-1][follows]]]  # each segment's geometry
    counts = np.bincount(owner, minlength=len(geometries))
    chunks_per = -(-counts // CHUNK)
    chunk_starts = np.concatenate([[0], np.cumsum(chunks_per)]).astype(np.int64)
    first_segment = np.concatenate([[0], np.cumsum(counts)])
    # Chunk c of geometry g starts at g's first segment + CHUNK * (c - g's first chunk).
    chunk_owner = np.repeat(np.arange(len(geometries)), chunks_per)
    segment_starts = np.append(
        first_segment[chunk_owner]
        + CHUNK * (np.arange(len(chunk_owner)) - chunk_starts[chunk_owner]),
        len(segments),
    ).astype(np.int64)
    chunk_boxes = _chunk_boxes(segments, segment_starts)
    bounds = shapely.bounds(array)
    empty = shapely.is_empty(array)
    bounds[empty] = (np.inf, np.inf, -np.inf, -np.inf)
    return PackedRings(
        segments=np.ascontiguousarray(segments, dtype=np.float64),
        segment_starts=segment_starts,
        chunk_boxes=chunk_boxes,
        chunk_starts=chunk_starts,
        boxes=np.ascontiguousarray(bounds, dtype=np.float64),
        supports=_supports(segments, owner, len(geometries)),
    )


def _supports(segments: np.ndarray, owner: np.ndarray, count: int) -> np.ndarray:
    """Per polygon, max over its segments' first vertices (every vertex of a closed ring) of
    n . q along :data:`DIRECTIONS`, plus the margin for its largest coordinate."""
    out = np.full((count, SUPPORT_DIRECTIONS), -np.inf)
    if len(segments):
        np.maximum.at(out, owner, segments[:, :2] @ DIRECTIONS.T)
        scale = np.zeros(count)
        np.maximum.at(scale, owner, np.abs(segments[:, :2]).max(axis=1))
        out += (SUPPORT_MARGIN * (1.0 + scale))[:, None]
    return np.ascontiguousarray(out)


def _chunk_boxes(segments: np.ndarray, segment_starts: np.ndarray) -> np.ndarray:
    if len(segment_starts) <= 1:
        return np.zeros((0, 4))
    begins = segment_starts[:-1]
    xs = np.minimum(segments[:, 0], segments[:, 2]), np.maximum(segments[:, 0], segments[:, 2])
    ys = np.minimum(segments[:, 1], segments[:, 3]), np.maximum(segments[:, 1], segments[:, 3])
    return np.stack(
        [
            np.minimum.reduceat(xs[0], begins),
            np.minimum.reduceat(ys[0], begins),
            np.maximum.reduceat(xs[1], begins),
            np.maximum.reduceat(ys[1], begins),
        ],
        axis=1,
    )


#: Points as ``[N, 2]``, or as their contiguous columns (x, y) (:func:`point_columns`).
Points = np.ndarray | tuple[np.ndarray, np.ndarray]


def signed_distances_packed(
    packed: PackedRings,
    which: np.ndarray,
    xy: Points,
    pose: tuple[float, float, float] = IDENTITY,
) -> np.ndarray:
    """Signed distance of each point ``xy[i]`` to polygon ``which[i]`` of ``packed``, the points
    moved first into the frame of ``pose`` (x, y, heading; see :func:`frame`)."""
    xs, ys = point_columns(xy)
    out = np.empty(len(xs), dtype=np.float64)
    _all_signed(*_arrays(packed), *frame(pose), xs, ys, np.asarray(which, dtype=np.int64), out)
    return out


def trajectory_surrogates(
    packed: PackedRings,
    which: np.ndarray,
    xy: Points,
    starts: np.ndarray,
    threshold: float,
    group: int = 1,
    pose: tuple[float, float, float] = IDENTITY,
) -> np.ndarray:
    """Per probe, its signed distance to polygon ``which[i]`` or a lower bound of it, such that per
    trajectory the least value and the first point whose value is below ``threshold`` are those of
    the signed distances (see the module docstring). A point is ``group`` consecutive probes (a
    footprint's discs) and its value their least; trajectory k is the points
    ``starts[k]:starts[k + 1]``; the probes are moved first into the frame of ``pose``."""
    xs, ys = point_columns(xy)
    out = np.empty(len(xs), dtype=np.float64)
    begins = np.asarray(starts, dtype=np.int64)
    ends = np.empty_like(begins)
    ends[:-1] = begins[1:]
    ends[-1:] = len(xs) // group
    _surrogates(
        (*_arrays(packed), packed.boxes, packed.supports, DIRECTIONS),
        *frame(pose),
        xs,
        ys,
        np.asarray(which, dtype=np.int64),
        (begins, ends, group),
        float(threshold),
        out,
    )
    return out


def frame(pose: tuple[float, float, float]) -> tuple[float, float, float, float]:
    """(x, y, cos, sin) of a pose (x, y, heading), the cosine and sine as
    ``reach.frames.human_frames`` takes them."""
    x, y, heading = pose
    return float(x), float(y), math.cos(heading), math.sin(heading)


def compile_ring_kernels() -> None:
    """Compile (or load from numba's cache) the kernels before a check needs them (the first
    compilation after a change takes seconds)."""
    packed = pack_rings([box(0.0, 0.0, 1.0, 1.0)])
    xy = np.array([[0.5, 0.5], [2.0, 0.5]])
    signed_distances_packed(packed, np.zeros(2, dtype=np.int64), xy)
    for group in (1, 2):
        trajectory_surrogates(packed, np.zeros(2, dtype=np.int64), xy, np.array([0]), 0.0, group)


def _arrays(packed: PackedRings) -> tuple[np.ndarray, ...]:
    return packed.segments, packed.segment_starts, packed.chunk_boxes, packed.chunk_starts


def point_columns(xy: Points) -> tuple[np.ndarray, np.ndarray]:
    """The contiguous float columns (x, y) of points (as they are, if given so)."""
    if isinstance(xy, tuple):
        return xy
    return (
        np.ascontiguousarray(xy[:, 0], dtype=np.float64),
        np.ascontiguousarray(xy[:, 1], dtype=np.float64),
    )


@numba.njit(cache=True, inline="always")
def _to_frame(x0, y0, c, s, x, y):
    """(x, y) in the frame at (x0, y0) with heading cosine c and sine s, by the products and sums
    of ``reach.frames.human_frames`` in its order."""
    dx = x - x0
    dy = y - y0
    return c * dx + s * dy, -s * dx + c * dy


@numba.njit(cache=True, nogil=True)
def _signed(segments, segment_starts, chunk_boxes, chunk_starts, g, x, y, outside=False):
    """Signed distance from (x, y) to polygon g (+inf if it has no segments). A chunk whose box is
    no nearer than the nearest segment found, and that a ray from the point towards +x cannot
    cross, is skipped; for a point known ``outside`` g the ray's crossings are not counted."""
    best = np.inf
    inside = False
    # The segments of the chunk whose box is nearest first: the bound they give skips most others.
    nearest, nearest_gap = -1, np.inf
    for c in range(chunk_starts[g], chunk_starts[g + 1]):
        gx = max(chunk_boxes[c, 0] - x, x - chunk_boxes[c, 2], 0.0)
        gy = max(chunk_boxes[c, 1] - y, y - chunk_boxes[c, 3], 0.0)
        if gx * gx + gy * gy < nearest_gap:
            nearest, nearest_gap = c, gx * gx + gy * gy
    if nearest >= 0:
        for e in range(segment_starts[nearest], segment_starts[nearest + 1]):
            best = min(best, _segment_distance2(segments, e, x, y))
    for c in range(chunk_starts[g], chunk_starts[g + 1]):
        bx0, by0, bx1, by1 = (
            chunk_boxes[c, 0],
            chunk_boxes[c, 1],
            chunk_boxes[c, 2],
            chunk_boxes[c, 3],
        )
        gx = max(bx0 - x, x - bx1, 0.0)
        gy = max(by0 - y, y - by1, 0.0)
        near = gx * gx + gy * gy < best
        crossable = not outside and by0 <= y < by1 and x < bx1
        if not (near or crossable):
            continue
        for e in range(segment_starts[c], segment_starts[c + 1]):
            x0, y0, x1, y1 = segments[e, 0], segments[e, 1], segments[e, 2], segments[e, 3]
            dx, dy = x1 - x0, y1 - y0
            if near and c != nearest:
                best = min(best, _segment_distance2(segments, e, x, y))
            if crossable and (y0 > y) != (y1 > y) and x < x0 + (y - y0) * dx / dy:
                inside = not inside
    distance = np.sqrt(best)
    return -distance if inside else distance


@numba.njit(cache=True, nogil=True)
def _segment_distance2(segments, e, x, y):
    """Squared distance from (x, y) to segment e."""
    x0, y0, x1, y1 = segments[e, 0], segments[e, 1], segments[e, 2], segments[e, 3]
    dx, dy = x1 - x0, y1 - y0
    length2 = dx * dx + dy * dy
    u = 0.0 if length2 == 0.0 else ((x - x0) * dx + (y - y0) * dy) / length2
    u = min(max(u, 0.0), 1.0)
    ex, ey = x0 + u * dx - x, y0 + u * dy - y
    return ex * ex + ey * ey


@numba.njit(cache=True, inline="always")
def _box_bound(boxes, g, x, y):
    """Signed distance to polygon g's bounding box: a lower bound of the signed distance to the
    polygon."""
    x_lo, x_hi = boxes[g, 0], boxes[g, 2]
    if not x_lo <= x_hi:
        return np.inf  # an empty polygon's
    dx = max(x_lo - x, x - x_hi)
    dy = max(boxes[g, 1] - y, y - boxes[g, 3])
    if dx <= 0.0 and dy <= 0.0:
        return max(dx, dy)
    return np.sqrt(max(dx, 0.0) ** 2 + max(dy, 0.0) ** 2)


@numba.njit(cache=True, inline="always")
def _support_bound(supports, directions, g, x, y):
    """max_n (n . p - h(n)) less the margin: a lower bound of the signed distance to polygon g
    (+inf for an empty one, whose support values are -inf)."""
    best = -np.inf
    for k in range(directions.shape[0]):
        best = max(best, directions[k, 0] * x + directions[k, 1] * y - supports[g, k])
    return best - SUPPORT_MARGIN * (1.0 + abs(x) + abs(y))


@numba.njit(cache=True, nogil=True)
def _all_signed(
    segments, segment_starts, chunk_boxes, chunk_starts, x0, y0, c, s, xs, ys, which, out
):
    for i in range(len(xs)):
        x, y = _to_frame(x0, y0, c, s, xs[i], ys[i])
        out[i] = _signed(segments, segment_starts, chunk_boxes, chunk_starts, which[i], x, y)


@numba.njit(cache=True, inline="always")
def _evaluate(rings, which, xs, ys, group, p, out):
    """Point p's value, the least signed distance of its probes, whose lower bounds are in
    ``out``: probes measured (into ``out``) in increasing order of their bounds until the next
    bound is no less than the least distance found (the rest keep their bounds). ``rings``: the
    pack's segments, segment starts, chunk boxes and chunk starts."""
    segments, segment_starts, chunk_boxes, chunk_starts = rings
    first = p * group
    if group == 1:
        out[first] = _signed(
            segments,
            segment_starts,
            chunk_boxes,
            chunk_starts,
            which[first],
            xs[first],
            ys[first],
            out[first] > 0.0,
        )
        return out[first]
    least = np.inf
    done = 0  # a bit per probe measured (a footprint has at most 16 discs)
    for _ in range(group):
        i, bound = -1, np.inf
        for g in range(group):
            if not (done >> g) & 1 and out[first + g] < bound:
                i, bound = first + g, out[first + g]
        if i < 0 or bound >= least:
            break
        done |= 1 << (i - first)
        out[i] = _signed(
            segments, segment_starts, chunk_boxes, chunk_starts, which[i], xs[i], ys[i], bound > 0.0
        )
        least = min(least, out[i])
    return least


@numba.njit(cache=True, inline="always")
def _refine(supports, directions, which, xs, ys, group, p, out):
    """Point p's value with each probe's bound raised to its support bound where that is
    larger."""
    least = np.inf
    for i in range(p * group, (p + 1) * group):
        out[i] = max(out[i], _support_bound(supports, directions, which[i], xs[i], ys[i]))
        least = min(least, out[i])
    return least


@numba.njit(cache=True, inline="always")
def _trajectory(rings, bounds, which, xs, ys, group, a, b, threshold, exact, value, out):
    """The values of points ``a:b`` (module docstring), from their box bounds in ``value`` (their
    probes' in ``out``): the point of least bound evaluated, then, in order, each point whose
    bound is below the least value found refined and, if still below, evaluated; if the least
    value is below ``threshold``, the points in order again until the first whose distance is.
    ``bounds``: the pack's support values and :data:`DIRECTIONS`; ``exact``: the points
    evaluated."""
    supports, directions = bounds
    first, first_bound = -1, np.inf
    for p in range(a, b):
        if value[p] < first_bound:
            first, first_bound = p, value[p]
    if first < 0:
        return  # every bound infinite: no polygon at these points' times
    least = _evaluate(rings, which, xs, ys, group, first, out)
    value[first] = least
    exact[first] = True
    for p in range(a, b):
        if exact[p] or value[p] >= least:
            continue
        value[p] = _refine(supports, directions, which, xs, ys, group, p, out)
        if value[p] >= least:
            continue
        value[p] = _evaluate(rings, which, xs, ys, group, p, out)
        exact[p] = True
        least = min(least, value[p])
    if least >= threshold:
        return
    for p in range(a, b):
        if value[p] >= threshold:
            continue
        if not exact[p]:
            value[p] = _refine(supports, directions, which, xs, ys, group, p, out)
            if value[p] >= threshold:
                continue
            value[p] = _evaluate(rings, which, xs, ys, group, p, out)
            exact[p] = True
        if value[p] < threshold:
            break


@numba.njit(cache=True, nogil=True)
def _surrogates(geometry, x0, y0, c, s, world_x, world_y, which, spans, threshold, out):
    begins, ends, group = spans
    segments, segment_starts, chunk_boxes, chunk_starts, boxes, supports, directions = geometry
    rings = (segments, segment_starts, chunk_boxes, chunk_starts)
    bounds = (supports, directions)
    xs = np.empty(len(world_x))
    ys = np.empty(len(world_y))
    for i in range(len(world_x)):
        xs[i], ys[i] = _to_frame(x0, y0, c, s, world_x[i], world_y[i])
        out[i] = _box_bound(boxes, which[i], xs[i], ys[i])
    points = len(xs) // group
    exact = np.zeros(points, dtype=np.bool_)
    # A point of one probe is its value: the compiler, given the constant 1 and one array,
    # drops the loops over a point's probes.
    if group == 1:
        for k in range(len(begins)):
            _trajectory(
                rings, bounds, which, xs, ys, 1, begins[k], ends[k], threshold, exact, out, out
            )
        return
    value = np.empty(points, dtype=np.float64)
    for p in range(points):
        value[p] = out[p * group]
        for i in range(p * group + 1, (p + 1) * group):
            value[p] = min(value[p], out[i])
    for k in range(len(begins)):
        _trajectory(
            rings, bounds, which, xs, ys, group, begins[k], ends[k], threshold, exact, value, out
        )
