"""A small network for the (x, y) projection of the value function, distilled from the full one.

K(s) = {(x, y): min over heading, speed of V(s, x, y, heading, speed) <= delta} (paper, "Safe
Planning"). Evaluating that minimum with the full 14-D network costs one evaluation per stencil
point at each grid node; the service needs it on thousands of nodes per observation. This module
distils

    W(s, x, y; v_start, bounds) ~ min_stencil V(s, x, y, ., .; v_start, bounds)

(the teacher is the stencil minimum of V, ``models.value_fields.StencilField.stencil_min``) into a small MLP on the
same nominal-frame features, then calibrates its level against rollouts of the true dynamics, so the
service's K is {W <= delta_W} with a scenario guarantee like the main network's.

``python -m models.projection --model models/frt_unicycle.onnx`` writes
``models/<name>.projection.onnx`` and records it in the card (``projection_graph``).
"""

from __future__ import annotations

import argparse
import copy
import itertools
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from models.export_card import file_sha256, write_card
from models.network import NominalFrame, asinh_by_logs
from models.rollout import (
    EDGE_SHARE,
    rk4_rollout,
    sample_control_schedules,
    sample_initial_states,
    sample_reference_schedules,
)
from models.sampling import sample_parameters
from reach.contract import COL, HORIZON_S, INITIAL_SET, N_INPUTS
from reach.outer_bound import box_scale


class ProjectionNetwork(nn.Module):
    """W: the 14 contract columns (heading and speed ignored) -> [N, 1], in metres.

    Taking the contract layout keeps one input convention across graphs; the heading and speed
    columns are ignored because W is their minimum.
    """

    def __init__(self, width: int = 96, depth: int = 3, polar: bool = False) -> None:
        super().__init__()
        self.frame = NominalFrame(12, HORIZON_S, INITIAL_SET)
        layers: list[nn.Module] = []
        #: With ``polar``, also the position's bearing and distance from the start: the set at an
        #: instant is close to a band of distances per bearing, the notch behind the car included.
        self.polar = polar
        width_in = 16 + (4 if polar else 0)
        for _ in range(depth):
            layers += [nn.Linear(width_in, width), nn.SiLU()]
            width_in = width
        self.mlp = nn.Sequential(*layers, nn.Linear(width_in, 1))
        self.asinh = torch.asinh
        self.width, self.depth = width, depth

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        nom = self.frame(x)
        dx = x[:, COL["px"]] - nom["x"]
        dy = x[:, COL["py"]] - nom["y"]
        c, s = torch.cos(nom["heading"]), torch.sin(nom["heading"])
        along, cross = c * dx + s * dy, -s * dx + c * dy
        distance = torch.sqrt(along * along + cross * cross + 1e-12) - INITIAL_SET.radius_m
        scale = INITIAL_SET.radius_m + nom["along_spread"] + nom["cross_spread"]
        t = x[:, COL["t"]]
        feats = torch.stack(
            [
                t / HORIZON_S,
                self.asinh(along / nom["along_spread"]),
                self.asinh(cross / nom["cross_spread"]),
                along / 50.0,
                cross / 50.0,
                torch.log(nom["along_spread"]),
                torch.log(nom["cross_spread"]),
                torch.log(nom["heading_spread"]),
                torch.log(nom["speed_spread"]),
                nom["heading"] / math.pi,
                nom["speed"] / 50.0,
                x[:, COL["v_start"]] / 20.0,
                x[:, COL["u1_min_start"]] / 2.0,
                x[:, COL["u1_max_start"]] / 2.0,
                x[:, COL["u2_min_start"]] / 10.0,
                x[:, COL["u2_max_start"]] / 10.0,
            ]
            + (self._polar(x, scale) if self.polar else []),
            dim=1,
        )
        return (distance + (t / HORIZON_S) * scale * self.mlp(feats)[:, 0])[:, None]

    @staticmethod
    def _polar(x: torch.Tensor, scale: torch.Tensor) -> list[torch.Tensor]:
        px, py = x[:, COL["px"]], x[:, COL["py"]]
        rho = torch.sqrt(px * px + py * py + 1e-12)
        return [px / rho, py / rho, rho / scale, torch.log(scale)]


#: Instants of the calibration points: every 0.05 s, a grid that contains the engine's slices.
CALIBRATION_SLICE_DT = 0.05


def _slice_times(slice_dt: float) -> np.ndarray:
    return np.arange(1, round(HORIZON_S / slice_dt) + 1) * slice_dt


def reachable_xy(
    n_settings: int,
    per_setting: int,
    slice_dt: float,
    rng: np.random.Generator,
    times_per_setting: int = 4,
    edge: bool = True,
) -> np.ndarray:
    """Rows [n, 14] of states reached at slice times, from rollouts of the true dynamics.

    Each setting gets ``times_per_setting`` slice times with ``per_setting // times_per_setting``
    rollouts each, so rows come in blocks that share (setting, time). With ``edge`` the rollouts
    follow the evaluation's schedules (extremal ones included, half started on the initial set's
    edge), which calibration needs; without, the switching schedules the shipped projection graph
    is distilled on.
    """
    block = max(per_setting // times_per_setting, 1)
    params = np.repeat(sample_parameters(n_settings, rng), times_per_setting * block, axis=0)
    n = len(params)
    times = rng.choice(_slice_times(slice_dt), size=(n_settings * times_per_setting, 1))
    t = np.repeat(times, block, axis=1).ravel()
    if edge:
        start = sample_initial_states(params[:, COL["v_start"]], rng, on_boundary=EDGE_SHARE)
        a1, a2, sw = sample_reference_schedules(n, HORIZON_S, rng)
    else:
        start = sample_initial_states(params[:, COL["v_start"]], rng)
        a1, a2, sw = sample_control_schedules(n, HORIZON_S, rng)
    end, _ = rk4_rollout(start, params, t, a1, a2, sw * (t / HORIZON_S)[:, None], 60)
    x = params.copy()
    x[:, COL["t"]] = t
    for name, value in zip(("px", "py", "heading", "speed"), end, strict=True):
        x[:, COL[name]] = value
    return x


def blocks(rows: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges of consecutive rows that share the time and parameter columns."""
    key = np.concatenate([rows[:, :1], rows[:, COL["v_start"] :]], axis=1)
    change = np.any(np.diff(key, axis=0) != 0, axis=1)
    edges = np.concatenate([[0], np.nonzero(change)[0] + 1, [len(rows)]])
    return list(itertools.pairwise(edges))


def teacher_dataset(engine, n_settings: int, per_setting: int, rng: np.random.Generator):
    """(inputs, stencil-min targets): reachable points, perturbed ones and uniform outer-box ones."""
    base = reachable_xy(n_settings, per_setting, engine.slice_dt, rng, edge=False)
    noise = 10 ** rng.uniform(-1.3, 0.8, len(base))
    near = base.copy()
    near[:, COL["px"]] += rng.normal(0, 1, len(base)) * noise
    near[:, COL["py"]] += rng.normal(0, 1, len(base)) * noise
    rows = np.concatenate([base, near])
    targets = np.empty(len(rows), dtype=np.float32)
    for a, b in tqdm(blocks(rows), desc="teacher", mininterval=5):
        r = rows[a:b]
        v_start, params = float(r[0, COL["v_start"]]), r[0, 6:].astype(np.float32)
        ob = engine.outer(v_start, params)
        targets[a:b], _ = engine.value_field.stencil_min(
            float(r[0, COL["t"]]), r[:, COL["px"]], r[:, COL["py"]], v_start, params, ob
        )
    return rows.astype(np.float32), targets


TEACHERS = {
    "value": "StencilField.stencil_min of the runtime graph",
    "occupancy": "distance to positions reached by rollouts of the true dynamics "
    "(models.projection.occupancy_dataset)",
}

#: Far-field occupancy targets are clipped here: beyond a few metres only their sign matters.
OCCUPANCY_CLIP_M = 20.0
#: The local spacing of the reached positions, subtracted from the distance to the nearest one:
#: that position's distance to its GAP_NEIGHBOURS-th nearest neighbour.
GAP_NEIGHBOURS = 4


def occupancy_dataset(
    n_settings: int,
    rng: np.random.Generator,
    rollouts: int = 2048,
    instants: int = 4,
    queries: int = 64,
    slice_dt: float = CALIBRATION_SLICE_DT,
) -> tuple[np.ndarray, np.ndarray]:
    """(inputs, targets) for W from rollouts of the true dynamics instead of from V: the target at
    (s, x, y) is the distance from (x, y) to the nearest of ``rollouts`` positions reached at
    exactly s (the evaluation's schedules, half started on the initial set's edge), less the local
    spacing of those positions (``GAP_NEIGHBOURS``), clipped at ``OCCUPANCY_CLIP_M``: negative
    inside the sampled set, positive outside it.

    Per setting and each of ``instants`` random instants, ``queries`` points: a third reached
    positions (target minus their spacing), drawn in proportion to it so that sparse places count
    as much as dense ones, a third reached positions moved by log-uniform noise (0.05-6 m), a third
    uniform in the outer box at s, which holds the notch behind a car that can turn round: inside
    the convex outer polygon, never reached, and called reachable by the value network
    (docs/model.md). This teacher is an inner reference, so the level calibrated afterwards on
    fresh rollouts (``calibrated_levels``) is what makes the set contain what is reachable."""
    from scipy.spatial import cKDTree

    from reach.outer_bound import outer_bound

    steps = round(HORIZON_S / slice_dt)
    rows, targets = [], []
    third = queries // 3
    for params in tqdm(sample_parameters(n_settings, rng), desc="occupancy", mininterval=5):
        v_start, bounds = float(params[COL["v_start"]]), params[6:]
        batch = np.repeat(params[None], rollouts, axis=0)
        start = sample_initial_states(batch[:, COL["v_start"]], rng, on_boundary=EDGE_SHARE)
        a1, a2, sw = sample_reference_schedules(rollouts, HORIZON_S, rng)
        _, trace = rk4_rollout(
            start, batch, np.full(rollouts, HORIZON_S), a1, a2, sw, steps, record=True
        )
        ob = outer_bound(v_start, bounds, support_directions=0)
        for k in rng.choice(steps, size=instants, replace=False):
            tau, (px, py, _, _) = trace[k]
            s = float(tau[0])
            reached = np.stack([px, py], axis=1)
            tree = cKDTree(reached)
            spacing = tree.query(reached, k=GAP_NEIGHBOURS + 1)[0][:, -1]
            # Sparse places (thin tails of the set, its edge) as often as dense ones.
            weight = spacing / spacing.sum() if spacing.sum() > 0 else None
            pick = reached[rng.choice(rollouts, queries - 2 * third, p=weight)]
            near = reached[rng.choice(rollouts, third, p=weight)]
            near = near + rng.normal(0, 1, near.shape) * 10 ** rng.uniform(-1.3, 0.8, (third, 1))
            x_lo, x_hi, y_lo, y_hi = ob.box_at[ob.nearest_row(s)]
            box = np.stack([rng.uniform(x_lo, x_hi, third), rng.uniform(y_lo, y_hi, third)], axis=1)
            xy = np.concatenate([pick, near, box])
            distance, nearest = tree.query(xy)
            # Less the spacing of the samples there: inside a large set 2 048 positions leave
            # gaps of metres, which are reachable all the same.
            distance = distance - spacing[nearest]
            r = np.repeat(params[None], len(xy), axis=0)
            r[:, COL["t"]] = s
            r[:, COL["px"]], r[:, COL["py"]] = xy[:, 0], xy[:, 1]
            rows.append(r)
            targets.append(np.minimum(distance, OCCUPANCY_CLIP_M))
    return np.concatenate(rows).astype(np.float32), np.concatenate(targets).astype(np.float32)


def unreachable_xy(
    n_settings: int,
    per_setting: int,
    slice_dt: float,
    rng: np.random.Generator,
    bins: tuple[int, int] = (16, 6),
) -> tuple[np.ndarray, np.ndarray]:
    """Positions proven unreachable at their time although inside the convex outer polygon: rows
    [n, 14] (t, px, py and the parameters set) and the size of their set (``box_scale`` of the
    outer box at that time).

    Per random setting and slice time, points drawn uniformly in the outer box are kept when the
    outer polygon contains them and no heading x speed bin polygon of
    ``reach.corridors.partition_supports`` does: no trajectory from the initial set is there
    at that time (sound: tests/test_corridor_bound.py). Mostly the notch behind a car that can turn
    round, which the distilled V calls reachable (docs/model.md)."""
    from reach.corridors import DIRECTIONS
    from reach.outer_bound import outer_bound
    from reach.partition import partition_supports

    late = _slice_times(slice_dt)
    late = late[late >= 1.0]
    rows, scales = [], []
    for params in tqdm(sample_parameters(n_settings, rng), desc="unreachable", mininterval=5):
        v_start, bounds = float(params[COL["v_start"]]), params[6:]
        t = float(rng.choice(late))
        ob = outer_bound(v_start, bounds)
        k = ob.nearest_row(t)
        x_lo, x_hi, y_lo, y_hi = ob.box_at[k]
        xy = np.stack(
            [rng.uniform(x_lo, x_hi, per_setting), rng.uniform(y_lo, y_hi, per_setting)], axis=1
        )
        in_polygon = np.all(
            xy @ np.stack([np.cos(ob.directions), np.sin(ob.directions)]) <= ob.support_at[k],
            axis=1,
        )
        support, empty = partition_supports(v_start, bounds, [t], *bins)
        reach = xy @ np.stack([np.cos(DIRECTIONS), np.sin(DIRECTIONS)])
        covered = (np.all(reach[:, None, :] <= support[0][None] + 1e-9, axis=2) & ~empty[0]).any(1)
        keep = in_polygon & ~covered
        if keep.any():
            r = np.repeat(params[None], int(keep.sum()), axis=0)
            r[:, COL["t"]] = t
            r[:, COL["px"]], r[:, COL["py"]] = xy[keep, 0], xy[keep, 1]
            rows.append(r)
            scales.append(np.full(int(keep.sum()), float(box_scale(ob.box_at[k]))))
    if not rows:
        return np.zeros((0, N_INPUTS), dtype=np.float32), np.zeros(0, dtype=np.float32)
    return np.concatenate(rows).astype(np.float32), np.concatenate(scales).astype(np.float32)


def train_projection(
    x: np.ndarray,
    y: np.ndarray,
    steps: int,
    seed: int,
    over_weight: float = 4.0,
    lift: tuple[np.ndarray, np.ndarray] | None = None,
    lift_weight: float = 1.0,
    polar: bool = False,
) -> ProjectionNetwork:
    """Regression with a heavier penalty where W over-estimates the teacher (the unsafe side).

    ``lift`` = (rows, floors): positions proven unreachable and a value W should not fall below
    there (a hinge, squared); the calibration on reachable points then decides the level, so the
    hinge can only move the set where it does not cost containment."""
    torch.manual_seed(seed)
    net = ProjectionNetwork(polar=polar)
    optimiser = torch.optim.Adam(net.parameters(), lr=2e-3)
    xt, yt = torch.as_tensor(x), torch.as_tensor(y)
    lift_x = lift_floor = None
    if lift is not None and len(lift[0]):
        lift_x, lift_floor = torch.as_tensor(lift[0]), torch.as_tensor(lift[1])
    rng = np.random.default_rng(seed)
    bar = tqdm(range(steps), desc="distil", mininterval=5)
    for step in bar:
        for group in optimiser.param_groups:
            group["lr"] = 1e-5 + 0.5 * (2e-3 - 1e-5) * (1 + math.cos(math.pi * step / steps))
        idx = torch.as_tensor(rng.integers(0, len(xt), 4096))
        target = yt[idx].clamp(max=20.0)  # far-field values matter only in sign
        err = net(xt[idx])[:, 0] - target
        loss = torch.where(err > 0, over_weight * err * err, err * err).mean()
        if lift_x is not None and lift_floor is not None:
            pick = torch.as_tensor(rng.integers(0, len(lift_x), 1024))
            short = torch.relu(lift_floor[pick] - net(lift_x[pick])[:, 0])
            loss = loss + lift_weight * (short * short).mean()
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        if step % 100 == 0:
            bar.set_postfix(loss=f"{loss.item():.4g}")
    return net


class _ExportGraph(nn.Module):
    def __init__(self, net: ProjectionNetwork) -> None:
        super().__init__()
        self.net = copy.deepcopy(net).eval()
        self.net.asinh = asinh_by_logs

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


def export_projection(net: ProjectionNetwork, path: Path) -> None:
    from models.export import OPSET

    example = torch.zeros(4, N_INPUTS)
    torch.onnx.export(
        _ExportGraph(net),
        (example,),
        str(path),
        input_names=["x"],
        output_names=["value"],
        dynamic_axes={"x": {0: "N"}, "value": {0: "N"}},
        opset_version=OPSET,
        dynamo=False,
    )


#: Candidate slopes of the level per unit of set size (``box_scale``), for ``calibrated_levels``.
LEVEL_SLOPES = tuple(np.round(np.arange(0.0, 0.2001, 0.005), 3))


def set_scales(engine, reach: np.ndarray) -> np.ndarray:
    """``box_scale`` of the outer box at each row's instant (rows in blocks of one setting and
    instant, as ``reachable_xy`` gives them)."""
    scale = np.empty(len(reach))
    for a, b in blocks(reach):
        r = reach[a]
        ob = engine.outer(float(r[COL["v_start"]]), r[6:])
        scale[a:b] = box_scale(ob.box_at[ob.nearest_row(float(r[COL["t"]]))])
    return scale


def affine_level(
    w: np.ndarray, scale: np.ndarray, slopes: tuple[float, ...] = LEVEL_SLOPES
) -> tuple[float, float]:
    """(offset, slope) with ``w <= offset + slope * scale`` at every sample and the smallest mean
    level over the samples, the slope taken from ``slopes``."""
    offsets = np.array([float(np.max(w - slope * scale)) for slope in slopes])
    mean_level = offsets + np.asarray(slopes) * float(np.mean(scale))
    best = int(np.argmin(mean_level))
    return float(offsets[best]), float(slopes[best])


def calibrated_levels(
    engine, reach: np.ndarray, w: np.ndarray, affine: bool = False
) -> dict[str, Any]:
    """Levels of W from its values ``w`` at reachable rows ``reach`` (scenario optimisation).

    ``delta``: the largest W seen, one level for every set. The level the engine uses grows with
    the set, ``level_offset_m + level_per_scale * box_scale(outer box at the instant)``: the
    distilled network's errors are metres on a 60 m set and centimetres on a 3 m one. By default
    (the shipped rule) the offset is 0 and the slope the largest W / scale seen. With ``affine``,
    for each candidate slope in ``LEVEL_SLOPES`` the offset is the largest ``W - slope * scale``
    seen, and the pair with the smallest mean level over the samples is kept (``affine_level``).
    With N independent samples (and k candidates), a reachable point drawn from the same
    distribution is inside with probability >= 1 - eps with confidence 1 - k (1 - eps)^N (a union
    bound over the candidates); a guarantee over the sampling distribution, not per setting, which
    is why one level serves every (time, size) cell.
    """
    scale = set_scales(engine, reach)
    ratio = w / scale
    offset, slope = affine_level(w, scale) if affine else (0.0, float(ratio.max()))
    return {
        "delta": float(w.max()),
        "level_offset_m": offset,
        "level_per_scale": slope,
        "level_scale": "reach.outer_bound.box_scale of the outer box at the instant",
        "level_candidates": len(LEVEL_SLOPES) if affine else 1,
        "calibration_samples": len(reach),
        "quantiles_at_reachable": {q: float(np.quantile(w, float(q))) for q in ("0.5", "0.99")},
        "ratio_quantiles_at_reachable": {
            q: float(np.quantile(ratio, float(q))) for q in ("0.5", "0.99", "0.999")
        },
    }


def recalibrate(
    model_path: Path, n_settings: int, rng: np.random.Generator, affine: bool = False
) -> None:
    """Re-calibrate the shipped projection graph's levels in its card (no distillation)."""
    from models.runtime import ValueModel
    from models.value_fields import engine_for

    model = ValueModel.load(model_path, threads=2)
    engine = engine_for(model, stencil=True)
    reach = reachable_xy(n_settings, 64, CALIBRATION_SLICE_DT, rng).astype(np.float32)
    w = model.evaluate_projection(reach)
    card = json.loads(model_path.with_suffix(".json").read_text())
    card["projection_graph"].update(calibrated_levels(engine, reach, w, affine))
    write_card(card, model_path)
    print(json.dumps(card["projection_graph"], indent=2))


def main() -> None:
    from models.runtime import ValueModel
    from models.value_fields import engine_for

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--model", type=Path, default=Path("models/frt_unicycle.onnx"))
    parser.add_argument("--settings", type=int, default=3000)
    parser.add_argument("--per-setting", type=int, default=64)
    parser.add_argument("--steps", type=int, default=6000)
    parser.add_argument(
        "--teacher",
        choices=("value", "occupancy"),
        default="value",
        help="value: the full network's stencil minimum; occupancy: the distance to positions "
        "rollouts of the true dynamics reach (occupancy_dataset)",
    )
    parser.add_argument("--calibration-settings", type=int, default=12000)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument(
        "--lift-settings",
        type=int,
        default=0,
        help="settings whose positions proven unreachable (unreachable_xy) W is lifted at",
    )
    parser.add_argument(
        "--lift-floor",
        type=float,
        default=0.25,
        help="W's floor there per unit of set size (box_scale), above the calibrated level",
    )
    parser.add_argument("--lift-weight", type=float, default=1.0)
    parser.add_argument("--polar", action="store_true", help="ProjectionNetwork(polar=True)")
    parser.add_argument(
        "--affine-level",
        action="store_true",
        help="calibrate an offset as well as the slope per unit of set size (affine_level)",
    )
    parser.add_argument(
        "--over-weight", type=float, default=4.0, help="penalty factor where W is above the target"
    )
    parser.add_argument(
        "--calibrate-only",
        action="store_true",
        help="keep the shipped projection graph, re-calibrate its levels on fresh rollouts",
    )
    args = parser.parse_args()
    if args.calibrate_only:
        recalibrate(
            args.model,
            args.calibration_settings,
            np.random.default_rng(args.seed + 1),
            args.affine_level,
        )
        return
    started = time.monotonic()
    rng = np.random.default_rng(args.seed)
    model = ValueModel.load(args.model, threads=2)
    engine = engine_for(model, stencil=True)
    if args.teacher == "occupancy":
        x, y = occupancy_dataset(args.settings, rng)
    else:
        x, y = teacher_dataset(engine, args.settings, args.per_setting, rng)
    lift = None
    if args.lift_settings:
        rows, scale = unreachable_xy(args.lift_settings, 256, CALIBRATION_SLICE_DT, rng)
        lift = (rows, (args.lift_floor * scale).astype(np.float32))
    net = train_projection(
        x,
        y,
        args.steps,
        args.seed,
        over_weight=args.over_weight,
        lift=lift,
        lift_weight=args.lift_weight,
        polar=args.polar,
    )
    # Calibrate the level on fresh reachable points of the true dynamics (scenario optimisation).
    # One level for all settings: its guarantee is over the sampling distribution, not per
    # setting, so a finer table of levels would claim more than it holds.
    reach = reachable_xy(args.calibration_settings, 64, CALIBRATION_SLICE_DT, rng)
    reach = reach.astype(np.float32)
    with torch.no_grad():
        w = net(torch.as_tensor(reach)).numpy()[:, 0]
    levels = calibrated_levels(engine, reach, w, args.affine_level)
    path = args.model.with_name(args.model.stem + ".projection.onnx")
    export_projection(net, path)
    card = json.loads(args.model.with_suffix(".json").read_text())
    card["projection_graph"] = {
        "file": path.name,
        "sha256": file_sha256(path),
        **levels,
        "teacher": TEACHERS[args.teacher],
        "architecture": {
            "width": net.width,
            "depth": net.depth,
            "activation": "SiLU",
            "polar_features": net.polar,
        },
        "over_weight": args.over_weight,
        "distillation_samples": len(x),
        "lifted_unreachable_positions": 0 if lift is None else len(lift[0]),
        "lift_floor_per_scale": args.lift_floor if lift is not None else None,
        "steps": args.steps,
        "time_s": round(time.monotonic() - started, 1),
    }
    write_card(card, args.model)
    print(json.dumps(card["projection_graph"], indent=2))


if __name__ == "__main__":
    main()
