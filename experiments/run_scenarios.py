"""The case studies in closed loop through the real service, with confidence on and off.

Paper, section "Case Studies". One run: every 0.5 s (nuScenes' 2 Hz, the paper's prediction
step) the human is observed and the stand-in predictor's Gaussian sent to the service
(``POST /v1/agents/{id}/observations``, which scores the observed action, updates beta and the FRT);
every 0.1 s, until it first detects a conflict, the ego planner asks whether its 3 s constant-speed
plan enters C (``POST /v1/agents/{id}/collision-check``, ``mode: "tube"``). The ground truth (do
the two cars' footprints ever overlap?) is evaluated every 0.02 s.

Confidence on: beta_low = 0.03 (the paper's). Confidence off: beta fixed at 1, done with the
per-agent setting beta_low = 1 - 1e-6 (the API requires beta_low < 1): both hypotheses are then
within 1e-6 of 1, so beta stays in [1 - 1e-6, 1] and the control bounds are those of beta = 1 to
5e-7 relative; the filter still runs, it just cannot change anything. Every other setting (gamma
= 0.075, R_col = 1.5 m, epsilon the server's) is the same in both runs.

``python -m experiments.run_scenarios [--url URL | --model PATH]`` runs both scenes and writes
``results/scenarios.json``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import uuid
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from frt_client import FRTError

from experiments.planner import PLAN_DT_S, Detection, EgoCar
from experiments.predictor import (
    STEP_S,
    BimodalPredictor,
    GaussianPrediction,
    MixturePrediction,
    Observation,
    StopPredictor,
    observed_action,
)
from experiments.scenes import Scene, Trajectory, footprint, footprints_overlap, scene
from experiments.server import DEADLINE_MS, wait_exact

BETA_LOW = 0.03
GAMMA = 0.075
COLLISION_RADIUS_M = 1.5
#: "Confidence off": the closest to beta_low = 1 that the API accepts (it requires beta_low < 1).
BETA_LOW_OFF = 1.0 - 1e-6
#: Ground-truth collision test step (s).
TRUTH_DT_S = 0.02
#: Paper, "Case Studies" (with / without confidence); None = "a crash" (no stop).
PAPER = {
    "uturn": {
        "on": {"detection_distance_m": 52.46, "deceleration_mps2": -4.2, "stop_time_s": 4.9,
               "collision": False},
        "off": {"detection_distance_m": 10.49, "deceleration_mps2": -10.0, "stop_time_s": 2.1,
                "collision": True},
    },
    "stop_sign": {
        "on": {"detection_distance_m": 47.8, "deceleration_mps2": -4.61, "stop_time_s": 4.55,
               "collision": False},
        "off": {"detection_distance_m": 5.83, "deceleration_mps2": None, "stop_time_s": None,
                "collision": True},
    },
}  # fmt: skip


def predictor_for(sc: Scene) -> StopPredictor:
    """The stand-in predictor of a scene (see :mod:`experiments.predictor`).

    U-turn: "remain at rest", catching on after a quarter turn. Stop sign: "stop at the stop
    line", catching on once the car has rolled 6 m (well past its line).
    """
    if sc.name == "uturn":
        return StopPredictor(stop_line=sc.human_stop_line, catch_on_heading_rad=math.pi / 2)
    return StopPredictor(stop_line=sc.human_stop_line, catch_on_distance_m=6.0)


def agent_config(
    confidence: bool,
    beta_low: float = BETA_LOW,
    gamma: float = GAMMA,
    bounds_rule: str | None = None,
) -> dict:
    """Per-agent settings (API.md, Observation ``config``) for confidence on or off, with the
    confidence-to-bounds rule ``bounds_rule`` (None: the server's)."""
    config: dict[str, Any] = {
        "beta_low": beta_low if confidence else BETA_LOW_OFF,
        "gamma": gamma,
        "collision_radius": COLLISION_RADIUS_M,
    }
    if bounds_rule is not None:
        config["bounds_rule"] = bounds_rule
    return config


@dataclass
class Step:
    """One observation: what the service answered and where everybody was."""

    t: float
    beta: float
    belief_low: float
    prediction: str
    frt_version: int
    human: tuple[float, float, float, float]
    ego_x: float
    ego_speed: float
    #: A multi-modal prediction's mode posteriors (in the order given), else None.
    mode_posteriors: tuple[float, ...] | None = None


@dataclass
class ScenarioRun:
    """The outcome of one scene with confidence on or off."""

    scene: str
    confidence: bool
    beta_low: float
    gamma: float
    epsilon: float | None
    detection: Detection | None
    collision: bool
    collision_time_s: float | None
    min_centre_distance_m: float
    ego_stopped_at_s: float | None
    ego_stop_past_line_m: float | None
    conservative_answers: int
    #: Whether the detection came from a conservative answer (none is expected: every check waits
    #: for the exact set).
    detected_on_conservative: bool = False
    steps: list[Step] = field(default_factory=list)
    #: GeoJSON of the tube's K and C after each observation, keyed by its time.
    contours: dict[float, dict[str, Any]] = field(default_factory=dict, repr=False)

    def summary(self) -> dict[str, Any]:
        """The record of ``results/scenarios.json``."""
        d = self.detection
        return {
            "detection_distance_m": None if d is None else round(d.distance_to_stop_line_m, 2),
            "deceleration_mps2": None if d is None else round(d.deceleration_mps2, 2),
            "stop_time_s": None if d is None else round(d.stop_time_s, 2),
            "collision": self.collision,
            "detection_time_s": None if d is None else round(d.time_s, 2),
            "stops_before_line": None if d is None else d.can_stop_before_line,
            "beta_at_detection": _beta_at(self.steps, d.time_s) if d else None,
            "ego_stop_past_line_m": _round(self.ego_stop_past_line_m),
            "collision_time_s": _round(self.collision_time_s),
            "min_centre_distance_m": round(self.min_centre_distance_m, 2),
            "conservative_answers": self.conservative_answers,
            "detected_on_conservative_set": self.detected_on_conservative,
            "beta_low": self.beta_low,
            "gamma": self.gamma,
            "epsilon": self.epsilon,
            "collision_radius_m": COLLISION_RADIUS_M,
        }


def _round(value: float | None, ndigits: int = 2) -> float | None:
    return None if value is None else round(value, ndigits)


def _beta_at(steps: list[Step], t: float) -> float | None:
    before = [s for s in steps if s.t <= t + 1e-9]
    return round(before[-1].beta, 4) if before else None


def _truth(ego: EgoCar, human: Trajectory, t: float) -> tuple[bool, float]:
    """Ground truth at time t: do the footprints overlap, and how far apart are the centres."""
    h = human.state_at(t)
    gap = math.hypot(h[0] - ego.x, h[1] - ego.y)
    if gap > 6.0:  # farther than two half-diagonals: cannot touch
        return False, gap
    hit = footprints_overlap(footprint(ego.x, ego.y, 0.0), footprint(h[0], h[1], h[2]))
    return hit, gap


def run_scenario(
    client: Any,
    sc: Scene,
    confidence: bool,
    *,
    beta_low: float = BETA_LOW,
    gamma: float = GAMMA,
    predictor: StopPredictor | BimodalPredictor | None = None,
    bounds_rule: str | None = None,
    duration_s: float | None = None,
    keep_contours: bool = True,
    deadline_ms: float = DEADLINE_MS,
) -> ScenarioRun:
    """Drive one scene through the service (``client`` is an ``frt_client.FRTClient``).

    The loop ends at ``duration_s`` (default: the scene's) or once the ego has stopped: from then on
    the ego stands still and the human's trajectory is scripted, so the ground truth for the rest
    of the scene needs no service.
    """
    predictor = predictor or predictor_for(sc)
    human = sc.human_trajectory()
    duration = sc.duration_s if duration_s is None else min(duration_s, sc.duration_s)
    ego = EgoCar(x=sc.ego_start_x, y=sc.ego_y, speed=sc.ego_speed_mps, stop_line_x=sc.stop_line_x)
    agent_id = f"{sc.name}-{'on' if confidence else 'off'}-{uuid.uuid4().hex[:8]}"
    config = agent_config(confidence, beta_low, gamma, bounds_rule)
    run = ScenarioRun(
        scene=sc.name,
        confidence=confidence,
        beta_low=config["beta_low"],
        gamma=gamma,
        epsilon=None,
        detection=None,
        collision=False,
        collision_time_s=None,
        min_centre_distance_m=math.inf,
        ego_stopped_at_s=None,
        ego_stop_past_line_m=None,
        conservative_answers=0,
    )
    history: list[Observation] = []
    obs_every = round(STEP_S / PLAN_DT_S)
    substeps = round(PLAN_DT_S / TRUTH_DT_S)
    n_ticks = round(duration / PLAN_DT_S)
    prediction: GaussianPrediction | MixturePrediction | None = None
    try:
        for k in range(n_ticks + 1):
            t = k * PLAN_DT_S
            if k % obs_every == 0:
                s = human.state_at(t)
                history.append(Observation(t, *map(float, s)))
                prediction = predictor.predict(history)
                action = observed_action(history[-2], history[-1]) if len(history) > 1 else None
                answer = client.observe(
                    agent_id,
                    timestamp=t,
                    state=history[-1].state,
                    prediction=prediction.payload(),
                    observed_action=action,
                    config=config if len(history) == 1 else None,
                )
                wait_exact(client, agent_id)
                run.steps.append(
                    Step(
                        t=t,
                        beta=answer.beta,
                        belief_low=answer.belief.beta_low,
                        prediction=prediction.mode,
                        frt_version=answer.frt_version,
                        human=tuple(float(v) for v in s),
                        ego_x=ego.x,
                        ego_speed=ego.speed,
                        mode_posteriors=(
                            tuple(m.posterior for m in answer.modes) if answer.modes else None
                        ),
                    )
                )
                if keep_contours:
                    c = client.contours(agent_id, include=("K", "C"), tube=True)
                    run.conservative_answers += int(c.conservative)
                    run.contours[round(t, 3)] = {"K": c.tube.K, "C": c.tube.C}
            if ego.detection is None:
                check = client.collision_check(
                    agent_id,
                    ego.nominal_trajectory(t),
                    mode="tube",
                    collision_radius=COLLISION_RADIUS_M,
                    deadline_ms=deadline_ms,
                )
                run.conservative_answers += int(check.conservative)
                if check.collision:
                    ego.on_conflict(t)
                    run.detected_on_conservative = bool(check.conservative)
            for j in range(substeps):
                tj = t + j * TRUTH_DT_S
                hit, gap = _truth(ego, human, tj)
                run.min_centre_distance_m = min(run.min_centre_distance_m, gap)
                if hit and not run.collision:
                    run.collision, run.collision_time_s = True, tj
                ego.advance(tj, TRUTH_DT_S)
            if ego.stopped_at_s is not None:
                break
        if run.epsilon is None:
            run.epsilon = client.get_agent(agent_id).config.epsilon
    finally:
        with contextlib.suppress(FRTError):  # best effort: the agent expires anyway
            client.delete_agent(agent_id)
    run.detection = ego.detection
    # The ego now stands still (or the run hit its duration): finish the ground truth locally.
    if ego.stopped_at_s is not None:
        run.ego_stopped_at_s = ego.stopped_at_s
        run.ego_stop_past_line_m = -ego.distance_to_stop_line
        for tj in np.arange(ego.stopped_at_s, duration + 1e-9, TRUTH_DT_S):
            hit, gap = _truth(ego, human, float(tj))
            run.min_centre_distance_m = min(run.min_centre_distance_m, gap)
            if hit and not run.collision:
                run.collision, run.collision_time_s = True, float(tj)
    return run


def bimodal_predictor(sc: Scene) -> BimodalPredictor:
    """The U-turn's multi-modal stand-in: the single-Gaussian stand-in ("keeps going straight",
    0.9) and the U-turn on the scene's radius (0.1)."""
    radius = sc.driver.turn_radius_m
    assert radius is not None, "the U-turn scene turns on a radius"
    return BimodalPredictor(predictor_for(sc), turn_radius_m=radius, w_straight=0.9)


#: Rules :func:`run_all_scenes` runs with confidence on beside the server's.
COMPARED_RULES: tuple[str, ...] = ("paper", "uniform_mixture")
#: The scene each run of :func:`run_all_scenes` plays.
RUN_SCENES = {"uturn": "uturn", "uturn_bimodal": "uturn", "stop_sign": "stop_sign"}


def run_all_scenes(
    client: Any, rules: Sequence[str] = COMPARED_RULES, **kwargs: Any
) -> dict[str, dict[str, ScenarioRun]]:
    """Both scenes, confidence on and off with the server's bounds rule: ``{scene: {"on": run,
    "off": run}}``, plus confidence on with each of ``rules`` (``"on, <rule>"``); and the U-turn
    with the bimodal stand-in predictor (``uturn_bimodal``), the same runs."""
    out: dict[str, dict[str, ScenarioRun]] = {}
    for name in ("uturn", "stop_sign"):
        sc = scene(name)
        predictors: dict[str, StopPredictor | BimodalPredictor | None] = {name: None}
        if name == "uturn":
            predictors["uturn_bimodal"] = bimodal_predictor(sc)
        for run_name, predictor in predictors.items():
            runs = {
                "on": run_scenario(client, sc, True, predictor=predictor, **kwargs),
                "off": run_scenario(client, sc, False, predictor=predictor, **kwargs),
            }
            for rule in rules:
                runs[f"on, {rule}"] = run_scenario(
                    client, sc, True, predictor=predictor, bounds_rule=rule, **kwargs
                )
            out[run_name] = runs
    return out


def results_json(runs: dict[str, dict[str, ScenarioRun]], model: dict[str, Any]) -> dict:
    """The content of ``results/scenarios.json``."""
    return {
        "paper": "Nakamura & Bansal, Online Update of Safety Assurances Using Confidence-Based "
        "Predictions, section Case Studies",
        "model": model,
        "scenarios": {
            name: {mode: run.summary() for mode, run in pair.items()} for name, pair in runs.items()
        },
        "paper_figures": PAPER,
    }


def _fmt(value: Any, unit: str = "") -> str:
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return f"{value:.2f}{unit}"


def table(runs: dict[str, dict[str, ScenarioRun]]) -> str:
    """A Markdown table: ours next to the paper's, per scene and confidence on/off."""
    head = (
        "| scene | confidence | detection distance to stop line (m) | deceleration (m/s²) "
        "| time to stop (s) | collision | paper: detection / decel. / time / collision |\n"
        "| --- | --- | --- | --- | --- | --- | --- |\n"
    )
    rows = []
    for name, pair in runs.items():
        for mode in pair:
            s = pair[mode].summary()
            p = PAPER.get(name, {}).get(mode)
            paper = "—"  # the paper has no multi-modal predictor
            if p is not None:
                paper = (
                    f"{p['detection_distance_m']} m / "
                    + (
                        f"{p['deceleration_mps2']} / {p['stop_time_s']} s"
                        if p["stop_time_s"]
                        else "—"
                    )
                    + f" / {'crash' if p['collision'] else 'no'}"
                )
            rows.append(
                f"| {name} | {mode} | {_fmt(s['detection_distance_m'])} "
                f"| {_fmt(s['deceleration_mps2'])} | {_fmt(s['stop_time_s'])} "
                f"| {_fmt(s['collision'])} | {paper} |"
            )
    return head + "\n".join(rows) + "\n"


def save_runs(runs: dict[str, dict[str, ScenarioRun]], model: dict[str, Any], out: Path) -> None:
    """Write ``scenarios.json`` and the per-step traces (``scenario_traces.json``) into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "scenarios.json").write_text(json.dumps(results_json(runs, model), indent=2) + "\n")
    traces = {
        name: {mode: [asdict(s) for s in run.steps] for mode, run in pair.items()}
        for name, pair in runs.items()
    }
    (out / "scenario_traces.json").write_text(json.dumps(traces) + "\n")


def main(argv: list[str] | None = None) -> None:
    from experiments.server import DEFAULT_MODEL, ROOT, connect

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--url", help="a running service (default: start one locally)")
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    parser.add_argument("--out", type=Path, default=ROOT / "results")
    args = parser.parse_args(argv)
    with connect(args.url, args.model) as client:
        runs = run_all_scenes(client)
        card = client.model()
        save_runs(runs, {"name": card.name, "delta": card.delta}, args.out)
    print(table(runs))


if __name__ == "__main__":
    main()
