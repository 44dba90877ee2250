"""What a sound heading x speed partition of the outer bound would cut from the uncut exact set.

``python scripts/partition_bound.py`` (~20 s): for the evaluation settings whose tubes reach more
than 1.5 m beyond the rollout cells (the notch behind a car that can turn round), the uncut exact
tube (the engine's without its notch cut: what the service serves until its background refinement
lands, `make evaluate`'s "uncut" column) is cut to the union over instants 0.1 s apart of the
partition polygons of ``reach.corridors.partition_supports`` (one convex polygon per final
heading x final speed bin, each swept along its headings by how far a car moves in half an
instant, ``swept_supports``; a bin count
ending in ``c``, e.g. ``16x1c``, couples the speed over time by a linear programme per bin and
direction, ``reach.speed_programme``), and both are
compared with the rollout cells as in ``models.evaluate`` (recall, IoU, "beyond" p95). It also
times the partition per set: whether the cut could run online.

The cut is sound (tests/test_corridor_bound.py: every simulated position lies in its time's union),
so recall must stay 1; the question is how much of the notch it removes, and at what cost.
Writes ``results/partition_bound.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from models.eval_settings import SETTINGS  # noqa: E402
from models.evaluate import (  # noqa: E402
    CELL_M,
    compare_cells,
    model_cells,
    simulate,
    swept_cells,
)
from models.runtime import ValueModel  # noqa: E402
from models.value_fields import engine_for  # noqa: E402
from reach.frames import Pose  # noqa: E402
from reach.partition import partition_tubes  # noqa: E402

NAMES = (
    "stationary_wide_limits",
    "urban_wide",
    "fast_wide_limits",
    "shrinking_wide_to_narrow",
    "shrinking_steering_only",
    "growing_narrow_to_wide",
    "u_turn_like",
    "low_confidence_urban",
)
TIMES = (2.0, 3.0)
INSTANT_S = 0.1


#: Settings drawn by --plot, at t = 3 s.
PLOTTED = ("urban_wide", "shrinking_wide_to_narrow", "low_confidence_urban")


def plot(drawn: dict[str, tuple], path: Path) -> None:
    """Per setting: the rollout cells, the uncut exact tube and the coupled partition tube at 3 s."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(drawn), figsize=(4.4 * len(drawn), 4.6))
    panels = zip(np.atleast_1d(axes), drawn.items(), strict=True)
    for ax, (name, (reference, served, bound)) in panels:
        ax.scatter(
            (reference[:, 0] + 0.5) * CELL_M,
            (reference[:, 1] + 0.5) * CELL_M,
            s=0.2,
            c="tab:blue",
            label="rollout cells (reached)",
        )
        for geometry, colour, label in (
            (served, "tab:red", "exact tube, uncut"),
            (bound, "black", "partition, speed coupled (proven)"),
        ):
            for polygon in getattr(geometry, "geoms", [geometry]):
                ax.plot(*polygon.exterior.xy, color=colour, lw=1.1, label=label)
                for hole in polygon.interiors:
                    ax.plot(*hole.xy, color=colour, lw=0.8)
        ax.set_title(f"{name}, t = 3 s", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        handles, labels = ax.get_legend_handles_labels()
        unique = dict(zip(labels, handles, strict=False))
    fig.legend(unique.values(), unique.keys(), loc="lower center", ncol=3, fontsize=9)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def bin_label(bins: tuple[int, int, bool]) -> str:
    return f"{bins[0]}x{bins[1]}{'c' if bins[2] else ''}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    parser.add_argument("--rollouts", type=int, default=16384)
    parser.add_argument(
        "--bins",
        default="16x6,16x1c",
        help="heading x speed bin counts; a trailing c couples the speed over time",
    )
    parser.add_argument(
        "--steps", type=int, default=24, help="sub-intervals of [0, t] for the corridors"
    )
    parser.add_argument(
        "--coupled-steps", type=int, default=60, help="the same with the speed coupled"
    )
    parser.add_argument(
        "--partitioned-from",
        type=float,
        default=0.0,
        help="instants before this many seconds take the convex outer polygon (cheaper)",
    )
    parser.add_argument(
        "--directions", type=int, default=16, help="support directions of each bin's polygon"
    )
    parser.add_argument("--only", nargs="*", default=None, help="names of settings to run")
    parser.add_argument(
        "--instant", type=float, default=INSTANT_S, help="seconds between the tube's instants"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "partition_bound.json")
    parser.add_argument(
        "--plot", type=Path, default=None, help="PNG of three settings at 3 s (docs/...)"
    )
    args = parser.parse_args()
    bin_sets = [
        (int(h), int(v.rstrip("c")), v.endswith("c"))
        for h, v in (b.split("x") for b in args.bins.split(","))
    ]
    engine = engine_for(ValueModel.load(args.model, threads=2))
    settings = [s for s in SETTINGS if s.name in (args.only or NAMES)]
    directions = np.arange(args.directions) * (2 * np.pi / args.directions)
    rows = []
    drawn: dict[str, tuple] = {}
    for setting in tqdm(settings, desc="settings", unit="setting"):
        bounds = setting.bounds()
        rng = np.random.default_rng(args.seed)
        roll = simulate(setting.v_start, bounds, args.rollouts, rng)
        frt = engine.exact(Pose(0.0, 0.0, 0.0), setting.v_start, bounds)
        speed_max = float(engine.outer(setting.v_start, bounds).sweep_speed_max.max())
        tubes = {}
        for bins in bin_sets:
            started = time.perf_counter()
            cuts = partition_tubes(
                setting.v_start,
                bounds,
                TIMES,
                speed_max,
                *bins,
                steps=args.coupled_steps if bins[2] else args.steps,
                instant_s=args.instant,
                partitioned_from_s=args.partitioned_from,
                directions=directions,
            )
            tubes[bins] = (cuts, time.perf_counter() - started)
        for t, reference in zip(TIMES, swept_cells(roll, TIMES), strict=True):
            served = frt.geometry("tube", t)
            row = {
                "setting": setting.name,
                "t": t,
                "served": compare_cells(reference, model_cells(served, reference)),
            }
            for bins, (cuts, seconds) in tubes.items():
                both = served.intersection(cuts[TIMES.index(t)])
                row[f"cut_{bin_label(bins)}"] = {
                    **compare_cells(reference, model_cells(both, reference)),
                    "partition_s_to_3s": round(seconds, 3),
                }
            rows.append(row)
            coupled = [cuts for bins, (cuts, _) in tubes.items() if bins[2]]
            if setting.name in PLOTTED and t == max(TIMES) and coupled:
                drawn[setting.name] = (reference, served, coupled[0][TIMES.index(t)])
    header = f"{'setting':26s} {'t':>3s}  {'served IoU / beyond p95':>24s}"
    for bins in bin_sets:
        header += f"  {f'cut {bin_label(bins)}: recall / IoU / beyond / s':>38s}"
    print(header)
    for row in rows:
        line = (
            f"{row['setting']:26s} {row['t']:3.0f}  "
            f"{row['served']['iou']:11.3f} / {row['served']['beyond_p95_m']:6.2f} m"
        )
        for bins in bin_sets:
            c = row[f"cut_{bin_label(bins)}"]
            line += (
                f"  {c['recall_cells']:11.4f} / {c['iou']:5.3f} / "
                f"{c['beyond_p95_m']:6.2f} m / {c['partition_s_to_3s']:5.2f}"
            )
        print(line)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "rollouts": args.rollouts,
                "seed": args.seed,
                "steps": args.steps,
                "coupled_steps": args.coupled_steps,
                "partitioned_from_s": args.partitioned_from,
                "directions": args.directions,
                "instant_s": args.instant,
                "rows": rows,
            },
            indent=2,
        )
    )
    print(f"wrote {args.out}")
    if args.plot and drawn:
        plot(drawn, args.plot)
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
