"""Which reachable states set the value network's margin delta: ``python scripts/value_level_tail.py``.

The card's delta is the largest V over the calibration's reachable states (scenario optimisation,
``models.evaluate.calibrate``) plus the runtime graph's slack. This redraws those very states (same
generator, seed and counts as ``python -m models.evaluate --calibrate``), checks that their maximum
gives the card's delta, and prints the quantiles of V and the states at the top of its tail with
their settings: what a training would have to fit for delta to fall (~1 min). Writes
``results/value_level_tail.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from models.evaluate import calibration_draws, model_inputs  # noqa: E402
from models.runtime import ValueModel  # noqa: E402
from models.value_fields import engine_for  # noqa: E402
from reach.contract import COL  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    parser.add_argument("--settings", type=int, default=1000, help="as --calibration-settings")
    parser.add_argument("--per-setting", type=int, default=128, help="as --calibration-per-setting")
    parser.add_argument("--seed", type=int, default=2026, help="as models.evaluate's --seed")
    parser.add_argument("--top", type=int, default=10)
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "value_level_tail.json")
    args = parser.parse_args()
    model = ValueModel.load(args.model, threads=2)
    engine = engine_for(model)
    slice_times = np.arange(1, engine.n_slices) * engine.slice_dt
    rng = np.random.default_rng(args.seed)
    inputs = []
    for row, t, states in calibration_draws(args.settings, args.per_setting, slice_times, rng):
        inputs.append(model_inputs(t, states, float(row[COL["v_start"]]), row[6:]))
    x = np.concatenate(inputs)
    values = model.evaluate(x)
    calibration = model.card.raw["calibration"]
    slack = float(calibration.get("runtime_graph_slack", 0.0))
    quantiles = {q: float(np.quantile(values, float(q))) for q in ("0.99", "0.999", "0.9999")}
    top = [
        {
            "value": float(values[k]),
            "t": float(x[k, COL["t"]]),
            "v_start": float(x[k, COL["v_start"]]),
            "bounds": [round(float(b), 3) for b in x[k, 6:]],
            "state_x_y_heading_speed": [round(float(s), 2) for s in x[k, 1:5]],
        }
        for k in np.argsort(values)[::-1][: args.top]
    ]
    print(
        f"max V {values.max():.4f} + slack {slack:.2e} = {values.max() + slack:.4f} "
        f"(card delta: {calibration['delta']:.4f}) over {len(values)} states"
    )
    print("quantiles: " + ", ".join(f"{q}: {v:.4f}" for q, v in quantiles.items()))
    for row in top:
        x_, y_, _heading, speed = row["state_x_y_heading_speed"]
        print(
            f"  V {row['value']:5.2f}  t {row['t']:.2f}  v_start {row['v_start']:5.1f}  "
            f"at ({x_:6.1f}, {y_:6.1f}) speed {speed:5.1f}  bounds {row['bounds']}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "states": len(values),
                "max_value_plus_slack": float(values.max()) + slack,
                "card_delta": float(calibration["delta"]),
                "quantiles": quantiles,
                "top": top,
            },
            indent=2,
        )
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
