"""The envelope fit's linear programmes (``service.flows.bounds``), compiled: the highest-area line
below points.

Per row k: the start/end values (a_k, b_k) maximising ``a + b`` subject to
``(1 - w_j) a + w_j b <= c_kj`` and ``a, b >= floor_k`` (the envelope fit of
``service.flows.bounds.fit_bounds``, the paper's ``u~_min^tau`` with every step contained). Two
variables: the optimum is a vertex, the intersection of two constraints, and every vertex is
enumerated. Rows are independent, so a frame's programmes (four per mode of every agent) are
solved in one compiled pass, each row by the same operations whatever the others.

A vertex whose objective is no higher than the best feasible one found so far cannot be the
optimum, so its feasibility is only tested where it could be (the same maximum, fewer tests).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np


@dataclass(frozen=True)
class Vertices:
    """What the vertex enumeration needs from the abscissae w alone (the same for the four lines
    of one fit, and for every prediction with the same steps): the constraint matrix G [m + 2, 2]
    and, per pair of constraints that intersect, their rows and the determinant."""

    G: np.ndarray
    i: np.ndarray
    j: np.ndarray
    det: np.ndarray


@lru_cache(maxsize=64)
def vertices(n: int, dt: float, horizon: float) -> Vertices:
    """:class:`Vertices` of the step boundaries ``w = (0, dt, ..., (n - 1) dt, horizon) /
    horizon``: the constraints ``(1 - w_j, w_j)``, then ``-a <= -floor`` and ``-b <= -floor``."""
    w = np.append(np.arange(n, dtype=np.float64) * dt, horizon) / horizon
    G = np.vstack([np.column_stack([1.0 - w, w]), [[-1.0, 0.0], [0.0, -1.0]]])
    i, j = np.triu_indices(G.shape[0], k=1)
    det = G[i, 0] * G[j, 1] - G[i, 1] * G[j, 0]
    keep = np.abs(det) > 1e-12
    arrays = (
        np.ascontiguousarray(G),
        np.ascontiguousarray(i[keep], dtype=np.int64),
        np.ascontiguousarray(j[keep], dtype=np.int64),
        np.ascontiguousarray(det[keep]),
    )
    for array in arrays:
        array.flags.writeable = False  # cached: shared by every later fit
    return Vertices(*arrays)


def max_lines_below(
    v: Vertices, w: np.ndarray, c: np.ndarray, floor: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per row k of ``c`` [K, m]: start/end values (a_k, b_k) of the highest-area line below the
    points (w_j, c_kj), with a_k, b_k >= floor_k (``v`` = :func:`vertices` of ``w``).

    Feasibility is tested with a tolerance of ``1e-10 (1 + max |h_k|)`` (h_k the row's right-hand
    sides); where the optimum is an edge (several lines touch the same point at mid-horizon), the
    middle of that edge is taken: the mean of its vertices of least and greatest slope ``b - a``
    (the first of equal ones in pair order). Any rounding excess over a c_kj is finally
    subtracted, so the line never rises above a point."""
    c = np.ascontiguousarray(c, dtype=np.float64)
    floor = np.ascontiguousarray(floor, dtype=np.float64)
    a_out = np.empty(len(c))
    b_out = np.empty(len(c))
    _solve(v.G, v.i, v.j, v.det, np.ascontiguousarray(w, dtype=np.float64), c, floor, a_out, b_out)
    return a_out, b_out


def compile_envelope_kernels() -> None:
    """Compile (or load from numba's cache) the kernel before a frame needs it."""
    v = vertices(2, 1.0, 2.0)
    max_lines_below(v, np.array([0.0, 0.5, 1.0]), np.zeros((1, 3)), np.array([-1.0]))


@numba.njit(cache=True, inline="always")
def _vertex(G, i, j, det, h, p):
    """Vertex p: the intersection of constraints i[p] and j[p] (Cramer's rule)."""
    hi_, hj = h[i[p]], h[j[p]]
    gi0, gi1, gj0, gj1 = G[i[p], 0], G[i[p], 1], G[j[p], 0], G[j[p], 1]
    return (hi_ * gj1 - gi1 * hj) / det[p], (gi0 * hj - hi_ * gj0) / det[p]


@numba.njit(cache=True, inline="always")
def _feasible(G, h, tol, a, b):
    for r in range(len(h)):  # noqa: SIM110 (a loop numba compiles)
        if not G[r, 0] * a + G[r, 1] * b <= h[r] + tol:
            return False
    return True


@numba.njit(cache=True)
def _solve(G, i, j, det, w, c, floor, a_out, b_out):
    m = c.shape[1]
    h = np.empty(m + 2)
    for k in range(len(c)):
        h[:m] = c[k]
        h[m] = -floor[k]
        h[m + 1] = -floor[k]
        largest = 0.0
        for q in range(m + 2):
            largest = max(largest, abs(h[q]))
        tol = 1e-10 * (1.0 + largest)
        best = -np.inf  # never stays so: a = b = floor is a feasible vertex
        for p in range(len(det)):
            a, b = _vertex(G, i, j, det, h, p)
            if a + b > best and _feasible(G, h, tol, a, b):
                best = a + b
        lo_a = lo_b = hi_a = hi_b = 0.0
        lo_slope, hi_slope = np.inf, -np.inf
        for p in range(len(det)):
            a, b = _vertex(G, i, j, det, h, p)
            if not (a + b >= best - tol and _feasible(G, h, tol, a, b)):
                continue
            if b - a < lo_slope:
                lo_slope, lo_a, lo_b = b - a, a, b
            if b - a > hi_slope:
                hi_slope, hi_a, hi_b = b - a, a, b
        a_opt = 0.5 * (lo_a + hi_a)
        b_opt = 0.5 * (lo_b + hi_b)
        excess = 0.0
        for q in range(m):
            excess = max(excess, (1.0 - w[q]) * a_opt + w[q] * b_opt - c[k, q])
        a_out[k] = a_opt - excess
        b_out[k] = b_opt - excess
