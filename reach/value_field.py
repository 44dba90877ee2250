"""A value field that may cut a set: the plug-in point of a learned reachability network.

The certified geometry (outer bound, notch partition) gives, at each instant s_j, a region P_j that
holds every reachable position. A value field W(s, x, y) with a calibrated level c_j may cut it:
the set is {W <= c_j} ∩ P_j. Soundness of that cut is the field's claim, not the geometry's: the
network's level is calibrated by scenario optimisation (paper, "Safe Planning"; the model card's
``calibration``), so a cut position is unreachable only with the card's stated confidence. Without
a field the set is P_j itself, which is proven.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from reach.outer_bound import OuterBound


@runtime_checkable
class ValueField(Protocol):
    """W(s, x, y) for one FRT parameter setting, and the level below which a position is kept."""

    #: A short name for reports (``GET /v1/model``).
    name: str

    def covers(self, v_start: float, bounds: np.ndarray) -> bool:
        """Whether the field was trained on this setting (elsewhere it must not cut)."""
        ...

    def levels(self, outer_boxes: np.ndarray) -> np.ndarray:
        """The calibrated level at each instant, from the instants' outer boxes [J, 4]
        (x_lo, x_hi, y_lo, y_hi): [J]."""
        ...

    def values(
        self,
        times: np.ndarray,
        px: np.ndarray,
        py: np.ndarray,
        v_start: float,
        bounds: np.ndarray,
        bound: OuterBound,
    ) -> tuple[np.ndarray, int]:
        """W at the points (times[i], px[i], py[i]) [N] of one setting, and how many network
        evaluations that took. ``bound`` is the setting's outer bound (heading and speed
        intervals over time, for fields that search over them)."""
        ...
