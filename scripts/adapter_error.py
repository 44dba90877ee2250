"""How far the controls the SDK's adapters recover from a path drive the unicycle off that path.

``.venv/bin/python scripts/adapter_error.py``: every recorded road user of
``experiments.sensor_tracks.load_all`` (the Argoverse 2 sensor-log tracks of
``../shared/data/av2_sensor_tracks/tracks.json`` and the tracks of the motion-forecasting scenario
in ``data/av2/``, 10 Hz) is cut into windows every 0.5 s with 3 s of future. Each window's future
positions are taken as if a predictor had sent them: an Apollo ``PredictionObstacle`` with one
trajectory of points every 0.1 s, the obstacle at the window's first position with the track's
heading and speed there. ``frt_client.adapters.from_apollo`` turns it into controls at the step
``dt`` (0.1 s, the message's own; 0.5 s, resampled), and those controls are rolled from the same
state through ``reach.dynamics`` (RK4 at 0.01 s, the controls held over each step, the speed kept
>= 0 by the stop rule). The error is the distance between the rolled and the recorded position at
1, 2 and 3 s: median, p95 and max per agent class. The first-order differences of
``frt_client.paths.trajectory_controls`` are measured the same way for comparison.

The error has two sources: the method (second order in ``dt``) and any disagreement between the
recorded state and the recorded path (the sensor tracks' heading and speed are estimated from
noisy box centres, the scenario's are recorded apart from its positions, and a stopped object's
path jitters), which no control recovery can remove: the roll starts from the state, as the
service's sets do. Each class is reported over every window and
over the moving ones (first speed at least ``MOVING_MPS``). "beyond limits" is the share of
recovered steps outside the class's hard control limits (``reach.agent_classes``).

Writes ``results/adapter_error.json``. Data: Argoverse 2, © Argo AI, LLC, CC BY-NC-SA 4.0; the
figures carry that licence.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from frt_client.adapters import from_apollo  # noqa: E402
from frt_client.paths import trajectory_controls  # noqa: E402

from experiments.sensor_tracks import SENSOR_ATTRIBUTION, ClassedTrack, load_all  # noqa: E402
from reach.agent_classes import AGENT_CLASSES  # noqa: E402
from reach.dynamics import unicycle_derivative  # noqa: E402

SAMPLE_DT_S = 0.1
WINDOW_EVERY = 5  # samples between windows (0.5 s)
HORIZON_SAMPLES = 30  # 3 s of future
STEPS_DT_S = (0.1, 0.5)
TIMES_S = (1.0, 2.0, 3.0)
RK4_DT_S = 0.01
APOLLO_TYPES = {"car": "VEHICLE", "cyclist": "BICYCLE", "pedestrian": "PEDESTRIAN"}
METHODS = ("central (adapters)", "first order (trajectory_controls)")
#: A window is "moving" when its first speed is at least this (m/s; below it the estimated
#: heading of a recorded track is the box centres' jitter).
MOVING_MPS = 0.5


def windows(tracks: list[ClassedTrack]) -> list[tuple[str, np.ndarray, tuple[float, ...]]]:
    """(class, future positions (31, 2) every 0.1 s, state (x, y, heading, speed)) per window."""
    out = []
    for c in tracks:
        tr = c.track
        for s in range(0, len(tr.t) - HORIZON_SAMPLES, WINDOW_EVERY):
            future = np.stack(
                [tr.x[s : s + HORIZON_SAMPLES + 1], tr.y[s : s + HORIZON_SAMPLES + 1]], 1
            )
            state = (float(tr.x[s]), float(tr.y[s]), float(tr.heading[s]), float(tr.speed[s]))
            out.append((c.agent_class, future, state))
    return out


def apollo_obstacle(agent_class: str, future: np.ndarray, state: tuple[float, ...]) -> dict:
    """The window as an Apollo PredictionObstacle (protobuf's MessageToDict shape)."""
    x, y, heading, speed = state
    return {
        "perception_obstacle": {
            "position": {"x": x, "y": y},
            "theta": heading,
            "velocity": {"x": speed * math.cos(heading), "y": speed * math.sin(heading)},
            "type": APOLLO_TYPES[agent_class],
        },
        "trajectory": [
            {
                "probability": 1.0,
                "trajectory_point": [
                    {"path_point": {"x": px, "y": py}, "relative_time": k * SAMPLE_DT_S}
                    for k, (px, py) in enumerate(future.tolist())
                ],
            }
        ],
    }


def controls(method: str, window: tuple, dt: float) -> list[list[float]]:
    agent_class, future, state = window
    if method == METHODS[0]:
        piece = from_apollo(apollo_obstacle(agent_class, future, state), dt=dt)
        return piece["prediction"]["modes"][0]["mean"]
    stride = round(dt / SAMPLE_DT_S)
    return trajectory_controls(future[::stride].tolist(), dt, state[2], state[3])


def roll(states: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    """Positions (W, len(TIMES_S), 2) of W unicycles from ``states`` (W, 4) under controls
    ``u`` (W, S, 2) held over steps of ``dt``, by RK4 at ``RK4_DT_S``."""
    substeps = round(dt / RK4_DT_S)
    s = states.astype(float).copy()
    marks = {round(t / RK4_DT_S): i for i, t in enumerate(TIMES_S)}
    out = np.empty((len(s), len(TIMES_S), 2))

    def f(x: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
        return np.stack(unicycle_derivative(x[:, 2], x[:, 3], u1, u2, xp=np), axis=1)

    tick = 0
    for k in range(u.shape[1]):
        u1, u2 = u[:, k, 0], u[:, k, 1]
        for _ in range(substeps):
            k1 = f(s, u1, u2)
            k2 = f(s + 0.5 * RK4_DT_S * k1, u1, u2)
            k3 = f(s + 0.5 * RK4_DT_S * k2, u1, u2)
            k4 = f(s + RK4_DT_S * k3, u1, u2)
            s = s + RK4_DT_S / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
            s[:, 3] = np.maximum(s[:, 3], 0.0)
            tick += 1
            if tick in marks:
                out[:, marks[tick]] = s[:, :2]
    return out


def summary(errors: np.ndarray) -> dict[str, float]:
    return {
        "median": float(np.median(errors)),
        "p95": float(np.percentile(errors, 95)),
        "max": float(errors.max()),
    }


def groups(all_windows: list[tuple]) -> list[tuple[str, str, np.ndarray]]:
    """(class, subset, mask) per class and for all: every window, and the moving ones."""
    classes = np.array([w[0] for w in all_windows])
    moving = np.array([w[2][3] >= MOVING_MPS for w in all_windows])
    out = []
    for name in [*sorted(set(classes)), "all"]:
        of_class = classes == name if name != "all" else np.ones(len(classes), bool)
        out.append((name, "every", of_class))
        if np.any(of_class & moving):
            out.append((name, "moving", of_class & moving))
    return out


def measure(all_windows: list[tuple], method: str, dt: float) -> list[dict[str, Any]]:
    """One row per group (:func:`groups`) of the method at step ``dt``."""
    u = np.array([controls(method, w, dt) for w in all_windows])
    states = np.array([w[2] for w in all_windows])
    rolled = roll(states, u, dt)
    truth = np.stack([[w[1][round(t / SAMPLE_DT_S)] for t in TIMES_S] for w in all_windows])
    error = np.linalg.norm(rolled - truth, axis=2)  # (W, len(TIMES_S))
    limits = np.array([AGENT_CLASSES[w[0]].limits for w in all_windows])  # (W, 2)
    beyond = np.any(np.abs(u) > limits[:, None, :] + 1e-9, axis=2)  # (W, S)
    return [
        {
            "method": method,
            "dt": dt,
            "class": name,
            "windows": subset,
            "n": int(mask.sum()),
            "error_m": {f"{t:g}": summary(error[mask, i]) for i, t in enumerate(TIMES_S)},
            "beyond_limits": float(beyond[mask].mean()),
        }
        for name, subset, mask in groups(all_windows)
    ]


def table(rows: list[dict[str, Any]]) -> str:
    times = " | ".join(f"{t:g} s: median / p95 / max (m)" for t in TIMES_S)
    lines = [
        f"| method | dt (s) | class | windows | n | {times} | beyond limits |",
        "|" + " --- |" * (6 + len(TIMES_S)),
    ]
    for r in rows:
        cells = [
            "{median:.3f} / {p95:.3f} / {max:.3f}".format(**r["error_m"][f"{t:g}"]) for t in TIMES_S
        ]
        lines.append(
            f"| {r['method']} | {r['dt']:g} | {r['class']} | {r['windows']} | {r['n']} | "
            + " | ".join(cells)
            + f" | {100 * r['beyond_limits']:.1f} % |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "adapter_error.json")
    args = parser.parse_args()
    started = time.perf_counter()
    tracks = load_all()
    all_windows = windows(tracks)
    rows = [measure(all_windows, m, dt) for dt in STEPS_DT_S for m in METHODS]
    flat = [r for group in rows for r in group]
    print(table(flat))
    counts = {c: sum(t.agent_class == c for t in tracks) for c in sorted(AGENT_CLASSES)}
    print(f"\n{len(tracks)} tracks {counts}, {len(all_windows)} windows; {SENSOR_ATTRIBUTION}")
    result = {
        "command": ".venv/bin/python scripts/adapter_error.py",
        "method": "frt_client.adapters.from_apollo (path_controls: central differences); "
        "frt_client.paths.trajectory_controls for comparison",
        "windows_every_s": WINDOW_EVERY * SAMPLE_DT_S,
        "horizon_s": HORIZON_SAMPLES * SAMPLE_DT_S,
        "rk4_dt_s": RK4_DT_S,
        "tracks": counts,
        "rows": flat,
        "attribution": SENSOR_ATTRIBUTION,
        "seconds": round(time.perf_counter() - started, 1),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out} in {result['seconds']} s")


if __name__ == "__main__":
    main()
