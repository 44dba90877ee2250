"""The FRT engine: from (pose, v_start, control bounds) to the sets K and C and the answers on them.

Paper, "Safe Planning": K is the projection of the reachable set onto (x, y); C = K ⊕ R_col.
The value network has *set* semantics (reachable at exactly time s); the tube up to t is the union of
the sets over s <= t (API.md, "The model contract").

How a set is built (human frame: origin at the human, heading 0):

* time is cut into slices s_j = j * slice_dt; at each instant the guaranteed outer bound of
  ``models.outer_bound`` gives a convex polygon (16 support directions) containing every reachable
  position, and one lattice of (x, y) nodes covers them all;
* the network's projection W (or, without the distilled projection, the minimum of V over a small
  heading/speed stencil around the arc-consistent guess) is evaluated only at the nodes inside each
  instant's polygon, in one runtime call; the field max(W - level, polygon) gives K at s_j;
* between instants a car moves at most v_max * slice_dt / 2 from the nearer one, so the tube is the
  union of the instants' fields dilated on the grid by that much, each cut to the outer polygons of
  its interval: a running minimum of fields, contoured once (``FieldTubeSet``) - no polygon unions
  of near-identical slices, which made GEOS crawl for a parked car.

Every exact set is contained in the outer bound by construction, so the outer bound is a valid
conservative answer whenever the exact set is not ready (API.md: "conservative": true).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import overload

import contourpy
import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import box
from shapely.geometry.base import BaseGeometry
from shapely.geometry.polygon import orient

from models.contract import BOUND_COLUMNS, COL, N_INPUTS
from models.corridor_bound import (
    WAYPOINT_AT,
    bin_headings,
    bins_union,
    grown_to_hold,
    max_turn_rate,
    partition_supports,
    swept_supports,
)
from models.dynamics import wrap_angle
from models.outer_bound import (
    SUPPORT_DIRECTIONS,
    OuterBound,
    box_scale,
    convex_polygons,
    half_plane_polygons,
    outer_bound,
)
from service.field_stack import (
    FAR,
    WindowStack,
    block_reduce,
    dilate_discs,
    span_reduce,
)
from service.model_runtime import ValueModel
from service.refine import coarse_to_fine

#: Consecutive 0.025 s sweeps per window (0.1 s). The conservative set has one box per window;
#: the exact tube is cut to one outer polygon per window, the support functions' maximum over its
#: sweeps, whose four axis supports are that box's sides: the box holds the polygon, so the
#: conservative set holds the exact one. (Polygons over windows longer than the boxes bulge past
#: them between sweeps that step sideways: by up to 0.1 m with 0.1 s polygons and 0.05 s boxes.)
SWEEPS_PER_WINDOW = 4

#: The notch cut (``exact(notch_cut=True)``; the service refines its sets with it in the
#: background, ``FRT_FRT_NOTCH_CUT``): instants whose heading interval passes NOTCH_HEADING (the car
#: may head backwards, so the set may have a notch behind it) are cut to a speed-coupled partition
#: (``models.corridor_bound.partition_supports``) of one of NOTCH_STAGES.
NOTCH_HEADING = math.pi / 2


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
#: as soon as it is done, so a planner gets the quick cut ~0.1 s after an observation and the fine
#: one ~1.3 s after it if no newer observation has come first (``make bench``; a later stage is
#: skipped when it would land after the next observation). The fine stage's waypoint bins pin
#: the heading at a fifth and at half of the time (each split over the interval its bin leaves),
#: where the notch's walls are made, and its 32 directions fit each bin's polygon closer: on the
#: four settings with rows over 1.5 m (one-off runs of the evaluation with ``--only``), 4 x 2
#: waypoint bins left none over (at most 1.37 m), 8 x 2 none (1.25 m) for twice the time, 8 bins
#: split over the whole forward interval at a fifth of the time one (1.68 m); docs/model.md.
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
    (Only the cut instants' rows: a cached refined set keeps them for its slices, ~60 kB for the
    first stage.)"""

    cut: np.ndarray
    supports: np.ndarray
    empty: np.ndarray
    headings: np.ndarray
    reach_m: np.ndarray
    turn_rad: float
    #: Which of NOTCH_STAGES made it (1 for the first).
    stage: int
    directions: np.ndarray


#: Slice spacing when the distilled projection network is present (its level is calibrated on the
#: 0.05 s grid, which contains this one).
PROJECTION_SLICE_DT = 0.1


@dataclass(frozen=True)
class Pose:
    """The human's world pose at the observation time."""

    x: float
    y: float
    heading: float


class OutOfRangeError(ValueError):
    """A parameter lies outside the model's trained range (answered with 422)."""

    def __init__(self, field: str, value: float, lo: float, hi: float) -> None:
        super().__init__(f"{field}={value:g} is outside the model's trained range [{lo:g}, {hi:g}]")
        self.field = field
        self.value = value
        self.lo = lo
        self.hi = hi


def human_frames(xy_world: np.ndarray, poses: Sequence[Pose]) -> tuple[np.ndarray, np.ndarray]:
    """World points [N, 2] in the frame of each of A humans (origin at the human, heading 0):
    x, y [A, N]. One definition for a single set and for a check of many."""
    c = np.array([[math.cos(p.heading)] for p in poses])
    s = np.array([[math.sin(p.heading)] for p in poses])
    dx = xy_world[None, :, 0] - np.array([[p.x] for p in poses])
    dy = xy_world[None, :, 1] - np.array([[p.y] for p in poses])
    return c * dx + s * dy, -s * dx + c * dy


def to_human_frame(xy_world: np.ndarray, pose: Pose) -> np.ndarray:
    """World points [N, 2] -> the human frame (origin at the human, heading 0)."""
    x, y = human_frames(xy_world, [pose])
    return np.stack([x[0], y[0]], axis=1)


def to_world_frame(geometry: BaseGeometry, pose: Pose) -> BaseGeometry:
    c, s = math.cos(pose.heading), math.sin(pose.heading)
    return affinity.affine_transform(geometry, [c, -s, s, c, pose.x, pose.y])


def signed_distance(geometry: BaseGeometry, xy: np.ndarray) -> np.ndarray:
    """Distance from each point to ``geometry``; negative inside (minus the depth).

    Outside a polygon the distance to it is the distance to its boundary, so one distance call
    serves both sides."""
    if geometry.is_empty:
        return np.full(len(xy), np.inf)
    inside = shapely.contains_xy(geometry, xy[:, 0], xy[:, 1])
    distance = shapely.distance(geometry.boundary, shapely.points(xy))
    return np.where(inside, -distance, distance)


def box_union_distances(
    x: np.ndarray, y: np.ndarray, boxes: np.ndarray, counted: np.ndarray | None = None
) -> np.ndarray:
    """Distance from points to a union of axis-aligned boxes, for many sets at once: ``x``, ``y``
    [..., N, 1], ``boxes`` [..., 1, M, 4] as (x_lo, x_hi, y_lo, y_hi), ``counted`` [..., N, M]
    (None: every box counts for every point). Exact outside the union; inside, minus the depth
    in the deepest single box (at most the depth in the union).

    Per box: ``max(dx, dy)`` inside it (both <= 0), else the hypotenuse of their positive parts;
    squared distances are compared and one square root taken per point."""
    dx = np.maximum(boxes[..., 0] - x, x - boxes[..., 1])  # [..., N, M]
    dy = np.maximum(boxes[..., 2] - y, y - boxes[..., 3])
    depth = np.maximum(dx, dy)
    np.maximum(dx, 0.0, out=dx)
    np.maximum(dy, 0.0, out=dy)
    np.multiply(dx, dx, out=dx)
    np.multiply(dy, dy, out=dy)
    np.add(dx, dy, out=dx)
    if counted is not None:
        depth[~counted] = np.inf
        dx[~counted] = np.inf
    least = depth.min(axis=-1)
    return np.where(least <= 0.0, least, np.sqrt(dx.min(axis=-1)))


def signed_distances(geometries: np.ndarray, rows: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``signed_distance(geometries[rows[i]], xy[i])`` for every point i, in one vectorised call
    each; each geometry is prepared and its boundary taken once, however many points it serves."""
    shapely.prepare(geometries)  # what contains_xy does to a single geometry: in place, kept
    inside = shapely.contains_xy(geometries[rows], xy[:, 0], xy[:, 1])
    distance = shapely.distance(shapely.boundary(geometries)[rows], shapely.points(xy))
    signed = np.where(inside, -distance, distance)
    return np.where(shapely.is_empty(geometries)[rows], np.inf, signed)


class FRTSet:
    """K for every slice and the tubes up to each slice, in the human frame.

    Slice j is the set reachable at exactly ``j * slice_dt``; interval j (j >= 1) contains every
    position reached during [(j - 1) * slice_dt, j * slice_dt]; tube j contains every position
    reached during [0, j * slice_dt]. Subclasses say how each is built.
    """

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

    def missing_tubes(self, indices: list[int]) -> list[int]:
        """The tubes among ``indices`` not drawn yet (none where tubes cost nothing to draw)."""
        return []

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
                "K": _geojson(to_world_frame(k_set, self.pose)),
                "C": _geojson(to_world_frame(c_set, self.pose)),
            }
        return self._world_cache[key]


class BoxTubeSet(FRTSet):
    """The outer bound as a set: tube j is the union of the sweep boxes up to slice j."""

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
        union's polygon, 1-5 ms to build per version, stays out of collision checks)."""
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


@dataclass(frozen=True)
class Lattice:
    """Nodes x0 + i * step, y0 + k * step shared by every slice of one set."""

    x0: float
    y0: float
    step: float
    nx: int
    ny: int

    def xs(self, i0: int, i1: int) -> np.ndarray:
        return self.x0 + self.step * np.arange(i0, i1)

    def ys(self, k0: int, k1: int) -> np.ndarray:
        return self.y0 + self.step * np.arange(k0, k1)


@dataclass(frozen=True)
class SliceField:
    """Field values on the lattice window [k0:k0+ny, i0:i0+nx]; +inf outside the window."""

    k0: int
    i0: int
    values: np.ndarray  # [ny, nx]

    def contour(self, lattice: Lattice) -> BaseGeometry:
        ny, nx = self.values.shape
        xs, ys = lattice.xs(self.i0, self.i0 + nx), lattice.ys(self.k0, self.k0 + ny)
        return _filled_contour(xs, ys, self.values, 0.0)


class SliceFields:
    """The fields of every slice of one set, held as few objects: offsets in two integer arrays and
    the values in a tuple of arrays (neither is traversed by the garbage collector, whose full
    collections otherwise walked ~60 small objects per cached exact set: ~35 ms pauses with the
    cache full). Indexing gives :class:`SliceField` views."""

    def __init__(self, k0: np.ndarray, i0: np.ndarray, values: tuple[np.ndarray, ...]) -> None:
        self.k0 = np.asarray(k0, dtype=np.int64)
        self.i0 = np.asarray(i0, dtype=np.int64)
        self.values = tuple(values)

    def __len__(self) -> int:
        return len(self.values)

    @overload
    def __getitem__(self, j: int) -> SliceField: ...

    @overload
    def __getitem__(self, j: slice) -> list[SliceField]: ...

    def __getitem__(self, j: int | slice) -> SliceField | list[SliceField]:
        if isinstance(j, slice):
            return [self[i] for i in range(*j.indices(len(self)))]
        return SliceField(int(self.k0[j]), int(self.i0[j]), self.values[j])


#: A corner of an outer polygon turns by 2 pi / 16 = 22.5 degrees; the contour draws a chord across
#: it between points on the grid lines within a cell diagonal of the corner, which cuts at most
#: sqrt(2) sin(11.25 deg) = 0.28 node steps inside.
CORNER_CHORD = 0.3

#: An instant whose outer polygon holds fewer lattice nodes than this is not resolved by the grid
#: (a small early set on a lattice sized for the late, large ones): its outer polygon stands for K.
MIN_NODES_INSIDE = 16


def running_minimum(fields: list[SliceField]) -> SliceField:
    """The pointwise minimum of several windowed fields, on the window covering them all."""
    k0 = min(f.k0 for f in fields)
    i0 = min(f.i0 for f in fields)
    k1 = max(f.k0 + f.values.shape[0] for f in fields)
    i1 = max(f.i0 + f.values.shape[1] for f in fields)
    out = np.full((k1 - k0, i1 - i0), FAR, dtype=np.float32)
    for f in fields:
        ny, nx = f.values.shape
        window = out[f.k0 - k0 : f.k0 - k0 + ny, f.i0 - i0 : f.i0 - i0 + nx]
        np.minimum(window, f.values, out=window)
    return SliceField(k0, i0, out)


class FieldTubeSet(FRTSet):
    """The model's set from per-slice fields on one lattice; contours drawn lazily and cached.

    Per slice j (instant s_j = j * slice_dt):

    * ``instant[j]`` = max(W - level, P_j) with P_j the outer polygon at s_j (negative inside):
      K at s_j is {instant_j <= 0};
    * ``sweep[j]`` (j >= 1) = max(min(instant_(j-1), instant_j) grown by v_max * slice_dt / 2, Q_j)
      with Q_j the outer polygons of [s_(j-1), s_j]: a position reached during that interval is
      within v_max * dt / 2 of K at the nearer of its two ends, and inside Q_j. sweep[0] = instant[0],
      the initial set.

    Tube j is {min over i <= j of sweep_i <= 0} (the growth of instant_j spans one node step more,
    so a thin part of the set between nodes is not lost), grown by the contour's corner chords and
    cut to a union of outer polygons of [0, s_j], one per window of the conservative box tube,
    whose box holds it.
    """

    def __init__(
        self,
        pose: Pose,
        slice_dt: float,
        horizon_s: float,
        lattice: Lattice,
        instant: SliceFields,
        sweep: SliceFields,
        bound: OuterBound,
        bound_rows: list[int],
        outer: BoxTubeSet,
        coarse: np.ndarray | None = None,
        notch: NotchCut | None = None,
        notch_possible: bool = False,
    ) -> None:
        super().__init__(pose, slice_dt, horizon_s, len(instant), conservative=False)
        #: If set, every set drawn is also cut to the partition (``_notch_*``).
        self.notch = notch
        #: Whether some instant's heading interval passes +-NOTCH_HEADING: a cut could tighten
        #: this set (``FRTEngine.exact(notch_cut=True)``).
        self.notch_possible = notch_possible
        self._notch_regions: dict[tuple[int, bool, bool], BaseGeometry] = {}
        self._notch_tubes: dict[int, BaseGeometry] = {}
        self.lattice = lattice
        self.instant = instant
        self.sweep = sweep
        self.bound = bound
        self.bound_rows = bound_rows
        self.outer = outer
        #: Instants whose outer polygon holds fewer than MIN_NODES_INSIDE lattice nodes: the grid
        #: cannot resolve K there, so the outer polygon stands for it.
        self.coarse = np.zeros(len(instant), dtype=bool) if coarse is None else coarse
        self._tubes: dict[int, BaseGeometry] = {}
        self._slices: dict[int, BaseGeometry] = {}
        self._intervals: dict[int, BaseGeometry] = {}
        #: Outer polygons of the windows (SWEEPS_PER_WINDOW), and their unions by window count.
        self._outer_windows: np.ndarray | None = None
        self._outer_unions: dict[int, BaseGeometry] = {}
        self._hulls: dict[int, BaseGeometry] = {}
        self._lock = threading.Lock()

    def _grow(self, k_set: BaseGeometry) -> BaseGeometry:
        return k_set.buffer(self.lattice.step / 2, quad_segs=4) if not k_set.is_empty else k_set

    def tube(self, j: int) -> BaseGeometry:
        with self._lock:
            cached = self._tubes.get(j)
        if cached is not None:
            return cached
        outer = self.outer_tube(j)
        k_set = running_minimum(self.sweep[: j + 1]).contour(self.lattice)
        if not k_set.is_empty:
            # The grid dilation already covers the node sampling; this covers the chords that
            # linear interpolation draws across the outer polygons' corners, and the cut to the
            # outer polygons (exact geometry, not sampled) takes the excess back along their edges.
            k_set = k_set.buffer(CORNER_CHORD * self.lattice.step, quad_segs=4)
            k_set = k_set.intersection(outer)
        unresolved = self._unresolved_sweeps(j)
        if unresolved:
            k_set = shapely.union(k_set, self._unresolved_hull(unresolved).intersection(outer))
        if self.notch is not None:
            k_set = k_set.intersection(self._notch_tube(j))
        with self._lock:
            self._tubes[j] = k_set
        return k_set

    def _notch_region(self, j: int, before: bool = True, after: bool = True) -> BaseGeometry:
        """Every position reachable within half an instant of s_j, ``before`` and/or ``after`` it
        (neither: at s_j itself): where the set is cut at s_j, the partition's bins each swept
        along its headings by how far a car moves in half an instant (``swept_supports``); else
        the instant's convex outer polygon grown by as much either way."""
        notch = self.notch
        assert notch is not None
        key = (j, before, after) if notch.cut[j] else (j, True, True)
        with self._lock:
            cached = self._notch_regions.get(key)
        if cached is not None:
            return cached
        reach = float(notch.reach_m[j])
        if notch.cut[j]:
            i = int(np.count_nonzero(notch.cut[:j]))  # its row among the cut instants
            swept = swept_supports(
                notch.supports[i],
                notch.headings[i],
                reach,
                notch.turn_rad,
                notch.directions,
                before=before,
                after=after,
            )
            region = bins_union(swept, notch.empty[i], notch.directions)
        else:
            polygon = shapely.Polygon(self.bound.polygons_at([self.bound_rows[j]])[0])
            region = grown_to_hold(polygon, reach)
        with self._lock:
            self._notch_regions[key] = region
        return region

    def _notch_tube(self, j: int) -> BaseGeometry:
        """Every position reached during [0, s_j]: the tube to s_(j-1), the half instant after
        s_(j-1) and the half instant before s_j (grown from the largest tube already built;
        nothing after s_j, and each instant's two halves apart, which is thinner than both
        together where the car heads away from the set)."""
        with self._lock:
            built = dict(self._notch_tubes)
        if j in built:
            return built[j]
        start = max((i for i in built if i < j), default=-1)
        tube = built[start] if start >= 0 else self._notch_region(0, after=False)
        for i in range(max(start, 0) + 1, j + 1):
            tube = shapely.union_all(
                [tube, self._notch_region(i - 1, before=False), self._notch_region(i, after=False)]
            )
        with self._lock:
            self._notch_tubes[j] = tube
        return tube

    def missing_tubes(self, indices: list[int]) -> list[int]:
        with self._lock:
            return sorted(set(indices).difference(self._tubes))

    def nearest_built_tube(self, j: int) -> int:
        with self._lock:
            later = [i for i in self._tubes if i >= j]
        return min(later) if later else self.n_slices - 1

    def _unresolved_hull(self, sweeps: list[int]) -> BaseGeometry:
        """The polygon of the support functions' maximum over ``sweeps``, which contains their
        hull (the same for every tube past the last unresolved instant: built once). The lists of
        one set are prefixes of each other (``_unresolved_sweeps``), so their length names them."""
        key = len(sweeps)
        with self._lock:
            hull = self._hulls.get(key)
        if hull is None:
            hull = self._sweeps_polygon(sweeps)
            with self._lock:
                self._hulls[key] = hull
        return hull

    def _sweeps_polygon(self, sweeps: list[int] | slice) -> BaseGeometry:
        """The polygon of the support functions' maximum over ``sweeps``: it holds every position
        reached during them."""
        support = self.bound.sweep_support[sweeps].max(axis=0)
        return shapely.Polygon(half_plane_polygons(self.bound.directions, support[None])[0])

    def _unresolved_sweeps(self, j: int) -> list[int]:
        """Outer-bound sweeps of the intervals up to s_j that touch an unresolved instant."""
        k = self.bound_rows[1] - self.bound_rows[0] if len(self.bound_rows) > 1 else 1
        out: list[int] = []
        for i in range(1, j + 1):
            if self.coarse[i] or self.coarse[i - 1]:
                out.extend(range(self.bound_rows[i] - k, self.bound_rows[i]))
        return out

    def outer_tube(self, j: int) -> BaseGeometry:
        """A union of outer polygons that contains every position reached during [0, s_j]: one
        polygon per window of ``SWEEPS_PER_WINDOW`` sweeps (the support functions' maximum over
        them), inside the conservative set's box of that window.

        The windows' polygons are built once per set and the unions grow from the largest one
        already built (checks ask for many tubes of one set, mostly in increasing order)."""
        n = self.bound_rows[j]
        if n == 0:
            return self.outer.tube(0)
        chunk = SWEEPS_PER_WINDOW
        support = self.bound.sweep_support
        if n % chunk:  # a partial last window: not one of the shared windows
            windows = np.stack(
                [support[a : min(a + chunk, n)].max(axis=0) for a in range(0, n, chunk)]
            )
            return shapely.union_all(convex_polygons(self.bound.directions, windows))
        count = n // chunk
        with self._lock:
            polygons = self._outer_windows
            built = dict(self._outer_unions)
        if polygons is None:
            full = len(support) // chunk
            windows = support[: full * chunk].reshape(full, chunk, -1).max(axis=1)
            polygons = convex_polygons(self.bound.directions, windows)
        if count in built:
            union = built[count]
        else:
            start = max((c for c in built if c < count), default=0)
            parts = list(polygons[start:count])
            union = shapely.union_all(parts if start == 0 else [built[start], *parts])
        with self._lock:
            self._outer_windows = polygons
            self._outer_unions[count] = union
        return union

    def slice(self, j: int) -> BaseGeometry:
        with self._lock:
            cached = self._slices.get(j)
        if cached is not None:
            return cached
        k_set = self._grow(self.instant[j].contour(self.lattice))
        if self.coarse[j] or not k_set.is_empty:
            polygon = shapely.Polygon(self.bound.polygons_at([self.bound_rows[j]])[0])
            k_set = polygon if self.coarse[j] else k_set.intersection(polygon)
        if self.notch is not None and self.notch.cut[j]:
            k_set = k_set.intersection(self._notch_region(j, before=False, after=False))
        with self._lock:
            self._slices[j] = k_set
        return k_set

    def interval(self, j: int) -> BaseGeometry:
        """K over [s_(j-1), s_j]: {sweep_j <= 0} grown by the contour's corner chords and cut to
        the outer polygon of that window, or that polygon if either instant is unresolved."""
        j = max(j, 1)
        with self._lock:
            cached = self._intervals.get(j)
        if cached is not None:
            return cached
        polygon = self._sweeps_polygon(slice(self.bound_rows[j - 1], self.bound_rows[j]))
        if self.coarse[j] or self.coarse[j - 1]:
            k_set = polygon
        else:
            k_set = self.sweep[j].contour(self.lattice)
            if not k_set.is_empty:
                k_set = k_set.buffer(CORNER_CHORD * self.lattice.step, quad_segs=4)
            k_set = k_set.intersection(polygon)
        if self.notch is not None and (self.notch.cut[j] or self.notch.cut[j - 1]):
            k_set = k_set.intersection(
                shapely.union(
                    self._notch_region(j - 1, before=False), self._notch_region(j, after=False)
                )
            )
        with self._lock:
            self._intervals[j] = k_set
        return k_set


def _geojson(geometry: BaseGeometry) -> dict:
    """A GeoJSON Polygon or MultiPolygon of the geometry's polygons, coordinates rounded to the
    millimetre (each ring rounded and listed by numpy, not number by number in Python). Parts of
    lower dimension (a line or point where an intersection degenerates) have no area and are left
    out."""
    polygons: list[shapely.Polygon] = []
    pending = [geometry]
    while pending:
        part = pending.pop()
        if isinstance(part, shapely.Polygon):
            if not part.is_empty:
                polygons.append(part)
        elif isinstance(part, shapely.MultiPolygon | shapely.GeometryCollection):
            pending.extend(reversed(shapely.get_parts(part).tolist()))

    def rings(polygon: shapely.Polygon) -> list:
        polygon = orient(polygon, sign=1.0)  # RFC 7946: exterior counter-clockwise, holes clockwise
        return [
            np.round(shapely.get_coordinates(ring), 3).tolist()
            for ring in (polygon.exterior, *polygon.interiors)
        ]

    if len(polygons) == 1 and isinstance(geometry, shapely.Polygon):
        return {"type": "Polygon", "coordinates": rings(polygons[0])}
    return {"type": "MultiPolygon", "coordinates": [rings(p) for p in polygons]}


def _box(bounds: np.ndarray) -> BaseGeometry:
    x_lo, x_hi, y_lo, y_hi = (float(v) for v in bounds)
    return box(x_lo, y_lo, x_hi, y_hi)


def _box_union(boxes: np.ndarray) -> BaseGeometry:
    """The union of boxes [M, 4] given as (x_lo, x_hi, y_lo, y_hi)."""
    return shapely.union_all(shapely.box(boxes[:, 0], boxes[:, 2], boxes[:, 1], boxes[:, 3]))


def _filled_contour(xs: np.ndarray, ys: np.ndarray, z: np.ndarray, level: float) -> BaseGeometry:
    """The region {z <= level} of a node grid as a shapely geometry."""
    generator = contourpy.contour_generator(xs, ys, z, fill_type="OuterOffset")
    points, offsets = generator.filled(-np.inf, level)
    polygons = []
    for pts, off in zip(points, offsets, strict=True):
        rings = [pts[off[i] : off[i + 1]] for i in range(len(off) - 1)]
        rings = [r for r in rings if len(r) >= 4]
        if rings:
            polygons.append(shapely.Polygon(rings[0], rings[1:]))
    if not polygons:
        return shapely.Polygon()
    return shapely.make_valid(shapely.union_all(polygons))


class FRTEngine:
    """Builds exact and conservative FRT sets from a value model."""

    def __init__(
        self,
        model: ValueModel,
        slice_dt: float | None = None,
        resolution_m: float = 0.25,
        max_nodes: int | None = None,
        heading_samples: int = 3,
        speed_samples: int = 3,
        outer_step_s: float = 0.025,
        projection: bool = True,
        refine: bool = True,
        notch_cut: bool = False,
    ) -> None:
        self.model = model
        #: Cut exact sets to the speed-coupled partition where a notch is possible (``NotchCut``)
        #: unless ``exact`` is told otherwise (``make bench``'s exact cases time both).
        self.notch_cut = notch_cut
        #: Evaluate the projection coarse-to-fine (``service.refine``).
        self.refine = refine
        self.card = model.card
        self.horizon = self.card.horizon_s
        self.use_projection = projection and model.projection is not None
        # With the distilled projection a node costs one small evaluation: finer slices, less dilation.
        self.slice_dt = slice_dt or (PROJECTION_SLICE_DT if self.use_projection else 0.1)
        self.n_slices = round(self.horizon / self.slice_dt) + 1
        self.resolution_m = resolution_m
        self._max_nodes = max_nodes
        self.heading_samples = heading_samples
        self.speed_samples = speed_samples
        # The outer bound's sweeps stay 0.025 s long whatever the slice spacing.
        self.outer_steps_per_slice = max(round(self.slice_dt / outer_step_s), 1)
        self.outer_steps = (self.n_slices - 1) * self.outer_steps_per_slice
        stencil = self.card.raw.get("projection") or {}
        self.level = float(stencil.get("delta", self.card.delta))
        #: If set, the level at an instant is ``level_offset_m`` plus this times the outer box's
        #: scale (``box_scale``).
        self.level_per_scale: float | None = None
        self.level_offset_m = 0.0
        if self.use_projection:
            listed = self.card.raw["projection_graph"]
            self.level = float(listed["delta"])
            if listed.get("level_per_scale") is not None:
                self.level_per_scale = float(listed["level_per_scale"])
                self.level_offset_m = float(listed.get("level_offset_m", 0.0))
        self.max_nodes = max_nodes or 6000
        self.radius_m = float(self.card.initial_set.get("radius_m", 0.5))

    # ----------------------------------------------------------------- validation
    def validate(self, v_start: float, bounds: np.ndarray) -> None:
        """Raise OutOfRangeError if a parameter lies outside the trained ranges."""
        values = {"v_start": float(v_start)}
        values.update(dict(zip(BOUND_COLUMNS, (float(b) for b in bounds), strict=True)))
        for name, value in values.items():
            lo, hi = self.card.ranges[name]
            if not (math.isfinite(value) and lo - 1e-9 <= value <= hi + 1e-9):
                raise OutOfRangeError(name, value, lo, hi)
        b = dict(zip(BOUND_COLUMNS, bounds, strict=True))
        for dim in ("u1", "u2"):
            for end in ("start", "end"):
                lo, hi = b[f"{dim}_min_{end}"], b[f"{dim}_max_{end}"]
                if lo > hi + 1e-9:
                    raise OutOfRangeError(f"{dim}_min_{end}", float(lo), -math.inf, float(hi))

    # ----------------------------------------------------------------- outer bound
    def outer(
        self, v_start: float, bounds: np.ndarray, support_directions: int = SUPPORT_DIRECTIONS
    ) -> OuterBound:
        """The guaranteed outer bound of this engine's horizon, steps and initial set (with
        ``support_directions=0``: its boxes only)."""
        m = self.card.initial_set
        from models.contract import InitialSet

        initial = InitialSet(
            radius_m=m.get("radius_m", 0.5),
            speed_margin_mps=m.get("speed_margin_mps", 0.25),
            heading_margin_rad=m.get("heading_margin_rad", 0.05),
        )
        return outer_bound(
            v_start,
            np.asarray(bounds, float),
            self.horizon,
            self.outer_steps,
            8,
            initial,
            support_directions=support_directions,
        )

    def conservative(self, pose: Pose, v_start: float, bounds: np.ndarray) -> BoxTubeSet:
        """The outer bound as a set: contains the exact set; its boxes alone, ~1 ms here."""
        return self._box_tube(pose, self.outer(v_start, bounds, support_directions=0))

    def _box_tube(self, pose: Pose, ob: OuterBound) -> BoxTubeSet:
        """Tube j: the sweep boxes up to s_j + slice_dt / 2 (the half slice rounded up), merged
        ``SWEEPS_PER_WINDOW`` at a time (a box around each window: a superset that holds the exact
        set's outer polygons, and fewer boxes for a check of many agents to measure)."""
        k, g = self.outer_steps_per_slice, SWEEPS_PER_WINDOW
        n = len(ob.sweep)
        groups = math.ceil(n / g)
        padded = np.concatenate([ob.sweep, np.repeat(ob.sweep[-1:], groups * g - n, axis=0)])
        grouped = padded.reshape(groups, g, 4)
        boxes = np.stack(
            [
                grouped[:, :, 0].min(axis=1),
                grouped[:, :, 1].max(axis=1),
                grouped[:, :, 2].min(axis=1),
                grouped[:, :, 3].max(axis=1),
            ],
            axis=1,
        )
        upto = [math.ceil(min(j * k + (k + 1) // 2, n) / g) for j in range(self.n_slices)]
        return BoxTubeSet(
            pose=pose,
            slice_dt=self.slice_dt,
            horizon_s=self.horizon,
            boxes=boxes,
            boxes_until=np.array(upto),
            slice_boxes=np.array([min(j * k, n - 1) // g for j in range(self.n_slices)]),
            interval_boxes=np.array(
                [
                    [min(max(j - 1, 0) * k, n - 1) // g, math.ceil(max(j * k, 1) / g)]
                    for j in range(self.n_slices)
                ]
            ),
        )

    # ----------------------------------------------------------------- exact set
    def stencil_min(
        self,
        s: float,
        px: np.ndarray,
        py: np.ndarray,
        v_start: float,
        bounds: np.ndarray,
        ob: OuterBound,
    ) -> tuple[np.ndarray, int]:
        """min over a heading/speed stencil of V(s, x, y, heading, speed) at the points (px, py).

        The stencil is centred on the arc-consistent heading 2 atan2(y, x) and on the speed that
        covers the arc's length in time s at constant acceleration, both clipped to the exact
        heading and speed intervals at s. Returns the minima and the number of evaluations.
        """
        k = ob.nearest_row(s)
        th_lo, th_hi = ob.heading[k]
        v_lo, v_hi = ob.speed[k]
        guess = np.clip(2.0 * np.arctan2(py, px), th_lo, th_hi)
        chord = np.hypot(px, py)
        half_turn = np.abs(guess) / 2
        arc = chord * np.where(half_turn > 1e-6, half_turn / np.maximum(np.sin(half_turn), 1e-6), 1)
        speed_guess = np.clip(2 * arc / max(s, 1e-6) - v_start, v_lo, v_hi)
        d_th = np.clip((th_hi - th_lo) / 4, 0.01, 0.3)
        d_v = np.clip((v_hi - v_lo) / 4, 0.02, 2.0)
        offsets_th = np.linspace(-1, 1, self.heading_samples) * d_th
        offsets_v = np.linspace(-1, 1, self.speed_samples) * d_v
        heading = np.clip(guess[:, None, None] + offsets_th[None, :, None], th_lo, th_hi)
        speed = np.clip(speed_guess[:, None, None] + offsets_v[None, None, :], v_lo, v_hi)
        shape = (len(px), self.heading_samples, self.speed_samples)
        heading = np.broadcast_to(heading, shape).ravel()
        speed = np.broadcast_to(speed, shape).ravel()
        n = heading.size
        x = np.empty((n, N_INPUTS), dtype=np.float32)
        x[:, COL["t"]] = s
        x[:, COL["px"]] = np.repeat(px, shape[1] * shape[2])
        x[:, COL["py"]] = np.repeat(py, shape[1] * shape[2])
        x[:, COL["heading"]] = wrap_angle(heading)
        x[:, COL["speed"]] = speed
        x[:, COL["v_start"]] = v_start
        x[:, 6:] = bounds
        return self.model.evaluate(x).reshape(shape).min(axis=(1, 2)), n

    def projected_value(
        self,
        s: float | np.ndarray,
        px: np.ndarray,
        py: np.ndarray,
        v_start: float,
        bounds: np.ndarray,
    ) -> tuple[np.ndarray, int]:
        """W(s, x, y), the distilled minimum over heading and speed (one evaluation per point)."""
        x = np.zeros((len(px), N_INPUTS), dtype=np.float32)
        x[:, COL["t"]] = s
        x[:, COL["px"]] = px
        x[:, COL["py"]] = py
        x[:, COL["v_start"]] = v_start
        x[:, 6:] = bounds
        return self.model.evaluate_projection(x), len(px)

    def exact(
        self,
        pose: Pose,
        v_start: float,
        bounds: np.ndarray,
        notch_cut: bool | None = None,
        notch_stage: int | None = None,
    ) -> FieldTubeSet:
        """The model's set {W <= level} ∩ outer bound, sampled per slice (see FieldTubeSet); the
        whole tube is built at once (collision checks need it first), the rest on demand.
        ``notch_cut`` (default: the engine's) also cuts it to the speed-coupled partition where
        a notch is possible (``NotchCut``), and then draws every tube at once: a set cut in a
        worker process (the service's background refinement) reaches the server with them, so a
        check there draws none on the event loop. ``notch_stage``: which of NOTCH_STAGES cuts it
        (1 for the first; default the last, the finest).

        Every instant's fields are computed together on windows padded to one shape
        (``service.field_stack``)."""
        bounds = np.asarray(bounds, dtype=np.float32)
        ob = self.outer(v_start, bounds)
        k = self.outer_steps_per_slice
        rows = [j * k for j in range(self.n_slices)]
        cut = self.notch_instants(ob, rows)
        cut_now = (self.notch_cut if notch_cut is None else notch_cut) and bool(cut.any())
        box_at = ob.box_at[rows[1:]]
        # The node budget is spread over the slices' areas (an ellipse in each outer box).
        areas = (box_at[:, 1] - box_at[:, 0]) * (box_at[:, 3] - box_at[:, 2]) * (math.pi / 4)
        step = max(self.resolution_m, math.sqrt(areas.sum() / self.max_nodes))
        lattice = Lattice(
            x0=math.floor(ob.sweep[:, 0].min() / step) * step - 8 * step,
            y0=math.floor(ob.sweep[:, 2].min() / step) * step - 8 * step,
            step=step,
            nx=math.ceil((ob.sweep[:, 1].max() - ob.sweep[:, 0].min()) / step) + 17,
            ny=math.ceil((ob.sweep[:, 3].max() - ob.sweep[:, 2].min()) / step) + 17,
        )
        # Slice j's window spans the sweeps of [s_(j-1), s_(j+1)] (both neighbours' intervals fit
        # in it); its interval polygon is the support functions' maximum over [s_(j-1), s_j].
        lo = np.stack(
            [
                span_reduce(block_reduce(ob.sweep[:, 0], k, np.minimum), np.minimum),
                span_reduce(block_reduce(ob.sweep[:, 2], k, np.minimum), np.minimum),
            ],
            axis=1,
        )
        hi = np.stack(
            [
                span_reduce(block_reduce(ob.sweep[:, 1], k, np.maximum), np.maximum),
                span_reduce(block_reduce(ob.sweep[:, 3], k, np.maximum), np.maximum),
            ],
            axis=1,
        )
        windows = WindowStack.make(lo, hi, (lattice.x0, lattice.y0), step, (lattice.nx, lattice.ny))
        valid = windows.valid()
        interval_supports = block_reduce(ob.sweep_support, k, np.maximum)
        clip, interval64 = windows.polygon_fields(
            ob.directions,
            [ob.support_at[rows], np.concatenate([interval_supports[:1], interval_supports])],
            valid,
        )
        clip[0] = np.hypot(windows.xs[0][None, :], windows.ys[0][:, None]) - self.radius_m
        interval = interval64.astype(np.float32)
        interval[0] = FAR
        inside = (clip <= 0) & valid
        inside[0] = False
        clip32 = clip.astype(np.float32)
        coarse = ((clip32 <= 0) & valid).sum(axis=(1, 2)) < MIN_NODES_INSIDE

        levels = self.levels(ob, rows)
        values, evaluations = self._values_inside(
            windows, inside, v_start, bounds, ob, levels, step
        )
        field = clip32
        at = np.nonzero(inside)
        field[at] = np.maximum(values - levels[at[0]], field[at])
        field[~valid] = FAR
        # Grid dilation by how far a car moves in half a slice, plus one node step for the node
        # sampling.
        speed = span_reduce(block_reduce(ob.sweep_speed_max, k, np.maximum), np.maximum)
        speed[0] = 0.0
        grown = dilate_discs(field, speed * self.slice_dt / 2 / step + 1.0)
        grown[~valid] = FAR
        sweep_stack = np.empty_like(field)
        sweep_stack[0] = field[0]
        for j in range(1, self.n_slices):
            near = np.minimum(grown[j], windows.shifted(grown, j - 1, j))
            np.maximum(near, interval[j], out=sweep_stack[j])
        sweep_stack[~valid] = FAR
        instant = SliceFields(
            windows.k0, windows.i0, tuple(windows.crop(field, j) for j in range(self.n_slices))
        )
        sweep = SliceFields(
            windows.k0,
            windows.i0,
            tuple(windows.crop(sweep_stack, j) for j in range(self.n_slices)),
        )
        frt = FieldTubeSet(
            pose,
            self.slice_dt,
            self.horizon,
            lattice,
            instant,
            sweep,
            ob,
            rows,
            self._box_tube(pose, ob),
            coarse=coarse,
            notch=(
                self._notch(ob, rows, v_start, bounds, cut, notch_stage or len(NOTCH_STAGES))
                if cut_now
                else None
            ),
            notch_possible=bool(cut.any()),
        )
        frt.evaluations = evaluations
        frt.tube(self.n_slices - 1)
        if frt.notch is not None:
            for j in range(self.n_slices):  # in increasing order: each cut region from the last
                frt.tube(j)
        return frt

    @staticmethod
    def notch_instants(ob: OuterBound, rows: list[int]) -> np.ndarray:
        """Per instant ``ob.times[rows]``, whether its heading interval passes +-NOTCH_HEADING
        (the car may head backwards, so the set may have a notch behind it)."""
        heading = ob.heading[rows]
        cut = (heading[:, 1] > NOTCH_HEADING) | (heading[:, 0] < -NOTCH_HEADING)
        cut[0] = False
        return cut

    def _notch(
        self,
        ob: OuterBound,
        rows: list[int],
        v_start: float,
        bounds: np.ndarray,
        cut: np.ndarray,
        stage: int,
    ) -> NotchCut:
        """The partition of NOTCH_STAGES[stage - 1] at the instants ``cut``
        (``notch_instants``)."""
        partition = NOTCH_STAGES[stage - 1]
        directions = partition.directions
        support, empty = partition_supports(
            v_start,
            bounds,
            ob.times[rows][cut],
            partition.heading_bins,
            1,
            steps=partition.steps,
            coupled_speed=True,
            directions=directions,
            waypoint_bins=partition.waypoint_bins,
            waypoint_at=partition.waypoint_at,
        )
        headings = bin_headings(
            bounds,
            ob.times[rows][cut],
            partition.heading_bins,
            partition.waypoint_bins,
            horizon=self.horizon,
        )
        # The fastest speed of the sweeps within half an instant of each instant.
        k = self.outer_steps_per_slice
        speed = ob.sweep_speed_max
        half = self.slice_dt / 2
        reach = np.array([speed[max(r - k // 2, 0) : r + (k + 1) // 2].max() * half for r in rows])
        return NotchCut(
            cut=cut,
            supports=support,
            empty=empty,
            headings=headings,
            reach_m=reach,
            turn_rad=max_turn_rate(bounds) * half,
            stage=stage,
            directions=directions,
        )

    def levels(self, ob: OuterBound, rows: list[int]) -> np.ndarray:
        """The calibrated level of W (or V) at each instant ``ob.times[rows]``."""
        if self.level_per_scale is None:
            return np.full(len(rows), self.level)
        return self.level_offset_m + self.level_per_scale * box_scale(ob.box_at[rows])

    def _values_inside(
        self,
        windows: WindowStack,
        inside: np.ndarray,
        v_start: float,
        bounds: np.ndarray,
        ob: OuterBound,
        levels: np.ndarray,
        step: float,
    ) -> tuple[np.ndarray, int]:
        """W (or the stencil minimum of V) at the nodes inside each slice's outer polygon
        (``inside`` [J, H, W]), in the order of ``np.nonzero(inside)``; with ``refine``, -inf at
        the nodes that ``service.refine`` shows cannot be cut (the set can only grow)."""
        times = np.arange(self.n_slices) * self.slice_dt

        def projected(mask: np.ndarray) -> np.ndarray:
            jj, hh, ww = np.nonzero(mask)
            px, py = windows.xs[jj, ww], windows.ys[jj, hh]
            return self.projected_value(times[jj], px, py, v_start, bounds)[0]

        if self.use_projection and self.refine:
            refined = coarse_to_fine(inside, windows.k0, windows.i0, step, levels, projected)
            return refined.values, refined.evaluated
        if self.use_projection:  # one runtime call for every slice
            return projected(inside), int(inside.sum())
        jj, hh, ww = np.nonzero(inside)
        px, py = windows.xs[jj, ww], windows.ys[jj, hh]
        values, evaluations = np.zeros(len(jj), dtype=np.float32), 0
        for j in np.unique(jj):
            rows = jj == j
            v, n = self.stencil_min(float(times[j]), px[rows], py[rows], v_start, bounds, ob)
            values[rows] = v
            evaluations += n
        return values, evaluations
