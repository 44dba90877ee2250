"""FRT sets: K at each instant, over each interval between instants, and the tubes up to each.

Slice j is the set reachable at exactly s_j = j * slice_dt; interval j (j >= 1) holds every position
reached during [s_(j-1), s_j]; tube j every position reached during [0, s_j] (set semantics,
API.md, "The model contract"). ``BoxTubeSet`` is the interval outer bound as a set (the conservative
answer); ``reach.field_tube.FieldTubeSet`` the tight one.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry import box
from shapely.geometry.base import BaseGeometry

from reach.distances import box_union_distances, signed_distance, signed_distances
from reach.frames import Pose, to_human_frame, to_world_frame
from reach.geojson import to_geojson
from reach.notch import NotchCut
from reach.packed_rings import PackedRings, pack_rings

#: Consecutive 0.025 s sweeps per window (0.1 s). The conservative set has one box per window;
#: the exact tube is cut to one outer polygon per window, the support functions' maximum over its
#: sweeps, whose four axis supports are that box's sides: the box holds the polygon, so the
#: conservative set holds the exact one. (Polygons over windows longer than the boxes bulge past
#: them between sweeps that step sideways: by up to 0.1 m with 0.1 s polygons and 0.05 s boxes.)
SWEEPS_PER_WINDOW = 4
#: Packs of tubes one set keeps (``FRTSet.packed_tubes``): a planner's batches ask for a few.
MAX_PACKS = 4


class FRTSet:
    """K for every slice and the tubes up to each slice, in the human frame.

    Slice j is the set reachable at exactly ``j * slice_dt``; interval j (j >= 1) contains every
    position reached during [(j - 1) * slice_dt, j * slice_dt]; tube j contains every position
    reached during [0, j * slice_dt]. Subclasses say how each is built.
    """

    #: Whether :meth:`clearance` measures distances to the drawn tubes (a time-indexed check then
    #: needs each tube it asks for drawn); False where a set measures them another way.
    clearance_from_tubes = True
    #: The notch cut this set has had (``reach.notch``), if any.
    notch: NotchCut | None = None
    #: Whether some instant may have a notch behind the car: the notch cut could tighten the set.
    notch_possible = False

    @property
    def notch_stage(self) -> int:
        """How many stages of ``reach.notch.NOTCH_STAGES`` have cut this set (0: uncut)."""
        return 0 if self.notch is None else self.notch.stage

    def __init__(
        self, pose: Pose, slice_dt: float, horizon_s: float, n_slices: int, conservative: bool
    ) -> None:
        self.pose = pose
        self.slice_dt = slice_dt
        self.horizon_s = horizon_s
        self.n_slices = n_slices
        self.conservative = conservative
        self.evaluations = 0
        self._world_cache: dict = {}

    def tube(self, j: int) -> BaseGeometry:
        raise NotImplementedError

    def slice(self, j: int) -> BaseGeometry:
        raise NotImplementedError

    def interval(self, j: int) -> BaseGeometry:
        raise NotImplementedError

    def tube_index(self, t_rel: float) -> int:
        """Index of the tube that contains every position reached in [0, t_rel]."""
        t = min(max(t_rel, 0.0), self.horizon_s)
        return min(math.ceil(t / self.slice_dt - 1e-9), self.n_slices - 1)

    def tube_indices(self, t_rel: np.ndarray) -> np.ndarray:
        """:meth:`tube_index` of every time in ``t_rel`` (flattened), as one int array."""
        t = np.clip(np.asarray(t_rel, dtype=np.float64).reshape(-1), 0.0, self.horizon_s)
        return np.minimum(np.ceil(t / self.slice_dt - 1e-9), self.n_slices - 1).astype(int)

    def tubes_present(self, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The distinct tube indices among ``indices`` (increasing) and each index's place among
        them: ``np.unique(indices, return_inverse=True)`` in one pass (the indices are bounded)."""
        present = np.zeros(self.n_slices, dtype=bool)
        present[indices] = True
        return np.flatnonzero(present), (np.cumsum(present) - 1)[indices]

    def clearance(self, xy_world: np.ndarray, t_rel: np.ndarray | None = None) -> np.ndarray:
        """Signed distance (m) from each world point to K (negative inside).

        ``t_rel`` None: the whole-horizon tube; else, per point, the tube up to ``t_rel`` seconds
        after the observation (clipped to [0, horizon]).
        """
        xy = to_human_frame(np.asarray(xy_world, dtype=float).reshape(-1, 2), self.pose)
        if t_rel is None:
            return signed_distance(self.tube(self.n_slices - 1), xy)
        unique, rows = np.unique(self.tube_indices(t_rel), return_inverse=True)
        tubes = np.empty(len(unique), dtype=object)
        tubes[:] = [self.tube(int(j)) for j in unique]
        return signed_distances(tubes, rows, xy)

    def packed_tubes(self, indices: tuple[int, ...]) -> PackedRings:
        """The tubes ``indices`` packed for ``reach.packed_rings``' kernels (polygon i of the pack
        is tube ``indices[i]``), kept for the next batch check of this set."""
        packs = self.__dict__.setdefault("_packed", {})
        if indices not in packs:
            if len(packs) >= MAX_PACKS:
                packs.clear()
            packs[indices] = pack_rings([self.tube(j) for j in indices])
        return packs[indices]  # type: ignore[no-any-return]

    def missing_tubes(self, indices: list[int]) -> list[int]:
        """The tubes among ``indices`` not drawn yet (none where tubes cost nothing to draw)."""
        return []

    def draw_tubes(self, upto: int | None = None) -> None:
        """Draw the tubes 0..``upto`` (None: every tube) not drawn yet, in increasing order (each
        grows from the one before)."""
        last = self.n_slices - 1 if upto is None else min(upto, self.n_slices - 1)
        for j in self.missing_tubes(list(range(last + 1))):
            self.tube(j)

    def nearest_built_tube(self, j: int) -> int:
        """The smallest tube index >= j already drawn (tubes grow with j: it contains tube j)."""
        return j

    def geometry(self, kind: str, t: float | None = None) -> BaseGeometry:
        """K in the human frame: the whole tube, the tube up to t, or the set at time t: the slice
        if t is one of the slices' instants, else the interval between the two instants around t,
        which contains every position reachable at t (a slice of a nearby instant need not)."""
        if kind == "tube":
            return self.tube(self.n_slices - 1 if t is None else self.tube_index(t))
        if kind == "slice":
            steps = min(max(t or 0.0, 0.0), self.horizon_s) / self.slice_dt
            j = min(round(steps), self.n_slices - 1)
            if abs(steps - j) <= 1e-6:
                return self.slice(j)
            return self.interval(min(math.ceil(steps), self.n_slices - 1))
        raise ValueError(f"unknown kind {kind!r}")

    def geojson(self, kind: str, t: float | None, collision_radius: float) -> dict:
        """{"K": GeoJSON, "C": GeoJSON} in the world frame; C = K ⊕ collision_radius."""
        key = (kind, t, collision_radius)
        if key not in self._world_cache:
            k_set = self.geometry(kind, t)
            c_set = k_set.buffer(collision_radius, quad_segs=8) if collision_radius > 0 else k_set
            self._world_cache[key] = {
                "K": to_geojson(to_world_frame(k_set, self.pose)),
                "C": to_geojson(to_world_frame(c_set, self.pose)),
            }
        return self._world_cache[key]


class BoxTubeSet(FRTSet):
    """The outer bound as a set: tube j is the union of the sweep boxes up to slice j."""

    clearance_from_tubes = False

    def __init__(
        self,
        pose: Pose,
        slice_dt: float,
        horizon_s: float,
        boxes: np.ndarray,
        boxes_until: np.ndarray,
        slice_boxes: np.ndarray,
        interval_boxes: np.ndarray,
    ) -> None:
        super().__init__(pose, slice_dt, horizon_s, len(boxes_until), conservative=True)
        self.boxes = boxes
        self.boxes_until = boxes_until
        self.slice_boxes = slice_boxes
        #: [n_slices, 2]: the boxes [first, last) whose union holds interval j.
        self.interval_boxes = interval_boxes
        self._unions: dict[int, BaseGeometry] = {}

    def clearance(self, xy_world: np.ndarray, t_rel: np.ndarray | None = None) -> np.ndarray:
        """Distance to the union of boxes: exact outside; inside, minus the depth in the deepest
        single box, which is at most the depth in the union (the point is inside either way; the
        union's polygon, costly to build per version, stays out of collision checks)."""
        xy = to_human_frame(np.asarray(xy_world, dtype=float).reshape(-1, 2), self.pose)
        b = self.boxes
        counted = None  # t_rel None: every box counts (the whole-horizon tube)
        if t_rel is not None:
            limit = self.boxes_until[self.tube_indices(t_rel)]
            counted = np.arange(len(b))[None, :] < limit[:, None]
        return box_union_distances(xy[:, :1], xy[:, 1:], b[None, :, :], counted)

    def tube(self, j: int) -> BaseGeometry:
        if j not in self._unions:
            self._unions[j] = _box_union(self.boxes[: self.boxes_until[j]])
        return self._unions[j]

    def slice(self, j: int) -> BaseGeometry:
        return _box(self.boxes[self.slice_boxes[j]])

    def interval(self, j: int) -> BaseGeometry:
        return _box_union(self.boxes[self.interval_boxes[j, 0] : self.interval_boxes[j, 1]])


def _box(bounds: np.ndarray) -> BaseGeometry:
    x_lo, x_hi, y_lo, y_hi = (float(v) for v in bounds)
    return box(x_lo, y_lo, x_hi, y_hi)


def _box_union(boxes: np.ndarray) -> BaseGeometry:
    """The union of boxes [M, 4] given as (x_lo, x_hi, y_lo, y_hi)."""
    return shapely.union_all(shapely.box(boxes[:, 0], boxes[:, 2], boxes[:, 1], boxes[:, 3]))
