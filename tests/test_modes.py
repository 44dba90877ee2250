"""The joint (mode, beta) filter, the mode set, and the union of per-mode sets.

References are computed independently here, in linear space with scipy.stats densities (every
normalising term kept), not with the module's log-space code path.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import multivariate_normal

from reach.engine import FRTEngine
from reach.frames import Pose
from reach.union import UnionSet, conservative_union, exact_union
from service.flows.bounds import PredictionError
from service.flows.confidence import Belief, hypotheses, prior_belief, update_belief
from service.flows.modes import JointBelief, select_modes, validate_mixture


def reference_joint(betas, weights, probs, action, means, covs, eps) -> np.ndarray:
    """One step in linear space: b_- = (1 - eps) b + eps w_m / n, then Bayes with scipy pdfs."""
    n = len(betas)
    prior = (1.0 - eps) * probs + eps * np.asarray(weights)[:, None] / n
    dens = np.array(
        [
            [multivariate_normal(means[m], np.asarray(covs[m]) / b).pdf(action) for b in betas]
            for m in range(len(weights))
        ]
    )
    post = dens * prior
    return post / post.sum()


def random_modes(rng: np.random.Generator, m: int) -> tuple[np.ndarray, np.ndarray]:
    a = rng.normal(size=(m, 2, 2)) * 0.3
    covs = a @ a.transpose(0, 2, 1) + 0.02 * np.eye(2)
    return rng.normal(size=(m, 2)) * 0.5, covs


@pytest.mark.parametrize(("m", "n", "eps"), [(2, 2, 0.05), (3, 2, 0.0), (6, 5, 0.2), (25, 3, 1e-6)])
def test_a_sequence_of_joint_updates_matches_scipy(m: int, n: int, eps: float) -> None:
    rng = np.random.default_rng(m * 10 + n)
    betas = hypotheses(0.05, n)
    weights = rng.uniform(0.1, 1.0, m)
    weights /= weights.sum()
    joint = JointBelief.prior(betas, weights)
    probs = weights[:, None] / n * np.ones((1, n))
    np.testing.assert_allclose(joint.probs, probs, rtol=1e-12)
    for _ in range(12):
        means, covs = random_modes(rng, m)
        action = means[rng.integers(m)] + rng.normal(size=2) * 0.4
        joint = joint.update(action, means, covs, eps)
        probs = reference_joint(betas, weights, probs, action, means, covs, eps)
        np.testing.assert_allclose(joint.probs, probs, rtol=1e-8, atol=1e-300)
        np.testing.assert_allclose(joint.mode_probs, probs.sum(axis=1), rtol=1e-8, atol=1e-300)
        conditional = probs / probs.sum(axis=1, keepdims=True)
        np.testing.assert_allclose(joint.mode_betas, conditional @ betas, rtol=1e-8)
        assert joint.beta_belief().beta == pytest.approx(float(probs.sum(axis=0) @ betas), 1e-9)


@given(
    st.integers(1, 8),
    st.integers(2, 6),
    st.floats(0.0, 0.5),
    st.lists(st.floats(-1e6, 1e6), min_size=2, max_size=2),
    st.integers(0, 2**32 - 1),
)
@settings(max_examples=60, deadline=None)
def test_joint_beliefs_are_distributions_and_betas_in_range(m, n, eps, action, seed) -> None:
    rng = np.random.default_rng(seed)
    betas = hypotheses(0.03, n)
    joint = JointBelief.prior(betas, rng.uniform(0.01, 1.0, m))
    for _ in range(3):
        means, covs = random_modes(rng, m)
        joint = joint.update(np.array(action), means, covs, eps)
        p = joint.probs
        assert np.isfinite(joint.log_probs).all() and (p >= 0).all()
        assert p.sum() == pytest.approx(1.0, abs=1e-12)
        assert ((joint.mode_betas >= betas[0]) & (joint.mode_betas <= 1.0)).all()
        if eps > 0:  # the transition keeps every pair at least eps w_m / n before Bayes
            assert (joint.transition(eps).probs >= eps * joint.weights[:, None] / n * 0.999).all()


def test_one_mode_is_the_single_gaussian_filter() -> None:
    rng = np.random.default_rng(4)
    betas = hypotheses(0.03)
    single = prior_belief(betas)
    joint = JointBelief.from_beta_belief(single, [1.0])
    for _ in range(20):
        means, covs = random_modes(rng, 1)
        action = means[0] + rng.normal(size=2) * 2.0
        single = update_belief(single, action, means[0], covs[0], 0.05)
        joint = joint.update(action, means, covs, 0.05)
        np.testing.assert_allclose(joint.beta_belief().probs, single.probs, rtol=1e-12)
        assert joint.mode_betas[0] == pytest.approx(single.beta, rel=1e-12)


def test_actions_following_the_minor_mode_raise_its_posterior() -> None:
    betas = hypotheses(0.03)
    cov = np.diag([0.01, 0.25])
    means = np.array([[0.0, 0.0], [0.5, -1.0]])  # straight (0.9), U-turn (0.1)
    joint = JointBelief.prior(betas, [0.9, 0.1])
    posteriors = [joint.mode_probs[1]]
    for _ in range(5):
        joint = joint.update(means[1], means, np.stack([cov, cov]), 0.05)
        posteriors.append(joint.mode_probs[1])
    assert all(b > a for a, b in itertools.pairwise(posteriors))
    assert posteriors[-1] > 0.99
    assert joint.mode_betas[1] > 0.9  # the U-turn mode explains them: high confidence in it


def test_a_thousand_sigma_action_leaves_a_finite_joint_belief() -> None:
    joint = JointBelief.prior(hypotheses(0.03), [0.5, 0.5])
    covs = np.stack([np.diag([0.01, 0.25])] * 2)
    joint = joint.update([1e200, -1e200], np.zeros((2, 2)), covs, 0.05)
    assert np.isfinite(joint.log_probs).all()
    assert joint.probs.sum() == pytest.approx(1.0)


def test_carrying_the_belief_to_a_new_prediction() -> None:
    betas = hypotheses(0.03)
    joint = JointBelief(betas, [0.5, 0.5], np.log([[0.1, 0.2], [0.3, 0.4]]))
    same = joint.for_prediction([0.2, 0.8])
    np.testing.assert_array_equal(same.log_probs, joint.log_probs)
    np.testing.assert_allclose(same.weights, [0.2, 0.8])
    other = joint.for_prediction([1.0, 1.0, 2.0])
    np.testing.assert_allclose(other.mode_probs, [0.25, 0.25, 0.5])
    np.testing.assert_allclose(other.beta_belief().probs, joint.beta_belief().probs)
    assert JointBelief.from_dict(joint.to_dict()).to_dict() == joint.to_dict()


@pytest.mark.parametrize(
    ("posterior", "mass", "floor", "expected"),
    [
        ([0.9, 0.1], 0.99, 1e-3, [0, 1]),
        ([0.995, 0.005], 0.99, 1e-3, [0, 1]),  # above the floor: kept
        ([0.9995, 0.0005], 0.99, 1e-3, [0]),
        ([0.2, 0.5, 0.3], 0.7, 0.0, [0, 1, 2]),  # a floor of 0 keeps every mode
        ([0.2, 0.5, 0.3], 0.7, 0.25, [1, 2]),
        ([0.2, 0.5, 0.3], 0.7, 0.1, [0, 1, 2]),
        ([0.25, 0.25, 0.5], 1.0, 0.5, [0, 1, 2]),
    ],
)
def test_select_modes(posterior, mass, floor, expected) -> None:
    assert select_modes(posterior, mass, floor) == expected


@given(st.lists(st.floats(1e-9, 1.0), min_size=1, max_size=32), st.floats(0.5, 1.0))
def test_the_modes_left_out_are_below_the_floor_and_the_mass(weights, mass) -> None:
    p = np.array(weights) / sum(weights)
    floor = 1e-3
    chosen = select_modes(p, mass, floor)
    left = [m for m in range(p.size) if m not in chosen]
    assert all(p[m] <= floor for m in left)
    assert p[left].sum() <= 1.0 - mass + 1e-9
    assert int(np.argmax(p)) in chosen


class _Mode:
    def __init__(self, weight, mean, cov) -> None:
        self.weight, self.mean, self.cov = weight, mean, cov


def test_mixture_validation_names_the_field() -> None:
    mean, cov = [[0.0, 0.0]] * 6, [[[0.01, 0.0], [0.0, 0.25]]] * 6
    mixture = validate_mixture([_Mode(2.0, mean, cov), _Mode(6.0, mean, cov)], 0.5, 64, 32)
    np.testing.assert_allclose(mixture.weights, [0.25, 0.75])  # normalised
    with pytest.raises(PredictionError) as exc:
        validate_mixture([_Mode(1.0, mean, cov)] * 33, 0.5, 64, 32)
    assert exc.value.field == "prediction.modes[32]"
    bad = [[[0.01, 0.0], [0.0, -0.25]]] * 6
    with pytest.raises(PredictionError) as exc:
        validate_mixture([_Mode(1.0, mean, cov), _Mode(1.0, mean, bad)], 0.5, 64, 32)
    assert exc.value.field == "prediction.modes[1].cov[0]"
    with pytest.raises(PredictionError) as exc:
        validate_mixture([_Mode(1.0, mean, cov), _Mode(1.0, mean[:3], cov[:3])], 0.5, 64, 32)
    assert exc.value.field == "prediction.modes[1].mean"
    for w in (0.0, -1.0, float("inf"), float("nan")):
        with pytest.raises(PredictionError) as exc:
            validate_mixture([_Mode(1.0, mean, cov), _Mode(w, mean, cov)], 0.5, 64, 32)
        assert exc.value.field == "prediction.modes[1].weight"


# --- the union ---------------------------------------------------------------------------------

STRAIGHT = np.array([-0.05, -1.0, -0.05, -1.0, 0.05, 1.0, 0.05, 1.0])
TURN = np.array([1.2, -3.0, 1.2, -3.0, 1.5, -2.0, 1.5, -2.0])
POSE = Pose(3.0, -2.0, 0.7)


def test_the_union_is_the_union_of_its_members() -> None:
    engine = FRTEngine()
    members = [engine.exact(POSE, 6.0, b, notch_cut=False) for b in (STRAIGHT, TURN)]
    union = exact_union(engine, POSE, 6.0, np.stack([STRAIGHT, TURN]))
    assert union.clearance_from_tubes and not union.missing_tubes([union.n_slices - 1])
    for j in (5, 17, union.n_slices - 1):
        expected = shapely.union_all([m.tube(j) for m in members])
        assert union.tube(j).symmetric_difference(expected).area < 1e-6
    rng = np.random.default_rng(0)
    xy = rng.uniform(-40, 40, (400, 2)) + np.array([3.0, -2.0])
    for t_rel in (None, rng.uniform(0, 3, 400)):
        got = union.clearance(xy, t_rel)
        each = np.min([m.clearance(xy, t_rel) for m in members], axis=0)
        outside = each > 0
        np.testing.assert_allclose(got[outside], each[outside], atol=1e-6)
        assert (got[~outside] <= each[~outside] + 1e-9).all()  # at least as deep inside
        assert ((got > 0) == outside).all()
    geo = union.geojson("tube", None, 1.5)
    assert set(geo) == {"K", "C"}


def test_the_conservative_union_holds_the_exact_union() -> None:
    engine = FRTEngine()
    bounds = np.stack([STRAIGHT, TURN])
    exact = exact_union(engine, POSE, 6.0, bounds)
    boxes = conservative_union(engine, POSE, 6.0, bounds)
    assert boxes.conservative and not boxes.clearance_from_tubes
    assert exact.tube(exact.n_slices - 1).difference(boxes.tube(boxes.n_slices - 1)).area < 1e-6
    xy = np.array([[3.0, -2.0], [100.0, 100.0]])
    np.testing.assert_allclose(
        boxes.clearance(xy), np.min([m.clearance(xy) for m in boxes.members], axis=0)
    )


def test_a_union_needs_members_of_one_setting() -> None:
    engine = FRTEngine()
    with pytest.raises(ValueError):
        UnionSet([])
    a = engine.conservative(POSE, 6.0, STRAIGHT)
    b = engine.conservative(Pose(0.0, 0.0, 0.0), 6.0, STRAIGHT)
    with pytest.raises(ValueError):
        UnionSet([a, b])


def test_beliefs_reject_bad_input() -> None:
    with pytest.raises(ValueError):
        JointBelief(hypotheses(0.03), [0.5, 0.5], np.zeros((3, 2)))
    with pytest.raises(ValueError):
        JointBelief.prior(hypotheses(0.03), [0.5, -0.5])
    with pytest.raises(ValueError):
        JointBelief.prior(hypotheses(0.03), [1.0]).transition(1.0)
    assert isinstance(JointBelief.prior(hypotheses(0.03), [1.0]).beta_belief(), Belief)
