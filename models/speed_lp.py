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
J_k+1 left by rise_k and the falling part right by fall_k, with a plateau between. All the
programmes (every instant, bin and direction) run together in numpy, each row with its own
constraints. Every optimum is raised by a relative 1e-6 plus 1e-6 for rounding.
"""

from __future__ import annotations

import numpy as np

#: Added to every optimum for floating-point rounding: relative, and absolute (metres).
TOLERANCE_REL = 1e-6
TOLERANCE_ABS = 1e-6


def _value_at(x: np.ndarray, y: np.ndarray, at: np.ndarray) -> np.ndarray:
    """A piecewise-linear function given by breakpoints (x [P, B] ascending, y [P, B]) at ``at``
    [P] inside its domain, by interpolation on the piece that holds it (a zero-length piece, a
    repeated breakpoint, holds one value)."""
    rows = np.arange(len(at))
    right = np.clip((x < at[:, None]).sum(axis=1), 1, x.shape[1] - 1)
    x0, x1 = x[rows, right - 1], x[rows, right]
    y0, y1 = y[rows, right - 1], y[rows, right]
    span = x1 - x0
    real = span > 1e-12
    fraction = np.where(real, (at - x0) / np.where(real, span, 1.0), 1.0)
    return y0 + fraction * (y1 - y0)


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
    nodes = weights.shape[1]
    empty = node_lo[:, -1] > node_hi[:, -1]
    x = np.stack([node_lo[:, -1], np.maximum(node_hi[:, -1], node_lo[:, -1])], axis=1)
    y = weights[:, -1:] * x
    for k in range(nodes - 2, -1, -1):
        # Window maximum: the rising part (up to the maximiser) moves left by rise, the falling part
        # right by fall; the maximiser's breakpoint is kept on both sides (a plateau between).
        peak = np.argmax(y, axis=1)
        left = np.arange(x.shape[1] + 1)[None, :] <= peak[:, None]
        x = np.where(
            left,
            np.concatenate([x, x[:, -1:]], axis=1) - rise[:, k : k + 1],
            np.concatenate([x[:, :1], x], axis=1) + fall[:, k : k + 1],
        )
        y = np.where(
            left, np.concatenate([y, y[:, -1:]], axis=1), np.concatenate([y[:, :1], y], axis=1)
        )
        lo = np.maximum(x[:, 0], node_lo[:, k])
        hi = np.minimum(x[:, -1], node_hi[:, k])
        empty |= lo > hi
        hi = np.maximum(hi, lo)  # an empty row goes on harmlessly; its answer is -inf
        y_lo, y_hi = _value_at(x, y, lo), _value_at(x, y, hi)
        y = np.where(x < lo[:, None], y_lo[:, None], np.where(x > hi[:, None], y_hi[:, None], y))
        x = np.clip(x, lo[:, None], hi[:, None])
        y = y + weights[:, k : k + 1] * x
    best = y.max(axis=1)
    best = best + TOLERANCE_REL * np.abs(best) + TOLERANCE_ABS
    return np.where(empty, -np.inf, best), empty


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

    def per_direction(a: np.ndarray) -> np.ndarray:
        """[N, K] constraint rows repeated for each direction: [N * M, K]."""
        return np.repeat(a, directions, axis=0)

    best, empty = max_linear_over_profiles(
        weights.transpose(0, 2, 1).reshape(n * directions, steps + 1),
        per_direction(np.maximum(node_lo, 0.0)),
        per_direction(node_hi),
        per_direction(rise),
        per_direction(fall),
    )
    excess = np.einsum("nsm,ns->nm", np.abs(g), chord_excess)
    return best.reshape(n, directions) + excess, empty.reshape(n, directions).any(axis=1)
