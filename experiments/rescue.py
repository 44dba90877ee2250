"""``python -m experiments.rescue`` (``make rescue``): does confidence rescue a wrong predictor?

Replays recorded road users of every class through the real service with a predictor that is
right, or that turns confidently wrong partway through each track, under each bounds rule
(``config.bounds_rule``: ``"paper"``, ``"uniform_mixture"``, ``"mass_ramp"``) with confidence on
and off, and measures how much of the actual future stays inside C and what C costs in area.

Data (``experiments.sensor_tracks``): the Argoverse 2 sensor-log tracks (cars, pedestrians, one
cyclist; heading and speed estimated from the box centres) and the motion-forecasting scenario's
vehicles and pedestrians. © Argo AI, LLC, CC BY-NC-SA 4.0: the results and the plot carry it.

Method:

1. per class, the tracks are split into a calibration and a held-out half, alternately by sorted
   id (``av2.folds``); the predictors' covariance is fitted per class on the calibration half only
   (``av2.fit_sigma``: diagonal, per 0.5 s step, from the constant velocity and turn rate
   residuals) and used on both halves;
2. predictors, per observation at sample ``i`` (6 steps of 0.5 s, that covariance):
   *right*: constant velocity and turn rate (``av2.cvtr_mean``); *wrong*: the mean steers
   ``WRONG_STEER`` rad/s against the agent's actual mean steering rate over the next 3 s and
   accelerates ``WRONG_ACCEL`` m/s^2 against its actual mean acceleration (``mu = -(WRONG_STEER,
   WRONG_ACCEL) * sign(actual)``, sign 0 taken as +). Both means are clipped to the class's
   control limits (``reach.agent_classes``). The wrong predictor is right for the predictions
   made before ``switch_s`` after a track's first sample and wrong from then on;
3. every track is observed every 0.5 s from its 0.5 s mark (``av2.Track.observation_indices``),
   up to ``after_s`` after the switch while 3 s of future remain, with the finite-difference
   observed action, its agent class, and the config of the run; each observation waits for the
   exact set, then its next 3 s of actual positions (30 at 10 Hz) are checked time-indexed
   (each point against the tube up to its time) with ``collision_radius = 0``: a point is in C
   when its clearance is at most the class's R_col; the area of C is that of the whole-horizon
   tube's C contour. Observations outside the class's speed range are skipped (the service
   would answer 422) and the next one is sent without an observed action;
4. figures are over the observations from the switch on (before it the two predictors are the
   same): coverage is the share of the future positions from +0.5 s to +3 s inside C of moving
   observations (speed at least ``MOVING_SPEED`` of the class), the same share once beta has
   seen the predictor wrong (observations ``INFORMED_S`` after the switch or later: the switch's
   own observation is scored on a beta updated by the still-right prediction before it, so no
   causal filter can have reacted), and the share at +3 s; the
   worst distance outside C is over those positions; area and beta are over every observation;
   "observations until beta < 0.5" counts, per track, observations after the switch until the
   first one answering beta < 0.5 (tracks that never do are counted apart);
5. ``rescue_onset`` per rule and class is chosen on the calibration half from ``ONSETS``: of the
   onsets whose wrong-predictor coverage with confidence once beta has seen it reaches
   ``COVERAGE_GOAL`` of the class,
   the one with the smallest right-predictor mean area of C with confidence (none reaching it:
   the highest coverage, then the smallest area, marked as not reached); the held-out half is
   replayed at that choice, and every figure reported is the held-out half's.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import statistics
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from frt_client import FRTClient, FRTError
from shapely.geometry import shape

from experiments import av2, sensor_tracks
from experiments.run_scenarios import BETA_LOW, BETA_LOW_OFF, GAMMA
from experiments.sensor_tracks import ClassedTrack
from experiments.server import (
    CLIENT_TIMEOUT_S,
    DEADLINE_MS,
    DEFAULT_MODEL,
    ROOT,
    local_server,
    wait_exact,
)
from reach.agent_classes import AGENT_CLASSES
from reach.dynamics import wrap_angle

RULES: tuple[str, ...] = ("paper", "uniform_mixture", "mass_ramp")
#: The rules whose onset is chosen (the paper's rule has none).
RESCUE_RULES: tuple[str, ...] = ("uniform_mixture", "mass_ramp")
ONSETS: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 0.9)
#: Wrong-predictor coverage with confidence the onset has to reach, per class.
COVERAGE_GOAL: dict[str, float] = {"car": 0.99, "cyclist": 0.99, "pedestrian": 0.995}
#: An observation is of a moving agent at this speed (m/s) or above.
MOVING_SPEED: dict[str, float] = {"car": 1.0, "cyclist": 1.0, "pedestrian": 0.5}
WRONG_STEER = 0.2
WRONG_ACCEL = 3.0
#: The wrong predictor turns wrong this long (s) after a track's first sample.
SWITCH_S = 1.0
#: Observations up to this long (s) after the switch.
AFTER_S = 3.0
#: Coverage counts the future positions from this far ahead (s) to the horizon.
COVERAGE_FROM_S = 0.5
#: "Once beta has seen it": observations this long (s) after the switch or later, the first
#: whose observed action the wrong prediction made before it had to explain.
INFORMED_S = 0.5
#: Tracks replayed at once (each its own agent): the service overlaps their exact sets.
CONCURRENT_TRACKS = 4
#: FRT_FRT_WORKERS of the local service.
FRT_WORKERS = 2
CLASSES_REPORTED: tuple[str, ...] = ("car", "pedestrian", "cyclist")


@dataclass(frozen=True)
class Run:
    """One replay setting: predictor, confidence, bounds rule and its onset per class."""

    predictor: str  # "right" or "wrong"
    confidence: bool
    rule: str = "paper"
    #: rescue_onset per class (None: the service's default; the paper's rule has none).
    onsets: tuple[tuple[str, float], ...] | None = None
    #: The label's onset part ("chosen"); default the onset when it is the same for every class.
    onset_name: str | None = None

    @property
    def label(self) -> str:
        """``predictor/on|off/rule[@onset]``, e.g. ``wrong/on/uniform_mixture@0.5``."""
        conf = "on" if self.confidence else "off"
        onset = ""
        if self.onset_name is not None:
            onset = f"@{self.onset_name}"
        elif self.onsets is not None:
            values = sorted({v for _, v in self.onsets})
            onset = "@" + (
                f"{values[0]:g}"
                if len(values) == 1
                else ",".join(f"{c}={v:g}" for c, v in self.onsets)
            )
        return f"{self.predictor}/{conf}/{self.rule}{onset}"

    def onset_for(self, agent_class: str) -> float | None:
        return None if self.onsets is None else dict(self.onsets).get(agent_class)

    def config(self, agent_class: str) -> dict[str, Any]:
        """The observation's ``config``: beta_low, gamma, the class's R_col, rule and onset (both
        omitted for the paper's rule without an onset, the service's default)."""
        out: dict[str, Any] = {
            "beta_low": BETA_LOW if self.confidence else BETA_LOW_OFF,
            "gamma": GAMMA,
            "collision_radius": AGENT_CLASSES[agent_class].collision_radius_m,
        }
        onset = self.onset_for(agent_class)
        if self.rule != "paper" or onset is not None:
            out["bounds_rule"] = self.rule
        if onset is not None:
            out["rescue_onset"] = onset
        return out


def uniform_onsets(onset: float) -> tuple[tuple[str, float], ...]:
    """The same onset for every class."""
    return tuple((c, onset) for c in sorted(AGENT_CLASSES))


@dataclass(frozen=True)
class Observation:
    """One observation's figures: coverage of its future by C, the area of C and beta."""

    track_id: str
    agent_class: str
    t: float
    #: Seconds since the predictor turned wrong (negative before the switch).
    since_switch_s: float
    speed: float
    beta: float
    #: Share of the future positions from +0.5 s to +3 s inside C (time-indexed).
    in_c: float
    #: Whether the position at +3 s is inside C.
    in_c_end: bool
    #: The largest distance (m) outside C of those positions (<= 0: all inside).
    worst_outside_m: float
    area_c_m2: float
    conservative: bool


@dataclass
class RunResult:
    """A run's observations on some tracks."""

    run: Run
    observations: list[Observation] = field(default_factory=list)
    skipped_out_of_range: int = 0


def sign0(value: float) -> float:
    """The sign of ``value``, with 0 as +1."""
    return -1.0 if value < 0.0 else 1.0


def clip_mean(mean: np.ndarray, agent_class: str) -> np.ndarray:
    """Per-step means (S, 2) clipped to the class's control limits."""
    limits = np.array(AGENT_CLASSES[agent_class].limits)
    return np.clip(mean, -limits, limits)


def right_mean(track: av2.Track, i: int, agent_class: str) -> np.ndarray:
    """Constant velocity and turn rate (``av2.cvtr_mean``), clipped to the class's limits."""
    return clip_mean(av2.cvtr_mean(track, i), agent_class)


def wrong_mean(track: av2.Track, i: int, agent_class: str) -> np.ndarray:
    """The confidently wrong mean: against the actual mean steering rate and acceleration over
    the next 3 s (see the module), for every step, clipped to the class's limits."""
    actual = track.future_actions(i).mean(axis=0)
    step = np.array([-WRONG_STEER * sign0(actual[0]), -WRONG_ACCEL * sign0(actual[1])])
    return clip_mean(np.tile(step, (av2.STEPS, 1)), agent_class)


def is_wrong(run: Run, track: av2.Track, i: int, switch_s: float) -> bool:
    """Whether the prediction made at sample ``i`` is the wrong one."""
    return run.predictor == "wrong" and track.t[i] - track.t[0] >= switch_s - 1e-9


def observed_indices(track: av2.Track, switch_s: float, after_s: float) -> list[int]:
    """The samples observed: ``av2``'s, up to ``after_s`` after the switch."""
    end = track.t[0] + switch_s + after_s + 1e-9
    return [i for i in track.observation_indices() if track.t[i] <= end]


def score_future(
    clearance: Sequence[float], times_ahead: Sequence[float], radius: float
) -> tuple[float, bool, float]:
    """``(share inside C, inside at the last point, worst distance outside)`` of the future
    positions ``COVERAGE_FROM_S`` s ahead or more, from their clearances to K."""
    d = np.asarray(clearance, dtype=float)
    ahead = np.asarray(times_ahead, dtype=float)
    sel = d[ahead >= COVERAGE_FROM_S - 1e-9]
    return float(np.mean(sel <= radius)), bool(d[-1] <= radius), float(np.max(sel) - radius)


def replay_track(
    client: Any,
    ct: ClassedTrack,
    sigma: np.ndarray,
    run: Run,
    switch_s: float = SWITCH_S,
    after_s: float = AFTER_S,
) -> RunResult:
    """Observe one track under ``run`` and score each observation (see the module)."""
    track, klass = ct.track, AGENT_CLASSES[ct.agent_class]
    tag = run.label.replace("/", "-").replace("@", "-").replace(",", "-").replace("=", "")
    agent_id = f"rescue-{tag}-{uuid.uuid4().hex[:8]}"[:128]
    result = RunResult(run)
    first, fresh = True, True
    try:
        for i in observed_indices(track, switch_s, after_s):
            if not klass.speed_min <= track.speed[i] <= klass.speed_max:
                result.skipped_out_of_range += 1
                fresh = True
                continue
            mean = (wrong_mean if is_wrong(run, track, i, switch_s) else right_mean)(
                track, i, ct.agent_class
            )
            answer = client.observe(
                agent_id,
                timestamp=float(track.t[i]),
                state=(
                    float(track.x[i]),
                    float(track.y[i]),
                    float(wrap_angle(track.heading[i])),
                    float(track.speed[i]),
                ),
                prediction=av2.prediction(mean, sigma),
                observed_action=None if fresh else track.action(i),
                config=run.config(ct.agent_class) if first else None,
                agent_class=ct.agent_class if first else None,
            )
            first, fresh = False, False
            wait_exact(client, agent_id)
            j = slice(i + 1, i + av2.HORIZON_SAMPLES + 1)
            future = np.stack([track.t[j], track.x[j], track.y[j]], axis=1)
            check = client.collision_check(
                agent_id, future, mode="time_indexed", collision_radius=0.0,
                deadline_ms=DEADLINE_MS,
            )  # fmt: skip
            sets = client.contours(agent_id, include=("C",), tube=True)
            in_c, in_end, worst = score_future(
                check.clearance, track.t[j] - track.t[i], klass.collision_radius_m
            )
            result.observations.append(
                Observation(
                    track_id=track.track_id,
                    agent_class=ct.agent_class,
                    t=round(float(track.t[i]), 3),
                    since_switch_s=round(float(track.t[i] - track.t[0] - switch_s), 3),
                    speed=float(track.speed[i]),
                    beta=float(answer.beta),
                    in_c=in_c,
                    in_c_end=in_end,
                    worst_outside_m=worst,
                    area_c_m2=float(shape(sets.tube.C).area) if sets.tube.C else 0.0,
                    conservative=bool(check.conservative or sets.conservative),
                )
            )
    finally:
        with contextlib.suppress(FRTError):  # best effort: the agent expires anyway
            client.delete_agent(agent_id)
    return result


# ---------------------------------------------------------------------------------- summaries


def _mean(values: Sequence[float]) -> float | None:
    return float(np.mean(values)) if len(values) else None


def _round(value: float | None, digits: int) -> float | None:
    return None if value is None else round(value, digits)


def until_beta_half(observations: Sequence[Observation]) -> dict[str, Any]:
    """Per track, observations after the switch until the first answering beta < 0.5 (0: the
    switch's own); the median and max over the tracks that get there, and how many never do."""
    counts: list[int] = []
    never = 0
    tracks: dict[str, list[Observation]] = {}
    for o in observations:
        if o.since_switch_s >= -1e-9:
            tracks.setdefault(o.track_id, []).append(o)
    for rows in tracks.values():
        hit = next(
            (o for o in sorted(rows, key=lambda o: o.t) if o.beta < 0.5), None
        )  # fmt: skip
        if hit is None:
            never += 1
        else:
            counts.append(round(hit.since_switch_s / (av2.OBS_EVERY * av2.SAMPLE_DT_S)))
    return {
        "median": float(statistics.median(counts)) if counts else None,
        "max": max(counts) if counts else None,
        "tracks": len(tracks),
        "never": never,
    }


def summarise(observations: Sequence[Observation], moving_speed: float) -> dict[str, Any]:
    """A run's figures over ``observations`` from the switch on (see the module)."""
    after = [o for o in observations if o.since_switch_s >= -1e-9]
    moving = [o for o in after if o.speed >= moving_speed]
    worst = max((o.worst_outside_m for o in moving), default=None)
    return {
        "observations": len(after),
        "moving_observations": len(moving),
        "tracks": len({o.track_id for o in after}),
        "coverage_c": _round(_mean([o.in_c for o in moving]), 4),
        "coverage_c_informed": _round(
            _mean([o.in_c for o in moving if o.since_switch_s >= INFORMED_S - 1e-9]), 4
        ),
        "coverage_c_3s": _round(_mean([float(o.in_c_end) for o in moving]), 4),
        "coverage_c_every_observation": _round(_mean([o.in_c for o in after]), 4),
        "worst_outside_c_m": None if worst is None else round(max(worst, 0.0), 3),
        "mean_area_c_m2": _round(_mean([o.area_c_m2 for o in after]), 2),
        "mean_area_c_moving_m2": _round(_mean([o.area_c_m2 for o in moving]), 2),
        "mean_beta": _round(_mean([o.beta for o in after]), 4),
        "until_beta_below_half": until_beta_half(after),
        "conservative_answers": sum(o.conservative for o in after),
    }


def by_time(observations: Sequence[Observation], moving_speed: float) -> list[dict[str, Any]]:
    """Coverage (moving), mean area of C and mean beta per time since the switch."""
    out = []
    for since in sorted({o.since_switch_s for o in observations if o.since_switch_s >= -1e-9}):
        rows = [o for o in observations if o.since_switch_s == since]
        moving = [o for o in rows if o.speed >= moving_speed]
        out.append(
            {
                "since_switch_s": since,
                "observations": len(rows),
                "coverage_c": _round(_mean([o.in_c for o in moving]), 4),
                "mean_area_c_m2": _round(_mean([o.area_c_m2 for o in rows]), 2),
                "mean_beta": _round(_mean([o.beta for o in rows]), 4),
            }
        )
    return out


def figures(
    results: Sequence[RunResult], half_of: dict[str, str]
) -> dict[str, dict[str, dict[str, dict[str, Any]]]]:
    """``{run label: {half: {class: summary + "by_time"}}}`` of every run on its tracks."""
    out: dict[str, dict[str, dict[str, dict[str, Any]]]] = {}
    merged: dict[str, list[Observation]] = {}
    for r in results:
        merged.setdefault(r.run.label, []).extend(r.observations)
    for label, obs in merged.items():
        for half in ("calibration", "held_out"):
            for klass in CLASSES_REPORTED:
                rows = [o for o in obs if o.agent_class == klass and half_of[o.track_id] == half]
                if not rows:
                    continue
                speed = MOVING_SPEED[klass]
                out.setdefault(label, {}).setdefault(half, {})[klass] = {
                    **summarise(rows, speed),
                    "by_time": by_time(rows, speed),
                }
    return out


def choose_onset(
    figs: dict[str, Any], rule: str, agent_class: str, onsets: Sequence[float]
) -> dict[str, Any]:
    """The onset of ``rule`` for ``agent_class`` from the calibration half (see the module)."""
    goal = COVERAGE_GOAL[agent_class]
    rows = []
    for onset in onsets:
        wrong = figs[f"wrong/on/{rule}@{onset:g}"]["calibration"][agent_class]
        right = figs[f"right/on/{rule}@{onset:g}"]["calibration"][agent_class]
        rows.append((onset, wrong["coverage_c_informed"], right["mean_area_c_m2"]))
    reached = [r for r in rows if r[1] is not None and r[1] >= goal - 1e-12]
    best = (
        min(reached, key=lambda r: (r[2], r[0]))
        if reached
        else min(rows, key=lambda r: (-(r[1] if r[1] is not None else -math.inf), r[2], r[0]))
    )
    return {
        "onset": best[0],
        "goal": goal,
        "reached": bool(reached),
        "wrong_coverage_calibration": best[1],
        "right_area_calibration_m2": best[2],
        "grid": [{"onset": o, "wrong_coverage": c, "right_mean_area_c_m2": a} for o, c, a in rows],
    }


# ---------------------------------------------------------------------------------- replays


def halves(tracks: Sequence[ClassedTrack]) -> dict[str, list[ClassedTrack]]:
    """Per class, alternately by sorted id (``av2.folds``): the calibration and held-out halves."""
    out: dict[str, list[ClassedTrack]] = {"calibration": [], "held_out": []}
    for group in sensor_tracks.by_class(tracks).values():
        of = {c.track_id: c for c in group}
        first, second = av2.folds([c.track for c in group])
        out["calibration"] += [of[t.track_id] for t in first]
        out["held_out"] += [of[t.track_id] for t in second]
    return out


def fit_sigmas(calibration: Sequence[ClassedTrack]) -> dict[str, np.ndarray]:
    """Per class, ``av2.fit_sigma`` on the calibration half's tracks of that class."""
    return {
        klass: av2.fit_sigma([c.track for c in group])
        for klass, group in sensor_tracks.by_class(calibration).items()
    }


def limit_tracks(tracks: Sequence[ClassedTrack], per_class: int | None) -> list[ClassedTrack]:
    """The first ``per_class`` tracks of each class (all if None), in the given order."""
    if per_class is None:
        return list(tracks)
    return [c for group in sensor_tracks.by_class(tracks).values() for c in group[:per_class]]


def replay_all(
    client: Any,
    jobs: Sequence[tuple[Run, ClassedTrack]],
    sigmas: dict[str, np.ndarray],
    switch_s: float,
    after_s: float,
    progress: Callable[[int], None] = lambda n: None,
) -> list[RunResult]:
    """Every (run, track) job, ``CONCURRENT_TRACKS`` at once, results in the jobs' order."""
    with ThreadPoolExecutor(CONCURRENT_TRACKS) as pool:
        futures = {
            pool.submit(replay_track, client, ct, sigmas[ct.agent_class], run, switch_s, after_s): k
            for k, (run, ct) in enumerate(jobs)
        }
        out: list[RunResult | None] = [None] * len(jobs)
        for future in as_completed(futures):
            out[futures[future]] = future.result()
            progress(1)
    return [r for r in out if r is not None]


def calibration_runs(onsets: Sequence[float], rules: Sequence[str]) -> list[Run]:
    """The calibration half's runs: per predictor, off and on with the paper's rule, and each
    rescue rule with confidence at every onset."""
    runs = []
    for predictor in ("right", "wrong"):
        runs += [Run(predictor, False), Run(predictor, True)]
        runs += [
            Run(predictor, True, rule, uniform_onsets(onset)) for rule in rules for onset in onsets
        ]
    return runs


def held_out_runs(choice: dict[str, dict[str, Any]], rules: Sequence[str]) -> list[Run]:
    """The held-out half's runs: per predictor, off and on with the paper's rule and each rescue
    rule at its chosen onsets; and the wrong predictor off under the first rescue rule (the rule
    is the paper's at beta = 1: the check that it is)."""
    chosen = {
        rule: tuple(sorted((c, v["onset"]) for c, v in choice[rule].items())) for rule in rules
    }
    runs = []
    for predictor in ("right", "wrong"):
        runs += [Run(predictor, False), Run(predictor, True)]
        runs += [Run(predictor, True, rule, chosen[rule], "chosen") for rule in rules]
    if rules:
        runs.append(Run("wrong", False, rules[0], chosen[rules[0]], "chosen"))
    return runs


@contextlib.contextmanager
def service(url: str | None, model: Path, workers: int = FRT_WORKERS) -> Iterator[FRTClient]:
    """An SDK client to ``url``, or to a local service on ``model`` with ``workers`` FRT workers."""
    if url is not None:
        with FRTClient(url, timeout=CLIENT_TIMEOUT_S) as client:
            client.wait_ready(timeout_s=60.0)
            yield client
        return
    log = Path(tempfile.gettempdir()) / "frt-rescue-service.log"
    with (
        local_server(model, log, workers=workers) as local_url,
        FRTClient(local_url, timeout=CLIENT_TIMEOUT_S) as client,
    ):
        yield client


def rescue(
    client: Any,
    tracks: Sequence[ClassedTrack],
    rules: Sequence[str] = RESCUE_RULES,
    onsets: Sequence[float] = ONSETS,
    switch_s: float = SWITCH_S,
    after_s: float = AFTER_S,
    max_tracks: int | None = None,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Split, fit, replay the calibration half's grid, choose the onsets, replay the held-out
    half at the choice (see the module). ``rules`` are the rescue rules (none: the paper's rule
    only, sent without ``bounds_rule``)."""
    from tqdm import tqdm

    split = {name: limit_tracks(ts, max_tracks) for name, ts in halves(tracks).items()}
    half_of = {c.track_id: name for name, ts in split.items() for c in ts}
    sigmas = fit_sigmas(split["calibration"])
    missing = {c.agent_class for c in split["held_out"]} - set(sigmas)
    if missing:
        raise ValueError(f"no calibration tracks of class {sorted(missing)}")
    results: list[RunResult] = []

    def phase(name: str, runs: Sequence[Run], half: str) -> list[RunResult]:
        jobs = [(run, ct) for run in runs for ct in split[half]]
        log(f"{name}: {len(runs)} runs x {len(split[half])} tracks of the {half} half")
        with tqdm(total=len(jobs), desc=name, file=sys.stderr, unit="track") as bar:
            done = replay_all(client, jobs, sigmas, switch_s, after_s, bar.update)
        return done

    results += phase("calibration", calibration_runs(onsets, rules), "calibration")
    figs = figures(results, half_of)
    choice = {
        rule: {
            klass: choose_onset(figs, rule, klass, onsets)
            for klass in sorted({c.agent_class for c in split["calibration"]})
        }
        for rule in rules
    }
    for rule, per in choice.items():
        for klass, v in per.items():
            flag = "" if v["reached"] else " (goal not reached)"
            log(f"{rule}, {klass}: rescue_onset {v['onset']:g}{flag}")
    results += phase("held-out", held_out_runs(choice, rules), "held_out")
    figs = figures(results, half_of)
    return {
        "split": {name: [c.track_id for c in ts] for name, ts in split.items()},
        "sigma": {klass: np.round(s, 4).tolist() for klass, s in sigmas.items()},
        "choice": choice,
        "figures": figs,
        "skipped_out_of_range": {
            label: sum(r.skipped_out_of_range for r in results if r.run.label == label)
            for label in figs
        },
    }


# ---------------------------------------------------------------------------------- report


def _pct(value: float | None, digits: int = 1) -> str:
    return "–" if value is None else f"{value:.{digits}%}"


def _num(value: float | None, fmt: str = ".1f") -> str:
    return "–" if value is None else format(value, fmt)


def held_out_table(result: dict[str, Any], agent_class: str) -> str:
    """Markdown: every held-out run of ``agent_class``."""
    rows = [
        "| predictor | confidence | bounds rule | rescue_onset | observations (moving) "
        "| in C, +0.5…+3 s | once β has seen it | in C at +3 s | worst outside C (m) | mean area of C (m²) "
        "| mean β | obs. until β < 0.5: median / max (never) |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for label, halves_ in result["figures"].items():
        s = halves_.get("held_out", {}).get(agent_class)
        if s is None:
            continue
        predictor, conf, rule = label.split("/")
        rule, _, onset = rule.partition("@")
        if onset == "chosen":
            onset = f"{result['choice'][rule][agent_class]['onset']:g}"
        u = s["until_beta_below_half"]
        rows.append(
            f"| {predictor} | {conf} | {rule} | {onset or '–'} "
            f"| {s['observations']} ({s['moving_observations']}) | {_pct(s['coverage_c'])} "
            f"| {_pct(s['coverage_c_informed'])} | {_pct(s['coverage_c_3s'])} | {_num(s['worst_outside_c_m'], '.2f')} "
            f"| {_num(s['mean_area_c_m2'])} | {_num(s['mean_beta'], '.3f')} "
            f"| {_num(u['median'], 'g')} / {_num(u['max'], 'g')} ({u['never']} of {u['tracks']}) |"
        )
    return "\n".join(rows) + "\n"


def grid_table(result: dict[str, Any]) -> str:
    """Markdown: the calibration half's onset grid per rule and class, and the choice."""
    rows = [
        "| bounds rule | class | rescue_onset | wrong predictor: in C | right predictor: mean area "
        "of C (m²) | chosen |",
        "| --- | --- | ---: | ---: | ---: | --- |",
    ]
    for rule, per in result["choice"].items():
        for klass, v in per.items():
            for g in v["grid"]:
                mark = ""
                if g["onset"] == v["onset"]:
                    mark = "yes" if v["reached"] else "yes (goal not reached)"
                rows.append(
                    f"| {rule} | {klass} | {g['onset']:g} | {_pct(g['wrong_coverage'], 2)} "
                    f"| {_num(g['right_mean_area_c_m2'])} | {mark} |"
                )
    return "\n".join(rows) + "\n"


def area_ratios(result: dict[str, Any], half: str = "held_out") -> dict[str, dict[str, Any]]:
    """Per rescue rule and class: the right predictor's mean area of C with confidence against
    the paper rule's (same half)."""
    figs = result["figures"]
    out: dict[str, dict[str, Any]] = {}
    for rule in result["choice"]:
        for klass in CLASSES_REPORTED:
            mine = figs.get(f"right/on/{rule}@chosen", {}).get(half, {}).get(klass)
            paper = figs.get("right/on/paper", {}).get(half, {}).get(klass)
            if mine and paper and paper["mean_area_c_m2"]:
                out.setdefault(rule, {})[klass] = round(
                    mine["mean_area_c_m2"] / paper["mean_area_c_m2"], 3
                )
    return out


def markdown(result: dict[str, Any], command: str) -> str:
    """``results/rescue.md``."""
    s = result["settings"]
    parts = [
        "# Confidence that rescues a wrong predictor (issue 35)\n",
        f"Command: `{command}`; model {result['model']}; {result['seconds']:.0f} s. "
        f"{sensor_tracks.SENSOR_ATTRIBUTION}; these figures carry that licence.\n",
        f"The wrong predictor turns wrong {s['switch_s']:g} s after a track's first sample "
        f"(steering {s['wrong_steer_radps']:g} rad/s and accelerating {s['wrong_accel_mps2']:g} "
        f"m/s² against the actual controls); figures are over the observations from then on, up "
        f"to {s['after_s']:g} s after it. γ = {s['gamma']:g}, β_low = {s['beta_low_on']:g} "
        f"(off: {s['beta_low_off']}). Coverage: moving observations, future positions "
        f"+{s['coverage_from_s']:g}…+3 s, time-indexed, inside C = K ⊕ R_col of the class. "
        "Every table but the grid is the held-out half's.\n",
    ]
    for klass in CLASSES_REPORTED:
        if any(klass in h.get("held_out", {}) for h in result["figures"].values()):
            parts.append(
                f"## {klass.capitalize()}s, held-out half\n\n{held_out_table(result, klass)}"
            )
    ratios = area_ratios(result)
    if ratios:
        parts.append(
            "## Right predictor: mean area of C against the paper rule's (held-out)\n\n"
            + "\n".join(
                f"- {rule}: " + ", ".join(f"{k} {v:.3f}×" for k, v in per.items())
                for rule, per in ratios.items()
            )
            + "\n"
        )
    if result["choice"]:
        parts.append(f"## The onset, chosen on the calibration half\n\n{grid_table(result)}")
    return "\n".join(parts)


def plot(result: dict[str, Any], out: Path, half: str = "held_out") -> Path:
    """Coverage and mean area of C against time since the predictor went wrong: one line per
    (rule, confidence) of the wrong predictor, the right predictor's dashed; cars and
    pedestrians as columns."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    classes = [
        k
        for k in ("car", "pedestrian")
        if any(k in h.get(half, {}) for h in result["figures"].values())
    ]
    fig, axes = plt.subplots(2, len(classes), figsize=(5.2 * len(classes), 7.0), squeeze=False)
    colours = ["tab:orange", "tab:blue", "tab:green", "tab:purple", "tab:red", "tab:brown"]
    lines = sorted(
        {
            label.split("/", 1)[1]
            for label in result["figures"]
            if label.endswith("/paper") or (label.startswith("wrong/on/") and "@chosen" in label)
        }
    )
    for col, klass in enumerate(classes):
        for n, setting in enumerate(lines):
            for predictor, style in (("wrong", "-"), ("right", "--")):
                s = result["figures"].get(f"{predictor}/{setting}", {}).get(half, {}).get(klass)
                if not s:
                    continue
                ts = [p["since_switch_s"] for p in s["by_time"]]
                conf, rule = setting.split("/")
                name = f"confidence {conf}, {rule.replace('@chosen', '')}"
                name = name if predictor == "wrong" else None
                for row, key in ((0, "coverage_c"), (1, "mean_area_c_m2")):
                    ys = [np.nan if p[key] is None else p[key] for p in s["by_time"]]
                    axes[row][col].plot(ts, ys, style, marker="o", ms=3,
                                        color=colours[n % len(colours)], label=name)  # fmt: skip
        axes[0][col].set_title(f"{klass}s ({half.replace('_', '-')} half)", fontsize=10)
        axes[0][col].set_ylabel("future positions in C (moving, +0.5…+3 s)")
        axes[1][col].set_ylabel("mean area of C (m²)")
        axes[1][col].set_xlabel("time since the predictor went wrong (s)")
        axes[1][col].set_yscale("log")
        for row in (0, 1):
            axes[row][col].grid(alpha=0.3)
    axes[0][0].plot([], [], "k-", label="wrong predictor")
    axes[0][0].plot([], [], "k--", label="right predictor")
    axes[0][0].legend(fontsize=6.5, loc="lower right")
    fig.suptitle(
        "Does confidence rescue a wrong predictor?\n" + sensor_tracks.SENSOR_ATTRIBUTION,
        fontsize=7,
    )
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=130)
    plt.close(fig)
    return out


def settings(switch_s: float, after_s: float, onsets: Sequence[float]) -> dict[str, Any]:
    """The replay's settings, for the results."""
    return {
        "switch_s": switch_s,
        "after_s": after_s,
        "wrong_steer_radps": WRONG_STEER,
        "wrong_accel_mps2": WRONG_ACCEL,
        "gamma": GAMMA,
        "beta_low_on": BETA_LOW,
        "beta_low_off": BETA_LOW_OFF,
        "collision_radius_m": {k: c.collision_radius_m for k, c in AGENT_CLASSES.items()},
        "moving_speed_mps": MOVING_SPEED,
        "coverage_from_s": COVERAGE_FROM_S,
        "coverage_goal": COVERAGE_GOAL,
        "onsets": list(onsets),
        "observation_every_s": av2.OBS_EVERY * av2.SAMPLE_DT_S,
        "horizon_s": av2.STEPS * av2.OBS_EVERY * av2.SAMPLE_DT_S,
        "concurrent_tracks": CONCURRENT_TRACKS,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Does confidence rescue a wrong predictor?")
    parser.add_argument("--rules", default=",".join(RESCUE_RULES),
                        help="rescue rules to try besides the paper's (empty: the paper's only)")  # fmt: skip
    parser.add_argument("--onsets", default=",".join(f"{o:g}" for o in ONSETS))
    parser.add_argument("--switch-s", type=float, default=SWITCH_S)
    parser.add_argument("--after-s", type=float, default=AFTER_S)
    parser.add_argument("--max-tracks", type=int, help="tracks per class and half")
    parser.add_argument("--quick", action="store_true",
                        help="a short run: 4 tracks per class and half, onsets 0 and 0.5")  # fmt: skip
    parser.add_argument("--url", help="a running service (default: start one locally)")
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    parser.add_argument("--workers", type=int, default=FRT_WORKERS, help="FRT_FRT_WORKERS")
    parser.add_argument("--out", type=Path, default=ROOT / "results")
    parser.add_argument("--docs", type=Path, default=ROOT / "docs")
    args = parser.parse_args(argv)
    start = time.monotonic()

    def log(message: str) -> None:
        print(f"[{time.monotonic() - start:6.1f} s] {message}", file=sys.stderr, flush=True)

    rules = [r for r in args.rules.split(",") if r]
    unknown = set(rules) - set(RESCUE_RULES)
    if unknown:
        parser.error(f"unknown rules {sorted(unknown)} (use {', '.join(RESCUE_RULES)})")
    onsets = [float(o) for o in args.onsets.split(",") if o]
    max_tracks = args.max_tracks
    if args.quick:
        max_tracks, onsets = max_tracks or 4, [0.0, 0.5]
    tracks = sensor_tracks.load_all()
    flips = sensor_tracks.sensor_yaw_flips()
    log(f"{len(tracks)} tracks; {len(flips)} sensor tracks with flipped box yaws while moving")
    with service(args.url, args.model, args.workers) as client:
        model_name = client.model().name
        result = rescue(client, tracks, rules, onsets, args.switch_s, args.after_s, max_tracks, log)
    result = {
        "attribution": sensor_tracks.SENSOR_ATTRIBUTION,
        "licence": "CC BY-NC-SA 4.0 (derived data carries the same licence; non-commercial use)",
        "model": model_name,
        "settings": {
            **settings(args.switch_s, args.after_s, onsets),
            "rules": ["paper", *rules],
            "max_tracks_per_class_and_half": max_tracks,
            "frt_workers": args.workers,
        },
        "sensor_tracks_with_flipped_yaw": flips,
        "area_ratio_right_predictor_vs_paper": None,
        **result,
        "seconds": round(time.monotonic() - start, 1),
    }
    result["area_ratio_right_predictor_vs_paper"] = area_ratios(result)
    command = (
        "make rescue"
        if argv is None and len(sys.argv) == 1
        else "python -m experiments.rescue " + " ".join(sys.argv[1:] if argv is None else argv)
    )
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "rescue.json").write_text(json.dumps(result, indent=2) + "\n")
    md = markdown(result, command)
    (args.out / "rescue.md").write_text(md)
    plot(result, args.docs / "rescue.png")
    print(md, flush=True)
    log(f"wrote {args.out / 'rescue.json'}, {args.out / 'rescue.md'}, {args.docs / 'rescue.png'}")


if __name__ == "__main__":
    main()
