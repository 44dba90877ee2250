"""The beta Bayes filter (paper, "Confidence estimation and update", eq. beta).

References are computed independently here, in linear space with scipy.stats, not with the
module's log-space code path.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import multivariate_normal

from service.flows.confidence import (
    Belief,
    hypotheses,
    prior_belief,
    stored_estimates,
    transition,
    update_belief,
)

BETA_LOWS = (0.01, 0.03, 0.075, 0.2)
MEAN = np.array([0.0, 0.0])
SIGMA = np.array([0.1, 0.5])  # steering rate [rad/s], acceleration [m/s^2]
COV = np.diag(SIGMA**2)


def scripted_sequence() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The belief-evolution scenario of the paper's U-turn figure, at 10 Hz over 7 s.

    The prediction is N(MEAN, COV) throughout. Actions match it (within one sigma per control)
    until 2 s, then leave it from 2 s to 4 s (steering 0.6 rad/s = 6 sigma, braking -1 m/s^2 =
    2 sigma: the human starts a U-turn the predictor did not foresee), then match again.
    Returns (times [s], actions (N, 2), deviating mask (N,)). Also plotted by
    scripts/plot_belief.py.
    """
    dt = 0.1
    times = dt * np.arange(1, 71)
    rng = np.random.default_rng(7)
    actions = MEAN + SIGMA * np.clip(0.5 * rng.standard_normal((times.size, 2)), -1.0, 1.0)
    deviating = (times > 2.0 + 1e-9) & (times < 4.0 + 1e-9)
    actions[deviating] = [0.6, -1.0]
    return times, actions, deviating


def run_filter(beta_low: float, actions: np.ndarray, epsilon: float) -> np.ndarray:
    """beta after each observation, from the paper's prior."""
    belief = prior_belief(hypotheses(beta_low))
    out = []
    for action in actions:
        belief = update_belief(belief, action, MEAN, COV, epsilon)
        out.append(belief.beta)
    return np.array(out)


def reference_update(
    betas: np.ndarray, probs: np.ndarray, action, mean, cov, epsilon: float
) -> np.ndarray:
    """Eq. beta with the epsilon-static transition, in linear space with scipy densities."""
    prior = (1.0 - epsilon) * probs + epsilon / len(betas)
    dens = np.array([multivariate_normal(mean, cov / b).pdf(action) for b in betas])
    post = dens * prior
    return post / post.sum()


# --- hypotheses and the prior ----------------------------------------------------------------


def test_two_hypotheses_are_the_papers_pair() -> None:
    assert hypotheses(0.03).tolist() == [0.03, 1.0]
    prior = prior_belief(hypotheses(0.03))
    assert prior.probs.tolist() == [0.5, 0.5]
    assert prior.beta == pytest.approx((0.03 + 1.0) / 2, rel=1e-15)


@given(st.floats(1e-4, 0.99), st.integers(2, 12))
def test_grid_is_ascending_from_beta_low_to_one(beta_low: float, n: int) -> None:
    betas = hypotheses(beta_low, n)
    assert betas.shape == (n,)
    assert betas[0] == beta_low and betas[-1] == 1.0
    assert np.all(np.diff(betas) > 0)


@pytest.mark.parametrize("bad", [0.0, 1.0, -0.1, 1.5, float("nan"), float("inf")])
def test_hypotheses_reject_bad_beta_low(bad: float) -> None:
    with pytest.raises(ValueError):
        hypotheses(bad)


# --- values against scipy --------------------------------------------------------------------

CASES = [
    # betas, prior probs, action, mean, cov, epsilon
    ([0.03, 1.0], [0.5, 0.5], [0.05, -0.3], [0.0, 0.1], [[0.01, 0.0], [0.0, 0.25]], 0.05),
    ([0.03, 1.0], [0.2, 0.8], [0.3, 0.1], [0.0, 0.1], [[0.01, 0.0], [0.0, 0.25]], 0.05),
    ([0.1, 1.0], [0.9, 0.1], [0.0, 0.0], [0.02, -0.05], [[0.04, 0.01], [0.01, 0.09]], 0.0),
    ([0.075, 1.0], [0.5, 0.5], [-0.4, 2.0], [0.1, 0.5], [[0.02, -0.012], [-0.012, 0.5]], 1e-8),
    (
        [0.01, 0.1, 0.3, 1.0],
        [0.1, 0.2, 0.3, 0.4],
        [0.2, -1.0],
        [0.0, 0.0],
        np.diag([0.01, 0.25]),
        0.2,
    ),
]


@pytest.mark.parametrize(("betas", "probs", "action", "mean", "cov", "eps"), CASES)
def test_update_matches_scipy(betas, probs, action, mean, cov, eps) -> None:
    betas, probs, cov = np.array(betas), np.array(probs), np.array(cov, dtype=float)
    belief = Belief(betas=betas, log_probs=np.log(probs))
    expected = reference_update(betas, probs, action, mean, cov, eps)
    got = update_belief(belief, action, mean, cov, eps)
    np.testing.assert_allclose(got.probs, expected, rtol=1e-10, atol=1e-300)
    assert got.beta == pytest.approx(float(betas @ expected), rel=1e-12)


@pytest.mark.parametrize("n", [2, 5])
def test_a_sequence_of_updates_matches_scipy(n: int) -> None:
    rng = np.random.default_rng(n)
    betas = hypotheses(0.05, n)
    belief = prior_belief(betas)
    probs = np.full(n, 1.0 / n)
    for _ in range(15):
        a = rng.normal(size=(2, 2))
        cov = a @ a.T + 0.05 * np.eye(2)
        mean = rng.normal(size=2)
        action = mean + rng.normal(size=2) * 1.5
        belief = update_belief(belief, action, mean, cov, 0.05)
        probs = reference_update(betas, probs, action, mean, cov, 0.05)
        np.testing.assert_allclose(belief.probs, probs, rtol=1e-9)


def test_transition_mixes_in_the_uniform_prior() -> None:
    belief = Belief(betas=np.array([0.03, 1.0]), log_probs=np.log([0.999, 0.001]))
    np.testing.assert_allclose(
        transition(belief, 0.05).probs, [0.95 * 0.999 + 0.025, 0.95 * 0.001 + 0.025]
    )
    assert transition(belief, 0.0) == belief


# --- properties ------------------------------------------------------------------------------

step = st.tuples(
    st.floats(-30, 30),  # action offset in sigmas, per control
    st.floats(-30, 30),
    st.floats(1e-3, 3.0),  # standard deviations
    st.floats(1e-3, 3.0),
    st.floats(-0.95, 0.95),  # correlation
)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(1e-3, 0.9),
    st.integers(2, 6),
    st.floats(0.0, 0.5),
    st.lists(step, min_size=1, max_size=12),
)
def test_beliefs_are_distributions_and_beta_is_in_range(beta_low, n, eps, steps) -> None:
    belief = prior_belief(hypotheses(beta_low, n))
    for z1, z2, s1, s2, rho in steps:
        cov = np.array([[s1 * s1, rho * s1 * s2], [rho * s1 * s2, s2 * s2]])
        action = np.array([z1 * s1, z2 * s2])
        belief = update_belief(belief, action, MEAN, cov, eps)
        p = belief.probs
        assert np.all(np.isfinite(belief.log_probs))
        assert np.all((p >= 0.0) & (p <= 1.0))
        assert p.sum() == pytest.approx(1.0, abs=1e-12)
        assert beta_low <= belief.beta <= 1.0
    stored = json.dumps(belief.to_dict(), allow_nan=False)
    assert Belief.from_dict(json.loads(stored)) == belief


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.integers(2, 6), st.integers(0, 2**32 - 1)), min_size=1, max_size=9))
def test_stored_beliefs_estimates_together_are_each_ones_own(shapes) -> None:
    """``stored_estimates`` of beliefs of several sizes at once: bit for bit each stored
    belief's own ``beta`` read back alone."""
    stored = []
    for n, seed in shapes:
        rng = np.random.default_rng(seed)
        belief = prior_belief(hypotheses(float(rng.uniform(0.01, 0.5)), n))
        for _ in range(int(rng.integers(0, 5))):
            action = rng.normal(0.0, 3.0, size=2) * SIGMA
            belief = update_belief(belief, action, MEAN, COV, float(rng.uniform(0.0, 0.3)))
        stored.append(json.loads(json.dumps(belief.to_dict())))
    assert stored_estimates(stored) == [Belief.from_dict(b).beta for b in stored]


# --- far outliers ----------------------------------------------------------------------------


@pytest.mark.parametrize("sigmas", [1e3, 1e6, 1e200])
def test_far_action_gives_a_finite_belief_and_the_filter_recovers(sigmas: float) -> None:
    belief = prior_belief(hypotheses(0.03))
    for _ in range(5):
        belief = update_belief(belief, MEAN, MEAN, COV, 0.05)
    belief = update_belief(belief, MEAN + sigmas * SIGMA, MEAN, COV, 0.05)
    assert np.all(np.isfinite(belief.log_probs)) and np.all(np.isfinite(belief.probs))
    assert belief.beta == pytest.approx(0.03, abs=1e-12)
    json.dumps(belief.to_dict(), allow_nan=False)
    betas = []
    for _ in range(3):
        belief = update_belief(belief, MEAN, MEAN, COV, 0.05)
        betas.append(belief.beta)
    assert betas[-1] > 0.9  # epsilon = 0.05: trust is back within three matching observations
    assert betas == sorted(betas)


def test_overflowing_distance_is_finite_too() -> None:
    belief = update_belief(prior_belief([0.03, 1.0]), [1e308, -1e308], [-1e308, 1e308], COV, 0.05)
    assert np.all(np.isfinite(belief.log_probs)) and belief.beta == pytest.approx(0.03)


def test_without_epsilon_a_thousand_sigma_action_is_never_forgotten() -> None:
    # Why epsilon > 0: with pure Bayes the evidence (~ 0.97 * 1000^2 / 2 nats) must be paid back.
    belief = update_belief(prior_belief([0.03, 1.0]), 1000 * SIGMA, MEAN, COV, 0.0)
    assert np.all(np.isfinite(belief.log_probs))
    for _ in range(100):
        belief = update_belief(belief, MEAN, MEAN, COV, 0.0)
    assert belief.beta == pytest.approx(0.03, abs=1e-9)
    # The authors' epsilon = 1e-8 bounds it: log(2 / 1e-8) = 19 nats, log(1/0.03) = 3.5 a step.
    belief = update_belief(prior_belief([0.03, 1.0]), 1000 * SIGMA, MEAN, COV, 1e-8)
    for _ in range(7):
        belief = update_belief(belief, MEAN, MEAN, COV, 1e-8)
    assert belief.beta > 0.9


# --- the paper's qualitative result ----------------------------------------------------------


def first_index(mask: np.ndarray) -> int:
    assert mask.any()
    return int(np.argmax(mask))


@pytest.mark.parametrize(("epsilon", "fall_within"), [(0.05, 1), (1e-8, 2)])
def test_belief_evolution_on_the_scripted_sequence(epsilon: float, fall_within: int) -> None:
    _, actions, deviating = scripted_sequence()
    start, stop = first_index(deviating), len(deviating) - first_index(deviating[::-1])
    recovery = []
    for beta_low in BETA_LOWS:
        beta = run_filter(beta_low, actions, epsilon)
        # Trusted while the actions match the prediction ...
        assert np.all(beta[5:start] > 0.9)
        # ... falls sharply (to about beta_low) once they leave it, and stays down ...
        assert np.all(beta[start + fall_within - 1 : stop] < beta_low + 0.01)
        # ... and recovers once they match again.
        after = beta[stop:]
        assert after[-1] > 0.9
        recovery.append(first_index(after > 0.9))
    # A higher beta_low recovers later (paper, "Effect of beta_low").
    assert recovery == sorted(recovery)
    assert recovery[-1] > recovery[0]


def test_the_fall_is_immediate_with_the_default_epsilon() -> None:
    _, actions, deviating = scripted_sequence()
    k = first_index(deviating)
    for beta_low in BETA_LOWS:
        beta = run_filter(beta_low, actions, 0.05)
        assert beta[k - 1] > 0.99 and beta[k] < beta_low + 0.01


# --- invalid input ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("action", "cov", "eps"),
    [
        ([float("nan"), 0.0], COV, 0.05),
        ([0.0, float("inf")], COV, 0.05),
        ([0.0, 0.0], [[1.0, 2.0], [2.0, 1.0]], 0.05),  # indefinite
        ([0.0, 0.0], np.zeros((2, 2)), 0.05),
        ([0.0, 0.0, 0.0], COV, 0.05),  # shape
        ([0.0, 0.0], COV, 1.0),
        ([0.0, 0.0], COV, -0.1),
    ],
)
def test_update_rejects_bad_input(action, cov, eps) -> None:
    with pytest.raises(ValueError):
        update_belief(prior_belief([0.03, 1.0]), action, MEAN, cov, eps)


def test_belief_is_validated_normalised_and_frozen() -> None:
    b = Belief(betas=np.array([0.1, 1.0]), log_probs=np.array([0.0, math.log(3.0)]))
    np.testing.assert_allclose(b.probs, [0.25, 0.75])
    with pytest.raises(ValueError):
        b.log_probs[0] = 1.0
    for betas, log_probs in [([1.0, 0.1], [0, 0]), ([0.1, 1.0], [float("nan"), 0]), ([1.0], [0])]:
        with pytest.raises(ValueError):
            Belief(betas=np.array(betas), log_probs=np.array(log_probs, dtype=float))
