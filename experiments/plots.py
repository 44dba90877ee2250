"""Figures of the case studies and of the Argoverse 2 replay (PNG, matplotlib, no display).

Paper figures re-created: ``fig:uturn`` and ``fig:stopline`` (the scene with the FRT with and
without confidence at the moment of detection), ``fig:uturnBel`` (beta over time for several
beta_low), ``fig:gammaComp`` (the FRT for several gamma with the same prediction).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.patches import PathPatch, Polygon
from matplotlib.path import Path as MplPath

from experiments.planner import HORIZON_S
from experiments.run_scenarios import ScenarioRun
from experiments.scenes import CAR_LENGTH_M, LANE_M, Scene, footprint, footprints_overlap
from experiments.sweeps import BetaTrace, GammaFRT

WITH = "#00a6c8"  # cyan: with confidence (as in the paper)
WITHOUT = "#8e44ad"  # purple: without confidence
EGO = "#d62728"
HUMAN = "#1f5fbf"
DPI = 130


def geojson_patch(geometry: dict[str, Any] | None, **style: Any) -> PathPatch | None:
    """A patch of a GeoJSON Polygon or MultiPolygon (holes kept), or None if empty."""
    if not geometry or not geometry.get("coordinates"):
        return None
    polygons = (
        [geometry["coordinates"]] if geometry["type"] == "Polygon" else geometry["coordinates"]
    )
    vertices, codes = [], []
    for rings in polygons:
        for ring in rings:
            ring = np.asarray(ring, dtype=float)
            if len(ring) < 3:
                continue
            vertices.append(ring)
            codes += [MplPath.MOVETO] + [MplPath.LINETO] * (len(ring) - 2) + [MplPath.CLOSEPOLY]
    if not vertices:
        return None
    return PathPatch(MplPath(np.vstack(vertices), codes), **style)


def draw_set(ax: Axes, geometry: dict[str, Any] | None, color: str, label: str, **kw: Any) -> None:
    patch = geojson_patch(geometry, facecolor=color, edgecolor=color, label=label, **kw)
    if patch is not None:
        ax.add_patch(patch)


def draw_car(ax: Axes, x: float, y: float, heading: float, color: str, **kw: Any) -> None:
    ax.add_patch(Polygon(footprint(x, y, heading), closed=True, facecolor=color, **kw))


def draw_scene(ax: Axes, sc: Scene, xlim: tuple[float, float], ylim: tuple[float, float]) -> None:
    """Asphalt, painted lines, stop lines and the other (stopped) cars."""
    ax.set_facecolor("#6b8e4e")
    for x0, x1, y0, y1 in sc.roads():
        ax.add_patch(Polygon([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], facecolor="#555555"))
    for line in sc.lines:
        style = {
            "centre": {"color": "#f1c40f", "lw": 1.2},
            "lane": {"color": "white", "lw": 0.8, "ls": (0, (4, 4))},
            "stop": {"color": "white", "lw": 3.0},
        }[line.kind]
        ax.plot([line.x0, line.x1], [line.y0, line.y1], solid_capstyle="butt", **style)
    for x, y, heading in sc.parked:
        draw_car(ax, x, y, heading, "#9a9a9a", edgecolor="black", lw=0.5)
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def _obs_index(run: ScenarioRun, t: float) -> int:
    """Index of the last observation at or before ``t``: the one whose FRT the planner used."""
    times = [s.t for s in run.steps]
    return max(i for i, ti in enumerate(times) if ti <= t + 1e-9)


def _where(distance_m: float) -> str:
    """ "12.3 m before the stop line" or, once past it, "4.5 m past the stop line"."""
    if distance_m >= 0.0:
        return f"{distance_m:.1f} m before the stop line"
    return f"{-distance_m:.1f} m past the stop line"


def _ego_centre_at_detection(sc: Scene, run: ScenarioRun) -> float:
    assert run.detection is not None
    return sc.stop_line_x - run.detection.distance_to_stop_line_m - CAR_LENGTH_M / 2


def figure_detection(
    sc: Scene, on: ScenarioRun, off: ScenarioRun, out: Path, model_name: str = ""
) -> Path:
    """The scene at the moment of detection with confidence (top) and without (bottom).

    Top: at the first detection with confidence, C with confidence (cyan) and, from the same
    observation, C without confidence (purple): only the first crosses the ego's plan. Bottom: the
    moment the run without confidence finally detects. Both show the ego (red) with its 3 s
    constant-speed plan and where it comes to rest, the human (blue) and its true path.
    """
    human = sc.human_trajectory()
    fig, axes = plt.subplots(2, 1, figsize=(11, 8.6))
    xlim, ylim = (-62.0, 30.0), (-12.0, 13.0)
    panels = [("with confidence", on, [(on, WITH), (off, WITHOUT)]), ("without confidence", off,
              [(off, WITHOUT)])]  # fmt: skip
    for ax, (what, run, sets) in zip(axes, panels, strict=True):
        draw_scene(ax, sc, xlim, ylim)
        ax.plot(human.states[:, 0], human.states[:, 1], color="#9ecae1", lw=1.2, ls=":",
                label="human's true path")  # fmt: skip
        if run.detection is None:
            ax.set_title(f"{sc.title}, {what}: no detection")
            continue
        t_det = run.detection.time_s
        t_obs = run.steps[_obs_index(run, t_det)].t
        for r, color in sets:
            if t_obs not in r.contours:
                continue
            label = "with" if r.confidence else "without"
            draw_set(ax, r.contours[t_obs]["C"], color, f"C {label} confidence", alpha=0.35, lw=1)
            draw_set(ax, r.contours[t_obs]["K"], color, None, alpha=0.55, lw=0.5)
        hx, hy, hh, _ = human.state_at(t_det)
        draw_car(ax, hx, hy, hh, HUMAN, edgecolor="black", lw=0.6, label="human")
        ex = _ego_centre_at_detection(sc, run)
        draw_car(ax, ex, sc.ego_y, 0.0, EGO, edgecolor="black", lw=0.6, label="ego")
        ax.plot([ex, ex + sc.ego_speed_mps * HORIZON_S], [sc.ego_y] * 2, color=EGO, lw=1.2,
                ls="--", label="ego's 3 s plan")  # fmt: skip
        if run.ego_stop_past_line_m is not None:
            sx = sc.stop_line_x + run.ego_stop_past_line_m - CAR_LENGTH_M / 2
            draw_car(ax, sx, sc.ego_y, 0.0, "none", edgecolor="white", lw=1.5, ls="--",
                     label="ego at rest")  # fmt: skip
        d = run.detection
        outcome = "COLLISION" if run.collision else "no collision"
        ax.set_title(
            f"{sc.title}, {what}: detects at t = {t_det:.1f} s (FRT of the observation at "
            f"t = {t_obs:.1f} s), {_where(d.distance_to_stop_line_m)};\n"
            f"brakes at {d.deceleration_mps2:.1f} m/s² for {d.stop_time_s:.2f} s: {outcome}",
            fontsize=10,
        )
        ax.legend(loc="upper left", fontsize=7, framealpha=0.85, ncol=2)
    fig.suptitle(
        "β_low = 0.03 vs β fixed at 1; γ = 0.075, R_col = 1.5 m, T = 3 s"
        + (f" (model {model_name})" if model_name else ""),
        fontsize=11,
    )
    fig.tight_layout()
    fig.savefig(out, dpi=DPI)
    plt.close(fig)
    return out


def figure_beta(traces: Sequence[BetaTrace], scenes: dict[str, Scene], out: Path) -> Path:
    """beta over time for several beta_low, one panel per scene (paper, ``fig:uturnBel``)."""
    names = list(dict.fromkeys(t.scene for t in traces))
    fig, axes = plt.subplots(1, len(names), figsize=(6.2 * len(names), 4.2), squeeze=False)
    cmap = plt.get_cmap("viridis")
    for ax, name in zip(axes[0], names, strict=True):
        rows = [t for t in traces if t.scene == name]
        for k, tr in enumerate(rows):
            color = cmap(k / max(len(rows) - 1, 1))
            ax.plot(tr.t, tr.beta, marker="o", ms=3, color=color, label=f"β_low = {tr.beta_low:g}")
        sc = scenes[name]
        ax.axvline(sc.driver.start_s, color="grey", ls=":", lw=1)
        ax.text(sc.driver.start_s, 1.02, " human starts", color="grey", fontsize=8)
        wrong = [t for t, p in zip(rows[0].t, rows[0].prediction, strict=True) if p == "stop"]
        caught = [t for t, p in zip(rows[0].t, rows[0].prediction, strict=True) if p != "stop"]
        if caught:
            ax.axvspan(min(caught), max(rows[0].t), color="#2ecc71", alpha=0.12,
                       label="predictor has caught on")  # fmt: skip
        if wrong:
            ax.axvspan(sc.driver.start_s, min(caught) if caught else max(wrong), color="#e74c3c",
                       alpha=0.10, label="predictor wrong (\"stop\")")  # fmt: skip
        ax.set_yscale("log")
        ax.set_ylim(0.008, 1.3)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("β (log scale)")
        ax.set_title(f"{sc.title}: model confidence β over time")
        ax.legend(fontsize=8, loc="lower right")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=DPI)
    plt.close(fig)
    return out


def figure_gamma(
    frts: Sequence[GammaFRT], sc: Scene, state: tuple[float, float, float, float], out: Path
) -> Path:
    """K (filled) and C (outline) for each gamma, same prediction and beta (``fig:gammaComp``)."""
    fig, ax = plt.subplots(figsize=(7.5, 6))
    x, y, heading, speed = state
    xlim, ylim = (x - 22.0, x + 12.0), (y - 17.0, y + 10.0)
    draw_scene(ax, sc, xlim, ylim)
    cmap = plt.get_cmap("plasma")
    for k, f in reversed(list(enumerate(frts))):
        color = cmap(0.15 + 0.7 * k / max(len(frts) - 1, 1))
        draw_set(ax, f.K, color, f"K, γ = {f.gamma:g}", alpha=0.55, lw=0.8)
        draw_set(ax, f.C, color, None, fill=False, lw=1.0, ls="--")
    draw_car(ax, x, y, heading, HUMAN, edgecolor="black", lw=0.6)
    ax.set_title(
        f"{sc.title}: FRT for several γ, same prediction, β = {frts[0].beta:.3f}\n"
        f"(human at ({x:.1f}, {y:.1f}), {speed:.1f} m/s; dashed: C = K ⊕ 1.5 m)",
        fontsize=10,
    )
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    fig.savefig(out, dpi=DPI)
    plt.close(fig)
    return out


def figure_speeds(
    runs: dict[str, dict[str, ScenarioRun]], scenes: dict[str, Scene], out: Path
) -> Path:
    """Ego distance to its stop line over time, with and without confidence."""
    fig, axes = plt.subplots(1, len(runs), figsize=(6.2 * len(runs), 3.8), squeeze=False)
    for ax, (name, pair) in zip(axes[0], runs.items(), strict=True):
        sc = scenes[name]
        for mode, color in (("on", WITH), ("off", WITHOUT)):
            run = pair[mode]
            t = np.arange(0.0, sc.duration_s, 0.02)
            front0 = sc.ego_start_x + CAR_LENGTH_M / 2
            d = run.detection
            if d is None:
                pos = front0 + sc.ego_speed_mps * t
            else:
                a = -d.deceleration_mps2
                tau = np.clip(t - d.time_s, 0.0, d.stop_time_s)
                pos = np.where(
                    t < d.time_s,
                    front0 + sc.ego_speed_mps * t,
                    front0
                    + sc.ego_speed_mps * d.time_s
                    + sc.ego_speed_mps * tau
                    - 0.5 * a * tau**2,
                )
            label = f"confidence {mode}" + (" — collision" if run.collision else "")
            ax.plot(t, pos - sc.stop_line_x, color=color, label=label)
            if d is not None:
                ax.plot([d.time_s], [-d.distance_to_stop_line_m], "o", color=color)
            if run.collision_time_s is not None:
                k = int(min(run.collision_time_s / 0.02, len(t) - 1))
                ax.plot([run.collision_time_s], [pos[k] - sc.stop_line_x], "x", color="black", ms=9)
        inside = _in_ego_lane(sc)
        for k, (t0, t1) in enumerate(inside):
            ax.axvspan(
                t0, t1, color=HUMAN, alpha=0.12, label="human in the ego's lane" if k == 0 else None
            )
        ax.axhline(0.0, color="grey", lw=0.8)
        ax.set_ylim(-80, 30)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("ego front past its stop line (m)")
        predictor = " (bimodal predictor)" if name.endswith("_bimodal") else ""
        ax.set_title(f"{sc.title}{predictor}: the ego's front (dot: detection, x: collision)")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=DPI)
    plt.close(fig)
    return out


def _in_ego_lane(sc: Scene, dt: float = 0.05) -> list[tuple[float, float]]:
    """Time intervals during which the human's footprint overlaps the ego's lane."""
    human = sc.human_trajectory()
    half = LANE_M / 2
    lane = np.array([[-500.0, sc.ego_y - half], [500.0, sc.ego_y - half],
                     [500.0, sc.ego_y + half], [-500.0, sc.ego_y + half]])  # fmt: skip
    spans: list[tuple[float, float]] = []
    start = None
    times = np.arange(0.0, sc.duration_s + 1e-9, dt)
    for t in times:
        x, y, heading, _ = human.state_at(float(t))
        inside = footprints_overlap(footprint(x, y, heading), lane)
        if inside and start is None:
            start = float(t)
        if not inside and start is not None:
            spans.append((start, float(t)))
            start = None
    if start is not None:
        spans.append((start, float(times[-1])))
    return spans


def figure_av2(
    result: dict[str, Any], lanes: dict[str, list[np.ndarray]], attribution: str, out: Path
) -> Path:
    """Left: the map, the tracks and one observation's C with and without confidence.
    Right: coverage of the actual 3 s futures by K and C, and the mean area of C."""
    tracks = result["tracks"]
    replays = result["replays"]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 6), gridspec_kw={"width_ratios": [1.2, 1]})
    ax.set_facecolor("#e8efe0")
    for poly in lanes["drivable"]:
        ax.add_patch(Polygon(poly, closed=True, facecolor="#9a9a9a", edgecolor="none"))
    for poly in lanes["crossings"]:
        ax.add_patch(Polygon(poly, closed=True, facecolor="#f5f5f5", edgecolor="#aaaaaa", lw=0.4))
    for line in lanes["lanes"]:
        ax.plot(line[:, 0], line[:, 1], color="white", lw=0.6)
    on, off = replays["on"].observations, replays["off"].observations
    # the example: a moving car inside the mapped area where confidence helped most (more of the
    # actual future inside K), then where it widened C most
    mapped = np.vstack(lanes["drivable"])
    y_lo, y_hi = float(mapped[:, 1].min()) + 30.0, float(mapped[:, 1].max()) - 30.0
    where = {
        (t.track_id, round(float(tt), 2)): float(y)
        for t in tracks
        for tt, y in zip(t.t, t.y, strict=True)
    }
    pairs = [
        (a, b)
        for a, b in zip(on, off, strict=True)
        if a.speed >= 2.0 and a.t == b.t and y_lo <= where[(a.track_id, round(a.t, 2))] <= y_hi
    ]
    example = max(
        pairs, key=lambda p: (p[0].in_k - p[1].in_k, p[0].area_c - p[1].area_c), default=None
    )
    for tr in tracks:
        moving = float(np.mean(tr.speed)) >= 1.0
        ax.plot(tr.x, tr.y, color="#1f77b4" if moving else "#7f7f7f", lw=1.2 if moving else 0.8)
        ax.plot(tr.x[-1:], tr.y[-1:], ">" if moving else "s", color="#1f77b4" if moving
                else "#7f7f7f", ms=3)  # fmt: skip
    if example is not None:
        a, _ = example
        key = (a.track_id, round(a.t, 2))
        sets = result["contours"]
        if sets.get("on") and key in sets["on"]:
            draw_set(ax, sets["on"][key]["C"], WITH, f"C with confidence (β = {a.beta:.2f})",
                     alpha=0.35)  # fmt: skip
            draw_set(ax, sets["off"][key]["C"], WITHOUT, "C without confidence (β = 1)", alpha=0.4)
        tr = next(t for t in tracks if t.track_id == a.track_id)
        i = int(np.argmin(np.abs(tr.t - a.t)))
        ax.plot(tr.x[i : i + 31], tr.y[i : i + 31], "k.", ms=2.5, label="actual next 3 s")
        ax.plot(
            tr.x[i], tr.y[i], "o", color=HUMAN, ms=5, label=f"track {a.track_id}, t = {a.t:.1f} s"
        )
        ax.set_xlim(tr.x[i] - 45, tr.x[i] + 45)
        ax.set_ylim(tr.y[i] - 45, tr.y[i] + 45)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, city frame)")
    ax.set_ylabel("y (m)")
    ax.set_title(
        "Argoverse 2 scenario 0a1e6f0a (Austin): vehicle tracks\n(blue: moving, grey: stopped)",
        fontsize=10,
    )
    ax.legend(fontsize=7, loc="lower left")
    # bars
    labels = ["in K", "in C", "in K\n(time-indexed)", "moving:\nin K", "moving:\nin C"]
    vals = {}
    for mode, rep in replays.items():
        s = rep.summary()
        vals[mode] = [s["fraction_in_K"], s["fraction_in_C"], s["fraction_in_K_time_indexed"],
                      s["moving"]["fraction_in_K"], s["moving"]["fraction_in_C"]]  # fmt: skip
    xs = np.arange(len(labels))
    for k, (mode, color) in enumerate((("on", WITH), ("off", WITHOUT))):
        s = replays[mode].summary()
        bars = bx.bar(xs + (k - 0.5) * 0.38, vals[mode], 0.38, color=color,
                      label=f"confidence {mode}: mean area of C {s['mean_area_C_m2']:.0f} m²")  # fmt: skip
        for rect, v in zip(bars, vals[mode], strict=True):
            bx.text(rect.get_x() + rect.get_width() / 2, v + 0.005, f"{v:.1%}", ha="center",
                    fontsize=7, rotation=90, va="bottom")  # fmt: skip
    lo = min(min(v) for v in vals.values())
    bx.set_ylim(max(0.0, math.floor(lo * 10) / 10 - 0.1), 1.06)
    bx.set_xticks(xs, labels, fontsize=8)
    bx.set_ylabel("fraction of actual positions over the next 3 s")
    n = replays["on"].summary()["observations"]
    bx.set_title(f"{len(tracks)} vehicle tracks, {n} observations every 0.5 s", fontsize=10)
    bx.legend(fontsize=8, loc="lower right")
    bx.grid(axis="y", alpha=0.3)
    fig.text(0.5, 0.005, attribution, ha="center", fontsize=7, color="#444444")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(out, dpi=DPI)
    plt.close(fig)
    return out
