"""Signed distances from points to sets (negative inside: minus the depth), vectorised.

The clearance of a collision check is the signed distance to K minus R_col (API.md, "Collision
check"): a point is in C = K ⊕ R_col exactly when its distance to K is at most R_col.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry


def signed_distance(geometry: BaseGeometry, xy: np.ndarray) -> np.ndarray:
    """Distance from each point to ``geometry``; negative inside (minus the depth).

    Outside a polygon the distance to it is the distance to its boundary, so one distance call
    serves both sides."""
    if geometry.is_empty:
        return np.full(len(xy), np.inf)
    inside = shapely.contains_xy(geometry, xy[:, 0], xy[:, 1])
    distance = shapely.distance(geometry.boundary, shapely.points(xy))
    return np.where(inside, -distance, distance)


def box_union_distances(
    x: np.ndarray, y: np.ndarray, boxes: np.ndarray, counted: np.ndarray | None = None
) -> np.ndarray:
    """Distance from points to a union of axis-aligned boxes, for many sets at once: ``x``, ``y``
    [..., N, 1], ``boxes`` [..., 1, M, 4] as (x_lo, x_hi, y_lo, y_hi), ``counted`` [..., N, M]
    (None: every box counts for every point). Exact outside the union; inside, minus the depth
    in the deepest single box (at most the depth in the union).

    Per box: ``max(dx, dy)`` inside it (both <= 0), else the hypotenuse of their positive parts;
    squared distances are compared and one square root taken per point."""
    dx = np.maximum(boxes[..., 0] - x, x - boxes[..., 1])  # [..., N, M]
    dy = np.maximum(boxes[..., 2] - y, y - boxes[..., 3])
    depth = np.maximum(dx, dy)
    np.maximum(dx, 0.0, out=dx)
    np.maximum(dy, 0.0, out=dy)
    np.multiply(dx, dx, out=dx)
    np.multiply(dy, dy, out=dy)
    np.add(dx, dy, out=dx)
    if counted is not None:
        depth[~counted] = np.inf
        dx[~counted] = np.inf
    least = depth.min(axis=-1)
    return np.where(least <= 0.0, least, np.sqrt(dx.min(axis=-1)))


def box_union_distances_until(
    x: np.ndarray, y: np.ndarray, boxes: np.ndarray, until: np.ndarray
) -> np.ndarray:
    """:func:`box_union_distances` of A sets at N points each with a prefix of each set's boxes
    counted per point: ``x``, ``y`` [A, N], ``boxes`` [A, M, 4], ``until`` [A, N] (boxes
    ``0 .. until - 1`` count for that point). The same values bit for bit, in one compiled pass
    without the [A, N, M] temporaries."""
    out = np.empty(x.shape, dtype=np.float64)
    _box_union_until(
        np.ascontiguousarray(x, dtype=np.float64),
        np.ascontiguousarray(y, dtype=np.float64),
        np.ascontiguousarray(boxes, dtype=np.float64),
        np.ascontiguousarray(until, dtype=np.int64),
        out,
    )
    return out


@numba.njit(cache=True)
def _box_union_until(x, y, boxes, until, out):  # type: ignore[no-untyped-def]
    """:func:`box_union_distances`' arithmetic per set, point and counted box: the least
    ``max(dx, dy)`` (the depth, if at most 0), else the root of the least squared distance."""
    for a in range(x.shape[0]):
        for n in range(x.shape[1]):
            px, py = x[a, n], y[a, n]
            least, nearest = np.inf, np.inf
            for m in range(min(until[a, n], boxes.shape[1])):
                dx = max(boxes[a, m, 0] - px, px - boxes[a, m, 1])
                dy = max(boxes[a, m, 2] - py, py - boxes[a, m, 3])
                least = min(least, max(dx, dy))
                dx, dy = max(dx, 0.0), max(dy, 0.0)
                nearest = min(nearest, dx * dx + dy * dy)
            out[a, n] = least if least <= 0.0 else math.sqrt(nearest)


def compile_distance_kernels() -> None:
    """Compile (or load from numba's cache) this module's kernel before a check needs it."""
    box_union_distances_until(
        np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1, 4)), np.ones((1, 1), np.int64)
    )


def signed_distances(geometries: np.ndarray, rows: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``signed_distance(geometries[rows[i]], xy[i])`` for every point i, in one vectorised call
    each; each geometry is prepared and its boundary taken once, however many points it serves."""
    shapely.prepare(geometries)  # what contains_xy does to a single geometry: in place, kept
    inside = shapely.contains_xy(geometries[rows], xy[:, 0], xy[:, 1])
    distance = shapely.distance(shapely.boundary(geometries)[rows], shapely.points(xy))
    signed = np.where(inside, -distance, distance)
    return np.where(shapely.is_empty(geometries)[rows], np.inf, signed)
