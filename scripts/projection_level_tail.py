"""Which reachable points set the projection network's level: ``python scripts/projection_level_tail.py``.

The served K is {W <= lambda * box_scale} with lambda the largest W / box_scale over the card's
calibration points (scenario optimisation, ``models.projection.calibrated_levels``). This redraws
those very points (same generator, seed and counts as ``python -m models.projection
--calibrate-only``), checks that their maximum is the card's lambda, and prints the quantiles of the
ratio and the points at the top of its tail with their settings: what one would have to fix for
lambda to fall (~2 min). Writes ``results/projection_level_tail.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from models.projection import CALIBRATION_SLICE_DT, reachable_xy, set_scales  # noqa: E402
from models.runtime import ValueModel  # noqa: E402
from models.value_fields import engine_for  # noqa: E402
from reach.contract import COL  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    parser.add_argument("--settings", type=int, default=12000, help="as --calibration-settings")
    parser.add_argument("--seed", type=int, default=11, help="as models.projection's --seed")
    parser.add_argument("--top", type=int, default=8)
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "projection_level_tail.json")
    args = parser.parse_args()
    model = ValueModel.load(args.model, threads=2)
    engine = engine_for(model, stencil=True)
    rng = np.random.default_rng(args.seed + 1)  # the generator --calibrate-only draws from
    reach = reachable_xy(args.settings, 64, CALIBRATION_SLICE_DT, rng).astype(np.float32)
    w = model.evaluate_projection(reach)
    scale = set_scales(engine, reach)
    ratio = w / scale
    card = float(model.card.raw["projection_graph"]["level_per_scale"])
    quantiles = {q: float(np.quantile(ratio, float(q))) for q in ("0.999", "0.9999", "0.99999")}
    top = []
    for k in np.argsort(ratio)[::-1][: args.top]:
        top.append(
            {
                "ratio": float(ratio[k]),
                "w": float(w[k]),
                "box_scale": float(scale[k]),
                "t": float(reach[k, COL["t"]]),
                "v_start": float(reach[k, COL["v_start"]]),
                "bounds": [round(float(x), 3) for x in reach[k, 6:]],
                "state_x_y_heading_speed": [round(float(x), 2) for x in reach[k, 1:5]],
            }
        )
    print(f"max ratio {ratio.max():.4f} (card: {card:.4f}) over {len(reach)} points")
    print("quantiles: " + ", ".join(f"{q}: {v:.4f}" for q, v in quantiles.items()))
    for row in top:
        print(
            f"  ratio {row['ratio']:.4f}  W {row['w']:6.2f}  scale {row['box_scale']:6.1f}  "
            f"t {row['t']:.2f}  v_start {row['v_start']:5.1f}  speed {row['state_x_y_heading_speed'][3]:5.1f}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "points": len(reach),
                "max_ratio": float(ratio.max()),
                "card_level_per_scale": card,
                "quantiles": quantiles,
                "top": top,
            },
            indent=2,
        )
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
