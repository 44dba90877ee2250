"""The most a speed profile can gain along a direction, with the speed coupled over time.

The corridor bounds (``models.corridor_bound``) bound a position's component along a direction by
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
by numba: 7 ms for 4 608 programmes of 41 nodes where the same arithmetic on all rows at once in
numpy took 210 ms (one-off, the refinement's programmes of urban_wide at 16 bins x 40 steps).
Every optimum is raised by a relative 1e-6 plus 1e-6 for rounding.
"""

from __future__ import annotations

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
def _max_linear_rows(
    weights: np.ndarray, nodes_lo_hi: np.ndarray, rise_fall: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`max_linear_over_profiles` compiled (numba), programme by programme: M objectives
    (``weights`` [P, M, S + 1]) per row of constraints, the node bounds and the rates each stacked
    ([2, P, S + 1] and [2, P, S]). Returns [P, M] optima and empty flags."""
    node_lo, node_hi = nodes_lo_hi[0], nodes_lo_hi[1]
    rise, fall = rise_fall[0], rise_fall[1]
    rows, objectives, nodes = weights.shape
    best = np.empty((rows, objectives))
    empty = np.zeros((rows, objectives), dtype=np.bool_)
    x, y = np.empty(nodes + 2), np.empty(nodes + 2)  # J_k's breakpoints (n of them)
    wx, wy = np.empty(nodes + 3), np.empty(nodes + 3)  # the window maximum's (m)
    for row in range(rows * objectives):
        p, o = row // objectives, row % objectives
        w = weights[p, o]
        last = nodes - 1
        lo, hi = node_lo[p, last], max(node_hi[p, last], node_lo[p, last])
        none = node_lo[p, last] > node_hi[p, last]
        x[0], x[1] = lo, hi
        y[0], y[1] = w[last] * lo, w[last] * hi
        n = 2
        for k in range(nodes - 2, -1, -1):
            # Window maximum: the rising part (up to the maximiser) moves left by rise, the falling
            # part right by fall; the maximiser's breakpoint is kept on both sides (a plateau).
            peak = 0
            for i in range(1, n):
                if y[i] > y[peak]:
                    peak = i
            m = 0
            for i in range(peak + 1):
                wx[m], wy[m] = x[i] - rise[p, k], y[i]
                m += 1
            for i in range(peak, n):
                wx[m], wy[m] = x[i] + fall[p, k], y[i]
                m += 1
            lo = max(wx[0], node_lo[p, k])
            hi = min(wx[m - 1], node_hi[p, k])
            if lo > hi:
                none = True  # the row goes on harmlessly; its answer is -inf
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


def coupled_gain(
    g: np.ndarray,
    h: np.ndarray,
    node_lo: np.ndarray,
    node_hi: np.ndarray,
    step_lo: np.ndarray,
    step_hi: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Upper bounds [N, M] on the integral of v(s) g_m(s) over admissible speed profiles, and [N]
    True where no profile fits the node bounds (an empty row).

    ``g`` [N, S, M]: the largest g_m on each of S sub-intervals of length ``h`` [N];
    ``node_lo``, ``node_hi`` [N, S + 1]: sound bounds on the speed at the nodes; ``step_lo``,
    ``step_hi`` [N, S]: the least and greatest speed change u2 * h on each sub-interval (the stop
    rule's rest, change 0, is always allowed).
    """
    n, steps, directions = g.shape
    rise = np.maximum(step_hi, 0.0)
    fall = np.maximum(-step_lo, 0.0)
    half = 0.5 * h[:, None, None] * g  # [N, S, M]
    weights = np.zeros((n, steps + 1, directions))
    weights[:, :-1] += half
    weights[:, 1:] += half
    chord_excess = (rise + fall) * h[:, None] / 8.0  # e_k = (u - l) h^2 / 8, [N, S]

    best, empty = _max_linear_rows(  # one programme per row and direction, sharing the row's
        np.ascontiguousarray(weights.transpose(0, 2, 1)),
        np.stack([np.maximum(node_lo, 0.0), node_hi]).astype(np.float64, copy=False),
        np.stack([rise, fall]).astype(np.float64, copy=False),
    )
    excess = np.einsum("nsm,ns->nm", np.abs(g), chord_excess)
    return best + excess, empty.any(axis=1)


def compile_speed_programme() -> None:
    """Compile (or load from numba's cache) the dynamic programme before it is needed: a worker
    process calls this at start-up, so no refinement waits for the compiler (~1.5 s here)."""
    one = np.zeros((1, 2))
    max_linear_over_profiles(one, one, one + 1.0, one[:, :1] + 1.0, one[:, :1] + 1.0)
