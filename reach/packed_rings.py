"""Signed distances to polygons by a compiled kernel, reduced per trajectory where that suffices.

A polygon (or a multipolygon, with holes) is packed as the segments of its rings; the signed
distance of a point is the least distance to a segment, negative where a ray from the point
crosses the rings an odd number of times (inside): the same quantity as
``reach.distances.signed_distance`` (GEOS), computed without a geometry object per point.

A batch check needs per trajectory only its least clearance and its first colliding point, not
every point's distance. :func:`trajectory_surrogates` returns per point a *surrogate* s_i: the
exact signed distance d_i where it evaluated it, else a lower bound of it, the signed distance to
the polygon's bounding box (the polygon lies in its box: outside, the box is nearer; inside, the
point is at most as deep in the polygon as in the box). It evaluates points in increasing order of
their bound until the next bound is no less than the least distance found, so every point left
has d_i >= s_i >= min_j d_j: ``min s = min d``; and, in order, every point whose bound is below
the threshold until the first whose distance is, so the first s_i below the threshold is the first
d_i below it. Reductions of s by minimum and by first index below the threshold are therefore
those of d.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import shapely
from shapely.geometry import box
from shapely.geometry.base import BaseGeometry

#: Segments per chunk: a chunk's bounding box lets a point skip its segments together.
CHUNK = 8


@dataclass(frozen=True)
class PackedRings:
    """Polygons' ring segments ``[E, 4]`` as (x0, y0, x1, y1), in chunks of at most
    :data:`CHUNK` consecutive segments of one polygon with their bounding boxes ``[C, 4]`` (x_lo,
    y_lo, x_hi, y_hi); polygon g's chunks are ``chunk_starts[g]:chunk_starts[g + 1]``, chunk c's
    segments ``segment_starts[c]:segment_starts[c + 1]``; ``boxes[g]`` polygon g's bounding
    box."""

    segments: np.ndarray
    segment_starts: np.ndarray
    chunk_boxes: np.ndarray
    chunk_starts: np.ndarray
    boxes: np.ndarray


def pack_rings(geometries: list[BaseGeometry]) -> PackedRings:
    """The ring segments and bounding boxes of ``geometries`` (polygons or multipolygons; an
    empty one has no segments and an empty box, every point infinitely far from it)."""
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
    )


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


def signed_distances_packed(packed: PackedRings, which: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Signed distance of each point ``xy[i]`` to polygon ``which[i]`` of ``packed``."""
    out = np.empty(len(xy), dtype=np.float64)
    _all_signed(*_arrays(packed), *_points(xy), np.asarray(which, dtype=np.int64), out)
    return out


def trajectory_surrogates(
    packed: PackedRings,
    which: np.ndarray,
    xy: np.ndarray,
    starts: np.ndarray,
    threshold: float,
    group: int = 1,
) -> np.ndarray:
    """Per probe, its signed distance to polygon ``which[i]`` or a lower bound of it, such that per
    trajectory the least value and the first point whose value is below ``threshold`` are those of
    the signed distances (see the module docstring). A point is ``group`` consecutive probes (a
    footprint's discs) and its value their least; trajectory k is the points
    ``starts[k]:starts[k + 1]``."""
    out = np.empty(len(xy), dtype=np.float64)
    begins = np.asarray(starts, dtype=np.int64)
    ends = np.append(begins[1:], len(xy) // group)
    _surrogates(
        *_arrays(packed),
        packed.boxes,
        *_points(xy),
        np.asarray(which, dtype=np.int64),
        (begins, ends, group),
        float(threshold),
        out,
    )
    return out


def compile_ring_kernels() -> None:
    """Compile (or load from numba's cache) the kernels before a check needs them (the first
    compilation after a change takes seconds)."""
    packed = pack_rings([box(0.0, 0.0, 1.0, 1.0)])
    xy = np.array([[0.5, 0.5], [2.0, 0.5]])
    signed_distances_packed(packed, np.zeros(2, dtype=np.int64), xy)
    trajectory_surrogates(packed, np.zeros(2, dtype=np.int64), xy, np.array([0]), 0.0)


def _arrays(packed: PackedRings) -> tuple[np.ndarray, ...]:
    return packed.segments, packed.segment_starts, packed.chunk_boxes, packed.chunk_starts


def _points(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return (
        np.ascontiguousarray(xy[:, 0], dtype=np.float64),
        np.ascontiguousarray(xy[:, 1], dtype=np.float64),
    )


@numba.njit(cache=True)
def _signed(segments, segment_starts, chunk_boxes, chunk_starts, g, x, y):
    """Signed distance from (x, y) to polygon g (+inf if it has no segments). A chunk whose box is
    no nearer than the nearest segment found, and that a ray from the point towards +x cannot
    cross, is skipped."""
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
        crossable = by0 <= y < by1 and x < bx1
        if not (near or crossable):
            continue
        for e in range(segment_starts[c], segment_starts[c + 1]):
            x0, y0, x1, y1 = segments[e, 0], segments[e, 1], segments[e, 2], segments[e, 3]
            dx, dy = x1 - x0, y1 - y0
            if near and c != nearest:
                best = min(best, _segment_distance2(segments, e, x, y))
            if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * dx / dy:
                inside = not inside
    distance = np.sqrt(best)
    return -distance if inside else distance


@numba.njit(cache=True)
def _segment_distance2(segments, e, x, y):
    """Squared distance from (x, y) to segment e."""
    x0, y0, x1, y1 = segments[e, 0], segments[e, 1], segments[e, 2], segments[e, 3]
    dx, dy = x1 - x0, y1 - y0
    length2 = dx * dx + dy * dy
    u = 0.0 if length2 == 0.0 else ((x - x0) * dx + (y - y0) * dy) / length2
    u = min(max(u, 0.0), 1.0)
    ex, ey = x0 + u * dx - x, y0 + u * dy - y
    return ex * ex + ey * ey


@numba.njit(cache=True)
def _box_bound(box, x, y):
    """Signed distance to the box: a lower bound of the signed distance to a polygon inside it."""
    if not box[0] <= box[2]:
        return np.inf  # an empty polygon's
    dx = max(box[0] - x, x - box[2])
    dy = max(box[1] - y, y - box[3])
    if dx <= 0.0 and dy <= 0.0:
        return max(dx, dy)
    return np.sqrt(max(dx, 0.0) ** 2 + max(dy, 0.0) ** 2)


@numba.njit(cache=True)
def _all_signed(segments, segment_starts, chunk_boxes, chunk_starts, xs, ys, which, out):
    for i in range(len(xs)):
        out[i] = _signed(
            segments, segment_starts, chunk_boxes, chunk_starts, which[i], xs[i], ys[i]
        )


#: Trajectories up to this long find their next point by a scan, longer ones sort their bounds.
SCAN_POINTS = 64


@numba.njit(cache=True, inline="always")
def _evaluate(rings, xs, ys, which, group, p, out):
    """Point p's value, the least signed distance of its probes, whose lower bounds are in
    ``out``: probes measured (into ``out``) in increasing order of their bounds until the next
    bound is no less than the least distance found (the rest keep their bounds)."""
    segments, segment_starts, chunk_boxes, chunk_starts = rings
    first = p * group
    if group == 1:
        out[first] = _signed(
            segments, segment_starts, chunk_boxes, chunk_starts, which[first], xs[first], ys[first]
        )
        return out[first]
    least = np.inf
    done = np.zeros(group, dtype=np.bool_)
    for _ in range(group):
        i, bound = -1, np.inf
        for g in range(group):
            if not done[g] and out[first + g] < bound:
                i, bound = first + g, out[first + g]
        if i < 0 or bound >= least:
            break
        done[i - first] = True
        out[i] = _signed(
            segments, segment_starts, chunk_boxes, chunk_starts, which[i], xs[i], ys[i]
        )
        least = min(least, out[i])
    return least


@numba.njit(cache=True, inline="always")
def _least_by_bounds(rings, xs, ys, which, group, a, b, exact, value, out):
    """The least value of points ``a:b`` whose lower bounds are in ``value``: points evaluated
    (``exact``, ``value``, their probes' ``out``) in increasing order of their bounds until the
    next bound is no less than the least value found."""
    least = np.inf
    order = np.argsort(value[a:b]) + a if b - a > SCAN_POINTS else np.empty(0, dtype=np.int64)
    for r in range(b - a):
        if len(order):
            p = order[r]
        else:  # the unevaluated point of least bound
            p, bound = -1, np.inf
            for j in range(a, b):
                if not exact[j] and value[j] < bound:
                    p, bound = j, value[j]
            if p < 0:
                break
        if value[p] >= least:
            break
        value[p] = _evaluate(rings, xs, ys, which, group, p, out)
        exact[p] = True
        least = min(least, value[p])
    return least


@numba.njit(cache=True)
def _surrogates(
    segments, segment_starts, chunk_boxes, chunk_starts, boxes, xs, ys, which, spans, threshold, out
):
    begins, ends, group = spans
    rings = (segments, segment_starts, chunk_boxes, chunk_starts)
    points = len(xs) // group
    exact = np.zeros(points, dtype=np.bool_)
    value = np.empty(points, dtype=np.float64)
    for k in range(len(begins)):
        a, b = begins[k], ends[k]
        for p in range(a, b):
            bound = np.inf
            for i in range(p * group, (p + 1) * group):
                out[i] = _box_bound(boxes[which[i]], xs[i], ys[i])
                bound = min(bound, out[i])
            value[p] = bound
        least = _least_by_bounds(rings, xs, ys, which, group, a, b, exact, value, out)
        if least >= threshold:
            continue
        for p in range(a, b):
            if value[p] >= threshold:
                continue
            if not exact[p]:
                value[p] = _evaluate(rings, xs, ys, which, group, p, out)
                exact[p] = True
            if value[p] < threshold:
                break
