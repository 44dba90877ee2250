"""The compiled envelope programmes (``reach.envelope_lp``) against scipy's LP solver: on random
rows, with floors that bind and ties, the line stays below every point and above the floor, its
area is the optimum, and a row's answer does not depend on the rows solved with it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from reach.envelope_lp import max_lines_below, vertices


def _rows(rng: np.random.Generator, n: int, count: int) -> tuple[np.ndarray, np.ndarray]:
    c = rng.normal(0.0, 1.0, (count, n + 1)) * rng.choice([0.01, 1.0, 5.0], (count, 1))
    c[::3] = np.round(c[::3], 1)  # repeated values: optimal edges
    floor = c.min(axis=1) - rng.choice([0.0, 0.1, 3.0], count)  # 0: the floor touches a point
    return c, floor


@pytest.mark.parametrize("n, dt", [(1, 3.0), (6, 0.5), (12, 0.25), (30, 0.1)])
def test_lines_are_optimal_feasible_and_independent_of_their_batch(n: int, dt: float) -> None:
    rng = np.random.default_rng(n)
    w = np.append(np.arange(n) * dt, 3.0) / 3.0
    c, floor = _rows(rng, n, 40)
    a, b = max_lines_below(vertices(n, dt, 3.0), w, c, floor)
    A = np.column_stack([1.0 - w, w])
    for k in range(len(c)):
        line = (1.0 - w) * a[k] + w * b[k]  # the products the fit takes
        assert (line <= c[k]).all()
        assert a[k] >= floor[k] - 1e-9 and b[k] >= floor[k] - 1e-9
        best = linprog([-1, -1], A_ub=A, b_ub=c[k], bounds=[(floor[k], None)] * 2, method="highs")
        assert best.status == 0
        assert a[k] + b[k] == pytest.approx(-best.fun, abs=1e-6 * (1.0 + np.abs(c[k]).max()))
        alone = max_lines_below(vertices(n, dt, 3.0), w, c[k : k + 1], floor[k : k + 1])
        assert (alone[0][0], alone[1][0]) == (a[k], b[k])


def test_a_tie_takes_the_middle_of_the_optimal_edge() -> None:
    # Points (0, -1), (0.5, -1), (0.5, -0.5), (1, -0.5): every line through (0.5, -1) with slope
    # in [0, 1] is optimal; the middle one runs from -1.25 to -0.75.
    w = np.array([0.0, 0.5, 1.0])
    c = np.array([[-1.0, -1.0, -0.5]])
    a, b = max_lines_below(vertices(2, 1.5, 3.0), w, c, np.array([-10.0]))
    assert (a[0], b[0]) == pytest.approx((-1.25, -0.75))
