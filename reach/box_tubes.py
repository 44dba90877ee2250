"""The conservative sets of many settings at once: each setting's interval outer bound
(``reach.outer_bound``) as a tube of boxes (``reach.sets.BoxTubeSet``), the outer bounds of
every setting propagated together (``outer_boxes``: each row by the same operations whatever the
others, so a setting gets bit for bit the set it gets alone).

Tube j holds the sweep boxes up to s_j + slice_dt / 2 (the half slice rounded up), merged
``SWEEPS_PER_WINDOW`` at a time (a box around each window: a superset that holds the exact set's
outer polygons, and fewer boxes for a check of many agents to measure).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Protocol

import numpy as np

from reach.contract import InitialSet
from reach.frames import Pose
from reach.outer_bound import outer_boxes
from reach.sets import SWEEPS_PER_WINDOW, BoxTubeSet


class BoxGrid(Protocol):
    """What lays out an engine's box tubes (``reach.engine.FRTEngine`` has it)."""

    horizon: float
    slice_dt: float
    n_slices: int
    outer_steps: int
    outer_steps_per_slice: int
    initial_set: InitialSet


@dataclass(frozen=True)
class _Layout:
    """Which boxes (windows of sweeps) each slice, interval and tube of a grid holds; the same
    for every setting, shared read-only by its sets."""

    groups: int
    boxes_until: np.ndarray
    slice_boxes: np.ndarray
    interval_boxes: np.ndarray


@lru_cache(maxsize=16)
def _layout(n_slices: int, per_slice: int, n: int) -> _Layout:
    k, g = per_slice, SWEEPS_PER_WINDOW
    until = np.array([math.ceil(min(j * k + (k + 1) // 2, n) / g) for j in range(n_slices)])
    slices = np.array([min(j * k, n - 1) // g for j in range(n_slices)])
    intervals = np.array(
        [
            [min(max(j - 1, 0) * k, n - 1) // g, math.ceil(max(j * k, 1) / g)]
            for j in range(n_slices)
        ]
    )
    for array in (until, slices, intervals):
        array.flags.writeable = False
    return _Layout(math.ceil(n / g), until, slices, intervals)


def windowed(sweeps: np.ndarray, groups: int) -> np.ndarray:
    """The box around each window of ``SWEEPS_PER_WINDOW`` sweeps of each row ([B, n, 4] ->
    [B, groups, 4]); the last window padded with the last sweep."""
    b, n = sweeps.shape[:2]
    g = SWEEPS_PER_WINDOW
    pad = np.repeat(sweeps[:, -1:], groups * g - n, axis=1)
    grouped = np.concatenate([sweeps, pad], axis=1).reshape(b, groups, g, 4)
    return np.stack(
        [
            grouped[..., 0].min(axis=2),
            grouped[..., 1].max(axis=2),
            grouped[..., 2].min(axis=2),
            grouped[..., 3].max(axis=2),
        ],
        axis=2,
    )


def box_tubes_of(grid: BoxGrid, poses: Sequence[Pose], sweeps: np.ndarray) -> list[BoxTubeSet]:
    """The box tube of each pose and its outer bound's sweep boxes [B, n, 4]."""
    layout = _layout(grid.n_slices, grid.outer_steps_per_slice, sweeps.shape[1])
    boxes = windowed(sweeps, layout.groups)
    return [
        BoxTubeSet(
            pose=pose,
            slice_dt=grid.slice_dt,
            horizon_s=grid.horizon,
            boxes=boxes[i],
            boxes_until=layout.boxes_until,
            slice_boxes=layout.slice_boxes,
            interval_boxes=layout.interval_boxes,
        )
        for i, pose in enumerate(poses)
    ]


def box_tubes(
    grid: BoxGrid, poses: Sequence[Pose], v_starts: Sequence[float], bounds: np.ndarray
) -> list[BoxTubeSet]:
    """The conservative set of each setting (pose, v_start, a row of ``bounds`` [B, 8]): its
    outer bound's box tube, every outer bound propagated together."""
    sweeps = outer_boxes(
        np.asarray(v_starts, dtype=np.float64),
        np.asarray(bounds, dtype=np.float64).reshape(-1, 8),
        grid.horizon,
        grid.outer_steps,
        8,
        grid.initial_set,
    )
    return box_tubes_of(grid, poses, sweeps)
