"""Write tests/fixtures/accuracy_states.npz: seeded ground-truth states for the model accuracy test.

Reachable states come from rollouts of the true dynamics under the evaluation's schedules, extremal
ones included (models/rollout.py, ``sample_reference_schedules``); unreachable ones lie
at least 1 m outside the interval outer bound (reach/outer_bound.py). Neither uses the network.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from models.eval_settings import SETTINGS
from models.rollout import (
    EDGE_SHARE,
    rk4_rollout,
    sample_initial_states,
    sample_reference_schedules,
)
from reach.contract import COL, HORIZON_S, N_INPUTS
from reach.outer_bound import outer_bound

NAMES = (
    "stationary_narrow",
    "urban_narrow",
    "fast_medium_asym",
    "left_turn",
    "braking_to_stop",
    "shrinking_wide_to_narrow",
    "growing_narrow_to_wide",
    "low_confidence_urban",
)
PER_SETTING = 800
OUT = Path(__file__).resolve().parent.parent / "tests" / "fixtures" / "accuracy_states.npz"


def main() -> None:
    rng = np.random.default_rng(20261122)
    reachable, unreachable, names = [], [], []
    for setting in (s for s in SETTINGS if s.name in NAMES):
        bounds = setting.bounds()
        params = np.zeros((PER_SETTING, N_INPUTS))
        params[:, COL["v_start"]] = setting.v_start
        params[:, 6:] = bounds
        t = rng.uniform(0.05, HORIZON_S, PER_SETTING)
        start = sample_initial_states(params[:, COL["v_start"]], rng, on_boundary=EDGE_SHARE)
        a1, a2, sw = sample_reference_schedules(PER_SETTING, HORIZON_S, rng)
        end, _ = rk4_rollout(start, params, t, a1, a2, sw * (t / HORIZON_S)[:, None], 150)
        rows = params.copy()
        rows[:, COL["t"]] = t
        for name, value in zip(("px", "py", "heading", "speed"), end, strict=True):
            rows[:, COL[name]] = value
        rows[:, COL["heading"]] = (rows[:, COL["heading"]] + np.pi) % (2 * np.pi) - np.pi
        reachable.append(rows)

        ob = outer_bound(setting.v_start, bounds)
        far = params.copy()
        far[:, COL["t"]] = t
        for i, ti in enumerate(t):
            x_lo, x_hi, y_lo, y_hi = ob.box_containing_slice(float(ti))
            angle = rng.uniform(-np.pi, np.pi)
            cx, cy = 0.5 * (x_lo + x_hi), 0.5 * (y_lo + y_hi)
            reach = 0.5 * np.hypot(x_hi - x_lo, y_hi - y_lo) + rng.uniform(1.0, 10.0)
            far[i, COL["px"]] = cx + reach * np.cos(angle)
            far[i, COL["py"]] = cy + reach * np.sin(angle)
        far[:, COL["heading"]] = rng.uniform(-np.pi, np.pi, PER_SETTING)
        far[:, COL["speed"]] = rng.uniform(0, setting.v_start + 10, PER_SETTING)
        unreachable.append(far)
        names += [setting.name] * PER_SETTING
    np.savez_compressed(
        OUT,
        reachable=np.concatenate(reachable).astype(np.float32),
        unreachable=np.concatenate(unreachable).astype(np.float32),
        setting=np.array(names),
    )
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
