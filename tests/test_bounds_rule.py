"""The confidence-to-bounds rules (service.flows.bounds_rule): the paper's at full confidence bit for
bit, wider as the belief in beta_low rises, the class's limits at full distrust, the mixture's mass
held (checked by an independent quadrature), and through the API: chosen per agent, reported,
validated, and the served set holding rollouts under the bounds it was built from."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from statistics import NormalDist

import numpy as np
import pytest
import shapely
from fastapi.testclient import TestClient
from shapely.geometry import shape

from models.evaluate import simulate
from service.api.app import create_app
from service.flows.bounds import control_bounds, trim_intervals
from service.flows.bounds_rule import BOUNDS_RULES, distrust
from service.flows.confidence import Belief
from service.runtime.settings import Settings

GAMMA = 0.075
BETA_LOW = 0.03
LIMITS = (2.0, 10.0)
RNG = np.random.default_rng(35)


def prediction(rng: np.random.Generator, steps: int = 6) -> tuple[np.ndarray, np.ndarray]:
    mean = np.column_stack([rng.uniform(-0.5, 0.5, steps), rng.uniform(-4.0, 4.0, steps)])
    sd = np.column_stack([rng.uniform(0.02, 0.3, steps), rng.uniform(0.1, 1.5, steps)])
    cov = np.zeros((steps, 2, 2))
    cov[:, 0, 0], cov[:, 1, 1] = sd[:, 0] ** 2, sd[:, 1] ** 2
    return mean, cov


def beta_at(low_belief: float) -> float:
    """The paper's point estimate for b(beta_low) = low_belief over {beta_low, 1}."""
    p = np.clip([low_belief, 1.0 - low_belief], 1e-300, None)
    return Belief(betas=np.array([BETA_LOW, 1.0]), log_probs=np.log(p)).beta


@pytest.mark.parametrize("rule", BOUNDS_RULES)
@pytest.mark.parametrize("onset", [0.0, 0.3])
def test_full_confidence_is_the_papers_rule_bit_for_bit(rule: str, onset: float) -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        mean, cov = prediction(rng)
        paper = control_bounds(mean, cov, 0.5, 1.0, GAMMA, limits=LIMITS)
        assert (
            control_bounds(mean, cov, 0.5, 1.0, GAMMA, limits=LIMITS, rule=rule, onset=onset)
            == paper
        )
    # Inside the dead zone too: 1 - beta <= onset.
    beta = 0.75
    mean, cov = prediction(rng)
    lo, hi = trim_intervals(mean, cov, beta, GAMMA, rule=rule, onset=0.3, limits=LIMITS)
    plo, phi = trim_intervals(mean, cov, beta, GAMMA, limits=LIMITS)
    assert np.array_equal(lo, plo) and np.array_equal(hi, phi)


@pytest.mark.parametrize("rule", ["uniform_mixture", "mass_ramp"])
def test_bounds_widen_monotonically_as_the_belief_in_beta_low_rises(rule: str) -> None:
    rng = np.random.default_rng(2)
    mean, cov = prediction(rng)
    previous = None
    for b in np.linspace(0.0, 1.0, 41):
        beta = beta_at(float(b))
        lo, hi = trim_intervals(mean, cov, beta, GAMMA, rule=rule, limits=LIMITS)
        plo, phi = trim_intervals(mean, cov, beta, GAMMA, limits=LIMITS)
        assert np.all(lo <= plo) and np.all(hi >= phi), "narrower than the paper's rule"
        if previous is not None:
            assert np.all(lo <= previous[0] + 1e-12) and np.all(hi >= previous[1] - 1e-12)
        previous = (lo, hi)


def interval_mass(mu: float, sd: float, limit: float, w: float, lo: float, hi: float) -> float:
    """Mass of (1 - w) N(mu, sd^2) + w U[-limit, limit] on [lo, hi], by the normal CDF."""
    normal = NormalDist(mu, sd)
    gaussian = normal.cdf(hi) - normal.cdf(lo)
    uniform = max(0.0, min(hi, limit) - max(lo, -limit)) / (2.0 * limit)
    return (1.0 - w) * gaussian + w * uniform


def test_the_mixtures_interval_holds_its_target_mass_and_no_more_than_needed() -> None:
    rng = np.random.default_rng(3)
    for _ in range(30):
        mean, cov = prediction(rng)
        beta = float(rng.uniform(BETA_LOW, 1.0))
        w = distrust(beta)
        lo, hi = trim_intervals(mean, cov, beta, GAMMA, rule="uniform_mixture", limits=LIMITS)
        target = (1.0 - w) * GAMMA + w
        for k in range(mean.shape[0]):
            for d in range(2):
                sd = math.sqrt(cov[k, d, d] / beta)
                mass = interval_mass(mean[k, d], sd, LIMITS[d], w, lo[k, d], hi[k, d])
                paper_half = NormalDist().inv_cdf(0.5 + GAMMA / 2) * sd
                if hi[k, d] - mean[k, d] > paper_half * (1 + 1e-9):  # the mixture binds
                    assert mass == pytest.approx(target, abs=1e-9)
                else:
                    assert mass >= target - 1e-9


def test_at_full_distrust_the_bounds_reach_the_class_limits_within_the_stated_tolerance() -> None:
    """At b(beta_low) = 1, beta = beta_low and w = 1 - beta_low: the interval misses at most
    (1 - w)(1 - gamma) / w of the uniform's mass, i.e. that share of the range 2 L."""
    rng = np.random.default_rng(4)
    beta = beta_at(1.0)
    assert beta == pytest.approx(BETA_LOW)
    w = distrust(beta)
    tolerance = (1.0 - w) * (1.0 - GAMMA) / w
    for _ in range(30):
        mean, cov = prediction(rng)
        bounds = control_bounds(
            mean, cov, 0.5, beta, GAMMA, limits=LIMITS, rule="uniform_mixture"
        ).as_array()
        lo = np.minimum(bounds[[0, 1]], bounds[[2, 3]])  # u1, u2 min over start/end
        hi = np.maximum(bounds[[4, 5]], bounds[[6, 7]])
        limits = np.array(LIMITS)
        covered = (np.minimum(hi, limits) - np.maximum(lo, -limits)) / (2 * limits)
        assert np.all(covered >= 1.0 - tolerance - 1e-9), covered
    # The paper's rule at the same confidence stays near the mean.
    paper = control_bounds(mean, cov, 0.5, beta, GAMMA, limits=LIMITS).as_array()
    assert paper[4] - paper[0] < 0.5 * (2 * LIMITS[0])


def test_an_unknown_rule_and_onset_are_refused() -> None:
    mean, cov = prediction(np.random.default_rng(5))
    with pytest.raises(ValueError, match="bounds rule"):
        trim_intervals(mean, cov, 0.5, GAMMA, rule="wide", limits=LIMITS)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="rescue_onset"):
        distrust(0.5, onset=1.0)


# --- through the API --------------------------------------------------------------------------

COV = [[[0.0025, 0.0], [0.0, 0.25]]] * 6
MEAN = [[0.0, 0.0]] * 6


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    # The certified geometry alone (the analytic test network is a disc, not a value function).
    settings = Settings(model_path=analytic_model_path, log_requests=False, network="off")
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        deadline = time.monotonic() + 30
        while c.get("/readyz").status_code != 200:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        yield c


def body(t: float, action=None, config=None, prediction=None) -> dict:
    out = {
        "timestamp": t,
        "state": {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 5.0},
        "prediction": prediction or {"dt": 0.5, "mean": MEAN, "cov": COV},
    }
    if action is not None:
        out["observed_action"] = {"steering_rate": action[0], "acceleration": action[1]}
    if config is not None:
        out["config"] = config
    return out


def observe(client: TestClient, agent: str, payload: dict) -> dict:
    r = client.post(f"/v1/agents/{agent}/observations?wait_frt_ms=5000", json=payload)
    assert r.status_code == 200, r.text
    return r.json()


def test_the_rule_is_per_agent_reported_and_widens_on_a_wrong_prediction(
    client: TestClient,
) -> None:
    assert client.get("/v1/model").json()["active"]["bounds_rule"] == "paper"
    assert client.get("/readyz").json()["active"]["bounds_rule"] == "paper"
    widths = {}
    for rule in ("paper", "uniform_mixture"):
        agent = f"rule-{rule}"
        observe(client, agent, body(0.0, config={"beta_low": BETA_LOW, "bounds_rule": rule}))
        out = observe(client, agent, body(0.5, action=(0.6, 3.0)))  # 12 sigma off in u1
        assert out["beta"] < 0.1
        b = out["control_bounds"]
        widths[rule] = b["u1_max_start"] - b["u1_min_start"]
        view = client.get(f"/v1/agents/{agent}").json()
        assert view["config"]["bounds_rule"] == rule
    assert widths["uniform_mixture"] > 0.9 * 2 * 2.0  # nearly the car's whole steering range
    assert widths["paper"] < 0.2


def test_an_unknown_rule_is_a_422_naming_the_field_and_changes_nothing(client: TestClient) -> None:
    agent = "rule-bad"
    first = observe(client, agent, body(0.0))
    r = client.post(
        f"/v1/agents/{agent}/observations", json=body(0.5, config={"bounds_rule": "wide"})
    )
    assert r.status_code == 422
    assert r.json()["field"] == "config.bounds_rule"
    view = client.get(f"/v1/agents/{agent}").json()
    assert view["frt_version"] == first["frt_version"]
    assert view["config"]["bounds_rule"] == "paper"
    r = client.post(
        f"/v1/agents/{agent}/observations", json=body(0.5, config={"rescue_onset": 1.0})
    )
    assert r.status_code == 422 and r.json()["field"] == "config.rescue_onset"


def test_each_mode_of_a_mixture_widens_with_its_own_confidence(client: TestClient) -> None:
    modes = {
        "dt": 0.5,
        "modes": [
            {"weight": 0.7, "mean": MEAN, "cov": COV},
            {"weight": 0.3, "mean": [[0.3, -1.0]] * 6, "cov": COV},
        ],
    }
    spans = {}
    for rule in ("paper", "uniform_mixture"):
        agent = f"modes-{rule}"
        config = {"beta_low": BETA_LOW, "bounds_rule": rule, "mode_floor": 0.0, "mode_mass": 1.0}
        observe(client, agent, body(0.0, config=config, prediction=modes))
        out = observe(client, agent, body(0.5, action=(-0.8, 4.0), prediction=modes))
        spans[rule] = [
            m["control_bounds"]["u1_max_start"] - m["control_bounds"]["u1_min_start"]
            for m in out["modes"]
            if m["in_set"]
        ]
        assert len(spans[rule]) == 2
    assert all(u > 5 * p for u, p in zip(spans["uniform_mixture"], spans["paper"], strict=True))


def test_the_served_set_holds_rollouts_under_the_rescued_bounds(client: TestClient) -> None:
    agent = "rule-rollouts"
    observe(
        client, agent, body(0.0, config={"beta_low": BETA_LOW, "bounds_rule": "uniform_mixture"})
    )
    out = observe(client, agent, body(0.5, action=(0.6, 3.0)))
    b = out["control_bounds"]
    order = ["u1_min_start", "u2_min_start", "u1_min_end", "u2_min_end",
             "u1_max_start", "u2_max_start", "u1_max_end", "u2_max_end"]  # fmt: skip
    bounds = np.array([b[k] for k in order])
    sets = client.get(f"/v1/agents/{agent}/frt?slices=1.0,2.0,3.0&include=K").json()
    rollouts = simulate(5.0, bounds, 4096, np.random.default_rng(7))
    for item in sets["slices"]:
        t = item["time"] - out["timestamp"]  # slices are on the observations' clock
        k = shape(item["K"]).buffer(1e-6)
        at = np.isclose(rollouts.times, t, atol=1e-9)
        xy = rollouts.states[at][:, :, :2].reshape(-1, 2)
        assert len(xy) > 0
        inside = shapely.contains_xy(k, xy[:, 0], xy[:, 1])
        assert inside.all(), f"t={t}: {int((~inside).sum())} rollout points outside K"


def test_adaptive_gamma_is_the_rules_gamma(client: TestClient) -> None:
    """With a coverage target the rule trims the trusted part at adaptive gamma's current gamma:
    the served bounds are the rule's at the agent's beta and gamma_effective."""
    agent = "rule-adaptive"
    config = {"beta_low": BETA_LOW, "bounds_rule": "uniform_mixture", "coverage_target": 0.9}
    observe(client, agent, body(0.0, config=config))
    # Far from every earlier set: misses that move adaptive gamma, and an action that lowers beta.
    far = body(0.5, action=(0.3, 2.0))
    far["state"] = {"x": 40.0, "y": 15.0, "heading": 0.0, "speed": 5.0}
    out = observe(client, agent, far)
    view = client.get(f"/v1/agents/{agent}").json()
    gamma = view["gamma_effective"]
    assert gamma > GAMMA and out["beta"] < 0.5
    expected = control_bounds(
        np.array(MEAN), np.array(COV), 0.5, out["beta"], gamma, rule="uniform_mixture"
    ).to_dict()
    assert out["control_bounds"] == pytest.approx(expected, rel=1e-12, abs=1e-12)
