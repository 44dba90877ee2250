"""Multi-modal predictions from what predictors hand out, as an observation's ``prediction``.

- :func:`from_mixture`: a Trajectron++-style Gaussian mixture over the controls (per mode a
  log-weight, and per step a mean and covariance of (steering rate, acceleration)).
- :func:`from_trajectories`: weighted predicted paths (Apollo's and Autoware's prediction
  messages: per path a probability and positions at a fixed step), turned into controls by
  central differences (``frt_client.paths``) with the covariance rule stated there.

Both return ``{"dt": dt, "modes": [{"weight", "mean", "cov"}, ...]}``, which
``observe(prediction=...)`` takes. Pure Python: numpy arrays are accepted (through ``.tolist()``)
but not needed. The service normalises the weights; it accepts at most 32 modes.
"""

from __future__ import annotations

import math
from typing import Any

from frt_client.errors import ValidationError
from frt_client.inputs import plain
from frt_client.paths import path_controls

#: The most modes the service accepts in one prediction.
MAX_MODES = 32


def _keep(weights: list[float], max_modes: int) -> list[int]:
    """The indices of the ``max_modes`` largest weights, in their original order."""
    order = sorted(range(len(weights)), key=lambda m: (-weights[m], m))[:max_modes]
    return sorted(order)


def from_mixture(
    log_weights: Any, means: Any, covs: Any, dt: float, max_modes: int = MAX_MODES
) -> dict[str, Any]:
    """A mixture's modes as a prediction.

    Args:
        log_weights: ``(M,)`` log-weights (any offset: they are soft-maxed, stably).
        means: ``(M, S, 2)`` per mode and step, the mean (steering rate rad/s, acceleration m/s²).
        covs: ``(M, S, 2, 2)`` the matching covariances.
        dt: seconds per step (Trajectron++: 0.5).
        max_modes: keep the most probable this many modes (at most 32, the service's limit).
    """
    logs, mu, sigma = plain(log_weights), plain(means), plain(covs)
    if not isinstance(logs, list) or not logs or len(mu) != len(logs) or len(sigma) != len(logs):
        raise ValidationError(
            "log_weights, means and covs need one entry per mode", field="prediction.modes"
        )
    if not all(isinstance(v, int | float) and math.isfinite(v) for v in logs):
        raise ValidationError("log_weights must be finite numbers", field="prediction.modes")
    top = max(logs)
    weights = [math.exp(v - top) for v in logs]
    total = sum(weights)
    keep = _keep(weights, min(max_modes, MAX_MODES))
    return {
        "dt": float(dt),
        "modes": [{"weight": weights[m] / total, "mean": mu[m], "cov": sigma[m]} for m in keep],
    }


def from_trajectories(
    paths: Any,
    probabilities: Any,
    dt: float,
    heading: float,
    speed: float,
    sigma: tuple[float, float] = (0.1, 0.5),
    growth: float = 0.25,
    max_modes: int = MAX_MODES,
) -> dict[str, Any]:
    """Weighted predicted paths as a prediction (one mode per path).

    Args:
        paths: ``(M, S + 1, 2)`` per path, its points (x, y) every ``dt`` seconds, the first the
            human's current position (the world frame of the observation).
        probabilities: ``(M,)`` each path's probability (positive; need not sum to one).
        dt: seconds between points (Apollo: 0.1; Autoware: the message's time step).
        heading, speed: the human's current heading (rad) and speed (m/s), the state the first
            control starts from.
        sigma: the standard deviations (rad/s, m/s²) of the first step's controls.
        growth: how much the standard deviations grow per step.
        max_modes: keep the most probable this many paths (at most 32).

    The means are :func:`frt_client.paths.path_controls` (central differences). The covariance
    rule: paths carry no covariance,
    so step k gets ``diag((sigma_1 s_k)^2, (sigma_2 s_k)^2)`` with ``s_k = 1 + growth * k``:
    independent controls whose spread grows linearly along the path, as a predictor's does with
    the lead time.
    """
    points, probs = plain(paths), plain(probabilities)
    if not isinstance(probs, list) or not probs or len(points) != len(probs):
        raise ValidationError("paths and probabilities need one entry per mode", field="paths")
    if not all(isinstance(p, int | float) and math.isfinite(p) and p > 0 for p in probs):
        raise ValidationError("probabilities must be positive finite numbers", field="paths")
    s1, s2 = sigma
    keep = _keep([float(p) for p in probs], min(max_modes, MAX_MODES))
    total = sum(probs[m] for m in keep)
    modes = []
    for m in keep:
        mean = path_controls(points[m], dt, heading, speed)
        cov = []
        for k in range(len(mean)):
            scale = 1.0 + growth * k
            cov.append([[(s1 * scale) ** 2, 0.0], [0.0, (s2 * scale) ** 2]])
        modes.append({"weight": probs[m] / total, "mean": mean, "cov": cov})
    return {"dt": float(dt), "modes": modes}
