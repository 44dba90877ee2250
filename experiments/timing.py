"""How much the outcome depends on when the ego arrives: a sweep over the ego's start.

The paper's scenes are recorded edge cases; ours are built, and the one free choice that decides
the outcome is where the ego starts, i.e. when it would reach its stop line at 21 m/s. This sweep
re-runs each scene (confidence on and off) for a range of arrival times and reports for which of
them the paper's outcome holds (safe stop with confidence, collision without), so the chosen start
can be seen to sit inside that window rather than on its edge.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from experiments.run_scenarios import run_scenario
from experiments.scenes import Scene, arrival_for_start, scene, start_for_arrival


@dataclass(frozen=True)
class TimingRow:
    """One arrival time: the outcome with confidence and without."""

    arrival_s: float
    ego_start_x: float
    on_collision: bool
    on_detection_m: float | None
    off_collision: bool
    off_detection_m: float | None

    @property
    def paper_outcome(self) -> bool:
        """Safe with confidence, collision without."""
        return (not self.on_collision) and self.off_collision


def sweep(client: Any, name: str, arrivals: Sequence[float]) -> list[TimingRow]:
    """Run scene ``name`` with the ego arriving at each of ``arrivals`` (s)."""
    rows = []
    for arrival in arrivals:
        sc: Scene = scene(name, ego_start_x=start_for_arrival(float(arrival)))
        on = run_scenario(client, sc, True, keep_contours=False)
        off = run_scenario(client, sc, False, keep_contours=False)
        rows.append(
            TimingRow(
                arrival_s=round(float(arrival), 3),
                ego_start_x=round(sc.ego_start_x, 2),
                on_collision=on.collision,
                on_detection_m=None
                if on.detection is None
                else on.detection.distance_to_stop_line_m,
                off_collision=off.collision,
                off_detection_m=None
                if off.detection is None
                else off.detection.distance_to_stop_line_m,
            )
        )
    return rows


def window(rows: Sequence[TimingRow]) -> tuple[float, float] | None:
    """The widest contiguous range of arrival times over which the paper's outcome holds."""
    best: tuple[float, float] | None = None
    start = None
    for k, row in enumerate(rows):
        if row.paper_outcome and start is None:
            start = k
        if start is not None and (not row.paper_outcome or k == len(rows) - 1):
            end = k if row.paper_outcome else k - 1
            span = (rows[start].arrival_s, rows[end].arrival_s)
            if best is None or span[1] - span[0] > best[1] - best[0]:
                best = span
            start = None
    return best


def default_arrivals(centre: float, half_width: float = 1.0, step: float = 0.25) -> np.ndarray:
    """A grid of arrival times around ``centre``."""
    return np.round(np.arange(centre - half_width, centre + half_width + 1e-9, step), 3)


__all__ = [
    "TimingRow",
    "arrival_for_start",
    "default_arrivals",
    "start_for_arrival",
    "sweep",
    "window",
]
