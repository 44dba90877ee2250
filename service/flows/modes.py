"""Multi-modal predictions: the joint belief over (mode, beta) and the modes the served set holds.

A predictor such as Trajectron++ gives a mixture: mode m (weight w_m) is a Gaussian over the
controls, N(mu_m, Sigma_m) per step. The belief is over pairs (m, beta_i) jointly:

- the epsilon-static transition mixes it back towards the prior, the mode weights times the beta
  prior: ``b_-(m, beta) = (1 - eps) b_+(m, beta) + eps w_m / n`` (paper, "Confidence estimation
  and update", the transition after eq. ``beta``, with the prior over pairs);
- Bayes' rule with the observed action's likelihood under that mode's tempered Gaussian,
  ``b_+(m, beta) ∝ f(u; mu_m, Sigma_m / beta) b_-(m, beta)`` (paper, eq. ``predUpdate`` in eq.
  ``beta``, the sum running over every pair). Inferring which intent (mode) the human follows
  from their actions, jointly with how far to trust the model, is the goal/intent inference of
  Fisac et al., "Probabilistically safe robot planning with confidence-based human predictions",
  RSS 2018;
- each mode's point estimate is its conditional mean ``beta_m = sum_i beta_i b(beta_i | m)``
  (paper, the equation for beta^t, given the mode), and the agent's beta the marginal one.

Unlike the single-Gaussian filter, the likelihood's normalising term ``-(1/2) log det Sigma_m``
differs between modes, so it is kept; ``-(k/2) log 2 pi`` is shared by every pair and dropped.
Everything is on log-probabilities, as in ``service.flows.confidence``.

Modes are identified by their place in the list: the posterior of mode m carries over to mode m of
the next prediction when it has as many modes; otherwise the mode belief restarts from the new
weights, keeping the marginal belief over beta. With one mode the joint belief is the
single-Gaussian filter's, step for step (the same floating-point operations).

The served set is the union of the per-mode tubes (``reach.union``), each from its mode's own
bounds (its own beta), over the fewest most probable modes holding ``mode_mass`` of the posterior,
plus every mode whose posterior exceeds ``mode_floor``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from service.flows.bounds import PredictionError, validate_predictions
from service.flows.confidence import (
    Belief,
    log_likelihood_rows,
    mahalanobis2_rows,
    normalised_rows,
    point_estimates,
    prior_belief,
    probability_rows,
    transition_rows,
)

#: Defaults of the per-agent ``mode_mass`` and ``mode_floor``.
MODE_MASS = 0.99
MODE_FLOOR = 1e-3


def normalised_weights(weights: ArrayLike) -> np.ndarray:
    """The mode weights divided by their sum (each must be positive and finite)."""
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 1 or not w.size or not (np.isfinite(w).all() and (w > 0).all()):
        raise ValueError("mode weights must be a non-empty list of positive finite numbers")
    return weight_rows(w[None])[0]


# --- joint beliefs on rows: [A, M, n], one agent per row -----------------------------------------
#
# Every function below works agent by agent on arrays of agents with the same numbers of modes M
# and hypotheses n (the same floating-point operations on every agent, whatever the others): a
# frame's joint beliefs computed together are bit for bit the ones computed one by one, and
# :class:`JointBelief` is an agent on its own.


def weight_rows(weights: np.ndarray) -> np.ndarray:
    """Each agent's mode weights [A, M] divided by their sum."""
    with np.errstate(over="ignore"):
        total = weights.sum(axis=-1, keepdims=True)
    # Weights near the largest float overflow their sum: such a row is divided by its largest
    # weight first (any other row by 1.0, which leaves it as it is).
    scaled = weights / np.where(np.isfinite(total), 1.0, weights.max(axis=-1, keepdims=True))
    return scaled / scaled.sum(axis=-1, keepdims=True)


def joint_normalised(log_probs: np.ndarray) -> np.ndarray:
    """Each agent's b(m, beta_i) [A, M, n] normalised over all its pairs (``normalised_rows``)."""
    a, m, n = log_probs.shape
    return normalised_rows(log_probs.reshape(a, m * n)).reshape(a, m, n)


def joint_of_beta_beliefs(beta_log_probs: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Independent modes and beta, ``b(m, beta_i) = w_m b(beta_i)``: beliefs over beta [A, n]
    and normalised weights [A, M] in, normalised joint log-probabilities [A, M, n] out."""
    return joint_normalised(np.log(weights)[:, :, None] + beta_log_probs[:, None, :])


def joint_transition(
    log_probs: np.ndarray, weights: np.ndarray, epsilons: np.ndarray
) -> np.ndarray:
    """``b_- = (1 - eps) b_+ + eps w_m / n`` of each agent (its own epsilon), normalised."""
    a, m, n = log_probs.shape
    log_prior = np.broadcast_to(np.log(weights)[:, :, None] - math.log(n), (a, m, n))
    mixed = transition_rows(log_probs.reshape(a, m * n), log_prior.reshape(a, m * n), epsilons)
    return joint_normalised(mixed.reshape(a, m, n))


def joint_likelihoods(
    betas: np.ndarray, actions: np.ndarray, means: np.ndarray, covs: np.ndarray
) -> np.ndarray:
    """``log f(u; mu_m, Sigma_m / beta_i)`` [A, M, n] of each agent's action [A, k] under each of
    its modes (means [A, M, k], covs [A, M, k, k]) and hypotheses (betas [A, n]), up to a constant
    shared by all of the agent's pairs: the ``- (1/2) log det Sigma_m`` that differs between modes
    is kept, relative to the agent's smallest (0 for one mode)."""
    a, m, k = means.shape
    u = np.broadcast_to(actions[:, None, :], (a, m, k)).reshape(a * m, k)
    d2 = mahalanobis2_rows(u, means.reshape(a * m, k), covs.reshape(a * m, k, k)).reshape(a, m)
    log_dets = np.linalg.slogdet(0.5 * (covs + covs.swapaxes(-1, -2)))[1]
    log_dets = log_dets - log_dets.min(axis=-1, keepdims=True)
    return log_likelihood_rows(betas[:, None, :], d2, k) - 0.5 * log_dets[:, :, None]


def joint_update(
    log_probs: np.ndarray,
    weights: np.ndarray,
    epsilons: np.ndarray,
    betas: np.ndarray,
    observed: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> np.ndarray:
    """One filter step of each agent: the transition, then Bayes' rule over every (mode, beta)
    pair with the ``observed`` (actions [A, k], means [A, M, k], covs [A, M, k, k]), normalised."""
    prior = joint_transition(log_probs, weights, epsilons)
    return joint_normalised(prior + joint_likelihoods(betas, *observed))


def joint_mode_probs(log_probs: np.ndarray) -> np.ndarray:
    """Each agent's mode posterior P(m) [A, M]."""
    a, m, n = log_probs.shape
    return probability_rows(log_probs.reshape(a, m * n)).reshape(a, m, n).sum(axis=-1)


def joint_mode_betas(betas: np.ndarray, log_probs: np.ndarray) -> np.ndarray:
    """Each agent's per-mode point estimates E[beta | m] [A, M], inside [beta_low, 1]: the point
    estimate of each conditional belief b(beta | m), as the single-Gaussian filter's."""
    return point_estimates(betas[:, None, :], normalised_rows(log_probs))


def joint_beta_marginals(log_probs: np.ndarray) -> np.ndarray:
    """Each agent's marginal belief over beta [A, n], normalised."""
    top = log_probs.max(axis=1, keepdims=True)
    lse = top + np.log(np.exp(log_probs - top).sum(axis=1, keepdims=True))
    return normalised_rows(lse[:, 0, :])


def _row(value: np.ndarray) -> np.ndarray:
    return np.asarray(value, dtype=np.float64)[None]


@dataclass(frozen=True, eq=False)
class JointBelief:
    """b(m, beta_i) as normalised log-probabilities ``log_probs`` [M, n], with the mode weights
    ``weights`` [M] (normalised) the transition mixes back towards: one agent of the functions
    above."""

    betas: np.ndarray
    weights: np.ndarray
    log_probs: np.ndarray

    def __post_init__(self) -> None:
        betas = np.array(self.betas, dtype=np.float64)
        weights = normalised_weights(self.weights)
        log_probs = np.array(self.log_probs, dtype=np.float64)
        if betas.ndim != 1 or betas.size < 2 or log_probs.shape != (weights.size, betas.size):
            raise ValueError("log_probs must be [modes, hypotheses]")
        if not (np.isfinite(betas).all() and (betas > 0).all() and (np.diff(betas) > 0).all()):
            raise ValueError("betas must be positive, finite and strictly ascending")
        if np.isnan(log_probs).any() or not np.isfinite(log_probs).any():
            raise ValueError("log_probs must be numbers with at least one finite entry")
        log_probs = joint_normalised(log_probs[None])[0]
        for name, value in (("betas", betas), ("weights", weights), ("log_probs", log_probs)):
            value.flags.writeable = False
            object.__setattr__(self, name, value)

    @classmethod
    def prior(cls, betas: ArrayLike, weights: ArrayLike) -> JointBelief:
        """The prior b_-^0(m, beta_i) = w_m / n."""
        return cls.from_beta_belief(prior_belief(betas), weights)

    @classmethod
    def from_beta_belief(cls, belief: Belief, weights: ArrayLike) -> JointBelief:
        """Independent modes and beta: b(m, beta_i) = w_m b(beta_i)."""
        w = normalised_weights(weights)
        return cls(belief.betas, w, joint_of_beta_beliefs(_row(belief.log_probs), w[None])[0])

    def transition(self, epsilon: float) -> JointBelief:
        """``b_- = (1 - eps) b_+ + eps w_m / n`` (identity for eps = 0)."""
        if not (math.isfinite(epsilon) and 0.0 <= epsilon < 1.0):
            raise ValueError(f"epsilon must lie in [0, 1), got {epsilon!r}")
        if epsilon == 0.0:
            return self
        mixed = joint_transition(_row(self.log_probs), _row(self.weights), np.array([epsilon]))
        return JointBelief(self.betas, self.weights, mixed[0])

    def update(
        self, action: ArrayLike, means: ArrayLike, covs: ArrayLike, epsilon: float
    ) -> JointBelief:
        """One filter step: the transition, then Bayes' rule over every (mode, beta) pair with
        ``f(u; mu_m, Sigma_m / beta_i)``; ``means`` [M, k], ``covs`` [M, k, k] (each positive
        definite), one per mode."""
        mu = np.asarray(means, dtype=np.float64)
        sigma = np.asarray(covs, dtype=np.float64)
        u = np.asarray(action, dtype=np.float64)
        if mu.ndim != 2 or mu.shape[0] != self.weights.size or sigma.shape[0] != mu.shape[0]:
            raise ValueError(f"need one mean and cov per mode: {mu.shape}, {sigma.shape}")
        if not (np.isfinite(u).all() and np.isfinite(mu).all() and np.isfinite(sigma).all()):
            raise ValueError("action, means and covs must be finite")
        if not (math.isfinite(epsilon) and 0.0 <= epsilon < 1.0):
            raise ValueError(f"epsilon must lie in [0, 1), got {epsilon!r}")
        observed = (u[None], mu[None], sigma[None])
        log_probs = joint_update(
            _row(self.log_probs),
            _row(self.weights),
            np.array([epsilon]),
            _row(self.betas),
            observed,
        )
        return JointBelief(self.betas, self.weights, log_probs[0])

    @property
    def probs(self) -> np.ndarray:
        """b(m, beta_i) [M, n], summing to one."""
        m, n = self.log_probs.shape
        return probability_rows(self.log_probs.reshape(1, m * n)).reshape(m, n)

    @property
    def mode_probs(self) -> np.ndarray:
        """The mode posterior P(m) [M]."""
        return joint_mode_probs(_row(self.log_probs))[0]

    @property
    def mode_betas(self) -> np.ndarray:
        """Each mode's point estimate E[beta | m] [M], inside [beta_low, 1]: the point estimate
        of its conditional belief b(beta | m), computed as the single-Gaussian filter's."""
        return joint_mode_betas(_row(self.betas), _row(self.log_probs))[0]

    def beta_belief(self) -> Belief:
        """The marginal belief over beta."""
        return Belief(betas=self.betas, log_probs=joint_beta_marginals(_row(self.log_probs))[0])

    def for_prediction(self, weights: ArrayLike) -> JointBelief:
        """The belief carried to a new prediction with ``weights``: the same posterior when it
        has as many modes (mode m is mode m), else the marginal beta belief times the new
        weights."""
        w = normalised_weights(weights)
        if w.size == self.weights.size:
            return JointBelief(self.betas, w, self.log_probs)
        return JointBelief.from_beta_belief(self.beta_belief(), w)

    def regrid(self, betas: np.ndarray) -> JointBelief:
        """The same weights on new hypotheses (a new beta_low), as ``service.flows.agents``
        does for a single Gaussian."""
        if np.array_equal(betas, self.betas):
            return self
        return JointBelief(betas, self.weights, self.log_probs)

    def to_dict(self) -> dict[str, Any]:
        return {
            "betas": self.betas.tolist(),
            "weights": self.weights.tolist(),
            "log_probs": self.log_probs.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> JointBelief:
        return cls(
            np.asarray(data["betas"]), np.asarray(data["weights"]), np.asarray(data["log_probs"])
        )


def select_modes(
    posterior: ArrayLike, mode_mass: float = MODE_MASS, mode_floor: float = MODE_FLOOR
) -> list[int]:
    """The modes the served set holds, in index order: the fewest most probable ones whose
    posterior adds up to ``mode_mass`` (ties by index), and every mode above ``mode_floor``.
    The modes left out have posterior at most ``mode_floor`` each and less than
    ``1 - mode_mass`` together (to float rounding)."""
    p = np.asarray(posterior, dtype=np.float64)
    if not (0.0 < mode_mass <= 1.0 and 0.0 <= mode_floor < 1.0):
        raise ValueError("mode_mass must lie in (0, 1] and mode_floor in [0, 1)")
    if p.size == 1:  # a single Gaussian: the loop below takes its mode unless its mass is none
        return [] if p[0] <= 0.0 else [0]
    order = sorted(range(p.size), key=lambda m: (-p[m], m))
    chosen: set[int] = set()
    total = 0.0
    for m in order:
        if total >= mode_mass * (1.0 - 1e-12) * p.sum():
            break
        chosen.add(m)
        total += p[m]
    chosen.update(m for m in range(p.size) if p[m] > mode_floor)
    return sorted(chosen)


@dataclass(frozen=True)
class Mixture:
    """A validated multi-modal prediction: weights [M] (normalised), means [M, S, 2], covs
    [M, S, 2, 2] (symmetrised)."""

    dt: float
    weights: np.ndarray
    means: np.ndarray
    covs: np.ndarray


def validate_mixture(
    modes: list[Any],
    dt: Any,
    max_steps: int,
    max_modes: int,
    checked: list[tuple[np.ndarray, np.ndarray] | PredictionError] | None = None,
) -> Mixture:
    """Check a multi-modal prediction: at most ``max_modes`` modes, each a valid Gaussian
    (``validate_prediction``) with as many steps as the first, weights positive and finite
    (normalised here: they need not sum to one). Raises PredictionError naming the field
    (``prediction.modes[32]`` for the first mode beyond the limit,
    ``prediction.modes[m].cov[k]`` ...). ``checked``: the modes' ``validate_predictions``
    results, if the caller has them (a frame's modes are checked together)."""
    if len(modes) > max_modes:
        raise PredictionError(f"prediction.modes[{max_modes}]", f"at most {max_modes} modes")
    if checked is None:
        checked = validate_predictions([(m.mean, m.cov, dt) for m in modes], max_steps)
    means, covs, weights = [], [], []
    for m, (mode, result) in enumerate(zip(modes, checked, strict=True)):
        field = f"prediction.modes[{m}]"
        w = mode.weight
        if not (isinstance(w, int | float) and math.isfinite(w) and w > 0):
            raise PredictionError(f"{field}.weight", "must be a positive finite number")
        if isinstance(result, PredictionError):
            field_of = result.field.replace("prediction", field, 1)
            raise PredictionError(field_of, result.message) from None
        mean, cov = result
        if means and mean.shape != means[0].shape:
            raise PredictionError(
                f"{field}.mean", f"has {len(mean)} steps but prediction.modes[0] {len(means[0])}"
            )
        means.append(mean)
        covs.append(cov)
        weights.append(float(w))
    return Mixture(float(dt), normalised_weights(weights), np.stack(means), np.stack(covs))
