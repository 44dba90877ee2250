"""Control bounds: gamma trimming of the tempered prediction, clipping, and the start/end bound fit.

Paper, section "Collision Set Update":

- trimming: for each step and control dimension i, ``u_i in [mu_i - delta, mu_i + delta]`` where the
  density ``f(u_i; mu_i, Sigma_ii / beta)`` integrates to gamma over that interval (the unnumbered
  equation after "We use a probability mass threshold gamma"); in closed form
  ``delta = z_gamma sqrt(Sigma_ii / beta)`` with ``z_gamma = Phi^-1((1 + gamma) / 2)``;
- the network is conditioned on bounds at the start and the end of the horizon only, and the bounds
  at time tau are their linear interpolation (the equation for ``u~_min^tau``), so the per-step
  bounds are fitted by two start/end pairs per control (:func:`fit_bounds`).

Time convention: prediction step k covers ``[k dt, (k + 1) dt]`` intersected with ``[0, T]``. Steps
that start at or after T are ignored; if the prediction covers less than T, the last step's interval
holds until T. Either way the last step used ends exactly at T.

Hard limits (API.md): ``|u1| <= 2 rad/s``, ``|u2| <= 10 m/s^2`` by default, passed as ``limits``.
When a predicted interval lies partly outside the limits it is cut at the limit; when it lies wholly
outside (the mean beyond a limit by more than delta) it collapses onto the nearest limit, a
zero-width interval at ``+-limit``: the human cannot exceed the limit, so the admissible control
closest to the prediction is the limit itself. Fitted bounds are always inside the limits too.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from reach.contract import HORIZON_S, U1_LIMIT, U2_LIMIT
from reach.envelope_lp import max_lines_below, vertices
from service.flows.bounds_rule import BoundsRule, distrust, half_width_factor, half_widths

DEFAULT_LIMITS: tuple[float, float] = (U1_LIMIT, U2_LIMIT)
#: A covariance is symmetric when |S01 - S10| <= SYMMETRY_RTOL * max(|S00|, |S11|); then the mean
#: of S and S^T is used. 1e-6 accepts matrices computed in float32 (rounding ~6e-8 relative).
SYMMETRY_RTOL = 1e-6
#: A symmetric covariance is positive definite when its eigenvalues satisfy
#: lambda_min > PD_RTOL * lambda_max > 0 (condition number below 1e12): flatter matrices make the
#: likelihood's Sigma^-1 meaningless at float64 precision.
PD_RTOL = 1e-12
#: A step starting within this fraction of T before T counts as starting at T (float rounding of
#: k * dt), so it is ignored rather than becoming a sliver that sets the end bound.
_TIME_RTOL = 1e-9

BoundsFit = Literal["envelope", "endpoints"]


class PredictionError(ValueError):
    """Invalid prediction or filter parameter; ``field`` names it (e.g. ``prediction.cov[3]``)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


@dataclass(frozen=True)
class ControlBounds:
    """The network's eight bound parameters, in the model contract's order (API.md).

    Bounds at time tau in [0, T] are ``(1 - tau/T) start + (tau/T) end`` (paper, eq. for
    ``u~_min^tau``); u1 is the steering rate [rad/s], u2 the acceleration [m/s^2].
    """

    u1_min_start: float
    u2_min_start: float
    u1_min_end: float
    u2_min_end: float
    u1_max_start: float
    u2_max_start: float
    u1_max_end: float
    u2_max_end: float

    def as_array(self) -> np.ndarray:
        """The eight values as float64, in contract order."""
        return np.array([getattr(self, name) for name in _BOUND_FIELDS], dtype=np.float64)

    def to_dict(self) -> dict[str, float]:
        """Field name -> value, in contract order (JSON-safe)."""
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_row(cls, row: np.ndarray) -> ControlBounds:
        """The eight values of ``row``, in contract order."""
        return cls(*(float(b) for b in row))


#: ControlBounds' fields in order (``dataclasses.asdict`` deep-copies, which costs every observation).
_BOUND_FIELDS = tuple(f.name for f in fields(ControlBounds))


# --- gamma trimming ---------------------------------------------------------------------------


@dataclass(frozen=True)
class TrimRows:
    """What trims each row of a batch of predictions besides the prediction itself: its beta,
    gamma, confidence-to-bounds rule and onset, and its class's hard limits ([B, 2])."""

    betas: np.ndarray
    gammas: np.ndarray
    rules: tuple[BoundsRule, ...]
    onsets: np.ndarray
    limits: np.ndarray

    @classmethod
    def one(
        cls, beta: float, gamma: float, rule: BoundsRule, onset: float, limits: Sequence[float]
    ) -> TrimRows:
        return cls(
            np.array([beta], dtype=np.float64),
            np.array([gamma], dtype=np.float64),
            (rule,),
            np.array([onset], dtype=np.float64),
            _limits(limits)[None],
        )


def trim_rows(means: np.ndarray, covs: np.ndarray, rows: TrimRows) -> tuple[np.ndarray, np.ndarray]:
    """:func:`trim_intervals` of every row of a batch (means [B, S, 2], covs [B, S, 2, 2]), each
    with its own parameters; the same operations on every row, whatever the others."""
    betas = rows.betas
    bad = ~(np.isfinite(betas) & (betas > 0.0))
    if bad.any():
        raise ValueError(f"beta must be positive, got {float(betas[bad.argmax()])!r}")
    variances = covs[:, :, [0, 1], [0, 1]]
    if not (variances > 0.0).all():
        raise ValueError("covariance diagonals must be positive")
    tempered = np.sqrt(variances / betas[:, None, None])
    z = np.array([half_width_factor(float(g)) for g in rows.gammas])
    delta = z[:, None, None] * tempered
    for i, rule in enumerate(rows.rules):
        if rule != "paper":
            w = distrust(min(float(betas[i]), 1.0), float(rows.onsets[i]))
            gamma = float(rows.gammas[i])
            delta[i] = half_widths(means[i], tempered[i], gamma, z[i], rows.limits[i], rule, w)
    return means - delta, means + delta


def trim_intervals(
    mean: ArrayLike,
    cov: ArrayLike,
    beta: float,
    gamma: float,
    rule: BoundsRule = "paper",
    onset: float = 0.0,
    limits: Sequence[float] = DEFAULT_LIMITS,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-step, per-dimension intervals ``mu_i -+ delta`` of the tempered prediction N(mu, Sigma/beta).

    Paper, "Collision Set Update" (gamma trimming) applied to the tempered prediction of eq.
    ``predUpdate``: under ``rule = "paper"``, ``delta = z_gamma sqrt(Sigma_ii / beta)`` (mass gamma);
    the other rules (``service.flows.bounds_rule``) widen it with the distrust
    ``w = distrust(beta, onset)`` towards the ``limits`` and equal it where ``w = 0``. Only the
    diagonal of each covariance is used (the bounds are a box, one interval per control). ``mean``
    is (S, 2), ``cov`` (S, 2, 2); returns ``(lo, hi)``, each (S, 2), not yet clipped to the limits.
    """
    mu = np.asarray(mean, dtype=np.float64)
    sigma = np.asarray(cov, dtype=np.float64)
    if mu.ndim != 2 or mu.shape[1] != 2 or sigma.shape != (mu.shape[0], 2, 2):
        raise ValueError(
            f"expected mean (S, 2) and cov (S, 2, 2), got {mu.shape} and {sigma.shape}"
        )
    lo, hi = trim_rows(mu[None], sigma[None], TrimRows.one(beta, gamma, rule, onset, limits))
    return lo[0], hi[0]


def _limits(limits: Sequence[float]) -> np.ndarray:
    lim = np.asarray(limits, dtype=np.float64)
    if lim.shape != (2,) or not np.all(np.isfinite(lim)) or not np.all(lim > 0.0):
        raise ValueError(f"limits must be two positive numbers, got {limits!r}")
    return lim


def clip_intervals(
    lo: ArrayLike, hi: ArrayLike, limits: Sequence[float] = DEFAULT_LIMITS
) -> tuple[np.ndarray, np.ndarray]:
    """Clip intervals to the hard limits ``|u_i| <= limits[i]`` (API.md; paper, "Case Studies").

    Both ends are clipped into ``[-limit, limit]``: an interval straddling a limit is cut there,
    and one wholly beyond a limit collapses onto it (``lo = hi = +-limit``). ``lo <= hi`` is kept.
    """
    lim = _limits(limits)
    return np.clip(lo, -lim, lim), np.clip(hi, -lim, lim)


# --- the start/end fit ------------------------------------------------------------------------


def steps_in_horizon(n_steps: int, dt: float, horizon: float = HORIZON_S) -> int:
    """How many prediction steps start before T (at least one): the steps the fit uses."""
    if not (math.isfinite(dt) and dt > 0.0 and math.isfinite(horizon) and horizon > 0.0):
        raise ValueError(f"dt and horizon must be positive, got {dt!r}, {horizon!r}")
    ratio = horizon * (1.0 - _TIME_RTOL) / dt  # k dt < T (1 - rtol) <=> k < ceil(ratio)
    if not ratio < n_steps:  # every step (a dt so small that the ratio is infinite too)
        return max(1, n_steps)
    return max(1, min(n_steps, math.ceil(ratio)))


def _boundary_values(values: np.ndarray, reduce: Any) -> np.ndarray:
    """Step values [..., n] at the step boundaries 0, dt, ..., T: the binding one of the two
    adjacent steps."""
    inner = reduce(values[..., :-1], values[..., 1:])
    return np.concatenate([values[..., :1], inner, values[..., -1:]], axis=-1)


def _envelope(
    lo: np.ndarray, hi: np.ndarray, dt: float, horizon: float, lim: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Start and end values ([B, min|max, dim]) of the envelope fit (see :func:`fit_bounds`) of
    each row (lo, hi [B, n, 2], limits [B, 2]): the highest line below each dimension's lower
    values and, mirrored, the lowest line above its upper ones, four programmes a row, all
    solved together."""
    b, n = lo.shape[:2]
    w = np.append(np.arange(n, dtype=np.float64) * dt, horizon) / horizon
    v = vertices(n, dt, horizon)
    rows = [_boundary_values(lo[:, :, d], np.minimum) for d in range(2)]
    rows += [-_boundary_values(hi[:, :, d], np.maximum) for d in range(2)]
    floors = -np.concatenate([lim, lim], axis=1)  # [B, 4]
    a, e = max_lines_below(v, w, np.stack(rows, axis=1).reshape(4 * b, -1), floors.reshape(-1))
    a, e = a.reshape(b, 4), e.reshape(b, 4)
    start = np.stack([a[:, :2], -a[:, 2:]], axis=1)  # [B, min|max, dim]
    end = np.stack([e[:, :2], -e[:, 2:]], axis=1)
    return start, end


def fit_rows(
    lo: np.ndarray,
    hi: np.ndarray,
    dt: float,
    limits: np.ndarray,
    horizon: float = HORIZON_S,
    method: BoundsFit = "envelope",
) -> np.ndarray:
    """:func:`fit_bounds` of every row of a batch (lo, hi [B, S, 2], each row's limits [B, 2]):
    the eight bounds of each row [B, 8] in contract order, each row by the same operations
    whatever the others."""
    lim = np.asarray(limits, dtype=np.float64)
    if lim.ndim != 2 or lim.shape[1] != 2 or not (np.isfinite(lim).all() and (lim > 0.0).all()):
        raise ValueError(f"limits must be two positive numbers a row, got {limits!r}")
    lo_arr = np.clip(lo, -lim[:, None, :], lim[:, None, :])
    hi_arr = np.clip(hi, -lim[:, None, :], lim[:, None, :])
    if lo_arr.ndim != 3 or lo_arr.shape[2] != 2 or hi_arr.shape != lo_arr.shape or not lo_arr.size:
        raise ValueError(f"expected lo, hi of shape (S, 2), got {lo_arr.shape} and {hi_arr.shape}")
    if not np.all(lo_arr <= hi_arr):
        raise ValueError("every interval needs lo <= hi")
    n = steps_in_horizon(lo_arr.shape[1], dt, horizon)
    lo_arr, hi_arr = lo_arr[:, :n], hi_arr[:, :n]
    if method == "endpoints":
        start = np.stack([lo_arr[:, 0], hi_arr[:, 0]], axis=1)
        end = np.stack([lo_arr[:, -1], hi_arr[:, -1]], axis=1)
    elif method == "envelope":
        start, end = _envelope(lo_arr, hi_arr, dt, horizon, lim)
    else:
        raise ValueError(f"unknown bounds fit {method!r} (use 'envelope' or 'endpoints')")
    start = np.clip(start, -lim[:, None, :], lim[:, None, :])
    end = np.clip(end, -lim[:, None, :], lim[:, None, :])
    # Contract order: u1_min_start, u2_min_start, u1_min_end, u2_min_end, then the maxima.
    return np.concatenate([start[:, 0], end[:, 0], start[:, 1], end[:, 1]], axis=1)


def fit_bounds(
    lo: ArrayLike,
    hi: ArrayLike,
    dt: float,
    horizon: float = HORIZON_S,
    method: BoundsFit = "envelope",
    limits: Sequence[float] = DEFAULT_LIMITS,
) -> ControlBounds:
    """Fit the network's start/end bounds to per-step intervals (paper, eq. for ``u~_min^tau``).

    The intervals are first clipped to the limits (:func:`clip_intervals`). Steps are placed as in
    the module docstring (steps from T on ignored, the last step used held until T).

    - ``"endpoints"`` (the paper): start = the first step's interval, end = the last used step's.
    - ``"envelope"`` (default): per control, the start/end values whose linear interpolation over
      [0, T] contains every step's interval over the whole step, as tightly as possible: the lower
      line maximises, the upper line minimises, its integral over [0, T], subject to
      ``line(t) <= lo_k`` (resp. ``>= hi_k``) at both ends of step k (enough, the line being
      linear) and to staying within the limits at 0 and T. Ties go to the middle of the optimal
      edge. Containment holds to float rounding; lower line <= upper line everywhere.

    Both results lie within ``[-limit, limit]``.
    """
    lo_arr = np.asarray(lo, dtype=np.float64)
    hi_arr = np.asarray(hi, dtype=np.float64)
    if lo_arr.ndim != 2 or lo_arr.shape[1] != 2 or hi_arr.shape != lo_arr.shape or not lo_arr.size:
        raise ValueError(f"expected lo, hi of shape (S, 2), got {lo_arr.shape} and {hi_arr.shape}")
    row = fit_rows(lo_arr[None], hi_arr[None], dt, _limits(limits)[None], horizon, method)
    return ControlBounds.from_row(row[0])


def control_bounds_rows(
    means: np.ndarray,
    covs: np.ndarray,
    dt: float,
    rows: TrimRows,
    horizon: float = HORIZON_S,
    method: BoundsFit = "envelope",
) -> np.ndarray:
    """:func:`control_bounds` of every row of a batch of predictions with the same steps (means
    [B, S, 2], covs [B, S, 2, 2], each row's parameters ``rows``): [B, 8] in contract order."""
    lo, hi = trim_rows(means, covs, rows)
    return fit_rows(lo, hi, dt, rows.limits, horizon, method)


def control_bounds(
    mean: ArrayLike,
    cov: ArrayLike,
    dt: float,
    beta: float,
    gamma: float,
    horizon: float = HORIZON_S,
    method: BoundsFit = "envelope",
    limits: Sequence[float] = DEFAULT_LIMITS,
    rule: BoundsRule = "paper",
    onset: float = 0.0,
) -> ControlBounds:
    """The FRT's control bounds from a prediction and beta: trim, clip, fit.

    Paper, "Collision Set Update": gamma trimming of N(mu, Sigma / beta) (eq. ``predUpdate``) under
    the confidence-to-bounds ``rule`` (``service.flows.bounds_rule``; ``"paper"`` is the paper's),
    the hard limits, then the start/end parameterisation (eq. for ``u~_min^tau``); see
    :func:`trim_intervals`, :func:`clip_intervals`, :func:`fit_bounds`.
    """
    lo, hi = trim_intervals(mean, cov, beta, gamma, rule=rule, onset=onset, limits=limits)
    return fit_bounds(lo, hi, dt, horizon=horizon, method=method, limits=limits)  # clips first


# --- validation -------------------------------------------------------------------------------


def _number(value: Any, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise PredictionError(field, f"must be a number, got {type(value).__name__}")
    if not math.isfinite(value):
        raise PredictionError(field, f"must be finite, got {value!r}")
    return float(value)


def _steps(value: Any, field: str, max_steps: int) -> list[Any]:
    if isinstance(value, np.ndarray) and value.ndim >= 1:
        value = list(value)
    if not isinstance(value, list | tuple):
        raise PredictionError(field, "must be a list with one entry per step")
    if not 1 <= len(value) <= max_steps:
        raise PredictionError(field, f"must have 1 to {max_steps} steps, got {len(value)}")
    return list(value)


def _array(value: Any, shape: tuple[int, ...], field: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise PredictionError(field, "must contain only numbers") from None
    if arr.shape != shape:
        raise PredictionError(
            field, f"must have shape {'x'.join(map(str, shape))}, got {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise PredictionError(field, "must contain only finite numbers")
    return arr


def validate_prediction(
    mean: Any, cov: Any, dt: Any, max_steps: int = 64
) -> tuple[np.ndarray, np.ndarray]:
    """Check a prediction (paper, eq. ``pred``: one Gaussian over the 2 controls per step).

    Requires: ``dt`` a finite number > 0; ``mean`` 1..max_steps rows of 2 finite numbers; ``cov``
    one 2x2 matrix of finite numbers per row of ``mean``, symmetric (to :data:`SYMMETRY_RTOL`) and
    positive definite (to :data:`PD_RTOL`). Raises :class:`PredictionError` naming the first
    offending field (``prediction.dt``, ``prediction.mean``, ``prediction.mean[k]``,
    ``prediction.cov``, ``prediction.cov[k]``); returns ``(mean (S, 2), cov (S, 2, 2))`` as float64
    with each covariance replaced by the mean of it and its transpose.
    """
    (result,) = validate_predictions([(mean, cov, dt)], max_steps)
    if isinstance(result, PredictionError):
        raise result
    return result


def validate_predictions(
    predictions: Sequence[tuple[Any, Any, Any]], max_steps: int = 64
) -> list[tuple[np.ndarray, np.ndarray] | PredictionError]:
    """:func:`validate_prediction` of each ``(mean, cov, dt)``: its arrays, or the error naming
    its first offending field. The predictions with as many steps are checked together (the same
    element-wise arithmetic and checks per prediction, whatever the others)."""
    results: list[tuple[np.ndarray, np.ndarray] | PredictionError | None] = []
    by_steps: dict[int, list[int]] = {}
    steps: list[tuple[list[Any], list[Any]] | None] = []
    for i, (mean, cov, dt) in enumerate(predictions):
        try:
            rows, mats = _step_lists(mean, cov, dt, max_steps)
        except PredictionError as exc:
            results.append(exc)
            steps.append(None)
            continue
        results.append(None)
        steps.append((rows, mats))
        by_steps.setdefault(len(rows), []).append(i)
    for members in by_steps.values():
        group = [steps[i] for i in members]
        valid = _valid_at_once([g[0] for g in group], [g[1] for g in group])  # type: ignore[index]
        for j, i in enumerate(members):
            if valid is not None and valid[2][j]:
                results[i] = (valid[0][j], valid[1][j])
            else:  # something is wrong: step by step, to name the first offending field
                try:
                    results[i] = _checked_step_by_step(*steps[i])  # type: ignore[misc]
                except PredictionError as exc:
                    results[i] = exc
    return results  # type: ignore[return-value]


def _step_lists(mean: Any, cov: Any, dt: Any, max_steps: int) -> tuple[list[Any], list[Any]]:
    """A prediction's dt checked and its means and covariances as lists of as many steps."""
    step = _number(dt, "prediction.dt")
    if step <= 0.0:
        raise PredictionError("prediction.dt", f"must be > 0, got {step!r}")
    rows = _steps(mean, "prediction.mean", max_steps)
    mats = _steps(cov, "prediction.cov", max_steps)
    if len(mats) != len(rows):
        raise PredictionError(
            "prediction.cov", f"has {len(mats)} steps but prediction.mean has {len(rows)}"
        )
    return rows, mats


def _checked_step_by_step(rows: list[Any], mats: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    mean_arr = np.stack([_array(r, (2,), f"prediction.mean[{k}]") for k, r in enumerate(rows)])
    cov_list = []
    for k, m in enumerate(mats):
        field = f"prediction.cov[{k}]"
        s = _array(m, (2, 2), field)
        scale = max(abs(s[0, 0]), abs(s[1, 1]))
        if abs(s[0, 1] - s[1, 0]) > SYMMETRY_RTOL * scale:
            raise PredictionError(field, "must be symmetric")
        s = 0.5 * (s + s.T)
        eig = np.linalg.eigvalsh(s)
        if not (eig[1] > 0.0 and eig[0] > PD_RTOL * eig[1]):
            raise PredictionError(field, "must be positive definite")
        cov_list.append(s)
    return mean_arr, np.stack(cov_list)


def _valid_at_once(
    rows: list[Any], mats: list[Any]
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """:func:`validate_prediction`'s checks and result for G predictions of S steps each at once
    (the same element-wise arithmetic, one eigvalsh call for the stack): means [G, S, 2], the
    symmetrised covariances [G, S, 2, 2] and whether each passed [G]; None if they do not form
    such arrays (then the step-by-step checks find and name what is wrong)."""
    try:
        mean = np.asarray(rows, dtype=np.float64)
        cov = np.asarray(mats, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    g, n = len(rows), len(rows[0])
    if mean.shape != (g, n, 2) or cov.shape != (g, n, 2, 2):
        return None
    ok = np.isfinite(mean).all(axis=(1, 2)) & np.isfinite(cov).all(axis=(1, 2, 3))
    with np.errstate(over="ignore", invalid="ignore"):  # the non-finite are failed already
        scale = np.maximum(np.abs(cov[..., 0, 0]), np.abs(cov[..., 1, 1]))
        ok &= ~(np.abs(cov[..., 0, 1] - cov[..., 1, 0]) > SYMMETRY_RTOL * scale).any(axis=1)
        cov = 0.5 * (cov + cov.swapaxes(-1, -2))
    ok &= np.isfinite(cov).all(axis=(1, 2, 3))
    eig = np.linalg.eigvalsh(np.where(ok[:, None, None, None], cov, np.eye(2)))
    ok &= ((eig[..., 1] > 0.0) & (eig[..., 0] > PD_RTOL * eig[..., 1])).all(axis=1)
    return mean, cov, ok


def validate_filter_params(
    gamma: float | None = None, beta_low: float | None = None, epsilon: float | None = None
) -> None:
    """Check the filter's parameters; ``None`` skips one (for partial per-agent configs).

    gamma in (0, 1) (paper, gamma trimming), 0 < beta_low < 1 (paper, "Confidence estimation and
    update": 0 < beta_low < beta_high = 1), epsilon in [0, 1) (the epsilon-static transition).
    Raises :class:`PredictionError` with field ``gamma``, ``beta_low`` or ``epsilon``.
    """
    if gamma is not None and not 0.0 < _number(gamma, "gamma") < 1.0:
        raise PredictionError("gamma", f"must lie in (0, 1), got {gamma!r}")
    if beta_low is not None and not 0.0 < _number(beta_low, "beta_low") < 1.0:
        raise PredictionError("beta_low", f"must lie in (0, 1), got {beta_low!r}")
    if epsilon is not None and not 0.0 <= _number(epsilon, "epsilon") < 1.0:
        raise PredictionError("epsilon", f"must lie in [0, 1), got {epsilon!r}")
