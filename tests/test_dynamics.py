"""The shared maths: bounds interpolation, stop rule, l(x), the closed-form Hamiltonian."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models.rollout import rk4_rollout
from models.sampling import sample_parameters
from reach.contract import COL, COLUMNS, HORIZON_S, INITIAL_SET, N_INPUTS
from reach.dynamics import (
    heading_interval,
    initial_set_value,
    interpolate_bounds,
    optimal_hamiltonian,
    unicycle_derivative,
    wrap_angle,
)

finite = st.floats(-50, 50, allow_nan=False)


def test_layout_matches_the_contract() -> None:
    assert N_INPUTS == 14
    assert COLUMNS[0] == "t" and COLUMNS[-1] == "u2_max_end"
    assert COL["v_start"] == 5 and COL["u1_max_start"] == 10


@given(st.floats(-100, 100, allow_nan=False))
def test_wrap_angle_range(angle: float) -> None:
    w = float(wrap_angle(np.float64(angle)))
    assert -np.pi <= w < np.pi
    assert np.isclose(np.cos(w), np.cos(angle), atol=1e-9)


def test_interpolation_hits_both_ends() -> None:
    x = sample_parameters(50, np.random.default_rng(0))
    start = interpolate_bounds(x, np.zeros(50))
    end = interpolate_bounds(x, np.full(50, HORIZON_S))
    np.testing.assert_allclose(start[0], x[:, COL["u1_min_start"]])
    np.testing.assert_allclose(end[3], x[:, COL["u2_max_end"]])


def test_stopped_car_stays_stopped_when_braking() -> None:
    _, _, _, accel = unicycle_derivative(np.array([0.3]), np.array([0.0]), 0.0, np.array([-4.0]))
    assert accel[0] == 0.0
    _, _, _, accel = unicycle_derivative(np.array([0.3]), np.array([0.0]), 0.0, np.array([2.0]))
    assert accel[0] == 2.0


def test_initial_set_contains_nominal_state_and_excludes_far_states() -> None:
    assert initial_set_value(0.0, 0.0, 0.0, 5.0, 5.0) < 0
    m = INITIAL_SET
    assert initial_set_value(m.radius_m + 0.01, 0.0, 0.0, 5.0, 5.0) > 0
    assert initial_set_value(0.0, 0.0, m.heading_margin_rad + 0.01, 5.0, 5.0) > 0
    assert initial_set_value(0.0, 0.0, 2 * np.pi, 5.0, 5.0) < 0  # heading is periodic
    assert initial_set_value(0.0, 0.0, 0.0, 5.0 + m.speed_margin_mps + 0.01, 5.0) > 0


@settings(max_examples=200, deadline=None)
@given(
    p=st.tuples(finite, finite, finite, finite),
    heading=st.floats(-4, 4),
    speed=st.one_of(st.just(0.0), st.floats(0, 40)),
    b=st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(-10, 10), st.floats(-10, 10)),
)
def test_closed_form_hamiltonian_equals_brute_force_max(p, heading, speed, b) -> None:
    u1_lo, u1_hi = sorted(b[:2])
    u2_lo, u2_hi = sorted(b[2:])
    closed = optimal_hamiltonian(p, heading, speed, (u1_lo, u2_lo, u1_hi, u2_hi))
    u1, u2 = np.meshgrid(np.linspace(u1_lo, u1_hi, 41), np.linspace(u2_lo, u2_hi, 41))
    f = unicycle_derivative(np.full_like(u1, heading), np.full_like(u1, speed), u1, u2)
    brute = sum(pi * fi for pi, fi in zip(p, f, strict=True)).max()
    assert closed == pytest.approx(brute, rel=1e-9, abs=1e-9)


def test_heading_interval_contains_rollout_headings() -> None:
    rng = np.random.default_rng(1)
    x = sample_parameters(2000, rng)
    t = rng.uniform(0, HORIZON_S, 2000)
    a1 = rng.uniform(0, 1, (2000, 4))
    a2 = rng.uniform(0, 1, (2000, 4))
    sw = np.sort(rng.uniform(0, HORIZON_S, (2000, 3)), axis=1)
    zero = np.zeros(2000)
    (_, _, heading, speed), _ = rk4_rollout(
        (zero, zero, zero, x[:, COL["v_start"]]), x, t, a1, a2, sw, 30
    )
    lo, hi = heading_interval(x, t)
    assert np.all(heading >= lo - 1e-9) and np.all(heading <= hi + 1e-9)
    assert np.all(speed >= 0)


def test_rollout_matches_closed_form_straight_line() -> None:
    x = np.zeros((1, N_INPUTS))
    x[0, COL["v_start"]] = 10.0
    for name in ("u2_min_start", "u2_min_end", "u2_max_start", "u2_max_end"):
        x[0, COL[name]] = 2.0
    t = np.array([3.0])
    alpha = np.zeros((1, 2))
    (px, py, _, v), _ = rk4_rollout(
        (np.zeros(1), np.zeros(1), np.zeros(1), np.array([10.0])),
        x,
        t,
        alpha,
        alpha,
        np.array([[9.0]]),
        50,
    )
    assert px[0] == pytest.approx(10 * 3 + 0.5 * 2 * 9, rel=1e-9)
    assert py[0] == pytest.approx(0.0, abs=1e-12)
    assert v[0] == pytest.approx(16.0)


def test_braking_car_stops_and_stays() -> None:
    x = np.zeros((1, N_INPUTS))
    for name in ("u2_min_start", "u2_min_end", "u2_max_start", "u2_max_end"):
        x[0, COL[name]] = -5.0
    alpha = np.zeros((1, 2))
    (px, _, _, v), _ = rk4_rollout(
        (np.zeros(1), np.zeros(1), np.zeros(1), np.array([5.0])),
        x,
        np.array([3.0]),
        alpha,
        alpha,
        np.array([[9.0]]),
        300,
    )
    assert v[0] == 0.0
    assert px[0] == pytest.approx(5.0**2 / (2 * 5.0), abs=0.05)
