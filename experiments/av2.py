"""Replay of real recorded traffic (Argoverse 2) through the service: do K and C hold the truth?

Data: one Argoverse 2 motion-forecasting scenario (``data/av2/``, 11 s at 10 Hz, Austin).
© Argo AI, LLC, licensed under CC BY-NC-SA 4.0 (https://creativecommons.org/licenses/by-nc-sa/4.0/);
see ``data/av2/NOTICE.md``. Figures and numbers derived from it carry the same licence.

Method (paper, "Human Prediction Model" and "Confidence estimation and update", applied to
driving that nobody here scripted):

- every vehicle track with at least 4 s of contiguous data is observed every 0.5 s from its
  0.5 s mark (so that a turn rate can be estimated) while 3 s of future remain;
- the predictor is a constant velocity and turn rate Gaussian: mean steering rate = the heading
  change over the last 0.5 s divided by 0.5 s, mean acceleration 0, for 6 steps of 0.5 s; its
  covariance is diagonal, one variance per step and control, fitted as the mean squared residual
  of the actual future controls (finite differences over each 0.5 s step). Two-fold
  cross-fitting by track: tracks are split into two folds alternately by sorted id, and each
  track is predicted with the covariance fitted on the other fold only;
- the observed action is the finite-difference action over the last 0.5 s, as in the scenes;
- for each observation the actual positions over the next 3 s (30 points at 10 Hz) are checked
  against the agent's sets with ``collision_radius = 0``: the clearance is then the signed
  distance to K, so a point is in K when it is <= 0 and in C = K ⊕ R_col when it is <= R_col
  (1.5 m). ``mode: "tube"`` tests the whole-horizon K (the paper's K); ``"time_indexed"`` the
  stricter tube up to each point's time. The area of C is that of the tube's C polygon;
- confidence on (beta_low = 0.03) and off (beta_low = 1 - 1e-6, beta fixed at 1), gamma = 0.075.

Observations whose speed lies outside the model's trained ``v_start`` range are skipped (the
service would answer 422) and counted; parked and slow cars are observed like the others. After a
skipped observation the next one is sent without an observed action (the previous prediction is
stale), so the filter is not scored across the gap.
"""

from __future__ import annotations

import contextlib
import json
import math
import uuid
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
from frt_client import FRTError
from shapely.geometry import shape

from experiments.run_scenarios import COLLISION_RADIUS_M, GAMMA, agent_config
from experiments.server import DEADLINE_MS, wait_exact
from reach.dynamics import wrap_angle

ROOT = Path(__file__).resolve().parent.parent
DATA_DIR = ROOT / "data" / "av2"
SCENARIO_ID = "0a1e6f0a-1817-4a98-b02e-db8c9327d151"
SCENARIO_FILE = f"scenario_{SCENARIO_ID}.parquet"
MAP_FILE = f"log_map_archive_{SCENARIO_ID}.json"
ATTRIBUTION = (
    "Data: Argoverse 2 (scenario 0a1e6f0a), © Argo AI, LLC, CC BY-NC-SA 4.0 "
    "https://creativecommons.org/licenses/by-nc-sa/4.0/"
)
LICENCE_URL = "https://creativecommons.org/licenses/by-nc-sa/4.0/"

SAMPLE_DT_S = 0.1
OBS_EVERY = 5  # samples between observations (0.5 s)
STEPS = 6  # prediction steps of 0.5 s (3 s)
HORIZON_SAMPLES = STEPS * OBS_EVERY
MIN_TRACK_S = 4.0
#: Floors of the fitted standard deviations (rad/s, m/s^2), so the covariance stays well posed.
SIGMA_FLOOR = (0.02, 0.05)


@dataclass(frozen=True)
class Track:
    """One vehicle's contiguous track: times (s) and states (heading continuous, speed >= 0)."""

    track_id: str
    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])

    def observation_indices(self) -> list[int]:
        """Samples observed: every 0.5 s from the 0.5 s mark while 3 s of future remain."""
        return list(range(OBS_EVERY, len(self.t) - HORIZON_SAMPLES, OBS_EVERY))

    def action(self, i: int) -> tuple[float, float]:
        """Finite-difference action over the 0.5 s ending at sample ``i``."""
        j = i - OBS_EVERY
        dt = self.t[i] - self.t[j]
        return (
            float(wrap_angle(self.heading[i] - self.heading[j])) / dt,
            float(self.speed[i] - self.speed[j]) / dt,
        )

    def future_actions(self, i: int) -> np.ndarray:
        """The actual controls over the 6 steps of 0.5 s after sample ``i``, shape (6, 2)."""
        return np.array([self.action(i + (k + 1) * OBS_EVERY) for k in range(STEPS)])


def load_tracks(path: Path = DATA_DIR / SCENARIO_FILE, min_s: float = MIN_TRACK_S) -> list[Track]:
    """Vehicle tracks of the scenario lasting at least ``min_s`` without gaps, sorted by id."""
    table = pq.read_table(
        path,
        columns=["track_id", "object_type", "timestep", "position_x", "position_y", "heading",
                 "velocity_x", "velocity_y"],
    ).to_pydict()  # fmt: skip
    rows: dict[str, list[int]] = {}
    for i, (tid, kind) in enumerate(zip(table["track_id"], table["object_type"], strict=True)):
        if kind == "vehicle":
            rows.setdefault(tid, []).append(i)
    tracks = []
    for tid in sorted(rows):
        idx = sorted(rows[tid], key=lambda r: table["timestep"][r])
        steps = np.array([table["timestep"][r] for r in idx])
        if len(steps) < 2 or np.any(np.diff(steps) != 1):
            continue
        col = {k: np.array([table[k][r] for r in idx], dtype=float) for k in table if k not in
               ("track_id", "object_type")}  # fmt: skip
        track = Track(
            track_id=tid,
            t=steps * SAMPLE_DT_S,
            x=col["position_x"],
            y=col["position_y"],
            heading=np.unwrap(col["heading"]),
            speed=np.hypot(col["velocity_x"], col["velocity_y"]),
        )
        if track.duration_s >= min_s - 1e-9:
            tracks.append(track)
    return tracks


def cvtr_mean(track: Track, i: int) -> np.ndarray:
    """Constant velocity and turn rate: (heading rate over the last 0.5 s, 0) for every step."""
    omega, _ = track.action(i)
    return np.tile([omega, 0.0], (STEPS, 1))


def fit_sigma(tracks: Sequence[Track]) -> np.ndarray:
    """Per-step standard deviations (6, 2) of the CVTR residuals over ``tracks`` (floored)."""
    residuals = [
        t.future_actions(i) - cvtr_mean(t, i) for t in tracks for i in t.observation_indices()
    ]
    if not residuals:
        raise ValueError("no observations to fit the covariance on")
    sigma = np.sqrt(np.mean(np.square(residuals), axis=0))
    return np.maximum(sigma, np.array(SIGMA_FLOOR))


def folds(tracks: Sequence[Track]) -> tuple[list[Track], list[Track]]:
    """Two folds, alternating over the tracks sorted by id."""
    ordered = sorted(tracks, key=lambda t: t.track_id)
    return ordered[0::2], ordered[1::2]


def prediction(mean: np.ndarray, sigma: np.ndarray) -> dict[str, Any]:
    """API.md's prediction object from per-step means and standard deviations."""
    cov = np.zeros((STEPS, 2, 2))
    cov[:, 0, 0] = sigma[:, 0] ** 2
    cov[:, 1, 1] = sigma[:, 1] ** 2
    return {"dt": OBS_EVERY * SAMPLE_DT_S, "mean": mean.tolist(), "cov": cov.tolist()}


@dataclass
class ObservationResult:
    """Coverage of one observation's 3 s of future by K and C, and the sets' areas."""

    track_id: str
    t: float
    speed: float
    beta: float
    in_k: float
    in_c: float
    in_k_time: float
    area_k: float
    area_c: float
    conservative: bool
    #: Share of the future inside C at each point's time (the tube up to it, ⊕ R_col).
    in_c_time: float = float("nan")


@dataclass
class Replay:
    """All observations of all tracks with confidence on or off."""

    confidence: bool
    observations: list[ObservationResult] = field(default_factory=list)
    skipped_out_of_range: int = 0

    def summary(self) -> dict[str, Any]:
        obs = self.observations
        if not obs:
            return {
                "observations": 0,
                "skipped_out_of_range": self.skipped_out_of_range,
            }

        def mean(key: str, rows: Sequence[ObservationResult] = obs) -> float:
            return float(np.mean([getattr(o, key) for o in rows])) if rows else float("nan")

        moving = [o for o in obs if o.speed >= 1.0]
        return {
            "observations": len(obs),
            "tracks": len({o.track_id for o in obs}),
            "skipped_out_of_range": self.skipped_out_of_range,
            "fraction_in_K": round(mean("in_k"), 4),
            "fraction_in_C": round(mean("in_c"), 4),
            "fraction_in_K_time_indexed": round(mean("in_k_time"), 4),
            "mean_area_C_m2": round(mean("area_c"), 2),
            "mean_area_K_m2": round(mean("area_k"), 2),
            "mean_beta": round(mean("beta"), 4),
            "moving": {
                "observations": len(moving),
                "fraction_in_K": round(mean("in_k", moving), 4),
                "fraction_in_C": round(mean("in_c", moving), 4),
                "mean_area_C_m2": round(mean("area_c", moving), 2),
            },
            "conservative_answers": sum(o.conservative for o in obs),
        }


def _area(geojson: dict[str, Any] | None) -> float:
    return 0.0 if not geojson else float(shape(geojson).area)


def replay_track(
    client: Any,
    track: Track,
    sigma: np.ndarray,
    confidence: bool,
    v_max: float,
    replay: Replay,
    contours: dict[tuple[str, float], dict[str, Any]] | None = None,
    gamma: float = GAMMA,
    beta_low: float | None = None,
) -> None:
    """Observe one track every 0.5 s and score its actual future against K and C (with
    ``gamma``, and ``beta_low`` if confidence is on: the scenarios' default if None)."""
    agent_id = f"av2-{track.track_id}-{'on' if confidence else 'off'}-{uuid.uuid4().hex[:6]}"
    config = (
        agent_config(confidence, gamma=gamma)
        if beta_low is None
        else agent_config(confidence, beta_low=beta_low, gamma=gamma)
    )
    first, fresh = True, True
    try:
        for i in track.observation_indices():
            if not 0.0 <= track.speed[i] <= v_max:
                replay.skipped_out_of_range += 1
                fresh = True
                continue
            state = (
                float(track.x[i]),
                float(track.y[i]),
                float(wrap_angle(track.heading[i])),
                float(track.speed[i]),
            )
            answer = client.observe(
                agent_id,
                timestamp=float(track.t[i]),
                state=state,
                prediction=prediction(cvtr_mean(track, i), sigma),
                observed_action=None if fresh else track.action(i),
                config=config if first else None,
            )
            first, fresh = False, False
            wait_exact(client, agent_id)
            j = slice(i + 1, i + HORIZON_SAMPLES + 1)
            future = np.stack([track.t[j], track.x[j], track.y[j]], axis=1)
            tube = client.collision_check(
                agent_id, future, mode="tube", collision_radius=0.0, deadline_ms=DEADLINE_MS
            )
            timed = client.collision_check(
                agent_id,
                future,
                mode="time_indexed",
                collision_radius=0.0,
                deadline_ms=DEADLINE_MS,
            )
            sets = client.contours(agent_id, include=("K", "C"), tube=True)
            d = np.asarray(tube.clearance)
            d_time = np.asarray(timed.clearance)
            replay.observations.append(
                ObservationResult(
                    track_id=track.track_id,
                    t=float(track.t[i]),
                    speed=state[3],
                    beta=answer.beta,
                    in_k=float(np.mean(d <= 0.0)),
                    in_c=float(np.mean(d <= COLLISION_RADIUS_M)),
                    in_k_time=float(np.mean(d_time <= 0.0)),
                    area_k=_area(sets.tube.K),
                    area_c=_area(sets.tube.C),
                    conservative=bool(tube.conservative or timed.conservative or sets.conservative),
                    in_c_time=float(np.mean(d_time <= COLLISION_RADIUS_M)),
                )
            )
            if contours is not None:
                contours[(track.track_id, round(float(track.t[i]), 2))] = {
                    "K": sets.tube.K,
                    "C": sets.tube.C,
                }
    finally:
        with contextlib.suppress(FRTError):  # best effort: the agent expires anyway
            client.delete_agent(agent_id)


def run_av2(
    client: Any, tracks: Sequence[Track] | None = None, keep_contours: bool = True
) -> dict[str, Any]:
    """Replay every long-enough vehicle track with confidence on and off.

    Returns ``{"tracks", "sigma", "replays": {"on", "off"}, "contours": {"on", "off"}}``.
    """
    tracks = list(tracks) if tracks is not None else load_tracks()
    fold_a, fold_b = folds(tracks)
    sigma_a, sigma_b = fit_sigma(fold_a), fit_sigma(fold_b)
    sigma_for = {t.track_id: sigma_b for t in fold_a} | {t.track_id: sigma_a for t in fold_b}
    v_max = float(client.model().ranges.get("v_start", [0.0, math.inf])[1])
    replays, sets = {}, {}
    for mode in ("on", "off"):
        replays[mode] = Replay(confidence=mode == "on")
        sets[mode] = {} if keep_contours else None
        for track in tracks:
            replay_track(
                client, track, sigma_for[track.track_id], mode == "on", v_max, replays[mode],
                sets[mode],
            )  # fmt: skip
    return {
        "tracks": tracks,
        "sigma": {"fold_a": sigma_a, "fold_b": sigma_b},
        "folds": {"a": [t.track_id for t in fold_a], "b": [t.track_id for t in fold_b]},
        "replays": replays,
        "contours": sets,
    }


def miss_diagnostics(result: dict[str, Any], mode: str = "off") -> dict[str, Any]:
    """Which prediction errors go with the misses: mean |actual - predicted| control over the
    next 3 s for observations with less than 80 % of the future in K, and for the others."""
    tracks = {t.track_id: t for t in result["tracks"]}
    rows = []
    for o in result["replays"][mode].observations:
        t = tracks[o.track_id]
        i = int(np.argmin(np.abs(t.t - o.t)))
        err = np.abs(t.future_actions(i) - cvtr_mean(t, i)).mean(axis=0)
        rows.append((o.in_k < 0.8, float(err[0]), float(err[1])))
    out: dict[str, Any] = {"mode": mode}
    for name, flag in (("mostly_outside_K", True), ("mostly_inside_K", False)):
        sel = [r for r in rows if r[0] == flag]
        out[name] = {
            "observations": len(sel),
            "mean_abs_steering_rate_error_radps": round(float(np.mean([r[1] for r in sel])), 4)
            if sel
            else None,
            "mean_abs_acceleration_error_mps2": round(float(np.mean([r[2] for r in sel])), 4)
            if sel
            else None,
        }
    return out


def results_json(result: dict[str, Any], model: dict[str, Any]) -> dict[str, Any]:
    """The content of ``results/av2.json``."""
    return {
        "attribution": ATTRIBUTION,
        "licence": "CC BY-NC-SA 4.0 (derived data carries the same licence; non-commercial use)",
        "licence_url": LICENCE_URL,
        "scenario": SCENARIO_ID,
        "model": model,
        "settings": {
            "beta_low_on": agent_config(True)["beta_low"],
            "beta_low_off": agent_config(False)["beta_low"],
            "gamma": GAMMA,
            "collision_radius_m": COLLISION_RADIUS_M,
            "observation_every_s": OBS_EVERY * SAMPLE_DT_S,
            "horizon_s": STEPS * OBS_EVERY * SAMPLE_DT_S,
            "min_track_s": MIN_TRACK_S,
        },
        "predictor": {
            "kind": "constant velocity and turn rate; diagonal covariance per 0.5 s step",
            "sigma_u1_u2_fold_a": np.round(result["sigma"]["fold_a"], 4).tolist(),
            "sigma_u1_u2_fold_b": np.round(result["sigma"]["fold_b"], 4).tolist(),
            "folds": result["folds"],
        },
        "tracks": len(result["tracks"]),
        "summary": {mode: r.summary() for mode, r in result["replays"].items()},
        "miss_diagnostics": miss_diagnostics(result),
        "observations": {
            mode: [asdict(o) for o in r.observations] for mode, r in result["replays"].items()
        },
    }


def table(result: dict[str, Any]) -> str:
    """Markdown table of coverage and area, confidence on vs off."""
    rows = [
        "| confidence | observations | future positions in K | in C | in K (time-indexed) "
        "| mean area of C (m²) | mean β |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for mode, r in result["replays"].items():
        s = r.summary()
        rows.append(
            f"| {mode} | {s['observations']} | {s['fraction_in_K']:.1%} | {s['fraction_in_C']:.1%} "
            f"| {s['fraction_in_K_time_indexed']:.1%} | {s['mean_area_C_m2']:.1f} "
            f"| {s['mean_beta']:.3f} |"
        )
    return "\n".join(rows) + "\n"


def save(result: dict[str, Any], model: dict[str, Any], out: Path) -> None:
    """Write ``av2.json`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "av2.json").write_text(json.dumps(results_json(result, model), indent=2) + "\n")


def lane_map(path: Path = DATA_DIR / MAP_FILE) -> dict[str, list[np.ndarray]]:
    """The vector map for drawing: drivable areas, lane centre lines and crosswalks (x, y)."""
    raw = json.loads(path.read_text())

    def xy(points: list[dict[str, float]]) -> np.ndarray:
        return np.array([[p["x"], p["y"]] for p in points])

    return {
        "drivable": [xy(a["area_boundary"]) for a in raw["drivable_areas"].values()],
        "lanes": [xy(s["centerline"]) for s in raw["lane_segments"].values()],
        "crossings": [
            np.vstack([xy(c["edge1"]), xy(c["edge2"])[::-1]])
            for c in raw["pedestrian_crossings"].values()
        ],
    }
