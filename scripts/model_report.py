"""Render the model card's measured figures as Markdown: ``python scripts/model_report.py``.

Writes docs/model_accuracy.md from models/frt_unicycle.json, so the numbers in the docs are the
ones `make evaluate-full` measured and wrote into the card.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def render(card: dict) -> str:
    acc = card["accuracy"]
    cal = card["calibration"]
    proj = card.get("projection_graph", {})
    s = acc["summary"]
    lines = [
        "# Accuracy of the shipped value network (generated from the model card)",
        "",
        f"Model `{card['name']}` (`{card['file']}`, sha256 `{card['sha256'][:16]}…`), semantics "
        f"`{card['semantics']}`, horizon {card['horizon_s']} s. Measured by `make evaluate-full`: "
        f"{acc['rollouts_per_setting']} rollouts per setting (RK4, dt = {acc['dt_s']} s), "
        f"cells of {acc['cell_m']} m, seed {acc['seed']}.",
        "",
        f"Inner reference: {acc.get('reference', 'rollouts of the true dynamics')}.",
        "",
        "Columns: share of sampled reachable states with V <= delta; share of rollout (x, y) cells "
        "inside the service's tube K(t); IoU of K(t) with the rollout cells; 95th percentile of how far "
        "K(t) reaches beyond the rollout cells; IoU of the union of the interval outer bound's 0.025 s "
        "sweep polygons; IoU of the service's tube with no value field (the engine's "
        "outer-bound construction alone: the difference to the IoU column is what the network "
        "adds); then the speed-coupled partition bound (`reach.partition.partition_tubes`, a "
        "proven outer tube that has most of the notch behind a car that can turn round): its recall "
        'of rollout cells (must be 1), its IoU and "beyond" against the rollout cells, and how far '
        'the service\'s tube reaches beyond it (95th percentile over cells, as "beyond"): that '
        "part is proven unreachable, whatever the rollouts covered.",
        "",
        *_partition(acc),
        *_served(acc),
        "",
        "| setting | t [s] | recall (states) | recall (cells) | IoU | beyond p95 [m] "
        "| IoU outer bound | IoU without network | partition: recall (cells) / IoU / beyond p95 [m] "
        "| beyond partition p95 [m] | uncut: IoU / beyond p95 [m] "
        "| first stage: IoU / beyond p95 [m] |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in acc["rows"]:
        partition = (
            f"{r['partition_recall_cells']:.4f} / {r['partition_iou']:.3f} / "
            f"{r['partition_beyond_p95_m']:.2f}"
            if "partition_iou" in r
            else "–"
        )
        lines.append(
            f"| {r['setting']} | {r['t']:.0f} | {r['recall_states']:.4f} | {r['recall_cells']:.4f} "
            f"| {r['iou']:.3f} | {r['beyond_p95_m']:.2f} | {r['outer_bound_iou']:.3f} "
            f"| {r.get('iou_without_network', float('nan')):.3f} | {partition} "
            f"| {r.get('beyond_partition_p95_m', float('nan')):.2f} "
            f"| {r.get('iou_uncut', float('nan')):.3f} / "
            f"{r.get('beyond_uncut_p95_m', float('nan')):.2f} "
            f"| {r.get('iou_first_stage', float('nan')):.3f} / "
            f"{r.get('beyond_first_stage_p95_m', float('nan')):.2f} |"
        )
    lines += [
        "",
        "| summary | value |",
        "| --- | ---: |",
        f"| min recall (states) | {s['min_recall_states']:.4f} |",
        f"| min recall (cells) | {s['min_recall_cells']:.4f} |",
        f"| mean IoU | {s['mean_iou']:.3f} |",
        f"| worst IoU | {s['worst_iou']:.3f} |",
        f"| mean IoU of the outer bound alone | {s['mean_iou_outer_bound_alone']:.3f} |",
        f"| mean IoU without the network | {s.get('mean_iou_without_network', float('nan')):.3f} |",
        f"| rows where the network cuts the set | {s.get('rows_where_the_network_cuts', '?')} of "
        f"{len(acc['rows'])} |",
        f"| beyond p95, worst setting [m] | {s['p95_beyond_m_max']:.2f} |",
        f"| beyond p95, mean [m] | {s['p95_beyond_m_mean']:.2f} |",
        f"| rows with beyond p95 over 1.5 m | {s.get('rows_beyond_over_target', '?')} of "
        f"{len(acc['rows'])} |",
        f"| uncut set (served until the refinement lands): mean (worst) IoU | "
        f"{s.get('mean_iou_uncut', float('nan')):.3f} "
        f"({s.get('worst_iou_uncut', float('nan')):.3f}) |",
        f"| uncut set: beyond p95, mean (worst) [m]; rows over 1.5 m | "
        f"{s.get('p95_beyond_m_mean_uncut', float('nan')):.2f} "
        f"({s.get('p95_beyond_m_max_uncut', float('nan')):.2f}); "
        f"{s.get('rows_beyond_over_target_uncut', '?')} |",
        f"| first stage's cut (served until the last lands): mean (worst) IoU | "
        f"{s.get('mean_iou_first_stage', float('nan')):.3f} "
        f"({s.get('worst_iou_first_stage', float('nan')):.3f}) |",
        f"| first stage's cut: beyond p95, mean (worst) [m]; rows over 1.5 m | "
        f"{s.get('p95_beyond_m_mean_first_stage', float('nan')):.2f} "
        f"({s.get('p95_beyond_m_max_first_stage', float('nan')):.2f}); "
        f"{s.get('rows_beyond_over_target_first_stage', '?')} |",
        f"| farthest reach beyond the outer bound (union of 0.025 s sweep polygons) [m] | "
        f"{s.get('beyond_outer_bound_max_m', float('nan')):.3f} |",
        f"| partition bound: min recall (cells) | "
        f"{s.get('min_recall_cells_partition', float('nan')):.4f} |",
        f"| partition bound: beyond p95, mean (worst) [m] | "
        f"{s.get('p95_beyond_m_mean_partition', float('nan')):.2f} "
        f"({s.get('p95_beyond_m_max_partition', float('nan')):.2f}) |",
        f"| service's tube beyond the partition bound, p95: mean (worst) [m] | "
        f"{s.get('beyond_partition_p95_m_mean', float('nan')):.2f} "
        f"({s.get('beyond_partition_p95_m_max', float('nan')):.2f}) |",
        "",
        "## Calibration",
        "",
        f"- delta = {cal['delta']:.4f} ({cal['method']}; {cal['samples']} reachable states over "
        f"{cal['parameter_settings']} random parameter settings).",
        f"- Guarantee: {cal['guarantee']} (confidence {cal['confidence']:.6f}).",
    ]
    if proj:
        lines.append(
            f"- Projection network level delta_W = {proj['delta']:.4f}, calibrated the same way on "
            f"{proj['calibration_samples']} reachable (s, x, y) of the true dynamics."
        )
    return "\n".join(lines) + "\n"


def _partition(acc: dict) -> list[str]:
    """How fine the partition reference is, when the card says."""
    ref = acc.get("partition_reference")
    if not ref:
        return []
    return [
        f"The partition reference: {ref['heading_bins']} final-heading bins{_waypoints(ref)}, "
        f"speed programmes on {ref['steps']} sub-intervals, polygons in "
        f"{ref.get('n_directions', 16)} support directions, instants {ref['instant_s']} s apart, "
        "each bin swept along its headings to the instants' midpoints (the last instant of a tube "
        "backwards in time only).",
        "",
    ]


def _waypoints(partition: dict) -> str:
    """How a partition's bins are split by waypoint headings, in words ("" if they are not)."""
    counts = partition.get("waypoint_bins") or []
    counts = [counts] if isinstance(counts, int) else list(counts)
    fractions = partition.get("waypoint_at") or []
    fractions = [fractions] if isinstance(fractions, int | float) else list(fractions)
    splits = [
        f"{count} by the heading at {fraction} of the time"
        for count, fraction in zip(counts, fractions, strict=False)
        if count > 1
    ]
    return (", each split into " + ", then ".join(splits) + " (waypoint bins)") if splits else ""


def _served(acc: dict) -> list[str]:
    """What the IoU and "beyond" columns measure: the set served once refined."""
    notch = acc.get("notch_cut") or {}
    if not notch.get("on"):
        return ["The service's tube here is the exact set as computed (no notch cut)."]
    stages = notch.get("stages") or [
        {"heading_bins": notch["bins"], "waypoint_bins": 1, "steps": notch["steps"]}
    ]

    def partition(stage: dict) -> str:
        directions = stage.get("n_directions", 16)
        return (
            f"{stage['heading_bins']} heading bins{_waypoints(stage)}, speed programmes on "
            f"{stage['steps']} sub-intervals, polygons in {directions} directions"
        )

    described = "; then ".join(partition(stage) for stage in stages)
    return [
        "The service's tube here is the set it serves once refined (`FRT_FRT_NOTCH_CUT`, on by "
        "default): the exact set, where the car may turn round, cut to a speed-coupled partition "
        f"(`reach.notch.NOTCH_STAGES`: {described}), which a worker computes once the uncut "
        "set is ready, one stage after the other. The last columns are the sets the service "
        "answers from until then: the uncut set, and the first stage's cut."
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--card", type=Path, default=ROOT / "models" / "frt_unicycle.json")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "model_accuracy.md")
    args = parser.parse_args()
    args.out.write_text(render(json.loads(args.card.read_text())))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
