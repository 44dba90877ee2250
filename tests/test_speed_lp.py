"""The speed-coupling programme's dynamic programme against a general LP solver (HiGHS), and the
bound it gives against simulated speed profiles."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.sparse import diags, vstack

from reach.outer_bound import cos_max_towards
from reach.speed_programme import corridor_gain, max_linear_over_profiles


def highs_optimum(w, lo, hi, rise, fall) -> float:
    """The same programme by HiGHS: -inf when infeasible."""
    steps = len(rise)
    diff = diags([-np.ones(steps), np.ones(steps)], [0, 1], shape=(steps, steps + 1))
    result = linprog(
        -w,
        A_ub=vstack([diff, -diff]).tocsr(),
        b_ub=np.concatenate([rise, fall]),
        bounds=np.stack([lo, hi], axis=1),
        method="highs",
    )
    if result.status == 2:
        return -np.inf
    assert result.status == 0, result.message
    return -float(result.fun)


@pytest.mark.parametrize("seed", range(4))
def test_the_dynamic_programme_finds_the_linear_programmes_optimum(seed: int) -> None:
    """Random objectives (sign changes, plateaus of zero weight), node bounds that pinch, rates
    that are zero one way: the optimum matches HiGHS's to 1e-6, and infeasible rows are found."""
    rng = np.random.default_rng(seed)
    rows, steps = 60, 30
    w = rng.normal(size=(rows, steps + 1)) * rng.uniform(0.1, 3.0, (rows, 1))
    w[rng.uniform(size=w.shape) < 0.2] = 0.0
    centre = rng.uniform(0, 20, (rows, 1)) + np.cumsum(rng.normal(0, 0.5, (rows, steps + 1)), 1)
    width = rng.uniform(0.0, 8.0, (rows, steps + 1)) * (rng.uniform(size=(rows, 1)) < 0.8)
    lo = np.maximum(centre - width, 0.0)
    hi = np.maximum(centre + width, lo + rng.uniform(0, 0.3, (rows, steps + 1)))
    rise = rng.uniform(0, 1.0, (rows, steps)) * (rng.uniform(size=(rows, 1)) < 0.9)
    fall = rng.uniform(0, 1.0, (rows, steps)) * (rng.uniform(size=(rows, 1)) < 0.9)
    got, empty = max_linear_over_profiles(w, lo, hi, rise, fall)
    want = np.array([highs_optimum(w[i], lo[i], hi[i], rise[i], fall[i]) for i in range(rows)])
    assert np.array_equal(empty, np.isinf(want))
    if seed == 0:  # both kinds of row occur
        assert 0 < empty.sum() < rows
    feasible = ~empty
    np.testing.assert_allclose(got[feasible], want[feasible], rtol=1e-5, atol=1e-5)
    assert np.all(got[feasible] >= want[feasible] - 1e-9)  # raised, never lowered


def test_the_gain_bounds_the_integral_of_every_simulated_profile() -> None:
    """Speed profiles of the true dynamics (u2 switching inside its bounds, the stop rule) on a
    fine grid: the integral of v g never exceeds the coupled bound computed on a coarse grid with
    the sub-intervals' largest g, and the bound is within a few per cent of the best profile."""
    rng = np.random.default_rng(7)
    horizon, steps, fine = 3.0, 30, 3000
    t = np.linspace(0.0, horizon, fine + 1)
    g = np.cos(1.1 * t - 2.0)  # negative first: braking early, driving late pays
    a_lo, a_hi = -6.0, 4.0
    v0 = 8.0
    n = 4000
    switches = np.sort(rng.uniform(0, horizon, (n, 4)), axis=1)
    level = rng.uniform(0, 1, (n, 5))
    phase = (t[None, :, None] > switches[:, None, :]).sum(axis=2)  # [n, fine + 1]
    levels = np.take_along_axis(level, phase, axis=1)
    u = a_lo + (a_hi - a_lo) * levels
    bang = rng.uniform(size=n) < 0.5  # half of them at the bounds only
    u[bang] = np.where(levels[bang] < 0.5, a_lo, a_hi)
    dt = horizon / fine
    v = np.empty((n, fine + 1))
    v[:, 0] = v0
    for k in range(fine):
        v[:, k + 1] = np.maximum(v[:, k] + u[:, k] * dt, 0.0)
    gained = ((v[:, :-1] * g[:-1] + v[:, 1:] * g[1:]) / 2 * dt).sum(axis=1)

    nodes = np.linspace(0.0, horizon, steps + 1)
    h = horizon / steps
    heading = 1.1 * nodes - 2.0  # g(t) = cos(heading(t) - 0): a corridor of one heading per time
    step_lo, step_hi = np.full(steps, a_lo * h), np.full(steps, a_hi * h)
    v_hi = v0 + a_hi * nodes
    v_lo = np.maximum(v0 + a_lo * nodes, 0.0)
    bound, empty = corridor_gain(
        heading[None, :-1],
        heading[None, 1:],
        np.zeros(1),
        np.array([h]),
        v_lo[None],
        v_hi[None],
        step_lo[None],
        step_hi[None],
    )
    assert not empty[0]
    assert gained.max() <= bound[0, 0]
    assert bound[0, 0] <= gained.max() + 0.05 * abs(gained.max()) + 0.5


@pytest.mark.parametrize("seed", range(3))
def test_the_corridor_gain_is_the_programme_of_its_corridors_cosines(seed: int) -> None:
    """Random heading corridors (narrow ones facing a direction or away from it, so that the
    objective keeps one sign, and wide ones that turn), node bounds, rates: each (row, direction)
    optimum is HiGHS's optimum of the programme whose weights the corridor's largest cosines give
    (reach.outer_bound.cos_max_towards), plus the chord excess; rows without a profile are
    empty."""
    rng = np.random.default_rng(100 + seed)
    rows, steps = 24, 20
    directions = np.arange(8) * (2 * np.pi / 8)
    centre = rng.uniform(-4, 4, (rows, 1)) + np.cumsum(
        rng.normal(0, 0.3, (rows, steps)) * (rng.uniform(size=(rows, 1)) < 0.7), axis=1
    )
    width = rng.uniform(0.0, 1.5, (rows, steps)) * rng.uniform(0, 1, (rows, 1))
    th_lo, th_hi = centre - width / 2, centre + width / 2
    h = rng.uniform(0.02, 0.1, rows)
    mid = rng.uniform(0, 20, (rows, 1)) + np.cumsum(rng.normal(0, 0.5, (rows, steps + 1)), 1)
    spread = rng.uniform(0.0, 6.0, (rows, steps + 1))
    node_lo = np.maximum(mid - spread, 0.0)
    node_hi = np.maximum(mid + spread, node_lo + rng.uniform(0, 0.2, (rows, steps + 1)))
    step_lo = -rng.uniform(0, 1.0, (rows, steps))
    step_hi = rng.uniform(0, 1.0, (rows, steps))
    got, empty = corridor_gain(th_lo, th_hi, directions, h, node_lo, node_hi, step_lo, step_hi)

    g = cos_max_towards(th_lo, th_hi, directions)  # [rows, steps, M]
    rise, fall = step_hi, -step_lo
    single_sign = 0
    for i in range(rows):
        for m in range(len(directions)):
            w = np.zeros(steps + 1)
            w[:-1] += 0.5 * h[i] * g[i, :, m]
            w[1:] += 0.5 * h[i] * g[i, :, m]
            single_sign += bool(np.all(w >= 0) or np.all(w <= 0))
            want = highs_optimum(w, node_lo[i], node_hi[i], rise[i], fall[i])
            if np.isinf(want):
                assert empty[i] and got[i, m] == -np.inf
                continue
            want += np.sum(np.abs(g[i, :, m]) * (rise[i] + fall[i]) * h[i] / 8.0)
            assert not empty[i]
            assert want - 1e-9 <= got[i, m] <= want + 1e-5 * (1 + abs(want))
    assert 0 < single_sign < rows * len(directions)  # both of the kernel's paths are taken
    if seed == 0:
        assert 0 < empty.sum() < rows
