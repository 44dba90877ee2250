"""Signed distances from points to sets (negative inside: minus the depth), vectorised.

The clearance of a collision check is the signed distance to K minus R_col (API.md, "Collision
check"): a point is in C = K ⊕ R_col exactly when its distance to K is at most R_col.
"""

from __future__ import annotations

import math
from typing import Any

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
    return _on_boxes(_box_union_until, x, y, boxes, until)


def _on_boxes(
    kernel: Any, x: np.ndarray, y: np.ndarray, boxes: np.ndarray, until: np.ndarray
) -> np.ndarray:
    """``kernel(x, y, boxes, until, out)`` on contiguous arrays (float64, ``until`` int64), its
    values ``out`` [x.shape]."""
    out = np.empty(x.shape, dtype=np.float64)
    kernel(
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


#: Boxes per leaf of the tree :func:`union_box_distances_until` searches.
LEAF_BOXES = 4


def union_box_distances_until(
    x: np.ndarray, y: np.ndarray, boxes: np.ndarray, until: np.ndarray
) -> np.ndarray:
    """The least of :func:`box_union_distances_until` over the members of A unions, each union's
    members sharing a frame and a layout of boxes: ``x``, ``y`` [A, N], ``boxes`` [A, W, K, 4]
    (window w of member k), ``until`` [A, N] (windows ``0 .. until - 1`` count for that point).
    The same values bit for bit: the least depth over the counted boxes if at most 0, else the
    root of the least squared distance, which is the least member's value either way.

    Each union's W * K boxes are put in a tree of enclosing boxes (leaves of
    :data:`LEAF_BOXES` boxes in the Z-order of their centres and windows, each node the box
    around its children and the first window under it), searched from the root per point, the
    child whose box is deeper first. A node's box bounds each box under it from below, both
    ``max(dx, dy)`` and the squared distance (floating-point subtraction, products and sums of
    non-negative values are monotone), so a node whose bounds cannot lower what the boxes
    measured already have found, or whose boxes all come after the point's windows, is skipped
    without changing the result."""
    return _on_boxes(_union_until, x, y, boxes, until)


@numba.njit(cache=True, inline="always")
def _box_terms(box, px, py):  # type: ignore[no-untyped-def]
    """A box's ``max(dx, dy)`` at a point and its squared distance from it."""
    dx = max(box[0] - px, px - box[1])
    dy = max(box[2] - py, py - box[3])
    depth = max(dx, dy)
    dx, dy = max(dx, 0.0), max(dy, 0.0)
    return depth, dx * dx + dy * dy


@numba.njit(cache=True, inline="always")
def _spread_bits(v):  # type: ignore[no-untyped-def]
    """The low 10 bits of ``v`` spread to every third bit (a Z-order code's third)."""
    v &= 0x3FF
    v = (v | (v << 16)) & 0x030000FF
    v = (v | (v << 8)) & 0x0300F00F
    v = (v | (v << 4)) & 0x030C30C3
    return (v | (v << 2)) & 0x09249249


@numba.njit(cache=True)
def _z_order(flat, members):  # type: ignore[no-untyped-def]
    """The boxes ([W * K, 4], box i of window ``i // members``) in the Z-order of their centres
    and windows on a grid of 1024 steps a side (space on one scale), so that a node of the tree
    holds boxes near each other in space and in time."""
    cx = flat[:, 0] + flat[:, 1]
    cy = flat[:, 2] + flat[:, 3]
    x0, y0 = cx.min(), cy.min()
    step = 1023.0 / max(cx.max() - x0, cy.max() - y0, 1e-300)
    per_window = 1023.0 / max(len(flat) // members - 1, 1)
    codes = np.empty(len(flat), dtype=np.int64)
    for i in range(len(flat)):
        qx = np.int64(min(max((cx[i] - x0) * step, 0.0), 1023.0))
        qy = np.int64(min(max((cy[i] - y0) * step, 0.0), 1023.0))
        qt = np.int64(min((i // members) * per_window, 1023.0))
        codes[i] = _spread_bits(qx) | (_spread_bits(qy) << 1) | (_spread_bits(qt) << 2)
    return np.argsort(codes)


@numba.njit(cache=True)
def _box_tree(flat, members):  # type: ignore[no-untyped-def]
    """The tree of :func:`union_box_distances_until` over ``flat`` [W * K, 4] (box i is window
    ``i // members``): the boxes' order, and per node (a heap: node j's children are 2j + 1 and
    2j + 2; the last ``leaves`` nodes are the leaves) its box and its first window. Padding
    leaves hold no box: an empty box after every window."""
    order = _z_order(flat, members)
    leaves = 1
    while leaves * LEAF_BOXES < len(flat):
        leaves *= 2
    box = np.empty((2 * leaves - 1, 4))
    first = np.empty(2 * leaves - 1, dtype=np.int64)
    for node in range(leaves - 1, 2 * leaves - 1):
        box[node, 0], box[node, 1], box[node, 2], box[node, 3] = np.inf, -np.inf, np.inf, -np.inf
        first[node] = np.iinfo(np.int64).max
        start = (node - leaves + 1) * LEAF_BOXES
        for i in range(start, min(start + LEAF_BOXES, len(flat))):
            _enclose(box[node], flat[order[i]])
            first[node] = min(first[node], order[i] // members)
    for node in range(leaves - 2, -1, -1):
        box[node, :] = box[2 * node + 1, :]
        _enclose(box[node], box[2 * node + 2])
        first[node] = min(first[2 * node + 1], first[2 * node + 2])
    return order, box, first, leaves


@numba.njit(cache=True, inline="always")
def _enclose(outer, inner):  # type: ignore[no-untyped-def]
    """Grow the box ``outer`` to hold ``inner``, in place."""
    outer[0] = min(outer[0], inner[0])
    outer[1] = max(outer[1], inner[1])
    outer[2] = min(outer[2], inner[2])
    outer[3] = max(outer[3], inner[3])


@numba.njit(cache=True)
def _tree_distance(px, py, limit, flat, members, tree, stack):  # type: ignore[no-untyped-def]
    """One point's value of :func:`union_box_distances_until`, the boxes of windows before
    ``limit`` counted, searched in ``tree`` (:func:`_box_tree`) with ``stack`` for the nodes."""
    order, box, first, leaves = tree
    least, nearest = np.inf, np.inf
    top, stack[0] = 0, 0
    while top >= 0:
        node = stack[top]
        top -= 1
        depth, near = _box_terms(box[node], px, py)
        if first[node] >= limit or (depth >= least and (least <= 0.0 or near >= nearest)):
            continue
        if node >= leaves - 1:
            start = (node - leaves + 1) * LEAF_BOXES
            for i in range(start, min(start + LEAF_BOXES, len(flat))):
                if order[i] // members < limit:
                    depth, near = _box_terms(flat[order[i]], px, py)
                    least, nearest = min(least, depth), min(nearest, near)
            continue
        left = 2 * node + 1
        deeper = _box_terms(box[left], px, py)[0] <= _box_terms(box[left + 1], px, py)[0]
        stack[top + 1], stack[top + 2] = (left + 1, left) if deeper else (left, left + 1)
        top += 2
    return least if least <= 0.0 else math.sqrt(nearest)


@numba.njit(cache=True, nogil=True)
def _union_until(x, y, boxes, until, out):  # type: ignore[no-untyped-def]
    """:func:`union_box_distances_until`: each union's tree built once, searched per point."""
    windows, members = boxes.shape[1], boxes.shape[2]
    for a in range(x.shape[0]):
        if windows * members == 0:
            out[a, :] = np.inf
            continue
        flat = boxes[a].reshape(windows * members, 4)
        tree = _box_tree(flat, members)
        stack = np.empty(2 * (int(np.log2(tree[3])) + 2), dtype=np.int64)
        for n in range(x.shape[1]):
            out[a, n] = _tree_distance(x[a, n], y[a, n], until[a, n], flat, members, tree, stack)


def compile_distance_kernels() -> None:
    """Compile (or load from numba's cache) this module's kernels before a check needs them."""
    box_union_distances_until(
        np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1, 4)), np.ones((1, 1), np.int64)
    )
    union_box_distances_until(
        np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1, 1, 4)), np.ones((1, 1), np.int64)
    )


def signed_distances(geometries: np.ndarray, rows: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``signed_distance(geometries[rows[i]], xy[i])`` for every point i, in one vectorised call
    each; each geometry is prepared and its boundary taken once, however many points it serves."""
    shapely.prepare(geometries)  # what contains_xy does to a single geometry: in place, kept
    inside = shapely.contains_xy(geometries[rows], xy[:, 0], xy[:, 1])
    distance = shapely.distance(shapely.boundary(geometries)[rows], shapely.points(xy))
    signed = np.where(inside, -distance, distance)
    return np.where(shapely.is_empty(geometries)[rows], np.inf, signed)
