"""Training checkpoints side by side (torch, reference only): ``python
scripts/checkpoint_diagnostics.py A.pt B.pt ...``.

For each checkpoint (a run's ``checkpoint.pt`` or a weights-only ``.pt`` of the 3 x 256 network):

* V at 38 400 reachable states (300 random settings x 128, the calibration's mix of schedules and
  edge starts, random slice times): its maximum is what the calibration margin delta would be;
* at t = 3 s on four evaluation settings, the minimum of V over a 32 x 16 heading x speed grid at
  positions inside the outer polygon (1 m grid, up to 150 per bin), binned by their distance to
  the nearest position 32 768 rollouts reached: does the network separate reachable from
  unreachable positions (``make network-diagnostics`` asks the same of the shipped ONNX model).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import shapely
import torch
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from models.eval_settings import SETTINGS  # noqa: E402
from models.evaluate import model_inputs, simulate  # noqa: E402
from models.network import NetworkConfig, ValueNetwork  # noqa: E402
from models.rollout import (  # noqa: E402
    EDGE_SHARE,
    rk4_rollout,
    sample_initial_states,
    sample_reference_schedules,
)
from models.sampling import sample_parameters  # noqa: E402
from reach.contract import COL, HORIZON_S, N_INPUTS  # noqa: E402
from reach.outer_bound import outer_bound  # noqa: E402

NAMES = ("urban_wide", "shrinking_wide_to_narrow", "low_confidence_urban", "urban_medium")
BINS_M = ((0.0, 0.7), (2.0, 4.0), (4.0, 8.0), (8.0, np.inf))


def load(path: Path) -> ValueNetwork:
    net = ValueNetwork(NetworkConfig(width=256, depth=3))
    state = torch.load(path, weights_only=True)
    net.load_state_dict(state.get("model", state))
    return net.eval()


def values(net: ValueNetwork, x: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return np.concatenate(
            [
                net(torch.as_tensor(x[a : a + 65536], dtype=torch.float32))[:, 0].numpy()
                for a in range(0, len(x), 65536)
            ]
        )


def reachable_states(rng: np.random.Generator) -> np.ndarray:
    rows = []
    for row in sample_parameters(300, rng):
        p = np.repeat(row[None], 128, axis=0)
        t = rng.choice(np.arange(1, 31) * 0.1, 128)
        start = sample_initial_states(p[:, COL["v_start"]], rng, on_boundary=EDGE_SHARE)
        a1, a2, sw = sample_reference_schedules(128, HORIZON_S, rng)
        end, _ = rk4_rollout(start, p, t, a1, a2, sw * (t / HORIZON_S)[:, None], 60)
        rows.append(model_inputs(t, np.stack(end, 1), float(row[COL["v_start"]]), row[6:]))
    return np.concatenate(rows)


def main() -> None:
    torch.set_num_threads(1)
    nets = {Path(p).name: load(Path(p)) for p in sys.argv[1:]}
    reach = reachable_states(np.random.default_rng(5))
    delta = {}
    for name, net in nets.items():
        v = values(net, reach)
        delta[name] = float(v.max())
        print(f"{name}: V at reachable states max {v.max():.3f}, q99.9 {np.quantile(v, 0.999):.3f}")
    for setting in (s for s in SETTINGS if s.name in NAMES):
        bounds, t = setting.bounds(), 3.0
        roll = simulate(setting.v_start, bounds, 32768, np.random.default_rng(0))
        reached = roll.states[int(np.argmin(np.abs(roll.times - t))), :, :2]
        ob = outer_bound(setting.v_start, bounds)
        row = ob.nearest_row(t)
        x_lo, x_hi, y_lo, y_hi = ob.box_at[row]
        gx, gy = np.meshgrid(np.arange(x_lo, x_hi, 1.0), np.arange(y_lo, y_hi, 1.0))
        xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
        polygon = shapely.Polygon(ob.polygons_at([row])[0])
        xy = xy[shapely.contains_xy(polygon, xy[:, 0], xy[:, 1])]
        distance, _ = cKDTree(reached).query(xy)
        headings = (np.linspace(*ob.heading[row], 32) + np.pi) % (2 * np.pi) - np.pi
        speeds = np.linspace(*ob.speed[row], 16)
        for lo, hi in BINS_M:
            pick = np.flatnonzero((distance >= lo) & (distance < hi))[:150]
            if len(pick) == 0:
                continue
            x = np.zeros((len(pick), 32, 16, N_INPUTS), dtype=np.float32)
            x[..., COL["t"]] = t
            x[..., COL["px"]] = xy[pick, 0, None, None]
            x[..., COL["py"]] = xy[pick, 1, None, None]
            x[..., COL["heading"]] = headings[None, :, None]
            x[..., COL["speed"]] = speeds[None, None, :]
            x[..., COL["v_start"]] = setting.v_start
            x[..., 6:] = bounds
            cells = []
            for name, net in nets.items():
                v_min = values(net, x.reshape(-1, N_INPUTS)).reshape(len(pick), -1).min(axis=1)
                cells.append(
                    f"median {np.median(v_min):6.2f} >0 {np.mean(v_min > 0):.2f} "
                    f">max {np.mean(v_min > delta[name]):.2f}"
                )
            print(f"{setting.name:26s} {lo:g}-{hi:g} m n={len(pick):3d} | " + " | ".join(cells))


if __name__ == "__main__":
    main()
