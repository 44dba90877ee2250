"""``python -m experiments.run_all`` (``make scenarios``): every experiment of issue 8, end to end.

Starts the service on ``--model`` (default ``models/frt_unicycle.onnx``) on a free loopback port
unless ``--url`` is given, then, through the client SDK only:

1. the two case studies with confidence on and off -> ``results/scenarios.json``, a table;
2. beta over time for several beta_low (both scenes) -> ``results/beta_traces.json``;
3. the FRT for several gamma with the same prediction (the U-turn at its detection);
4. the sensitivity of the outcome to the ego's arrival time -> ``results/timing.json``;
5. the Argoverse 2 replay -> ``results/av2.json``, a table;
6. the figures (``results/*.png``; the key ones copied to ``docs/``) and
   ``results/summary.md`` with both tables.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from experiments import av2, plots, sweeps, timing
from experiments.predictor import Observation
from experiments.run_scenarios import RUN_SCENES, predictor_for, run_all_scenes, save_runs
from experiments.run_scenarios import table as scenario_table
from experiments.scenes import scene
from experiments.server import DEFAULT_MODEL, ROOT, connect

#: Figures copied into docs/ for docs/scenarios.md.
DOC_FIGURES = {
    "scenario_uturn.png": "scenarios_uturn.png",
    "scenario_stop_sign.png": "scenarios_stop_sign.png",
    "beta_low.png": "scenarios_beta_low.png",
    "gamma.png": "scenarios_gamma.png",
    "ego_motion.png": "scenarios_ego_motion.png",
    "av2.png": "scenarios_av2.png",
}


def _log(message: str, start: float) -> None:
    print(f"[{time.monotonic() - start:6.1f} s] {message}", flush=True)


def gamma_inputs(run: Any) -> tuple[tuple[float, float, float, float], Any, float]:
    """State, prediction and beta of the observation whose FRT triggered ``run``'s detection."""
    sc = scene(run.scene)
    human = sc.human_trajectory()
    t_det = run.detection.time_s if run.detection else sc.duration_s / 2
    steps = [s for s in run.steps if s.t <= t_det + 1e-9]
    history = [Observation(s.t, *map(float, human.state_at(s.t))) for s in steps]
    prediction = predictor_for(sc).predict(history)
    return history[-1].state, prediction, steps[-1].beta


def timing_table(rows: dict[str, list[timing.TimingRow]], chosen: dict[str, float]) -> str:
    lines = [
        "| scene | ego reaches its stop line at (s) | with confidence | without confidence |",
        "| --- | --- | --- | --- |",
    ]

    def cell(collision: bool, d: float | None) -> str:
        if d is None:
            det = "no detection"
        elif round(d, 1) >= 0.0:
            det = f"detects {abs(d):.1f} m before its line"
        else:
            det = f"detects {-d:.1f} m past its line"
        return f"{det}, {'**collision**' if collision else 'safe'}"

    for name, rs in rows.items():
        for r in rs:
            mark = " (chosen)" if abs(r.arrival_s - chosen[name]) < 1e-6 else ""
            lines.append(
                f"| {name} | {r.arrival_s:.2f}{mark} | {cell(r.on_collision, r.on_detection_m)} "
                f"| {cell(r.off_collision, r.off_detection_m)} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Run every experiment of issue 8.")
    parser.add_argument("--url", help="a running service (default: start one locally)")
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    parser.add_argument("--out", type=Path, default=ROOT / "results")
    parser.add_argument("--docs", type=Path, default=ROOT / "docs")
    parser.add_argument("--skip-timing", action="store_true", help="skip the arrival-time sweep")
    parser.add_argument("--skip-av2", action="store_true", help="skip the Argoverse 2 replay")
    args = parser.parse_args(argv)
    start = time.monotonic()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    scenes = {name: scene(name) for name in ("uturn", "stop_sign")}
    figures: list[Path] = []
    with connect(args.url, args.model) as client:
        card = client.model()
        model = {"name": card.name, "delta": card.delta, "semantics": card.semantics}
        _log(f"service ready, model {card.name}", start)

        runs = run_all_scenes(client)
        save_runs(runs, model, out)
        scen_table = scenario_table(runs)
        _log("case studies done", start)
        print(scen_table, flush=True)

        traces = [t for sc in scenes.values() for t in sweeps.beta_traces(client, sc)]
        (out / "beta_traces.json").write_text(json.dumps([asdict(t) for t in traces]) + "\n")
        state, prediction, beta = gamma_inputs(runs["uturn"]["on"])
        gamma_sets = sweeps.gamma_frts(client, state, prediction, beta)
        _log("beta_low and gamma sweeps done", start)

        timing_md = ""
        if not args.skip_timing:
            chosen = {n: timing.arrival_for_start(sc.ego_start_x) for n, sc in scenes.items()}
            rows = {n: timing.sweep(client, n, timing.default_arrivals(chosen[n])) for n in scenes}
            windows = {n: timing.window(r) for n, r in rows.items()}
            (out / "timing.json").write_text(
                json.dumps(
                    {
                        "chosen_arrival_s": chosen,
                        "window_s": windows,
                        "rows": {n: [asdict(r) for r in rs] for n, rs in rows.items()},
                    },
                    indent=2,
                )
                + "\n"
            )
            timing_md = timing_table(rows, chosen)
            _log(f"arrival-time sweep done: windows {windows}", start)

        av2_md = ""
        if not args.skip_av2:
            result = av2.run_av2(client)
            av2.save(result, model, out)
            av2_md = av2.table(result)
            _log("Argoverse 2 replay done", start)
            print(av2_md, flush=True)

    for name, sc in scenes.items():
        pair = runs[name]
        figures.append(
            plots.figure_detection(
                sc, pair["on"], pair["off"], out / f"scenario_{name}.png", card.name
            )
        )
    figures.append(plots.figure_beta(traces, scenes, out / "beta_low.png"))
    figures.append(plots.figure_gamma(gamma_sets, scenes["uturn"], state, out / "gamma.png"))
    run_scenes = {name: scene(RUN_SCENES[name]) for name in runs}
    figures.append(plots.figure_speeds(runs, run_scenes, out / "ego_motion.png"))
    if not args.skip_av2:
        figures.append(plots.figure_av2(result, av2.lane_map(), av2.ATTRIBUTION, out / "av2.png"))
    args.docs.mkdir(parents=True, exist_ok=True)
    for fig in figures:
        if fig.name in DOC_FIGURES:
            shutil.copyfile(fig, args.docs / DOC_FIGURES[fig.name])
    summary = (
        f"# Results (model {card.name})\n\n## Case studies\n\n{scen_table}\n"
        + (f"## Arrival-time sensitivity\n\n{timing_md}\n" if timing_md else "")
        + (f"## Argoverse 2 replay\n\n{av2_md}\n{av2.ATTRIBUTION}\n" if av2_md else "")
    )
    (out / "summary.md").write_text(summary)
    if timing_md:
        print(timing_md)
    _log(f"done; figures in {out}, key ones copied to {args.docs}", start)


if __name__ == "__main__":
    main()
