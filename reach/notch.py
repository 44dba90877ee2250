"""The notch cut: a set whose car may head backwards is cut to the speed-coupled partition.

An instant whose heading interval passes +-NOTCH_HEADING may have a notch behind the car that no
convex bound has; there the set is intersected with the union of the partition's bin polygons
(``reach.partition.partition_supports``), each swept along its headings by how far a car moves in
half an instant (``reach.partition.swept_supports``). Every bin holds every trajectory that ends in
it, so the cut keeps every reachable position. It runs in stages, coarse to fine
(``NOTCH_STAGES``): the service serves each as soon as it is done.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from reach.partition import WAYPOINT_AT

#: The notch cut (``FRTEngine.exact(notch_cut=True)``; the service refines its sets with it in the
#: background): instants whose heading interval passes NOTCH_HEADING (the car may head backwards,
#: so the set may have a notch behind it) are cut to a speed-coupled partition
#: (``reach.partition.partition_supports``) of one of NOTCH_STAGES.
NOTCH_HEADING = math.pi / 2

#: Whether a set is refined by the notch cut unless its caller says otherwise: what
#: ``make evaluate`` measures as served.
NOTCH_CUT_BY_DEFAULT = True


@dataclass(frozen=True)
class NotchPartition:
    """How finely one stage of the notch cut partitions the trajectories: final-heading bins,
    waypoint heading bins in each (a count per waypoint, at those fractions of the time;
    ``partition_supports``), sub-intervals of its speed programmes, and support directions of its
    bins' polygons (evenly spaced)."""

    heading_bins: int
    waypoint_bins: tuple[int, ...]
    waypoint_at: tuple[float, ...]
    steps: int
    n_directions: int

    @property
    def directions(self) -> np.ndarray:
        return np.arange(self.n_directions) * (2 * math.pi / self.n_directions)


#: The notch cut's stages, coarse to fine: the service refines a set by each in turn, each landing
#: as soon as it is done, the quick one well before the fine one (``make bench`` measures both); a
#: later stage is skipped when it would land after the next observation. The fine stage's waypoint
#: bins pin the heading at a fifth and at half of the time (each split over the interval its bin
#: leaves), where the notch's walls are made, and its 32 directions fit each bin's polygon closer
#: (docs/model.md compares the partitions tried).
NOTCH_STAGES = (
    NotchPartition(32, waypoint_bins=(), waypoint_at=(), steps=90, n_directions=16),
    NotchPartition(
        32, waypoint_bins=(4, 2), waypoint_at=(WAYPOINT_AT, 0.5), steps=90, n_directions=32
    ),
)


@dataclass(frozen=True)
class NotchCut:
    """The partition at the instants of a set it cuts (``cut`` [J], C of them): supports [C, B, M],
    ``empty`` bins [C, B] and each bin's headings [C, B, 2], one row per cut instant in order; per
    instant the farthest a car moves in half an instant either side of it (``reach_m`` [J]), and
    how far its heading turns meanwhile; the stage that made it and its support directions [M].
    (Only the cut instants' rows: a cached refined set keeps them for its slices.)"""

    cut: np.ndarray
    supports: np.ndarray
    empty: np.ndarray
    headings: np.ndarray
    reach_m: np.ndarray
    turn_rad: float
    #: Which of NOTCH_STAGES made it (1 for the first).
    stage: int
    directions: np.ndarray
