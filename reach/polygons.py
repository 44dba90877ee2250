"""Convex polygons from half-planes: {p : p . (cos phi_m, sin phi_m) <= h_m for every m}.

A support vector h [M] in directions phi [M] describes a convex polygon as the intersection of M
half-planes; its vertices are the intersections of pairs of boundary lines that satisfy every
constraint, sorted by angle about their centre (every feasible pair is kept, so a redundant
constraint cannot cut a corner off). The kernel is compiled by numba (``compile_polygon_kernel``
warms it before a request needs it). One builder for every polygon the service and the evaluation
draw: the outer bound's, the partition's bins', the tubes' windows.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np
import shapely


@functools.lru_cache(maxsize=8)
def _line_pairs(directions: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every pair of non-parallel boundary lines p . n_a = h_a, p . n_b = h_b: the indices
    (a, b) and the inverse of [[n_a], [n_b]] (the same for every support vector: computed once)."""
    angles = np.asarray(directions)
    normals = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    i, j = np.triu_indices(len(angles), k=1)
    pairs = np.stack([normals[i], normals[j]], axis=1)  # [P, 2, 2]
    ok = np.abs(np.linalg.det(pairs)) > 1e-9
    return i[ok], j[ok], np.linalg.inv(pairs[ok])


@numba.njit(cache=True)
def _feasible_vertices(
    first: np.ndarray,
    second: np.ndarray,
    inverse: np.ndarray,
    normals: np.ndarray,
    supports: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The vertices of {p : p . normal_m <= supports[k, m] for all m} for every row k of
    ``supports`` [K, M]: the intersections of every pair of boundary lines (``first``, ``second``
    [P], solved by their ``inverse`` [P, 2, 2], ``_line_pairs``) that satisfy every constraint,
    packed at the front of the row (x, y [K, P, 2]) and sorted by angle about their centre, and
    their counts [K]. Keeping all feasible pairs means redundant constraints cannot cut a corner
    off; a candidate stops being checked at the first constraint it breaks."""
    rows, directions = supports.shape
    pairs = len(first)
    points = np.empty((rows, pairs, 2))
    count = np.zeros(rows, dtype=np.int64)
    for k in range(rows):
        n = 0
        for q in range(pairs):
            a, b = supports[k, first[q]], supports[k, second[q]]
            x = inverse[q, 0, 0] * a + inverse[q, 0, 1] * b
            y = inverse[q, 1, 0] * a + inverse[q, 1, 1] * b
            inside = True
            for m in range(directions):
                slack = 1e-7 * (1 + abs(supports[k, m]))
                if x * normals[0, m] + y * normals[1, m] > supports[k, m] + slack:
                    inside = False
                    break
            if inside:
                points[k, n, 0], points[k, n, 1] = x, y
                n += 1
        if n:
            centre_x, centre_y = points[k, :n, 0].mean(), points[k, :n, 1].mean()
            angle = np.arctan2(points[k, :n, 1] - centre_y, points[k, :n, 0] - centre_x)
            points[k, :n] = points[k, :n][np.argsort(angle, kind="mergesort")]
        count[k] = n
    return points, count


def _vertices(directions: np.ndarray, supports: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``_feasible_vertices`` for evenly or unevenly spaced ``directions`` [M] (angles)."""
    first, second, inverse = _line_pairs(tuple(float(d) for d in directions))
    normals = np.stack([np.cos(directions), np.sin(directions)]).astype(np.float64)
    return _feasible_vertices(
        first, second, inverse, normals, np.ascontiguousarray(supports, dtype=np.float64)
    )


def half_plane_polygons(directions: np.ndarray, supports: np.ndarray) -> list[np.ndarray]:
    """Vertices (counter-clockwise) of {p : p . (cos phi_m, sin phi_m) <= support[k, m] for all m},
    for every row k of ``supports`` [K, M] (compiled, ``_feasible_vertices``: 32 directions cost
    what 16 did in numpy); each polygon is convex."""
    points, count = _vertices(directions, supports)
    return [points[k, :n] for k, n in enumerate(count.tolist())]


def convex_polygons(directions: np.ndarray, supports: np.ndarray) -> np.ndarray:
    """The polygons of :func:`half_plane_polygons` as shapely polygons [K], built for all rows at
    once (an empty polygon where the half-planes do not meet)."""
    points, count = _vertices(directions, supports)
    if np.any((count > 0) & (count < 3)):
        raise ValueError("half-planes meeting in a point or a segment make no polygon")
    polygons = np.empty(len(count), dtype=object)
    polygons[:] = shapely.Polygon()
    full = count >= 3
    if full.any():
        coords = points[np.arange(points.shape[1])[None, :] < count[:, None]]
        ring_of = np.repeat(np.arange(int(full.sum())), count[full])
        polygons[full] = shapely.polygons(shapely.linearrings(coords, indices=ring_of))
    return polygons


def compile_polygon_kernel() -> None:
    """Compile (or load from numba's cache) :func:`half_plane_polygons`' kernel before a request
    needs it (the first compilation after a change takes seconds)."""
    half_plane_polygons(np.arange(4) * (math.pi / 2), np.ones((1, 4)))


def half_plane_polygon(directions: np.ndarray, support: np.ndarray) -> np.ndarray:
    """The polygon of one support vector (see half_plane_polygons)."""
    return half_plane_polygons(directions, support[None, :])[0]
