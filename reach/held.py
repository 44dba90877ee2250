"""Intervals held by their outer polygons, shown from the outer bound alone.

Between the instants s_(j-1) and s_j a car moves at most r_j = V_j * slice_dt / 2 from where it
is at the nearer of the two, V_j the outer bound's largest speed over the interval's sweeps. So
every position reached during the interval lies in (A ⊕ B(r_j)) ∪ (B ⊕ B(r_j)), A and B the
instants' outer polygons (at s_0, the initial disc), and in the interval's outer polygon Q
(``reach.field_tube.FieldTubeSet``: K over an interval is Q cut to the instants' fields grown by
that much). When Q lies inside that union the cut takes nothing: K over the interval is Q, the
interval is held by its polygon, and no field is needed to draw it.

Q lies inside it when no support of Q exceeds B's (or A's, past the initial disc): Q ⊆ B. Else Q
is cut into equal strips across the way from A's centre to B's (turned by a few angles, in 8 and
then 32 strips), and each strip must lie within r_j of A or within r_j of B. A strip is a convex
polygon (Q between two lines) and the distance to a convex set is a convex function, so a strip
lies within r_j of A exactly when its vertices do: Q's own between the lines and where Q's edges
cross them. A cut that fails proves nothing (the interval is then left to the fields), so every
interval found held is held; the distances are measured with a margin (``HELD_MARGIN_M``) that
covers the rounding of the polygons' vertices.
"""

from __future__ import annotations

import numba
import numpy as np

from reach.polygons import _vertices

#: How far inside r_j every vertex must be (m): more than the polygons' vertices may lie outside
#: their half-planes (``reach.polygons`` keeps those within 1e-7 (1 + |h|), h up to ~100 m).
HELD_MARGIN_M = 1e-4
#: Strips Q is cut into (then four times as many), across the way from A's centre to B's turned
#: by each of these angles (rad).
STRIPS = 8
TURNS = np.array([0.0, 0.4, -0.4, 0.8, -0.8, np.pi / 2])


def held_intervals(
    directions: np.ndarray,
    instant_supports: np.ndarray,
    interval_supports: np.ndarray,
    reach_m: np.ndarray,
    initial_radius_m: float,
    check: np.ndarray,
) -> np.ndarray:
    """Per interval j (``interval_supports[j]`` [J, M], row 0 unused), whether its outer polygon
    lies within ``reach_m[j]`` of the outer polygon of instant j - 1 or j
    (``instant_supports`` [J, M]; instant 0 is the disc of ``initial_radius_m`` about the
    origin), for the intervals ``check`` [J] bool (the others come out False, as interval 0)."""
    instants, instant_counts = _vertices(directions, instant_supports)
    intervals, interval_counts = _vertices(directions, interval_supports)
    return _held(  # type: ignore[no-any-return]
        instants,
        instant_counts,
        intervals,
        interval_counts,
        np.ascontiguousarray(instant_supports, dtype=np.float64),
        np.ascontiguousarray(interval_supports, dtype=np.float64),
        np.asarray(reach_m, dtype=np.float64),
        float(initial_radius_m),
        np.asarray(check, dtype=np.bool_),
        TURNS,
    )


@numba.njit(cache=True)
def _distance_to_polygon(x: float, y: float, vertices: np.ndarray, count: int) -> float:
    """Distance from (x, y) to the convex polygon of ``vertices[:count]`` (counter-clockwise; a
    vertex may repeat): 0 inside, else to the nearest edge."""
    inside = True
    best = np.inf
    for i in range(count):
        ax, ay = vertices[i, 0], vertices[i, 1]
        k = i + 1 if i + 1 < count else 0
        ex, ey = vertices[k, 0] - ax, vertices[k, 1] - ay
        px, py = x - ax, y - ay
        length2 = ex * ex + ey * ey
        if ex * py - ey * px < 0.0:
            inside = False
        t = 0.0 if length2 == 0.0 else min(max((px * ex + py * ey) / length2, 0.0), 1.0)
        dx, dy = px - t * ex, py - t * ey
        best = min(best, np.sqrt(dx * dx + dy * dy))
    return 0.0 if inside else best


@numba.njit(cache=True)
def _distance(x: float, y: float, vertices: np.ndarray, count: int, disc: float) -> float:
    """Distance to the polygon, or to the disc of radius ``disc`` about the origin if >= 0."""
    if disc >= 0.0:
        return max(np.sqrt(x * x + y * y) - disc, 0.0)
    return _distance_to_polygon(x, y, vertices, count)


@numba.njit(cache=True)
def _strip_within(
    q: np.ndarray,
    nq: int,
    ux: float,
    uy: float,
    lo: float,
    hi: float,
    target: np.ndarray,
    nt: int,
    disc: float,
    limit: float,
) -> bool:
    """Whether the part of Q with lo <= p . u <= hi lies within ``limit`` of the target polygon
    (or disc): its vertices, Q's own in the strip and where Q's edges cross its two lines."""
    for i in range(nq):
        x, y = q[i, 0], q[i, 1]
        s = x * ux + y * uy
        if lo <= s <= hi and _distance(x, y, target, nt, disc) > limit:
            return False
        k = i + 1 if i + 1 < nq else 0
        xk, yk = q[k, 0], q[k, 1]
        sk = xk * ux + yk * uy
        for line in (lo, hi):
            if (s < line < sk) or (sk < line < s):
                t = (line - s) / (sk - s)
                cx, cy = x + t * (xk - x), y + t * (yk - y)
                if _distance(cx, cy, target, nt, disc) > limit:
                    return False
    return True


@numba.njit(cache=True)
def _strips_hold(
    q: np.ndarray,
    nq: int,
    a: np.ndarray,
    na: int,
    disc_a: float,
    b: np.ndarray,
    nb: int,
    limit: float,
    ux: float,
    uy: float,
    strips: int,
) -> bool:
    """Whether each of ``strips`` equal strips across Q along u lies within ``limit`` of A or of
    B (the first strip nearest A's side is tried against A first)."""
    first, last = np.inf, -np.inf
    for i in range(nq):
        s = q[i, 0] * ux + q[i, 1] * uy
        first, last = min(first, s), max(last, s)
    width = (last - first) / strips
    for k in range(strips):
        lo = -np.inf if k == 0 else first + k * width
        hi = np.inf if k == strips - 1 else first + (k + 1) * width
        if not (
            _strip_within(q, nq, ux, uy, lo, hi, a, na, disc_a, limit)
            or _strip_within(q, nq, ux, uy, lo, hi, b, nb, -1.0, limit)
        ):
            return False
    return True


@numba.njit(cache=True)
def _held(
    instants: np.ndarray,
    instant_counts: np.ndarray,
    intervals: np.ndarray,
    interval_counts: np.ndarray,
    instant_supports: np.ndarray,
    interval_supports: np.ndarray,
    reach_m: np.ndarray,
    initial_radius_m: float,
    check: np.ndarray,
    turns: np.ndarray,
) -> np.ndarray:
    """``held_intervals`` on the polygons' supports and vertices ([J, P, 2] and counts [J])."""
    count = len(reach_m)
    held = np.zeros(count, dtype=np.bool_)
    for j in range(1, count):
        if not check[j]:
            continue
        # Q inside B (or A, past the initial disc) outright: no larger support in any direction.
        if np.all(interval_supports[j] <= instant_supports[j]) or (
            j > 1 and np.all(interval_supports[j] <= instant_supports[j - 1])
        ):
            held[j] = True
            continue
        nq, na, nb = interval_counts[j], instant_counts[j - 1], instant_counts[j]
        if nq < 3 or nb < 3 or (j > 1 and na < 3):
            continue
        q, a, b = intervals[j], instants[j - 1], instants[j]
        disc_a = initial_radius_m if j == 1 else -1.0
        limit = reach_m[j] - HELD_MARGIN_M
        ax = 0.0 if j == 1 else a[:na, 0].mean()
        ay = 0.0 if j == 1 else a[:na, 1].mean()
        heading = np.arctan2(b[:nb, 1].mean() - ay, b[:nb, 0].mean() - ax)
        for turn in turns:
            for strips in (STRIPS, 4 * STRIPS):
                angle = heading + turn
                if _strips_hold(
                    q, nq, a, na, disc_a, b, nb, limit, np.cos(angle), np.sin(angle), strips
                ):
                    held[j] = True
                    break
            if held[j]:
                break
    return held


def compile_held_kernel() -> None:
    """Compile (or load from numba's cache) the kernels of this module before a set needs them."""
    directions = np.arange(4) * (np.pi / 2)
    ones = np.ones((2, 4))
    held_intervals(directions, ones, ones, np.ones(2), 1.0, np.ones(2, dtype=bool))
