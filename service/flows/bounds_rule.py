"""The confidence-to-bounds rule: how far each step's control interval reaches at confidence beta.

Paper, "Collision Set Update": the interval is ``[mu_i - delta, mu_i + delta]`` holding mass gamma
under the tempered prediction N(mu_i, Sigma_ii / beta) (the rule ``"paper"``). The paper's
motivation ("Confidence-aware prediction") is that "low model confidence transforms the agent's
predicted distribution over controls to be uniform": as beta -> 0 the tempered Gaussian flattens,
and once trimmed and clipped its interval is the whole box of admissible controls. At the paper's
finite beta_low and small gamma the interval stays near the mean (``delta = z_gamma sigma /
sqrt(beta_low)``, 0.54 sigma at gamma = 0.075 and beta_low = 0.03), so a predictor that is
confidently wrong by several sigma is missed however low beta falls. The rules below make that
limit reachable at the confidence the filter actually reports (docs/confidence.md, "From beta to
the bounds", has the derivation and the replay behind the choice):

- ``"uniform_mixture"``: the distrust ``w = 1 - beta`` (beta the filter's point estimate, the
  paper's "beta^t") weighs a uniform distribution over the class's limits ``U[-L_i, L_i]`` against
  the tempered prediction, ``p_w = (1 - w) N(mu_i, Sigma_ii / beta) + w U[-L_i, L_i]``, the linear
  path in beta between the paper's two ends (the prediction as it is at beta = 1, uniform as
  beta -> 0). The interval ``[mu_i - delta, mu_i + delta]`` holds the mass
  ``gamma_w = (1 - w) gamma + w`` of ``p_w``: the trusted part trimmed at gamma, the distrusted
  part whole. Equivalently ``(1 - w) (m_N - gamma) = w (1 - m_U)``, with ``m_N``, ``m_U`` the
  masses the interval holds under each part. ``delta`` never falls below the paper's;
- ``"mass_ramp"``: the tempered Gaussian alone, trimmed at ``gamma + (RAMP_MASS_MAX - gamma) w``
  (the alternative: it widens with distrust, but around a wrong mean and by sigma, never to the
  limits when sigma is small).

Both are the paper's rule bit for bit where ``w = 0`` (beta = 1, and every beta above
``1 - onset``: :func:`distrust`).
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import Literal

import numpy as np

BoundsRule = Literal["paper", "uniform_mixture", "mass_ramp"]
BOUNDS_RULES: tuple[BoundsRule, ...] = ("paper", "uniform_mixture", "mass_ramp")
#: ``"mass_ramp"``'s trimmed mass at full distrust (w = 1).
RAMP_MASS_MAX = 0.999
#: The smallest Newton step, relative to delta: the solve ends one such step past the root.
_SOLVE_RTOL = 1e-12
_SOLVE_MAX_ITER = 200


_STANDARD_NORMAL = NormalDist()


def half_width_factor(gamma: float) -> float:
    """z_gamma with P(|Z| <= z_gamma) = gamma for Z ~ N(0, 1), i.e. Phi^-1((1 + gamma) / 2).

    Paper, "Collision Set Update" (the gamma-trimming equation): for u ~ N(mu, s^2) the interval
    [mu - delta, mu + delta] holds mass gamma iff delta = z_gamma s. Computed as
    -Phi^-1((1 - gamma) / 2) (``statistics.NormalDist``), which keeps gamma close to 1 precise; for
    gamma < 1/2 one Newton step on ``erf(z / sqrt 2) = gamma`` (erf is accurate near 0) keeps small
    gamma precise too.
    """
    if not (math.isfinite(gamma) and 0.0 < gamma < 1.0):
        raise ValueError(f"gamma must lie in (0, 1), got {gamma!r}")
    z = -_STANDARD_NORMAL.inv_cdf(0.5 * (1.0 - gamma))
    if gamma < 0.5:
        slope = math.sqrt(2.0 / math.pi) * math.exp(-0.5 * z * z)
        z -= (math.erf(z / math.sqrt(2.0)) - gamma) / slope
    return max(0.0, z)


def distrust(beta: float, onset: float = 0.0) -> float:
    """The weight of the uniform part, ``w = clip((1 - beta - onset) / (1 - onset), 0, 1)``.

    ``1 - beta`` is the filter's distrust in the predictor (0 at beta = 1); ``onset`` in [0, 1) is
    a dead zone: while ``1 - beta <= onset`` the rule is the paper's exactly.
    """
    if not (math.isfinite(beta) and 0.0 < beta <= 1.0):
        raise ValueError(f"beta must lie in (0, 1], got {beta!r}")
    if not (math.isfinite(onset) and 0.0 <= onset < 1.0):
        raise ValueError(f"rescue_onset must lie in [0, 1), got {onset!r}")
    return min(1.0, max(0.0, (1.0 - beta - onset) / (1.0 - onset)))


def _gaussian_mass(delta: float, sigma: float) -> float:
    """Mass of N(mu, sigma^2) on [mu - delta, mu + delta]."""
    return math.erf(delta / (sigma * math.sqrt(2.0)))


def _uniform_mass(delta: float, mu: float, limit: float) -> float:
    """Mass of U[-limit, limit] on [mu - delta, mu + delta]."""
    overlap = min(mu + delta, limit) - max(mu - delta, -limit)
    return max(0.0, overlap) / (2.0 * limit)


def _slope(delta: float, mu: float, sigma: float, limit: float, w: float) -> float:
    """d/d delta of ``(1 - w) m_N + w m_U``: each end of the interval inside the box adds to m_U."""
    z = delta / sigma
    gaussian = math.sqrt(2.0 / math.pi) / sigma * math.exp(-0.5 * z * z)
    ends_inside = int(mu + delta < limit) + int(mu - delta > -limit)
    return (1.0 - w) * gaussian + w * ends_inside / (2.0 * limit)


def mixture_half_width(
    mu: float, sigma: float, limit: float, gamma: float, w: float, delta_paper: float
) -> float:
    """``delta`` with ``(1 - w) m_N(delta) + w m_U(delta) = (1 - w) gamma + w``, at least
    ``delta_paper`` (the paper's ``z_gamma sigma``).

    The left side minus the right, ``F``, is increasing and concave in delta (``m_N`` is concave
    for delta > 0, ``m_U`` piecewise linear with falling slopes), <= 0 at ``delta_paper`` (where
    ``m_N = gamma``) and >= 0 once the interval covers ``[-limit, limit]`` (``delta = limit +
    |mu|``). Newton's method from ``delta_paper`` therefore climbs to the root from below without
    overshooting; the value returned is the first one past it (``F >= 0``), so the interval holds
    at least the target mass.
    """
    if w <= 0.0:
        return delta_paper
    full = limit + abs(mu)
    if delta_paper >= full:
        return delta_paper
    target = (1.0 - w) * gamma + w

    def excess(delta: float) -> float:
        mass = (1.0 - w) * _gaussian_mass(delta, sigma) + w * _uniform_mass(delta, mu, limit)
        return mass - target

    x = delta_paper
    for _ in range(_SOLVE_MAX_ITER):
        f = excess(x)
        if f >= 0.0:
            return x
        slope = _slope(x, mu, sigma, limit, w)
        step = -f / slope if slope > 0.0 else full - x
        x = min(full, x + max(step, _SOLVE_RTOL * x))
        if x >= full:
            return full
    return full


def half_widths(
    mean: np.ndarray,
    sigma: np.ndarray,
    gamma: float,
    z_gamma: float,
    limits: np.ndarray,
    rule: BoundsRule,
    w: float,
) -> np.ndarray:
    """Per step and control, the interval's half-width ``delta`` under ``rule`` (see the module).

    ``mean`` and ``sigma`` (the tempered standard deviations ``sqrt(Sigma_ii / beta)``) are
    (S, 2); ``z_gamma`` is ``bounds.half_width_factor(gamma)``; ``limits`` the class's (2,).
    """
    paper = z_gamma * sigma
    if rule == "paper" or w <= 0.0:
        return paper
    if rule == "mass_ramp":
        return half_width_factor(gamma + (RAMP_MASS_MAX - gamma) * w) * sigma
    if rule != "uniform_mixture":
        raise ValueError(f"unknown bounds rule {rule!r} (use one of {', '.join(BOUNDS_RULES)})")
    out = np.empty_like(paper)
    for k in range(paper.shape[0]):
        for d in range(2):
            out[k, d] = mixture_half_width(
                float(mean[k, d]),
                float(sigma[k, d]),
                float(limits[d]),
                gamma,
                w,
                float(paper[k, d]),
            )
    return out
