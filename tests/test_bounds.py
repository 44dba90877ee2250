"""gamma trimming, clipping, the start/end bound fit and validation (paper, "Collision Set Update").

References are independent: scipy.stats for the trimmed intervals, scipy.optimize.linprog for the
envelope's linear programme.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog
from scipy.stats import norm

from reach.contract import BOUND_COLUMNS
from service.flows.bounds import (
    ControlBounds,
    PredictionError,
    clip_intervals,
    control_bounds,
    fit_bounds,
    half_width_factor,
    steps_in_horizon,
    trim_intervals,
    validate_filter_params,
    validate_prediction,
)

LIMITS = np.array([2.0, 10.0])
T = 3.0


def lines(b: ControlBounds, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The interpolated bounds (paper, eq. for u~^tau) at times t: (lo (N, 2), hi (N, 2))."""
    a = b.as_array().reshape(4, 2)  # rows: min_start, min_end, max_start, max_end
    w = (t / T)[:, None]
    return (1 - w) * a[0] + w * a[1], (1 - w) * a[2] + w * a[3]


def step_spans(n_steps: int, dt: float) -> list[tuple[float, float]]:
    """[start, end] of each step the fit uses: clipped to T, the last one held until T."""
    n = steps_in_horizon(n_steps, dt, T)
    return [(k * dt, T if k == n - 1 else min((k + 1) * dt, T)) for k in range(n)]


# --- the contract ----------------------------------------------------------------------------


def test_fields_follow_the_model_contract() -> None:
    names = [f.name for f in dataclasses.fields(ControlBounds)]
    assert names == list(BOUND_COLUMNS)
    b = ControlBounds(*map(float, range(8)))
    assert b.as_array().tolist() == list(range(8))
    assert list(json.loads(json.dumps(b.to_dict()))) == list(BOUND_COLUMNS)


# --- gamma trimming against scipy ------------------------------------------------------------


@pytest.mark.parametrize("gamma", [1e-9, 0.05, 0.075, 0.1, 0.125, 0.5, 0.95, 0.999999, 1 - 1e-12])
def test_half_width_factor_matches_scipy(gamma: float) -> None:
    assert half_width_factor(gamma) == pytest.approx(norm.isf((1 - gamma) / 2), rel=1e-12)


@given(st.floats(1e-6, 1 - 1e-9))
def test_half_width_factor_holds_mass_gamma(gamma: float) -> None:
    z = half_width_factor(gamma)
    assert norm.cdf(z) - norm.cdf(-z) == pytest.approx(gamma, rel=1e-10)


TRIM_CASES = [
    # mean, cov, beta, gamma
    ([[0.0, 0.1]], [[[0.01, 0.0], [0.0, 0.25]]], 1.0, 0.075),
    ([[0.0, 0.1]], [[[0.01, 0.0], [0.0, 0.25]]], 0.03, 0.075),
    ([[0.3, -2.0], [0.1, 1.0]], [[[0.04, 0.01], [0.01, 1.0]], [[0.2, 0.0], [0.0, 4.0]]], 0.4, 0.5),
    ([[-1.5, 8.0]], [[[0.5, -0.1], [-0.1, 9.0]]], 0.075, 0.125),
]


@pytest.mark.parametrize(("mean", "cov", "beta", "gamma"), TRIM_CASES)
def test_trim_matches_scipy(mean, cov, beta, gamma) -> None:
    mean, cov = np.array(mean), np.array(cov)
    lo, hi = trim_intervals(mean, cov, beta, gamma)
    for k in range(len(mean)):
        for i in range(2):
            dist = norm(loc=mean[k, i], scale=np.sqrt(cov[k, i, i] / beta))
            ref_lo, ref_hi = dist.interval(gamma)
            assert lo[k, i] == pytest.approx(ref_lo, rel=1e-12, abs=1e-14)
            assert hi[k, i] == pytest.approx(ref_hi, rel=1e-12, abs=1e-14)
            assert dist.cdf(hi[k, i]) - dist.cdf(lo[k, i]) == pytest.approx(gamma, rel=1e-10)


def test_clipping_cuts_at_the_limit_and_collapses_beyond_it() -> None:
    lo = np.array([[-0.5, -12.0], [2.5, 9.0], [-3.0, -20.0]])
    hi = np.array([[0.5, -8.0], [3.0, 11.0], [-2.5, -11.0]])
    clo, chi = clip_intervals(lo, hi, (2.0, 10.0))
    np.testing.assert_array_equal(clo, [[-0.5, -10.0], [2.0, 9.0], [-2.0, -10.0]])
    np.testing.assert_array_equal(chi, [[0.5, -8.0], [2.0, 10.0], [-2.0, -10.0]])


# --- hand-picked fits ------------------------------------------------------------------------


def test_envelope_of_a_staircase() -> None:
    # Step k = [0.5 k, 0.5 (k + 1)] has lo = 0.1 k, hi = 0.1 k + 0.2: the tightest lines are
    # lo: through (0.5, 0) and (3, 0.5) -> -0.1 .. 0.5; hi: through (0, 0.2) and (2.5, 0.7) -> 0.2 .. 0.8.
    k = np.arange(6.0)
    lo = np.column_stack([0.1 * k, -0.1 * k])
    hi = np.column_stack([0.1 * k + 0.2, -0.1 * k + 0.2])
    b = fit_bounds(lo, hi, 0.5)
    assert b.u1_min_start == pytest.approx(-0.1) and b.u1_min_end == pytest.approx(0.5)
    assert b.u1_max_start == pytest.approx(0.2) and b.u1_max_end == pytest.approx(0.8)
    # u2 is the mirror image, shifted: -hi = 0.1 k - 0.2 and -lo = 0.1 k.
    assert b.u2_max_start == pytest.approx(0.3) and b.u2_max_end == pytest.approx(-0.3)
    assert b.u2_min_start == pytest.approx(0.0) and b.u2_min_end == pytest.approx(-0.6)


def test_envelope_tie_takes_the_middle_of_the_optimal_edge() -> None:
    # Steps [0, 1.5] and [1.5, 3] with lo = -1 and -0.5: every line through (1.5, -1) with slope
    # in [0, 1/3] per second is optimal; the middle one runs from -1.25 to -0.75.
    lo = np.array([[-1.0, 0.0], [-0.5, 0.0]])
    b = fit_bounds(lo, lo + 1.0, 1.5)
    assert b.u1_min_start == pytest.approx(-1.25) and b.u1_min_end == pytest.approx(-0.75)


def test_envelope_respects_the_limits_while_containing_the_steps() -> None:
    # Unconstrained, the best line under lo = (-2, -1, 1) runs from -3 to 0; clipping -3 to -2 would
    # lift the line above step 0. With the limit in the programme the answer is the constant -2.
    lo = np.array([[-2.0, 0.0], [-1.0, 0.0], [1.0, 0.0]])
    b = fit_bounds(lo, lo + 0.5, 1.0)
    assert (b.u1_min_start, b.u1_min_end) == pytest.approx((-2.0, -2.0))


def test_constant_intervals_fit_exactly_by_both_methods() -> None:
    lo, hi = np.tile([-0.2, -1.0], (6, 1)), np.tile([0.3, 2.0], (6, 1))
    for method in ("envelope", "endpoints"):
        b = fit_bounds(lo, hi, 0.5, method=method)
        np.testing.assert_allclose(b.as_array(), [-0.2, -1, -0.2, -1, 0.3, 2, 0.3, 2], atol=1e-12)


def test_steps_beyond_the_horizon_are_ignored() -> None:
    lo = np.tile([-0.1, -1.0], (10, 1))
    lo[6:] = [-1.5, -9.0]  # from t = 3 s on: outside the horizon
    for method in ("envelope", "endpoints"):
        b = fit_bounds(lo, lo + 0.2, 0.5, method=method)
        assert b.u1_min_end == pytest.approx(-0.1) and b.u2_min_end == pytest.approx(-1.0)
    assert steps_in_horizon(40, 0.1, 3.0) == 30  # 30 * 0.1 = 3.0000000000000004: not inside
    assert steps_in_horizon(7, 3.0 / 7.0, 3.0) == 7


def test_a_short_prediction_holds_its_last_step_until_the_horizon() -> None:
    lo = np.array([[-0.1, -1.0], [-0.3, -2.0]])  # covers [0, 1] s of the 3 s horizon
    hi = lo + 0.5
    b = fit_bounds(lo, hi, 0.5)
    lo_t, hi_t = lines(b, np.linspace(0.5, 3.0, 200))
    assert np.all(lo_t <= lo[1] + 1e-12) and np.all(hi_t >= hi[1] - 1e-12)
    e = fit_bounds(lo, hi, 0.5, method="endpoints")
    assert (e.u1_min_end, e.u2_min_end) == tuple(lo[1])
    assert (e.u1_max_end, e.u2_max_end) == tuple(hi[1])


# --- properties ------------------------------------------------------------------------------


@st.composite
def predictions(draw, max_steps: int = 12):
    n = draw(st.integers(1, max_steps))
    dt = draw(st.sampled_from([0.1, 0.25, 0.3, 0.5, 0.7, 1.0]))
    mean = np.array([[draw(st.floats(-2.5, 2.5)), draw(st.floats(-12.0, 12.0))] for _ in range(n)])
    sd = np.array([[draw(st.floats(1e-3, 2.0)), draw(st.floats(1e-3, 8.0))] for _ in range(n)])
    rho = np.array([draw(st.floats(-0.9, 0.9)) for _ in range(n)])
    cov = np.empty((n, 2, 2))
    cov[:, 0, 0], cov[:, 1, 1] = sd[:, 0] ** 2, sd[:, 1] ** 2
    cov[:, 0, 1] = cov[:, 1, 0] = rho * sd[:, 0] * sd[:, 1]
    return mean, cov, dt


betas = st.floats(0.005, 1.0)
gammas = st.floats(0.01, 0.99)


@settings(max_examples=80, deadline=None)
@given(predictions(), betas, gammas)
def test_intervals_contain_the_mean_inside_the_limits(pred, beta, gamma) -> None:
    mean, cov, _ = pred
    lo, hi = clip_intervals(*trim_intervals(mean, cov, beta, gamma), LIMITS)
    inside = np.abs(mean) <= LIMITS
    assert np.all((lo <= mean)[inside]) and np.all((mean <= hi)[inside])
    assert np.all(lo <= hi) and np.all(np.abs(lo) <= LIMITS) and np.all(np.abs(hi) <= LIMITS)
    # Outside the limits the interval collapses onto (or is cut at) the nearest limit.
    beyond = np.abs(lo) >= LIMITS
    assert np.all(np.isin(np.abs(lo[beyond]), LIMITS))


@settings(max_examples=80, deadline=None)
@given(predictions(), betas, betas, gammas, gammas)
def test_bounds_widen_as_beta_falls_and_gamma_rises(pred, b1, b2, g1, g2) -> None:
    mean, cov, dt = pred
    (b_lo, b_hi), (g_lo, g_hi) = sorted([b1, b2]), sorted([g1, g2])
    narrow = clip_intervals(*trim_intervals(mean, cov, b_hi, g_lo), LIMITS)
    wide = clip_intervals(*trim_intervals(mean, cov, b_lo, g_hi), LIMITS)
    assert np.all(wide[0] <= narrow[0]) and np.all(wide[1] >= narrow[1])
    # Nested per-step intervals give nested endpoint fits, and envelopes enclosing more area.
    n = control_bounds(mean, cov, dt, b_hi, g_lo, method="endpoints").as_array().reshape(2, 4)
    w = control_bounds(mean, cov, dt, b_lo, g_hi, method="endpoints").as_array().reshape(2, 4)
    assert np.all(w[0] <= n[0]) and np.all(w[1] >= n[1])
    n = control_bounds(mean, cov, dt, b_hi, g_lo).as_array().reshape(2, 2, 2)
    w = control_bounds(mean, cov, dt, b_lo, g_hi).as_array().reshape(2, 2, 2)
    area_n, area_w = n[1].sum(axis=0) - n[0].sum(axis=0), w[1].sum(axis=0) - w[0].sum(axis=0)
    assert np.all(area_w >= area_n - 1e-9)


@settings(max_examples=80, deadline=None)
@given(predictions(max_steps=16), betas, gammas)
def test_envelope_contains_every_step_densely_in_time(pred, beta, gamma) -> None:
    mean, cov, dt = pred
    lo, hi = clip_intervals(*trim_intervals(mean, cov, beta, gamma), LIMITS)
    b = control_bounds(mean, cov, dt, beta, gamma)
    assert np.all(np.abs(b.as_array().reshape(4, 2)) <= LIMITS)
    for k, (t0, t1) in enumerate(step_spans(len(mean), dt)):
        lo_t, hi_t = lines(b, np.linspace(t0, t1, 25))
        assert np.all(lo_t <= lo[k] + 1e-9), k
        assert np.all(hi_t >= hi[k] - 1e-9), k


@settings(max_examples=60, deadline=None)
@given(predictions(), betas, gammas)
def test_endpoints_fit_is_the_first_and_last_step(pred, beta, gamma) -> None:
    mean, cov, dt = pred
    lo, hi = clip_intervals(*trim_intervals(mean, cov, beta, gamma), LIMITS)
    last = steps_in_horizon(len(mean), dt, T) - 1
    b = control_bounds(mean, cov, dt, beta, gamma, method="endpoints")
    assert (b.u1_min_start, b.u2_min_start, b.u1_max_start, b.u2_max_start) == (*lo[0], *hi[0])
    assert (b.u1_min_end, b.u2_min_end, b.u1_max_end, b.u2_max_end) == (*lo[last], *hi[last])


@settings(max_examples=40, deadline=None)
@given(predictions(max_steps=16), betas, gammas)
def test_envelope_is_optimal_against_linprog(pred, beta, gamma) -> None:
    """The fitted lines enclose the least area: same optimum as scipy's LP solver."""
    mean, cov, dt = pred
    lo, hi = clip_intervals(*trim_intervals(mean, cov, beta, gamma), LIMITS)
    b = control_bounds(mean, cov, dt, beta, gamma).as_array().reshape(2, 2, 2)  # [min|max, s|e, d]
    spans = step_spans(len(mean), dt)
    for d in range(2):
        rows, rhs_lo, rhs_hi = [], [], []
        for k, (t0, t1) in enumerate(spans):
            for t in (t0, t1):
                rows.append([1 - t / T, t / T])
                rhs_lo.append(lo[k, d])
                rhs_hi.append(hi[k, d])
        A = np.array(rows)
        box = [(-LIMITS[d], LIMITS[d])] * 2
        best_lo = linprog([-1, -1], A_ub=A, b_ub=rhs_lo, bounds=box, method="highs")
        best_hi = linprog([1, 1], A_ub=-A, b_ub=-np.array(rhs_hi), bounds=box, method="highs")
        assert best_lo.status == 0 and best_hi.status == 0
        # HiGHS meets its constraints to its feasibility tolerance (1e-7 each): its optimum may
        # sit that far past ours on each of the two endpoints.
        assert b[0, :, d].sum() == pytest.approx(-best_lo.fun, abs=1e-6)
        assert b[1, :, d].sum() == pytest.approx(best_hi.fun, abs=1e-6)


def test_no_confidence_opens_the_bounds_to_the_limits() -> None:
    mean = np.zeros((6, 2))
    cov = np.tile(np.diag([0.5, 20.0]), (6, 1, 1))
    b = control_bounds(mean, cov, 0.5, beta=1e-6, gamma=0.9)
    np.testing.assert_allclose(b.as_array(), [-2, -10, -2, -10, 2, 10, 2, 10])


# --- validation ------------------------------------------------------------------------------

GOOD_MEAN = [[0.0, 0.1]] * 4
GOOD_COV = [[[0.01, 0.0], [0.0, 0.25]]] * 4


def with_cov(k: int, matrix) -> list:
    cov = list(GOOD_COV)
    cov[k] = matrix
    return cov


def with_mean(k: int, row) -> list:
    mean = list(GOOD_MEAN)
    mean[k] = row
    return mean


@pytest.mark.parametrize(
    ("mean", "cov", "dt", "field"),
    [
        (GOOD_MEAN, GOOD_COV, 0.0, "prediction.dt"),
        (GOOD_MEAN, GOOD_COV, -0.5, "prediction.dt"),
        (GOOD_MEAN, GOOD_COV, float("nan"), "prediction.dt"),
        (GOOD_MEAN, GOOD_COV, "0.5", "prediction.dt"),
        ([], [], 0.5, "prediction.mean"),
        ([[0.0, 0.0]] * 65, [GOOD_COV[0]] * 65, 0.5, "prediction.mean"),
        (GOOD_MEAN, GOOD_COV[:3], 0.5, "prediction.cov"),
        (GOOD_MEAN, "cov", 0.5, "prediction.cov"),
        (with_mean(2, [0.0, float("nan")]), GOOD_COV, 0.5, "prediction.mean[2]"),
        (with_mean(1, [0.0]), GOOD_COV, 0.5, "prediction.mean[1]"),
        (with_mean(0, ["a", 0.0]), GOOD_COV, 0.5, "prediction.mean[0]"),
        (GOOD_MEAN, with_cov(3, [[0.01, 0.001], [0.0, 0.25]]), 0.5, "prediction.cov[3]"),
        (GOOD_MEAN, with_cov(1, [[0.01, 0.1], [0.1, 0.25]]), 0.5, "prediction.cov[1]"),
        (GOOD_MEAN, with_cov(2, [[0.0, 0.0], [0.0, 0.25]]), 0.5, "prediction.cov[2]"),
        (GOOD_MEAN, with_cov(0, [[-0.01, 0.0], [0.0, -0.25]]), 0.5, "prediction.cov[0]"),
        (GOOD_MEAN, with_cov(3, [[0.01, 0.0], [0.0, float("inf")]]), 0.5, "prediction.cov[3]"),
        (GOOD_MEAN, with_cov(2, [[0.01, 0.0, 0.0], [0.0, 0.25, 0.0]]), 0.5, "prediction.cov[2]"),
    ],
)
def test_validation_names_the_field(mean, cov, dt, field) -> None:
    with pytest.raises(PredictionError) as err:
        validate_prediction(mean, cov, dt)
    assert err.value.field == field
    assert err.value.message and str(err.value).startswith(field)


def test_validation_accepts_and_symmetrises() -> None:
    tiny = 1e-9 * 0.25  # within the documented tolerance (1e-6 of the largest variance)
    cov = with_cov(1, [[0.01, 0.002 + tiny], [0.002, 0.25]])
    mean, cov_arr = validate_prediction(GOOD_MEAN, cov, 0.5)
    assert mean.shape == (4, 2) and cov_arr.shape == (4, 2, 2)
    np.testing.assert_array_equal(cov_arr, np.transpose(cov_arr, (0, 2, 1)))
    validate_prediction(np.zeros((64, 2)), np.tile(np.eye(2), (64, 1, 1)), 0.1)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"gamma": 0.0}, "gamma"),
        ({"gamma": 1.0}, "gamma"),
        ({"gamma": float("nan")}, "gamma"),
        ({"beta_low": 0.0}, "beta_low"),
        ({"beta_low": 1.0}, "beta_low"),
        ({"beta_low": True}, "beta_low"),
        ({"epsilon": 1.0}, "epsilon"),
        ({"epsilon": -1e-9}, "epsilon"),
    ],
)
def test_filter_param_validation_names_the_field(kwargs, field) -> None:
    params = {"gamma": 0.075, "beta_low": 0.03, "epsilon": 0.05, **kwargs}
    with pytest.raises(PredictionError) as err:
        validate_filter_params(**params)
    assert err.value.field == field


def test_filter_params_accept_the_defaults_and_the_edges() -> None:
    validate_filter_params(gamma=0.075, beta_low=0.03, epsilon=0.05)
    validate_filter_params(gamma=0.5, beta_low=0.5, epsilon=0.0)
    validate_filter_params()
