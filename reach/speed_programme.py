"""The most a speed profile can gain along a direction, with the speed coupled over time.

The corridor bounds (``reach.corridors``) bound a position's component along a direction by
the integral of max over the speed interval of v(s) g(s), where g(s) is the largest
cos(theta(s) - phi) the heading corridor allows: at every instant the speed takes whichever end of
its interval suits that instant. No car does that: to be fast late while it was slow early it must
have accelerated in between, at a bounded rate. This module computes the coupled maximum

    max  integral over [0, t] of v(s) g(s) ds
    over speed profiles v with v(s_k) in [lo_k, hi_k] at the nodes (lo_k >= 0) and
         v' in [min(a_lo, 0), max(a_hi, 0)] on each sub-interval,

a relaxation of the true speed dynamics (v' = u2 in [a_lo, a_hi] while moving, 0 when stopped by the
stop rule), so its maximum is at least what any admissible trajectory gains: a sound bound.

The integral is discretised outward. On a sub-interval of length h whose rates lie in [l, u]
(l <= 0 <= u), a profile lies under the roof min(v_k + u s, v_k+1 - l (h - s)) and above the
matching floor, which differ from the chord between v_k and v_k+1 by at most the area of the
roof's triangle over the chord, u (-l) h^2 / (2 (u - l)) <= e = (u - l) h^2 / 8. With g_k the
largest g on the sub-interval,

    integral of v g  <=  g_k (h (v_k + v_k+1) / 2) + |g_k| e,

for either sign of g_k (v >= 0). What is left is a linear programme in the node speeds,

    max sum_k w_k v_k   s.t.  v_k in [lo_k, hi_k],  v_k+1 - v_k in [-fall_k, rise_k],

solved exactly by dynamic programming backwards in time (:func:`max_linear_over_profiles`): the
best gain from node k on, J_k(v), is concave and piecewise linear in v (the value of a linear
programme in its right-hand side), so it is kept as its breakpoints; the best next speed from v is
the window [v - fall_k, v + rise_k] clipped at J_k+1's maximiser, which shifts the rising part of
J_k+1 left by rise_k and the falling part right by fall_k, with a plateau between. Each programme
(every instant, bin and direction, each with its own constraints) runs row by row in code compiled
by numba, which is far faster than the same arithmetic on all rows at once in numpy.
Every optimum is raised by a relative 1e-6 plus 1e-6 for rounding.

:func:`corridor_gain` takes the heading corridor itself and computes each g on the fly in the same
compiled loop, so no [N, S, M] array of cosines, weights or their transposes is ever made; where
the weights keep one sign the optimum is the greatest (or least) feasible profile, two passes per
row shared by every direction, and the dynamic programme runs only where they change sign (two
thirds of the programmes of fast_wide_limits); the supports equal those of the programme solved on
the corridor's cosines (``tests/test_speed_lp.py``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: Added to every optimum for floating-point rounding: relative, and absolute (metres).
TOLERANCE_REL = 1e-6
TOLERANCE_ABS = 1e-6


@numba.njit(cache=True)
def _value_at(x: np.ndarray, y: np.ndarray, n: int, at: float) -> float:
    """A piecewise-linear function given by its first ``n`` breakpoints (x ascending, y) at ``at``
    inside its domain, by interpolation on the piece that holds it (a zero-length piece, a
    repeated breakpoint, holds one value)."""
    if at <= x[0]:
        return y[0]
    for i in range(1, n):
        if at <= x[i]:
            span = x[i] - x[i - 1]
            if span > 1e-12:
                return y[i - 1] + (at - x[i - 1]) / span * (y[i] - y[i - 1])
            return y[i]
    return y[n - 1]


@numba.njit(cache=True)
def _programme(
    w: np.ndarray,
    node_lo: np.ndarray,
    node_hi: np.ndarray,
    rise: np.ndarray,
    fall: np.ndarray,
    buffers: np.ndarray,
) -> tuple[float, bool]:
    """One programme of :func:`max_linear_over_profiles`, by the dynamic programme: its optimum
    (not yet raised for rounding) and whether it is infeasible. ``buffers`` [4, S + 3]: scratch."""
    x, y, wx, wy = buffers[0], buffers[1], buffers[2], buffers[3]
    last = len(w) - 1
    lo, hi = node_lo[last], max(node_hi[last], node_lo[last])
    none = node_lo[last] > node_hi[last]
    x[0], x[1] = lo, hi
    y[0], y[1] = w[last] * lo, w[last] * hi
    n = 2
    for k in range(last - 1, -1, -1):
        # Window maximum: the rising part (up to the maximiser) moves left by rise, the falling
        # part right by fall; the maximiser's breakpoint is kept on both sides (a plateau).
        peak = 0
        for i in range(1, n):
            if y[i] > y[peak]:
                peak = i
        m = 0
        for i in range(peak + 1):
            wx[m], wy[m] = x[i] - rise[k], y[i]
            m += 1
        for i in range(peak, n):
            wx[m], wy[m] = x[i] + fall[k], y[i]
            m += 1
        lo = max(wx[0], node_lo[k])
        hi = min(wx[m - 1], node_hi[k])
        if lo > hi:
            none = True  # the programme goes on harmlessly; its answer is -inf
        hi = max(hi, lo)
        # Clipped to [lo, hi], each breakpoint once (the clip piles them up at its ends).
        x[0], y[0] = lo, _value_at(wx, wy, m, lo)
        n = 1
        for i in range(m):
            if lo < wx[i] < hi and wx[i] > x[n - 1]:
                x[n], y[n] = wx[i], wy[i]
                n += 1
        if hi > x[n - 1] or n == 1:
            x[n], y[n] = hi, _value_at(wx, wy, m, hi)
            n += 1
        for i in range(n):
            y[i] += w[k] * x[i]
    top = y[0]
    for i in range(1, n):
        top = max(top, y[i])
    return top, none


@numba.njit(cache=True)
def _max_linear_rows(
    weights: np.ndarray, nodes_lo_hi: np.ndarray, rise_fall: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`max_linear_over_profiles` compiled (numba), programme by programme: M objectives
    (``weights`` [P, M, S + 1]) per row of constraints, the node bounds and the rates each stacked
    ([2, P, S + 1] and [2, P, S]). Returns [P, M] optima and empty flags."""
    rows, objectives, nodes = weights.shape
    best = np.empty((rows, objectives))
    empty = np.zeros((rows, objectives), dtype=np.bool_)
    buffers = np.empty((4, nodes + 3))
    for p in range(rows):
        for o in range(objectives):
            top, none = _programme(
                weights[p, o],
                nodes_lo_hi[0, p],
                nodes_lo_hi[1, p],
                rise_fall[0, p],
                rise_fall[1, p],
                buffers,
            )
            best[p, o] = -np.inf if none else top + TOLERANCE_REL * abs(top) + TOLERANCE_ABS
            empty[p, o] = none
    return best, empty


def max_linear_over_profiles(
    weights: np.ndarray,
    node_lo: np.ndarray,
    node_hi: np.ndarray,
    rise: np.ndarray,
    fall: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """For each row p: max over v of sum_k weights[p, k] v_k subject to v_k in [node_lo[p, k],
    node_hi[p, k]] and v_k+1 - v_k in [-fall[p, k], rise[p, k]] (``weights``, ``node_lo``,
    ``node_hi`` [P, S + 1]; ``rise``, ``fall`` [P, S], both >= 0). Returns the optima [P] and [P]
    True where no v satisfies the constraints (optimum -inf there)."""

    best, empty = _max_linear_rows(
        np.ascontiguousarray(weights, dtype=np.float64)[:, None, :],
        np.stack([node_lo, node_hi]).astype(np.float64, copy=False),
        np.stack([rise, fall]).astype(np.float64, copy=False),
    )
    return best[:, 0], empty[:, 0]


@numba.njit(cache=True)
def _extreme_profiles(
    node_lo: np.ndarray,
    node_hi: np.ndarray,
    rise: np.ndarray,
    fall: np.ndarray,
    up: np.ndarray,
    down: np.ndarray,
) -> bool:
    """The greatest and the least feasible profile (into ``up`` and ``down``) of one row's
    constraints, and whether it has none. Difference constraints on a chain: the feasible set is
    closed under pointwise max and min, and its greatest element is the least of every node's
    upper bound carried to each node at the fastest rates (a pass forwards, a pass backwards);
    likewise the least. A nonnegative objective is maximal at ``up``, a nonpositive one at
    ``down``."""
    nodes = len(node_lo)
    up[0], down[0] = node_hi[0], node_lo[0]
    for k in range(1, nodes):
        up[k] = min(node_hi[k], up[k - 1] + rise[k - 1])
        down[k] = max(node_lo[k], down[k - 1] - fall[k - 1])
    for k in range(nodes - 2, -1, -1):
        up[k] = min(up[k], up[k + 1] + fall[k])
        down[k] = max(down[k], down[k + 1] - rise[k])
    return bool(np.any(up < node_lo))


@numba.njit(cache=True)
def _corridor_gain_rows(
    cos_sin_lo: np.ndarray,
    cos_sin_hi: np.ndarray,
    width: np.ndarray,
    th_lo: np.ndarray,
    directions: np.ndarray,
    h: np.ndarray,
    nodes_lo_hi: np.ndarray,
    rise_fall: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`corridor_gain` compiled: per row and direction, g on each sub-interval from the
    heading corridor (as ``reach.outer_bound.cos_max_towards``), the objective's weights, and the
    programme (the extreme profiles where the weights keep one sign, else the dynamic programme),
    with no [N, S, M] array in memory.

    A numeric kernel kept whole so its maths reads in one place."""
    rows, steps = th_lo.shape
    best = np.empty((rows, len(directions)))
    empty = np.zeros(rows, dtype=np.bool_)
    buffers = np.empty((4, steps + 4))
    up, down = np.empty(steps + 1), np.empty(steps + 1)
    g, w = np.empty(steps), np.empty(steps + 1)
    for p in range(rows):
        node_lo, node_hi = nodes_lo_hi[0, p], nodes_lo_hi[1, p]
        rise, fall = rise_fall[0, p], rise_fall[1, p]
        if _extreme_profiles(node_lo, node_hi, rise, fall, up, down):
            empty[p] = True
            best[p, :] = -np.inf
            continue
        half = 0.5 * h[p]
        for m in range(len(directions)):
            phi = directions[m]
            c, s = math.cos(phi), math.sin(phi)
            excess = 0.0
            for k in range(steps):
                if (phi - th_lo[p, k]) % (2 * math.pi) <= width[p, k]:
                    g[k] = 1.0
                else:
                    g[k] = max(
                        cos_sin_lo[0, p, k] * c + cos_sin_lo[1, p, k] * s,
                        cos_sin_hi[0, p, k] * c + cos_sin_hi[1, p, k] * s,
                    )
                excess += abs(g[k]) * (rise[k] + fall[k]) * h[p] / 8.0
            w[0], w[steps] = half * g[0], half * g[steps - 1]
            for k in range(1, steps):
                w[k] = half * (g[k - 1] + g[k])
            positive, negative = True, True
            for k in range(steps + 1):
                positive &= w[k] >= 0.0
                negative &= w[k] <= 0.0
            if positive or negative:
                profile = up if positive else down
                top = 0.0
                for k in range(steps + 1):
                    top += w[k] * profile[k]
            else:
                top, none = _programme(w, node_lo, node_hi, rise, fall, buffers)
                if none:
                    empty[p] = True
            best[p, m] = top + TOLERANCE_REL * abs(top) + TOLERANCE_ABS + excess
        if empty[p]:
            best[p, :] = -np.inf
    return best, empty


def corridor_gain(
    th_lo: np.ndarray,
    th_hi: np.ndarray,
    directions: np.ndarray,
    h: np.ndarray,
    node_lo: np.ndarray,
    node_hi: np.ndarray,
    step_lo: np.ndarray,
    step_hi: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Upper bounds [N, M] on the integral of v(s) g_m(s) over admissible speed profiles, with
    g_m(s) the largest cos(theta - phi_m) over the heading corridor, and [N] True where no profile
    fits the node bounds (an empty row).

    ``th_lo``, ``th_hi`` [N, S]: the heading corridor on S sub-intervals of length ``h`` [N];
    ``directions`` [M]; ``node_lo``, ``node_hi`` [N, S + 1]: sound bounds on the speed at the
    nodes; ``step_lo``, ``step_hi`` [N, S]: the least and greatest speed change u2 * h on each
    sub-interval (the stop rule's rest, change 0, is always allowed).
    """
    th_lo = np.asarray(th_lo, dtype=np.float64)
    th_hi = np.asarray(th_hi, dtype=np.float64)
    rise = np.maximum(step_hi, 0.0)
    fall = np.maximum(-step_lo, 0.0)
    return _corridor_gain_rows(
        np.stack([np.cos(th_lo), np.sin(th_lo)]),
        np.stack([np.cos(th_hi), np.sin(th_hi)]),
        th_hi - th_lo,
        th_lo,
        np.asarray(directions, dtype=np.float64),
        np.asarray(h, dtype=np.float64),
        np.stack([np.maximum(node_lo, 0.0), node_hi]).astype(np.float64, copy=False),
        np.stack([rise, fall]).astype(np.float64, copy=False),
    )


def compile_speed_programme() -> None:
    """Compile (or load from numba's cache) the dynamic programme before it is needed: a worker
    process calls this at start-up, so no refinement waits for the compiler."""
    one = np.zeros((1, 2))
    max_linear_over_profiles(one, one, one + 1.0, one[:, :1] + 1.0, one[:, :1] + 1.0)
    corridor_gain(one[:, :1], one[:, :1], np.zeros(1), np.ones(1), one, one + 1.0, -one[:, :1],
                  one[:, :1])  # fmt: skip
