"""States with a proven lower bound on V, for training: ``python -m models.bounded_states``.

Rollout endpoints moved off the reachable set, each with the bound of ``reach.corridors`` on V,
which tells training *where the network must be high* (the PDE residual alone conveys it slowly).
"""

from __future__ import annotations

import math

import numpy as np

from reach.contract import COL, HORIZON_S
from reach.corridors import value_lower_bound


def sample_bounded_states(
    n_params: int, per_param: int, rng: np.random.Generator, horizon: float = HORIZON_S
) -> tuple[np.ndarray, np.ndarray]:
    """States near and around the reachable set with their proven lower bound on V, for
    training: rollout endpoints (reachable positions) moved 0.5-20 m in a random direction,
    with the heading and speed of another rollout of the same setting. Returns (x [N, 14], lower
    bound [N]), keeping only the states the bound excludes (bound >= 0)."""
    from models.rollout import rk4_rollout, sample_control_schedules, sample_initial_states
    from models.sampling import sample_parameters, set_state

    params = np.repeat(sample_parameters(n_params, rng), per_param, axis=0)
    n = len(params)
    t = np.repeat(rng.uniform(0.3, horizon, n_params), per_param)
    start = sample_initial_states(params[:, COL["v_start"]], rng)
    a1, a2, switches = sample_control_schedules(n, horizon, rng)
    end, _ = rk4_rollout(start, params, t, a1, a2, switches * (t / horizon)[:, None], 24)
    other = (np.arange(n) // per_param) * per_param + rng.integers(0, per_param, n)
    distance = 10 ** rng.uniform(math.log10(0.5), math.log10(20.0), n)
    angle = rng.uniform(-math.pi, math.pi, n)
    heading = (end[2][other] + math.pi) % (2 * math.pi) - math.pi
    x = set_state(
        params,
        t,
        (
            end[0] + distance * np.cos(angle),
            end[1] + distance * np.sin(angle),
            heading,
            end[3][other],
        ),
    )
    bound = value_lower_bound(x)
    keep = bound >= 0
    return x[keep], bound[keep]


def main() -> None:
    import argparse
    from pathlib import Path

    from tqdm import tqdm

    parser = argparse.ArgumentParser(description="States with a proven lower bound on V.")
    parser.add_argument("--out", type=Path, required=True, help=".npz with x and lower_bound")
    parser.add_argument("--params", type=int, default=4000)
    parser.add_argument("--per-param", type=int, default=32)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    xs, bounds = [], []
    for _ in tqdm(range(0, args.params, 100), desc="lower bounds", unit="100 settings"):
        x, bound = sample_bounded_states(100, args.per_param, rng)
        xs.append(x)
        bounds.append(bound)
    x, bound = np.concatenate(xs), np.concatenate(bounds)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, x=x.astype(np.float32), lower_bound=bound.astype(np.float32))
    print(f"{len(x)} states, lower bound median {np.median(bound):.2f}, wrote {args.out}")


if __name__ == "__main__":
    main()
