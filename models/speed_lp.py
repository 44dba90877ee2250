"""The most a speed profile can gain along a direction, with the speed coupled over time.

The corridor bounds (``models.corridor_bound``) bound a position's component along a direction by
the integral of max over the speed interval of v(s) g(s), where g(s) is the largest
cos(theta(s) - phi) the heading corridor allows: at every instant the speed takes whichever end of
its interval suits that instant. No car does that: to be fast late while it was slow early it must
have accelerated in between, at a bounded rate. This module computes the coupled maximum

    max  integral over [0, t] of v(s) g(s) ds
    over speed profiles v with v >= 0, v(s_k) in [lo_k, hi_k] at the nodes, and
         v' in [min(a_lo, 0), max(a_hi, 0)] on each sub-interval,

a relaxation of the true speed dynamics (v' = u2 in [a_lo, a_hi] while moving, 0 when stopped by the
stop rule), so its maximum is at least what any admissible trajectory gains: a sound bound.

The integral is discretised outward. On a sub-interval of length h whose rates lie in [l, u]
(l <= 0 <= u), a profile lies under the roof min(v_k + u s, v_k+1 - l (h - s)) and above the
matching floor, which differ from the chord between v_k and v_k+1 by at most the area
e = (u - l) h^2 / 8 (the roof's apex over the chord, attained when v_k = v_k+1). With g_k the
largest g on the sub-interval,

    integral of v g  <=  g_k (h (v_k + v_k+1) / 2) + |g_k| e,

for either sign of g_k (v >= 0). The result is a linear programme in the node speeds, one per
(row, direction), solved by HiGHS (``scipy.optimize.linprog``); its optimum is raised by a
relative 1e-6 plus 1e-6 for the solver's tolerance. Offline only: ~1 ms per programme.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog
from scipy.sparse import csr_matrix, diags, vstack

#: Added to every optimum for the solver's tolerance: relative, and absolute (metres).
TOLERANCE_REL = 1e-6
TOLERANCE_ABS = 1e-6


def _difference_rows(steps: int) -> csr_matrix:
    """Rows v_k+1 - v_k (k < steps) over the node speeds v_0..v_steps."""
    return diags([-np.ones(steps), np.ones(steps)], [0, 1], shape=(steps, steps + 1)).tocsr()


def coupled_gain(
    weights: np.ndarray,
    h: np.ndarray,
    node_lo: np.ndarray,
    node_hi: np.ndarray,
    step_lo: np.ndarray,
    step_hi: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Upper bounds [N, M] on the integral of v(s) g_m(s) over admissible speed profiles, and [N]
    True where no profile fits the node bounds (an empty row).

    ``weights`` [N, S, M]: the largest g_m on each of S sub-intervals of length ``h`` [N];
    ``node_lo``, ``node_hi`` [N, S + 1]: sound bounds on the speed at the nodes; ``step_lo``,
    ``step_hi`` [N, S]: the least and greatest speed change u2 * h on each sub-interval (the stop
    rule's rest, change 0, is always allowed).
    """
    n, steps, directions = weights.shape
    diff = _difference_rows(steps)
    a_ub = vstack([diff, -diff]).tocsr()
    rise = np.maximum(step_hi, 0.0)
    fall = np.maximum(-step_lo, 0.0)
    gain = np.empty((n, directions))
    empty = np.zeros(n, dtype=bool)
    for i in range(n):
        lo = np.maximum(node_lo[i], 0.0)
        hi = node_hi[i]
        if np.any(lo > hi):
            empty[i] = True
            gain[i] = -np.inf
            continue
        b_ub = np.concatenate([rise[i], fall[i]])
        chord_excess = (rise[i] + fall[i]) * h[i] / 8.0  # e_k = (u - l) h^2 / 8
        bounds = np.stack([lo, hi], axis=1)
        for m in range(directions):
            g = weights[i, :, m]
            c = np.zeros(steps + 1)
            c[:-1] += 0.5 * h[i] * g
            c[1:] += 0.5 * h[i] * g
            result = linprog(-c, A_ub=a_ub, b_ub=b_ub, bounds=bounds, method="highs")
            if result.status == 2:  # infeasible: the rates cannot join the node bounds
                empty[i] = True
                gain[i] = -np.inf
                break
            if result.status != 0:
                raise RuntimeError(f"speed LP failed: {result.message}")
            best = -float(result.fun) + float(np.abs(g) @ chord_excess)
            gain[i, m] = best + TOLERANCE_REL * abs(best) + TOLERANCE_ABS
    return gain, empty
