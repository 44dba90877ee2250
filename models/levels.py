"""Conditional calibration of the projection network's level: a table over (time, set size).

One scalar margin over all parameter settings is set by the hardest ones (wide, low-confidence
bounds late in the horizon) and inflates every narrow set. Instead, calibration samples are binned
by the slice time s and by the size of the guaranteed outer bound at the horizon (its box diagonal,
a proxy for how wide the bounds are), and each cell gets the largest value seen at reachable states
in it (scenario optimisation per cell). The table is made non-decreasing in both time and size, so a
later or larger set never gets a tighter level than an earlier or smaller one.

Torch-free: the service imports it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LevelTable:
    time_edges: np.ndarray  # [T + 1], increasing
    size_edges: np.ndarray  # [S + 1], increasing
    table: np.ndarray  # [T, S]
    counts: np.ndarray  # [T, S] calibration samples per cell

    def level(self, s: float, size: float) -> float:
        i = int(
            np.clip(np.searchsorted(self.time_edges, s, side="right") - 1, 0, len(self.table) - 1)
        )
        j = int(
            np.clip(
                np.searchsorted(self.size_edges, size, side="right") - 1, 0, self.table.shape[1] - 1
            )
        )
        return float(self.table[i, j])

    def to_dict(self) -> dict:
        return {
            "time_edges": self.time_edges.tolist(),
            "size_edges": self.size_edges.tolist(),
            "table": self.table.tolist(),
            "counts": self.counts.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict) -> LevelTable:
        return cls(
            np.asarray(data["time_edges"], float),
            np.asarray(data["size_edges"], float),
            np.asarray(data["table"], float),
            np.asarray(data["counts"], int),
        )


def calibrate_levels(
    s: np.ndarray, size: np.ndarray, values: np.ndarray, time_edges: np.ndarray, size_bins: int
) -> LevelTable:
    """Per cell, the max of ``values`` (W at reachable states); empty cells take their neighbours'
    monotone envelope; the first and last size edges are opened to cover any size."""
    inner = np.quantile(size, np.linspace(0, 1, size_bins + 1)[1:-1])
    size_edges = np.concatenate([[0.0], inner, [np.inf]])
    ti = np.clip(np.searchsorted(time_edges, s, side="right") - 1, 0, len(time_edges) - 2)
    si = np.clip(np.searchsorted(size_edges, size, side="right") - 1, 0, size_bins - 1)
    table = np.full((len(time_edges) - 1, size_bins), -np.inf)
    counts = np.zeros_like(table, dtype=int)
    np.maximum.at(table, (ti, si), values)
    np.add.at(counts, (ti, si), 1)
    table = np.maximum.accumulate(np.maximum.accumulate(table, axis=0), axis=1)
    table[~np.isfinite(table)] = float(values.max())
    return LevelTable(np.asarray(time_edges, float), size_edges, table, counts)
