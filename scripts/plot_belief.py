"""Plot beta over time on the scripted sequence (docs/belief.png) and print the trust time-scales.

The scripted sequence is the one tests/test_confidence.py asserts on (the paper's U-turn figure,
"Effect of beta_low"): actions match the prediction, leave it from 2 s to 4 s, then match again.
The table quantifies what epsilon bounds (docs/confidence.md):

- regain: observations, starting from total distrust (after an action 1000 sigma away), until
  beta >= 0.9, for actions exactly at the mean and for typical ones (d^2 = 2, the chi^2_2 mean);
- lose: the smallest Mahalanobis distance d* of a single action that pulls beta below 0.5 from the
  most trusting state the filter can reach; under a correct predictor such an action has
  probability about exp(-d*^2 / 2) per observation (2-D Gaussian tail).

Usage: ``.venv/bin/python scripts/plot_belief.py [--out docs/belief.png]``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from service.flows.confidence import Belief, hypotheses, prior_belief, update_belief  # noqa: E402
from tests.test_confidence import (  # noqa: E402
    BETA_LOWS,
    COV,
    MEAN,
    SIGMA,
    run_filter,
    scripted_sequence,
)

EPSILONS = (0.05, 1e-8)  # the server default, and the authors' code


def _observe(belief: Belief, d: float, epsilon: float) -> Belief:
    """One observation at Mahalanobis distance d from the mean (offset along u1)."""
    return update_belief(belief, MEAN + np.array([d, 0.0]) * SIGMA, MEAN, COV, epsilon)


def regain_observations(beta_low: float, epsilon: float, d: float, limit: int = 1000) -> int:
    """Observations at distance d, after a 1000-sigma action, until beta >= 0.9."""
    belief = _observe(prior_belief(hypotheses(beta_low)), 1000.0, epsilon)
    for n in range(1, limit + 1):
        belief = _observe(belief, d, epsilon)
        if belief.beta >= 0.9:
            return n
    return limit


def lose_threshold(beta_low: float, epsilon: float) -> float:
    """Smallest single-action distance d* (in sigmas) taking beta below 0.5 from full trust."""
    trusting = prior_belief(hypotheses(beta_low))
    for _ in range(200):
        trusting = _observe(trusting, 0.0, epsilon)
    lo, hi = 0.0, 100.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if _observe(trusting, mid, epsilon).beta < 0.5 else (mid, hi)
    return hi


def print_table() -> None:
    print("epsilon  beta_low  regain(d=0)  regain(d^2=2)  lose d*  P(false alarm)/obs")
    for epsilon in EPSILONS:
        for beta_low in BETA_LOWS:
            d_star = lose_threshold(beta_low, epsilon)
            print(
                f"{epsilon:<8.0e} {beta_low:<9} {regain_observations(beta_low, epsilon, 0.0):>11}"
                f" {regain_observations(beta_low, epsilon, math.sqrt(2.0)):>14}"
                f" {d_star:>8.2f} {math.exp(-0.5 * d_star**2):>19.1e}"
            )


def plot(out: Path) -> None:
    times, actions, deviating = scripted_sequence()
    t0, t1 = times[deviating][0] - 0.1, times[deviating][-1]
    fig = Figure(figsize=(8.0, 5.5), layout="constrained")
    axes = fig.subplots(len(EPSILONS), 1, sharex=True)
    for ax, epsilon in zip(axes, EPSILONS, strict=True):
        ax.axvspan(t0, t1, color="tab:red", alpha=0.12, label="actions leave the prediction")
        for beta_low in BETA_LOWS:
            beta = run_filter(beta_low, actions, epsilon)
            ax.plot(times, beta, marker=".", ms=3, lw=1.2, label=f"β_low = {beta_low}")
        ax.set_ylabel("β (point estimate)")
        ax.set_ylim(0.0, 1.05)
        ax.set_title(f"ε = {epsilon:g}" + (" (server default)" if epsilon == 0.05 else ""))
        ax.grid(alpha=0.3)
    axes[0].legend(loc="center right", fontsize=8)
    axes[-1].set_xlabel("time [s] (one observation every 0.1 s)")
    fig.suptitle("Model confidence β on the scripted sequence")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "belief.png")
    args = parser.parse_args()
    plot(args.out)
    print_table()


if __name__ == "__main__":
    main()
