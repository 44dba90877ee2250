"""Where the value network stands inside the outer bound: ``make network-diagnostics``.

The service's K is the network's set {W <= level} cut to the guaranteed outer polygons, and the
evaluation found the network cutting nothing there (docs/model.md). This asks why: at the positions
inside the outer polygon at t, binned by their distance to the nearest position the rollouts of
the true dynamics reached at t, it prints

* W, the distilled projection, against its calibrated level;
* the minimum of the full network V over a heading x speed grid (the projection W stands for),
  against the calibration margin delta;

so it shows whether the network's own values separate reachable from unreachable positions, or
whether only its calibration keeps it from cutting. Reference only: nothing here is served.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import shapely
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from models.eval_settings import SETTINGS  # noqa: E402
from models.evaluate import simulate  # noqa: E402
from models.runtime import ValueModel  # noqa: E402
from models.value_fields import engine_for  # noqa: E402
from reach.contract import COL, N_INPUTS  # noqa: E402
from reach.engine import FRTEngine  # noqa: E402

BINS_M = ((0.0, 0.5), (1.0, 2.0), (2.0, 4.0), (4.0, 8.0), (8.0, np.inf))
DEFAULT_SETTINGS = (
    "urban_narrow",
    "urban_wide",
    "shrinking_wide_to_narrow",
    "low_confidence_urban",
)


def min_over_heading_and_speed(
    model: ValueModel, t: float, xy: np.ndarray, v_start: float, bounds: np.ndarray, ob, row: int
) -> np.ndarray:
    """min of V over a 32 x 16 grid of the exact heading interval and the speed bound at t."""
    headings = np.linspace(*ob.heading[row], 32)
    speeds = np.linspace(*ob.speed[row], 16)
    x = np.zeros((len(xy), len(headings), len(speeds), N_INPUTS), dtype=np.float32)
    x[..., COL["t"]] = t
    x[..., COL["px"]] = xy[:, 0, None, None]
    x[..., COL["py"]] = xy[:, 1, None, None]
    x[..., COL["heading"]] = ((headings + np.pi) % (2 * np.pi) - np.pi)[None, :, None]
    x[..., COL["speed"]] = speeds[None, None, :]
    x[..., COL["v_start"]] = v_start
    x[..., 6:] = bounds
    values = model.evaluate(x.reshape(-1, N_INPUTS)).reshape(x.shape[:3])
    return values.min(axis=(1, 2))  # type: ignore[no-any-return]


def diagnose(
    model: ValueModel, engine: FRTEngine, name: str, t: float, rollouts: int, per_bin: int
) -> list[dict]:
    setting = {s.name: s for s in SETTINGS}[name]
    bounds = setting.bounds()
    rng = np.random.default_rng(0)
    roll = simulate(setting.v_start, bounds, rollouts, rng)
    reached = roll.states[int(np.argmin(np.abs(roll.times - t))), :, :2]
    ob = engine.outer(setting.v_start, bounds)
    row = ob.nearest_row(t)
    polygon = shapely.Polygon(ob.polygons_at([row])[0])
    x_lo, x_hi, y_lo, y_hi = ob.box_at[row]
    gx, gy = np.meshgrid(np.arange(x_lo, x_hi, 0.5), np.arange(y_lo, y_hi, 0.5))
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
    xy = xy[shapely.contains_xy(polygon, xy[:, 0], xy[:, 1])]
    distance, _ = cKDTree(reached).query(xy)
    level = float(engine.value_field.levels(ob.box_at[[row]])[0])
    delta = model.card.delta
    out = []
    for lo, hi in BINS_M:
        pick = np.flatnonzero((distance >= lo) & (distance < hi))
        if len(pick) == 0:
            continue
        pick = rng.choice(pick, size=min(per_bin, len(pick)), replace=False)
        w = engine.value_field.projected(
            np.full(len(pick), t), xy[pick, 0], xy[pick, 1], setting.v_start, bounds
        )
        v_min = min_over_heading_and_speed(model, t, xy[pick], setting.v_start, bounds, ob, row)
        out.append(
            {
                "setting": name,
                "t": t,
                "distance_m": [lo, hi],
                "positions": len(pick),
                "w_median": float(np.median(w)),
                "w_level": level,
                "share_w_above_level": float(np.mean(w > level)),
                "share_w_above_0": float(np.mean(w > 0)),
                "v_min_median": float(np.median(v_min)),
                "delta": delta,
                "share_v_min_above_delta": float(np.mean(v_min > delta)),
                "share_v_min_above_0": float(np.mean(v_min > 0)),
            }
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    parser.add_argument("--settings", nargs="*", default=list(DEFAULT_SETTINGS))
    parser.add_argument("--t", type=float, default=3.0)
    parser.add_argument("--rollouts", type=int, default=65536)
    parser.add_argument("--per-bin", type=int, default=200)
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "network_diagnostics.json")
    args = parser.parse_args()
    model = ValueModel.load(args.model, prefer_runtime_graph=False)
    engine = engine_for(ValueModel.load(args.model))
    rows = []
    for name in args.settings:
        rows += diagnose(model, engine, name, args.t, args.rollouts, args.per_bin)
    header = (
        f"{'setting':26s} {'dist [m]':>10s} {'n':>4s} {'W med':>7s} {'level':>6s} {'W>lvl':>6s} "
        f"{'W>0':>5s} {'minV med':>8s} {'minV>δ':>7s} {'minV>0':>7s}"
    )
    print(f"t = {args.t:g} s; δ = {model.card.delta:.3f}")
    print(header)
    for r in rows:
        lo, hi = r["distance_m"]
        print(
            f"{r['setting']:26s} {f'{lo:g}-{hi:g}':>10s} {r['positions']:4d} "
            f"{r['w_median']:7.2f} {r['w_level']:6.2f} {r['share_w_above_level']:6.2f} "
            f"{r['share_w_above_0']:5.2f} {r['v_min_median']:8.2f} "
            f"{r['share_v_min_above_delta']:7.2f} {r['share_v_min_above_0']:7.2f}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
