"""Model confidence beta: the Bayes filter over beta hypotheses, in log space.

Paper, section "Confidence estimation and update":

- the prediction is tempered by beta (eq. ``predUpdate``): ``u ~ N(mu, Sigma / beta)``;
- the belief over the hypotheses is updated by Bayes' rule with the Gaussian likelihood of the
  observed action (eq. ``beta``);
- before each update the epsilon-static transition mixes the prior back in:
  ``b_-^t = (1 - eps) b_+^{t-1} + eps b_-^0``;
- the point estimate is the belief-weighted mean ``beta^t = sum_i beta_i b_+^t(beta_i)``.

The paper uses two hypotheses {beta_low, beta_high = 1} with prior 0.5/0.5. Here the hypotheses are
any ascending grid over [beta_low, 1] (:func:`hypotheses`); with ``n = 2`` it is exactly the paper's
pair, and every formula below is the paper's with the sum running over the grid.

Everything is computed on log-probabilities: an action a thousand standard deviations (or 1e200)
away from the prediction gives a finite belief, never NaN, and the epsilon-static transition lets the
filter recover from it in a bounded number of observations (see docs/confidence.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

#: Log-probabilities are floored here so they stay finite and JSON-safe; exp(-1e300) is 0 in
#: float64, so the floor changes no probability.
LOG_PROB_FLOOR = -1.0e300
#: Squared Mahalanobis distances are capped here so an astronomically far action cannot overflow to
#: inf (inf * beta differences would give NaN); the posterior is then all on the lowest beta anyway.
MAHALANOBIS2_CAP = 1.0e300


def hypotheses(beta_low: float, n: int = 2) -> np.ndarray:
    """The beta hypotheses: ``n`` values from ``beta_low`` to ``beta_high = 1``, ascending.

    Paper, "Confidence estimation and update": beta in [beta_low, beta_high] with beta_high = 1 and
    0 < beta_low < 1. The grid is geometric (equal ratios) because beta scales a covariance, so
    log beta is its natural coordinate; with ``n = 2`` it is the paper's pair {beta_low, 1}.
    """
    if not (math.isfinite(beta_low) and 0.0 < beta_low < 1.0):
        raise ValueError(f"beta_low must lie in (0, 1), got {beta_low!r}")
    if n < 2:
        raise ValueError(f"need at least two hypotheses, got n={n}")
    return _grid(float(beta_low), n).copy()


@lru_cache(maxsize=256)
def _grid(beta_low: float, n: int) -> np.ndarray:
    """:func:`hypotheses` once per (beta_low, n): every observation asks, and geomspace is not free."""
    betas = np.geomspace(beta_low, 1.0, n)
    betas[0], betas[-1] = beta_low, 1.0
    betas.flags.writeable = False
    return betas


# --- the filter on rows: every belief of a frame at once, and one belief as a row of one --------
#
# A belief is a row of log-probabilities over its hypotheses, the last axis of an array; every
# function below works row by row (the same floating-point operations on every row, whatever the
# other rows), so a frame's beliefs computed together are bit for bit the ones computed one by one.


def normalised_rows(log_probs: np.ndarray) -> np.ndarray:
    """Each row shifted so that its probabilities sum to one (a stable log-sum-exp), then
    floored at :data:`LOG_PROB_FLOOR`; a row normalised already stays bit for bit the same."""
    top = log_probs.max(axis=-1, keepdims=True)
    lse = top + np.log(np.exp(log_probs - top).sum(axis=-1, keepdims=True))
    lse[np.abs(lse) < 1e-13] = 0.0  # normalised already: idempotent storage
    return np.maximum(log_probs - lse, LOG_PROB_FLOOR)


def probability_rows(log_probs: np.ndarray) -> np.ndarray:
    """Each row's probabilities: non-negative, summing to one."""
    p = np.exp(log_probs - log_probs.max(axis=-1, keepdims=True))
    return p / p.sum(axis=-1, keepdims=True)


def point_estimates(betas: np.ndarray, log_probs: np.ndarray) -> np.ndarray:
    """Each row's point estimate ``beta = sum_i beta_i b_+(beta_i)`` (paper, the equation after
    ``beta``), inside [betas[0], betas[-1]]; ``betas`` broadcasts against ``log_probs``."""
    betas = np.broadcast_to(betas, log_probs.shape)
    estimate = (betas * probability_rows(log_probs)).sum(axis=-1)
    return np.clip(estimate, betas[..., 0], betas[..., -1])


def stored_estimates(beliefs: Sequence[dict[str, Any]]) -> list[float]:
    """The point estimate of each stored belief (``Belief.to_dict``'s form, normalised at
    storage): bit for bit ``Belief.from_dict(b).beta``, the beliefs with as many hypotheses
    computed as the rows of one array."""
    out = [0.0] * len(beliefs)
    groups: dict[int, list[int]] = {}
    for i, belief in enumerate(beliefs):
        groups.setdefault(len(belief["betas"]), []).append(i)
    for members in groups.values():
        betas = np.array([beliefs[i]["betas"] for i in members], dtype=np.float64)
        log_probs = np.array([beliefs[i]["log_probs"] for i in members], dtype=np.float64)
        for i, estimate in zip(members, point_estimates(betas, log_probs).tolist(), strict=True):
            out[i] = estimate
    return out


def transition_rows(
    log_probs: np.ndarray, log_prior: np.ndarray, epsilons: np.ndarray
) -> np.ndarray:
    """The epsilon-static transition ``b_- = (1 - eps) b_+ + eps b_-^0`` of each row (paper, the
    equation after ``beta``), with its own epsilon in [0, 1) (``epsilons``, one per row) and
    prior ``log_prior`` (broadcast against ``log_probs``): a log-add-exp; eps = 0 keeps the row.
    Not normalised (:func:`normalised_rows`)."""
    eps = np.asarray(epsilons, dtype=np.float64).reshape(-1)
    if not (np.isfinite(eps).all() and (eps >= 0.0).all() and (eps < 1.0).all()):
        raise ValueError(f"epsilon must lie in [0, 1), got {eps.tolist()!r}")
    moving = eps > 0.0
    if not moving.any():
        return log_probs
    shape = (-1,) + (1,) * (log_probs.ndim - 1)
    keep = np.array([math.log1p(-e) for e in eps]).reshape(shape)
    mix = np.array([math.log(e) if e > 0.0 else -math.inf for e in eps]).reshape(shape)
    mixed = np.logaddexp(keep + log_probs, mix + log_prior)
    return np.where(moving.reshape(shape), mixed, log_probs)


def mahalanobis2_rows(actions: np.ndarray, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """``d2 = (u - mu)^T Sigma^-1 (u - mu)`` of each row ([R, k] actions and means, [R, k, k]
    covariances, each positive definite), as ``|L^-1 (u - mu)|^2`` with L the Cholesky factor of
    the symmetrised Sigma; capped at :data:`MAHALANOBIS2_CAP`, so an astronomically far action
    stays finite."""
    sym = 0.5 * (covs + covs.swapaxes(-1, -2))
    try:
        chol = np.linalg.cholesky(sym)
    except np.linalg.LinAlgError:
        raise ValueError("cov must be symmetric positive definite") from None
    with np.errstate(over="ignore", invalid="ignore"):
        z = np.linalg.solve(chol, (actions - means)[..., None])[..., 0]
        d2 = (z * z).sum(axis=-1)
    # Finite inputs: a non-finite d2 can only come from overflow, i.e. an astronomically far action.
    return np.where(np.isfinite(d2), np.minimum(d2, MAHALANOBIS2_CAP), MAHALANOBIS2_CAP)


def log_likelihood_rows(betas: np.ndarray, d2: np.ndarray, k: int) -> np.ndarray:
    """``log f(u; mu, Sigma / beta_i)`` per row and hypothesis, up to a constant shared by every
    hypothesis of the row (see :func:`log_likelihoods`); ``d2`` [...] broadcasts against the
    rows of ``betas`` [..., n]."""
    return 0.5 * k * np.log(betas) - 0.5 * betas * np.asarray(d2)[..., None]


@dataclass(frozen=True, eq=False)
class Belief:
    """A belief b(beta_i) over the hypotheses ``betas``, stored as normalised log-probabilities.

    Construction normalises ``log_probs`` and freezes both arrays, so every Belief is a valid
    distribution. Beliefs compare equal when both arrays are equal.
    """

    betas: np.ndarray
    log_probs: np.ndarray

    def __post_init__(self) -> None:
        betas = np.array(self.betas, dtype=np.float64)
        log_probs = np.array(self.log_probs, dtype=np.float64)
        if betas.ndim != 1 or betas.size < 2 or log_probs.shape != betas.shape:
            raise ValueError("betas and log_probs must be 1-D arrays of the same length >= 2")
        # Array methods rather than np.all/np.any: the same reductions without their wrappers
        # (a Belief is built several times per observation).
        if not (np.isfinite(betas).all() and (betas > 0).all() and (betas[1:] > betas[:-1]).all()):
            raise ValueError("betas must be positive, finite and strictly ascending")
        if np.isnan(log_probs).any() or not np.isfinite(log_probs).any():
            raise ValueError("log_probs must be numbers with at least one finite entry")
        log_probs = normalised_rows(log_probs[None])[0]
        betas.flags.writeable = False
        log_probs.flags.writeable = False
        object.__setattr__(self, "betas", betas)
        object.__setattr__(self, "log_probs", log_probs)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Belief):
            return NotImplemented
        return bool(
            np.array_equal(self.betas, other.betas)
            and np.array_equal(self.log_probs, other.log_probs)
        )

    __hash__ = None  # type: ignore[assignment]

    @classmethod
    def rows(cls, betas: np.ndarray, log_probs: np.ndarray) -> list[Belief]:
        """The beliefs of rows [A, n] normalised already (:func:`normalised_rows`' output, which
        construction would keep bit for bit), with their probabilities and point estimates
        computed for all rows at once."""
        probs = probability_rows(log_probs)
        estimates = point_estimates(betas, log_probs)
        out = []
        for i in range(len(log_probs)):
            belief = object.__new__(cls)
            for name, value in (("betas", betas[i].copy()), ("log_probs", log_probs[i].copy())):
                value.flags.writeable = False
                object.__setattr__(belief, name, value)
            probs[i].flags.writeable = False
            belief.__dict__["probs"] = probs[i]
            belief.__dict__["beta"] = float(estimates[i])
            out.append(belief)
        return out

    @cached_property
    def probs(self) -> np.ndarray:
        """b(beta_i): non-negative, summing to one."""
        probs = probability_rows(self.log_probs)
        probs.flags.writeable = False
        return probs

    @cached_property
    def beta(self) -> float:
        """The point estimate ``beta = sum_i beta_i b_+(beta_i)`` (paper, the equation after ``beta``).

        Always inside [betas[0], betas[-1]] = [beta_low, 1].
        """
        return float(point_estimates(self.betas, self.log_probs))

    def to_dict(self) -> dict[str, list[float]]:
        """JSON-safe form for storage: plain lists of finite floats."""
        return {"betas": self.betas.tolist(), "log_probs": self.log_probs.tolist()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Belief:
        """Inverse of :meth:`to_dict` (validates and re-normalises)."""
        return cls(betas=np.asarray(data["betas"]), log_probs=np.asarray(data["log_probs"]))


def prior_belief(betas: ArrayLike) -> Belief:
    """The prior b_-^0: uniform over the hypotheses (paper: 0.5 / 0.5 for the pair)."""
    betas = np.asarray(betas, dtype=np.float64)
    return Belief(betas=betas, log_probs=np.full(betas.shape, -math.log(betas.size)))


def transition(belief: Belief, epsilon: float) -> Belief:
    """The epsilon-static transition ``b_- = (1 - eps) b_+ + eps b_-^0`` with b_-^0 uniform.

    Paper, "Confidence estimation and update" (the equation after ``beta``). In log space it is a
    log-add-exp; ``epsilon = 0`` is the identity. After it every hypothesis holds at least
    ``eps / n`` of the mass, which is what bounds the time to regain (or lose) trust.
    """
    if not (math.isfinite(epsilon) and 0.0 <= epsilon < 1.0):
        raise ValueError(f"epsilon must lie in [0, 1), got {epsilon!r}")
    if epsilon == 0.0:
        return belief
    log_prior = np.full(belief.betas.shape, -math.log(belief.betas.size))
    mixed = transition_rows(belief.log_probs[None], log_prior, np.array([epsilon]))
    return Belief(betas=belief.betas, log_probs=mixed[0])


def log_likelihoods(
    betas: np.ndarray, action: ArrayLike, mean: ArrayLike, cov: ArrayLike
) -> np.ndarray:
    """log f(u; mu, Sigma / beta_i) for each hypothesis, up to a constant shared by all of them.

    Paper, eq. ``predUpdate`` (the tempered Gaussian) as used in eq. ``beta``. For k-dimensional u,
    ``log f = (k/2) log beta - beta d2 / 2 - (k/2) log(2 pi) - (1/2) log det Sigma`` with
    ``d2 = (u - mu)^T Sigma^-1 (u - mu)``; the last two terms do not depend on beta and cancel in
    the normalisation of eq. ``beta``, so they are dropped. ``d2`` is capped at
    :data:`MAHALANOBIS2_CAP`.
    """
    u = np.asarray(action, dtype=np.float64)
    mu = np.asarray(mean, dtype=np.float64)
    sigma = np.asarray(cov, dtype=np.float64)
    k = u.shape[0] if u.ndim == 1 else -1
    if u.ndim != 1 or mu.shape != u.shape or sigma.shape != (k, k):
        raise ValueError(f"shapes: action {u.shape}, mean {mu.shape}, cov {sigma.shape}")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(mu)) and np.all(np.isfinite(sigma))):
        raise ValueError("action, mean and cov must be finite")
    d2 = mahalanobis2_rows(u[None], mu[None], sigma[None])
    return log_likelihood_rows(betas, d2[0], k)


def update_belief(
    belief: Belief, action: ArrayLike, mean: ArrayLike, cov: ArrayLike, epsilon: float
) -> Belief:
    """One filter step: the epsilon-static transition, then Bayes' rule (paper, eq. ``beta``).

    ``b_+(beta_i) = f(u; mu, Sigma / beta_i) b_-(beta_i) / sum_j f(u; mu, Sigma / beta_j) b_-(beta_j)``
    with ``b_- = (1 - eps) b_+^{prev} + eps b_-^0``, computed on log-probabilities. ``action`` and
    ``mean`` have shape (2,), ``cov`` (2, 2) (any k works); ``cov`` must be positive definite
    (see ``service.flows.bounds.validate_prediction``).
    """
    prior = transition(belief, epsilon)
    return Belief(
        betas=prior.betas,
        log_probs=prior.log_probs + log_likelihoods(prior.betas, action, mean, cov),
    )
