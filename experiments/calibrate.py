"""``python -m experiments.calibrate`` (``make calibrate DATA=...``): choose gamma on recorded tracks.

Method (docs/coverage.md, "Calibrating gamma"):

1. the tracks of ``--data`` (``experiments.track_files``: the Argoverse 2 scenario, or the
   documented CSV format) are split into two halves, alternately by sorted id (``av2.folds``): the
   calibration half and the held-out half;
2. the predictor is the Argoverse 2 replay's (``experiments.av2``): constant velocity and turn rate,
   Gaussian, with a diagonal covariance per 0.5 s step fitted on the calibration half only, and
   used for both halves (the held-out half takes no part in any choice);
3. every track is replayed through the real service (a local ``uvicorn`` on ``--model``, or
   ``--url``) for every gamma of ``--gammas``, with confidence on for each beta_low of
   ``--beta-lows`` and off (beta fixed at 1), exactly as ``make scenarios`` replays the Argoverse 2
   tracks: observed every 0.5 s while 3 s of future remain, each observation's next 30 actual
   positions checked against its sets;
4. coverage is the share of those positions inside C = K ⊕ R_col at each position's time (the
   tube up to it: what a time-indexed check and the online audit test; ``--coverage tube`` uses
   the whole-horizon C instead); area is the mean area of the whole-horizon C;
5. per confidence setting, gamma is the smallest of the grid whose calibration-half coverage
   reaches ``--target``; of the settings that reach it, the one whose chosen gamma gives the
   smallest mean area of C on the calibration half. If none reaches it, each setting's gamma is
   the smallest reaching its own highest calibration-half coverage, the setting chosen is the one
   with the highest (then the smallest area), and the result says ``target_reached: false``;
6. the held-out half's coverage and mean area at that choice are reported, and the choice is
   written as a settings profile (``profiles/<name>.json``, ``FRT_PROFILE=<name>``), with the
   figures in ``results/calibration_<name>.json`` and ``.md`` and the plot of coverage against
   area for the whole grid in ``docs/calibration_<name>.png``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from experiments import av2, track_files
from experiments.run_scenarios import BETA_LOW, BETA_LOW_OFF, COLLISION_RADIUS_M
from experiments.server import DEFAULT_MODEL, ROOT, connect
from service.runtime.profiles import PROFILES_DIR, write_profile

#: The gamma grid: 0.05 to 0.99.
GAMMAS: tuple[float, ...] = (0.05, 0.075, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99)
TARGET = 0.99
#: Targets the report also shows the choice for, from the same replays.
OTHER_TARGETS: tuple[float, ...] = (0.95, 0.98)
DEFAULT_DATA = av2.DATA_DIR / av2.SCENARIO_FILE
#: Tracks replayed at once (each its own agent): the service overlaps their exact sets.
CONCURRENT_TRACKS = 4


@dataclass(frozen=True)
class Point:
    """Coverage and area of one (confidence setting, gamma) on one half."""

    #: "off" (beta fixed at 1), or "beta_low=<value>" (confidence on).
    confidence: str
    gamma: float
    half: str
    observations: int
    positions: int
    coverage_c: float
    coverage_c_tube: float
    coverage_k: float
    mean_area_c_m2: float
    mean_beta: float


def halves(tracks: Sequence[av2.Track]) -> dict[str, list[av2.Track]]:
    """The calibration and held-out halves (``av2.folds``: alternately by sorted id)."""
    first, second = av2.folds(tracks)
    return {"calibration": first, "held_out": second}


def summarise(
    replays: dict[tuple[str, float], av2.Replay], split: dict[str, list[av2.Track]]
) -> list[Point]:
    """Per (confidence, gamma) and half: coverage of the future positions (each observation's 30
    weigh the same) and mean area of C."""
    half_of = {t.track_id: name for name, tracks in split.items() for t in tracks}
    out = []
    for (confidence, gamma), replay in sorted(replays.items()):
        for half in split:
            rows = [o for o in replay.observations if half_of.get(o.track_id) == half]
            n = len(rows)

            def mean(key: str, rows: list[av2.ObservationResult] = rows) -> float:
                return float(np.mean([getattr(o, key) for o in rows])) if rows else math.nan

            out.append(
                Point(
                    confidence=confidence,
                    gamma=gamma,
                    half=half,
                    observations=n,
                    positions=n * av2.HORIZON_SAMPLES,
                    coverage_c=mean("in_c_time"),
                    coverage_c_tube=mean("in_c"),
                    coverage_k=mean("in_k_time"),
                    mean_area_c_m2=mean("area_c"),
                    mean_beta=mean("beta"),
                )
            )
    return out


def coverage_of(p: Point, kind: str) -> float:
    return p.coverage_c if kind == "time_indexed" else p.coverage_c_tube


def smallest_gamma(
    points: Sequence[Point], confidence: str, target: float, kind: str = "time_indexed"
) -> float | None:
    """The smallest gamma whose calibration-half coverage reaches ``target`` (None if none)."""
    ok = [
        p.gamma
        for p in points
        if p.confidence == confidence
        and p.half == "calibration"
        and coverage_of(p, kind) >= target - 1e-12
    ]
    return min(ok) if ok else None


def point(points: Sequence[Point], confidence: str, gamma: float, half: str) -> Point:
    return next(p for p in points if (p.confidence, p.gamma, p.half) == (confidence, gamma, half))


def choose(points: Sequence[Point], target: float, kind: str = "time_indexed") -> dict[str, Any]:
    """Per confidence setting the smallest gamma reaching ``target`` on the calibration half (or
    its highest coverage, if it never does), and the setting chosen (see the module)."""
    per: dict[str, Any] = {}
    for confidence in sorted({p.confidence for p in points}):
        gamma = smallest_gamma(points, confidence, target, kind)
        reached = gamma is not None
        if gamma is None:
            best = max(
                coverage_of(p, kind)
                for p in points
                if p.confidence == confidence and p.half == "calibration"
            )
            gamma = smallest_gamma(points, confidence, best, kind)
        assert gamma is not None
        per[confidence] = {
            "gamma": gamma,
            "reached": reached,
            "calibration": asdict(point(points, confidence, gamma, "calibration")),
            "held_out": asdict(point(points, confidence, gamma, "held_out")),
        }
    reached = [c for c, v in per.items() if v["reached"]]

    def area(c: str) -> float:
        return float(per[c]["calibration"]["mean_area_c_m2"])

    if reached:
        chosen = min(reached, key=area)
    else:
        chosen = min(
            per, key=lambda c: (-coverage_of(Point(**per[c]["calibration"]), kind), area(c))
        )
    return {
        "target": target,
        "coverage": kind,
        "per_confidence": per,
        "chosen": chosen,
        "target_reached": bool(reached),
    }


def setting_label(beta_low: float | None) -> str:
    """A confidence setting's name: "off" for None (beta fixed at 1), else "beta_low=<value>"."""
    return "off" if beta_low is None else f"beta_low={beta_low:g}"


def sweep(
    client: Any,
    tracks: Sequence[av2.Track],
    sigma: np.ndarray,
    gammas: Sequence[float],
    beta_lows: Sequence[float | None],
    log: Any = print,
) -> dict[tuple[str, float], av2.Replay]:
    """Replay every track for every gamma and confidence setting (``av2.replay_track``; a
    beta_low of None is confidence off), ``CONCURRENT_TRACKS`` tracks at once."""
    v_max = float(client.model().ranges.get("v_start", [0.0, math.inf])[1])
    replays: dict[tuple[str, float], av2.Replay] = {}
    with ThreadPoolExecutor(CONCURRENT_TRACKS) as pool:
        for beta_low in beta_lows:
            on = beta_low is not None
            label = setting_label(beta_low)
            for gamma in gammas:
                replay = av2.Replay(confidence=on)
                parts = [av2.Replay(confidence=on) for _ in tracks]
                jobs = [
                    pool.submit(
                        av2.replay_track,
                        client,
                        track,
                        sigma,
                        on,
                        v_max,
                        part,
                        None,
                        gamma=gamma,
                        beta_low=beta_low,
                    )
                    for track, part in zip(tracks, parts, strict=True)
                ]
                for job in jobs:
                    job.result()
                for part in parts:  # in track order, whatever order they finished in
                    replay.observations += part.observations
                    replay.skipped_out_of_range += part.skipped_out_of_range
                replays[(label, gamma)] = replay
                log(f"{label}, gamma {gamma:g}: {len(replay.observations)} observations")
    return replays


def table(points: Sequence[Point], choice: dict[str, Any]) -> str:
    """Markdown: the choice per confidence setting with its held-out figures."""
    kind = "time-indexed" if choice["coverage"] == "time_indexed" else "whole-horizon"
    rows = [
        f"Target: {choice['target']:.1%} of actual future positions inside C ({kind}).",
        "",
        "| confidence | γ (smallest reaching the target on the calibration half) "
        "| calibration: coverage "
        "| calibration: mean area of C (m²) | held-out: coverage | held-out: mean area of C (m²) "
        "| held-out: observations |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    if not choice["target_reached"]:
        rows[0] += (
            " **Not reached on the calibration half by any γ of the grid**: each setting's γ is "
            "the smallest reaching its highest coverage."
        )
    for confidence, v in choice["per_confidence"].items():
        mark = " (chosen)" if confidence == choice["chosen"] else ""
        c, h = v["calibration"], v["held_out"]
        flag = "" if v["reached"] else " (target not reached)"
        rows.append(
            f"| {confidence}{mark} | {v['gamma']:g}{flag} | {coverage_of(Point(**c), choice['coverage']):.2%} "
            f"| {c['mean_area_c_m2']:.1f} | {coverage_of(Point(**h), choice['coverage']):.2%} "
            f"| {h['mean_area_c_m2']:.1f} | {h['observations']} |"
        )
    return "\n".join(rows) + "\n"


def grid_table(points: Sequence[Point]) -> str:
    """Markdown: every (confidence, gamma, half)."""
    rows = [
        "| confidence | γ | half | in C (time-indexed) | in C (whole horizon) | in K (time-indexed) "
        "| mean area of C (m²) | mean β |",
        "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for p in points:
        rows.append(
            f"| {p.confidence} | {p.gamma:g} | {p.half} | {p.coverage_c:.2%} "
            f"| {p.coverage_c_tube:.2%} | {p.coverage_k:.2%} | {p.mean_area_c_m2:.1f} "
            f"| {p.mean_beta:.3f} |"
        )
    return "\n".join(rows) + "\n"


def plot(points: Sequence[Point], choice: dict[str, Any], out: Path, title: str) -> Path:
    """Coverage against mean area of C over the gamma grid, per confidence setting, both halves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kind = choice["coverage"]
    fig, ax = plt.subplots(figsize=(7.5, 5.0))
    labels = sorted({p.confidence for p in points}, key=lambda c: (c == "off", c))
    colours = ["tab:blue", "tab:green", "tab:purple", "tab:red", "tab:brown"]
    styles = {
        c: ("tab:orange", "without confidence")
        if c == "off"
        else (colours[i % len(colours)], f"with confidence, {c.replace('beta_low', 'β_low')}")
        for i, c in enumerate(labels)
    }
    for confidence, (colour, label) in styles.items():
        for half, line in (("calibration", "-"), ("held_out", "--")):
            ps = sorted(
                (p for p in points if p.confidence == confidence and p.half == half),
                key=lambda p: p.gamma,
            )
            if not ps:
                continue
            xs = [p.mean_area_c_m2 for p in ps]
            ys = [coverage_of(p, kind) for p in ps]
            ax.plot(xs, ys, line, marker="o", ms=3, color=colour,
                    label=f"{label}, {half.replace('_', '-')} half")  # fmt: skip
            if half == "calibration":
                for p, x, y in zip(ps, xs, ys, strict=True):
                    ax.annotate(f"{p.gamma:g}", (x, y), fontsize=6, xytext=(2, -8),
                                textcoords="offset points", color=colour)  # fmt: skip
    ax.axhline(choice["target"], color="grey", lw=0.8, ls=":", label="target")
    ax.set_xlabel("mean area of C over the horizon (m²)")
    ax.set_ylabel(
        "future positions inside C" + (" (time-indexed)" if kind == "time_indexed" else "")
    )
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=130)
    plt.close(fig)
    return out


def calibrate(
    client: Any,
    tracks: Sequence[av2.Track],
    gammas: Sequence[float] = GAMMAS,
    target: float = TARGET,
    beta_lows: Sequence[float] = (BETA_LOW,),
    kind: str = "time_indexed",
    log: Any = print,
) -> dict[str, Any]:
    """Split, fit the predictor on the calibration half, sweep, choose (see the module)."""
    split = halves(tracks)
    if not split["calibration"] or not split["held_out"]:
        raise ValueError("need at least two tracks (one per half)")
    sigma = av2.fit_sigma(split["calibration"])
    replays = sweep(client, tracks, sigma, gammas, [*beta_lows, None], log)
    points = summarise(replays, split)
    choice = choose(points, target, kind)
    chosen = choice["chosen"]
    calibration_ids = {t.track_id for t in split["calibration"]}
    key = "in_c_time" if kind == "time_indexed" else "in_c"
    misses = [
        {"track_id": o.track_id, "t": o.t, "speed": round(o.speed, 3), "in_c": getattr(o, key)}
        for o in replays[(chosen, choice["per_confidence"][chosen]["gamma"])].observations
        if o.track_id in calibration_ids and getattr(o, key) < 1.0
    ]
    return {
        "misses_at_choice_calibration_half": misses,
        "split": {name: [t.track_id for t in ts] for name, ts in split.items()},
        "sigma": sigma.tolist(),
        "beta_lows": list(beta_lows),
        "points": points,
        "choice": choice,
        "skipped_out_of_range": {
            f"{c}/{g:g}": r.skipped_out_of_range for (c, g), r in replays.items()
        },
    }


def profile_settings(result: dict[str, Any]) -> dict[str, Any]:
    """The server settings of the choice: gamma and beta_low (next to 1 for confidence off: beta
    stays at 1, as ``agent_config(False)``)."""
    chosen = result["choice"]["chosen"]
    beta_low = BETA_LOW_OFF if chosen == "off" else float(chosen.split("=", 1)[1])
    return {
        "gamma": result["choice"]["per_confidence"][chosen]["gamma"],
        "beta_low": beta_low,
        "collision_radius": COLLISION_RADIUS_M,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Choose gamma on recorded tracks.")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--target", type=float, default=TARGET)
    parser.add_argument("--profile", default="calibrated", help="name of the profile written")
    parser.add_argument("--gammas", default=",".join(f"{g:g}" for g in GAMMAS))
    parser.add_argument(
        "--beta-lows", default=f"{BETA_LOW:g},0.1", help="beta_low values with confidence on"
    )
    parser.add_argument("--coverage", choices=("time_indexed", "tube"), default="time_indexed")
    parser.add_argument("--url", help="a running service (default: start one locally)")
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    parser.add_argument("--out", type=Path, default=ROOT / "results")
    parser.add_argument("--docs", type=Path, default=ROOT / "docs")
    parser.add_argument("--profiles", type=Path, default=PROFILES_DIR)
    parser.add_argument(
        "--from-json",
        type=Path,
        help="a results/calibration_<name>.json: choose again from its replays (no service)",
    )
    args = parser.parse_args(argv)
    start = time.monotonic()

    def log(message: str) -> None:
        print(f"[{time.monotonic() - start:6.1f} s] {message}", flush=True)

    gammas = sorted(float(g) for g in args.gammas.split(","))
    name = args.profile
    data = args.data.resolve()
    data_name = str(data.relative_to(ROOT) if data.is_relative_to(ROOT) else data)
    if args.from_json is not None:  # the report again from saved replays, with this target
        body = json.loads(args.from_json.read_text())
        points = [Point(**p) for p in body["points"]]
        result = {**body, "points": points, "choice": choose(points, args.target, args.coverage)}
        model_name, data_name = body["model"], body["data"]
        gammas = sorted({p.gamma for p in points})
        log(f"replays of {args.from_json}")
    else:
        tracks = track_files.load(args.data)
        log(f"{len(tracks)} tracks from {args.data}")
        with connect(args.url, args.model) as client:
            model_name = client.model().name
            beta_lows = [float(b) for b in args.beta_lows.split(",") if b]
            result = calibrate(client, tracks, gammas, args.target, beta_lows, args.coverage, log)
    settings = profile_settings(result)
    body = {
        "data": data_name,
        "model": model_name,
        "predictor": "constant velocity and turn rate, diagonal covariance per 0.5 s step "
        "fitted on the calibration half (experiments/av2.py)",
        **{k: v for k, v in result.items() if k not in ("points", "seconds")},
        "points": [asdict(p) for p in result["points"]],
        "seconds": result.get("seconds", round(time.monotonic() - start, 1)),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"calibration_{name}.json").write_text(json.dumps(body, indent=2) + "\n")
    md = table(result["points"], result["choice"])
    others = "".join(
        f"### Target {t:.0%}\n\n{table(result['points'], choose(result['points'], t, args.coverage))}\n"
        for t in OTHER_TARGETS
        if abs(t - args.target) > 1e-9
    )
    (args.out / f"calibration_{name}.md").write_text(
        f"# Calibration `{name}` ({Path(data_name).name}, model {model_name})\n\n"
        f"Command: `make calibrate DATA={data_name} TARGET={args.target:g} PROFILE={name}`.\n\n"
        f"{md}\n## The same replays, other targets\n\n{others}"
        f"## Every γ\n\n{grid_table(result['points'])}"
    )
    plot(result["points"], result["choice"], args.docs / f"calibration_{name}.png",
         f"{Path(data_name).name}: coverage vs area of C, γ {gammas[0]:g}–{gammas[-1]:g}")  # fmt: skip
    choice = result["choice"]
    if not choice["target_reached"]:
        log(f"target {args.target} not reached on the calibration half by any gamma of the grid")
    path = write_profile(
        args.profiles / f"{name}.json",
        name,
        settings,
        source=f"make calibrate DATA={data_name} (results/calibration_{name}.json)",
        target=args.target,
        target_reached=choice["target_reached"],
        coverage=args.coverage,
        held_out=choice["per_confidence"][choice["chosen"]]["held_out"],
    )
    log(f"profile {path} (FRT_PROFILE={name}): {settings}")
    print(md, flush=True)
    log("done")


if __name__ == "__main__":
    main()
