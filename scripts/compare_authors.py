"""Compare the shipped network with the paper authors' published one on the same rollouts.

``python scripts/compare_authors.py`` (``make compare-authors``; needs the ``train`` extra for torch
and ``../shared/anchors/authors_model_final.pth``). Reference only: the authors' network is never
shipped or loaded by the service.

For every evaluation setting inside the authors' trained range (|u1| <= 1 rad/s) and each tube time
t in (1, 2, 3) s with at least half its states inside their trained domain (x in [-18, 36] m,
|y| <= 27 m, v <= 33 m/s; states outside it are dropped), states reached at times s <= t by rollouts of the true
dynamics (``models.evaluate.simulate``, RK4, our 0.5 m initial set, which lies inside theirs) are
checked against:

* the authors' tube (variational-inequality semantics, V(t, x) < 0 inside), evaluated at time t;
* ours at the state's own time s (set semantics; the tube is the union over s <= t): V <= delta.

Recall is the share of those states inside. As a tightness proxy, the share of "unreachable" states
(rollout states moved 3 m sideways, outside the interval outer bound) that each network excludes.
The authors' network is loaded from a plain state dict with ``weights_only=True`` (no pickle code).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import torch
from shapely import contains_xy
from shapely.geometry import Polygon

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from models.eval_settings import SETTINGS  # noqa: E402
from models.evaluate import TUBE_TIMES, simulate  # noqa: E402
from models.runtime import ValueModel  # noqa: E402
from reach.contract import BOUND_COLUMNS, COL, N_INPUTS  # noqa: E402
from reach.outer_bound import outer_bound  # noqa: E402

ANCHOR = ROOT.parent / "shared" / "anchors" / "authors_model_final.pth"
U1_RANGE = 1.0
SPEED_MAX = 33.0


class AuthorsNetwork(torch.nn.Module):
    """14 -> 512 x 4 -> 1 with sin(30 z) (SIREN), as published; inputs normalised to [-1, 1]."""

    def __init__(self, state: dict[str, torch.Tensor]) -> None:
        super().__init__()
        self.layers = torch.nn.ModuleList()
        for i in range(5):
            w, b = state[f"net.net.{i}.0.weight"], state[f"net.net.{i}.0.bias"]
            layer = torch.nn.Linear(w.shape[1], w.shape[0])
            layer.weight.data, layer.bias.data = w.float(), b.float()
            self.layers.append(layer)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        for layer in self.layers[:-1]:
            z = torch.sin(30.0 * layer(z))
        return self.layers[-1](z)


def authors_value(
    net: AuthorsNetwork, t: np.ndarray, states: np.ndarray, v0: float, b: dict
) -> np.ndarray:
    """V of the authors' tube at time t for states [N, 4] (x, y, heading, speed), per NOTICE.md."""
    x, y, th, v = (states[:, i] for i in range(4))
    th = (th + math.pi) % (2 * math.pi) - math.pi
    ones = np.ones_like(x)
    z = np.stack(
        [
            t / 3.0,
            (x / 9 - 1) / 3,
            (y / 9) / 3,
            th / (1.1 * math.pi),
            (v / 3 - 5.5) / 5.5,
            (v0 / 3 - 5.5) / 5.5 * ones,
            b["u2_min_start"] / 10 * ones,
            b["u2_max_start"] / 10 * ones,
            b["u1_min_start"] * ones,
            b["u1_max_start"] * ones,
            b["u2_min_end"] / 10 * ones,
            b["u2_max_end"] / 10 * ones,
            b["u1_min_end"] * ones,
            b["u1_max_end"] * ones,
        ],
        axis=1,
    )
    with torch.no_grad():
        out = net(torch.as_tensor(z, dtype=torch.float32)).numpy()[:, 0]
    l_pos = np.hypot(x / 9, y / 9) - 0.17
    l_rest = np.hypot(th, v / 3 - v0 / 3) - 0.5
    return 277.5 * out + np.maximum(l_pos, l_rest)


def our_inputs(s: np.ndarray, states: np.ndarray, v0: float, bounds: np.ndarray) -> np.ndarray:
    x = np.zeros((len(s), N_INPUTS), dtype=np.float32)
    x[:, COL["t"]] = s
    for i, name in enumerate(("px", "py", "heading", "speed")):
        x[:, COL[name]] = states[:, i]
    x[:, COL["v_start"]] = v0
    x[:, 6:] = bounds
    return x


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rollouts", type=int, default=8192)
    parser.add_argument("--samples", type=int, default=20000)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--json", type=Path, default=ROOT / "results" / "authors_comparison.json")
    args = parser.parse_args()
    if not ANCHOR.is_file():
        sys.exit(f"the authors' checkpoint is not at {ANCHOR}")
    state = torch.load(ANCHOR, map_location="cpu", weights_only=True)
    authors = AuthorsNetwork(state).eval()
    ours = ValueModel.load(ROOT / "models" / "frt_unicycle.onnx")
    delta = ours.card.delta
    rng = np.random.default_rng(args.seed)
    rows = []
    header = f"{'setting':26s} {'t':>4s} {'recall ours':>11s} {'recall authors':>14s} {'excl. ours':>10s} {'excl. authors':>13s}"
    print(header + "\n" + "-" * len(header))
    for setting in SETTINGS:
        u1 = setting.u1
        if max(abs(v) for v in u1) > U1_RANGE:
            continue
        bounds = setting.bounds()
        named = dict(zip(BOUND_COLUMNS, bounds, strict=True))
        roll = simulate(setting.v_start, bounds, args.rollouts, rng)
        ob = outer_bound(setting.v_start, bounds)
        for t in TUBE_TIMES:
            upto = roll.times <= t + 1e-9
            states = roll.states[upto].reshape(-1, 4)
            s = np.broadcast_to(roll.times[upto][:, None], roll.states[upto].shape[:2]).reshape(-1)
            pick = rng.choice(len(s), size=min(args.samples, len(s)), replace=False)
            states, s = states[pick], s[pick]
            # Inside the authors' trained domain only (x in [-18, 36] m, |y| <= 27 m, v <= 33 m/s).
            keep = ((states[:, 0] >= -18) & (states[:, 0] <= 36) & (np.abs(states[:, 1]) <= 27)) & (
                states[:, 3] <= SPEED_MAX
            )
            if keep.mean() < 0.5:
                continue
            states, s = states[keep], s[keep]
            v_ours = ours.evaluate(our_inputs(s, states, setting.v_start, bounds))
            v_auth = authors_value(authors, np.full(len(s), t), states, setting.v_start, named)
            # Unreachable probes: 3 m sideways of reached states, kept if outside the outer bound.
            side = np.stack([-np.sin(states[:, 2]), np.cos(states[:, 2])], axis=1)
            probes = states.copy()
            probes[:, :2] += 3.0 * side * rng.choice([-1.0, 1.0], size=(len(s), 1))
            k = ob.slice_index(t)
            tube = [Polygon(ob.sweep_polygon(i)) for i in range(k + 1)]
            outside = ~np.any([contains_xy(p, probes[:, 0], probes[:, 1]) for p in tube], axis=0)
            probes, ps = probes[outside], s[outside]
            ex_ours = (
                float(
                    np.mean(ours.evaluate(our_inputs(ps, probes, setting.v_start, bounds)) > delta)
                )
                if len(ps)
                else math.nan
            )
            ex_auth = (
                float(
                    np.mean(
                        authors_value(authors, np.full(len(ps), t), probes, setting.v_start, named)
                        >= 0
                    )
                )
                if len(ps)
                else math.nan
            )
            row = {
                "setting": setting.name,
                "t": t,
                "recall_ours": float(np.mean(v_ours <= delta)),
                "recall_authors": float(np.mean(v_auth < 0)),
                "unreachable_excluded_ours": ex_ours,
                "unreachable_excluded_authors": ex_auth,
                "unreachable_probes": len(ps),
                "share_in_authors_domain": float(keep.mean()),
            }
            rows.append(row)
            print(
                f"{setting.name:26s} {t:4.1f} {row['recall_ours']:11.4f} {row['recall_authors']:14.4f} "
                f"{ex_ours:10.3f} {ex_auth:13.3f}"
            )
    summary = {
        key: float(np.nanmin([r[key] for r in rows])) for key in ("recall_ours", "recall_authors")
    }
    summary.update(
        {
            f"mean_{key}": float(np.nanmean([r[key] for r in rows]))
            for key in ("unreachable_excluded_ours", "unreachable_excluded_authors")
        }
    )
    print(
        json.dumps(
            {"min_" + k if k.startswith("recall") else k: v for k, v in summary.items()}, indent=2
        )
    )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(
            {"rollouts": args.rollouts, "seed": args.seed, "summary": summary, "rows": rows},
            indent=2,
        )
    )
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
