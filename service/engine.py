"""The FRT engine: from (pose, v_start, control bounds) to the sets K and C and the answers on them.

Paper, "Safe Planning": K is the projection of the reachable set onto (x, y); C = K ⊕ R_col.
The value network has *set* semantics (reachable at exactly time s); the tube up to t is the union of
the sets over s <= t (API.md, "The model contract").

How a set is built (human frame: origin at the human, heading 0):

* time is cut into slices s_j = j * slice_dt; for each slice the guaranteed outer bound of
  ``models.outer_bound`` gives a box that contains every reachable position;
* inside that box the network is evaluated on an (x, y) grid; at each node the heading and speed are
  minimised over a small stencil around the arc-consistent guess (a constant-curvature arc from the
  origin reaching (x, y) ends with heading 2 atan2(y, x)), clipped to the exact heading and speed
  intervals; the slice K_j is the filled contour {min V <= delta};
* between slices a car moves at most v_max * slice_dt / 2 from the nearest slice, so the tube up to
  slice j is the union over i <= j of (K_i ⊕ v_max,i slice_dt / 2) ∩ (outer bound of that interval).

Every exact set is contained in the outer bound by construction, so the outer bound is a valid
conservative answer whenever the exact set is not ready (API.md: "conservative": true).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import contourpy
import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import Point, box, mapping
from shapely.geometry.base import BaseGeometry

from models.contract import BOUND_COLUMNS, COL, N_INPUTS
from models.dynamics import wrap_angle
from models.outer_bound import OuterBound, outer_bound
from service.model_runtime import ValueModel

#: Slice spacing when the distilled projection network is present (its level is calibrated at it).
PROJECTION_SLICE_DT = 0.05


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


def to_human_frame(xy_world: np.ndarray, pose: Pose) -> np.ndarray:
    """World points [N, 2] -> the human frame (origin at the human, heading 0)."""
    c, s = math.cos(pose.heading), math.sin(pose.heading)
    dx = xy_world[:, 0] - pose.x
    dy = xy_world[:, 1] - pose.y
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=1)


def to_world_frame(geometry: BaseGeometry, pose: Pose) -> BaseGeometry:
    c, s = math.cos(pose.heading), math.sin(pose.heading)
    return affinity.affine_transform(geometry, [c, -s, s, c, pose.x, pose.y])


def signed_distance(geometry: BaseGeometry, xy: np.ndarray) -> np.ndarray:
    """Distance from each point to ``geometry``; negative inside (minus the depth)."""
    if geometry.is_empty:
        return np.full(len(xy), np.inf)
    points = shapely.points(xy)
    inside = shapely.contains_xy(geometry, xy[:, 0], xy[:, 1])
    outside_distance = shapely.distance(geometry, points)
    depth = shapely.distance(geometry.boundary, points)
    return np.where(inside, -depth, outside_distance)


@dataclass
class FRTSet:
    """K for every slice and the tubes up to each slice, in the human frame."""

    pose: Pose
    slice_dt: float
    horizon_s: float
    slices: list[BaseGeometry]
    tubes: list[BaseGeometry]
    conservative: bool
    evaluations: int = 0
    _world_cache: dict = field(default_factory=dict, repr=False)

    def tube_index(self, t_rel: float) -> int:
        """Index of the tube that contains every position reached in [0, t_rel]."""
        t = min(max(t_rel, 0.0), self.horizon_s)
        return min(math.ceil(t / self.slice_dt - 1e-9), len(self.tubes) - 1)

    def clearance(self, xy_world: np.ndarray, t_rel: np.ndarray | None = None) -> np.ndarray:
        """Signed distance (m) from each world point to K (negative inside).

        ``t_rel`` None: the whole-horizon tube; else, per point, the tube up to ``t_rel`` seconds
        after the observation (clipped to [0, horizon]).
        """
        xy = to_human_frame(np.asarray(xy_world, dtype=float).reshape(-1, 2), self.pose)
        if t_rel is None:
            return signed_distance(self.tubes[-1], xy)
        index = np.array([self.tube_index(float(t)) for t in np.asarray(t_rel).reshape(-1)])
        out = np.empty(len(xy))
        for j in np.unique(index):
            rows = index == j
            out[rows] = signed_distance(self.tubes[j], xy[rows])
        return out

    def geometry(self, kind: str, t: float | None = None) -> BaseGeometry:
        """K in the human frame: the whole tube, the tube up to t, or the slice nearest t."""
        if kind == "tube":
            return self.tubes[-1] if t is None else self.tubes[self.tube_index(t)]
        if kind == "slice":
            j = round(min(max(t or 0.0, 0.0), self.horizon_s) / self.slice_dt)
            return self.slices[min(j, len(self.slices) - 1)]
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


@dataclass
class BoxTubeSet(FRTSet):
    """A tube given as a union of axis-aligned boxes (the outer bound); geometry built lazily."""

    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    boxes_until: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    slice_boxes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    def tube_index(self, t_rel: float) -> int:
        t = min(max(t_rel, 0.0), self.horizon_s)
        return min(math.ceil(t / self.slice_dt - 1e-9), len(self.boxes_until) - 1)

    def clearance(self, xy_world: np.ndarray, t_rel: np.ndarray | None = None) -> np.ndarray:
        """Distance to the union of boxes (exact outside; inside, the depth in the deepest box)."""
        xy = to_human_frame(np.asarray(xy_world, dtype=float).reshape(-1, 2), self.pose)
        b = self.boxes
        dx = np.maximum(b[None, :, 0] - xy[:, None, 0], xy[:, None, 0] - b[None, :, 1])
        dy = np.maximum(b[None, :, 2] - xy[:, None, 1], xy[:, None, 1] - b[None, :, 3])
        outside = np.hypot(np.maximum(dx, 0), np.maximum(dy, 0))
        distance = np.where((dx <= 0) & (dy <= 0), np.maximum(dx, dy), outside)
        if t_rel is None:
            n = np.full(len(xy), self.boxes_until[-1])
        else:
            idx = [self.tube_index(float(t)) for t in np.asarray(t_rel).reshape(-1)]
            n = self.boxes_until[np.array(idx, dtype=int)]
        mask = np.arange(len(b))[None, :] < n[:, None]
        result = np.where(mask, distance, np.inf).min(axis=1)
        for row in np.nonzero(result < 0)[0]:  # inside: the depth in the union, not in one box
            geometry = self._union(int(np.searchsorted(self.boxes_until, n[row])))
            result[row] = signed_distance(geometry, xy[row : row + 1])[0]
        return result

    def _union(self, j: int) -> BaseGeometry:
        if j not in self._world_cache:
            self._world_cache[j] = shapely.union_all(
                [_box(b) for b in self.boxes[: self.boxes_until[j]]]
            )
        return self._world_cache[j]

    def geometry(self, kind: str, t: float | None = None) -> BaseGeometry:
        if kind == "tube":
            j = len(self.boxes_until) - 1 if t is None else self.tube_index(t)
            return self._union(j)
        if kind == "slice":
            j = round(min(max(t or 0.0, 0.0), self.horizon_s) / self.slice_dt)
            return _box(self.boxes[self.slice_boxes[min(j, len(self.slice_boxes) - 1)]])
        raise ValueError(f"unknown kind {kind!r}")


def _geojson(geometry: BaseGeometry) -> dict:
    if geometry.is_empty:
        return {"type": "MultiPolygon", "coordinates": []}
    mapped = mapping(geometry)

    def listify(value):
        if isinstance(value, tuple | list):
            return [listify(v) for v in value]
        return round(float(value), 3)

    return {"type": mapped["type"], "coordinates": listify(mapped["coordinates"])}


def _box(bounds: np.ndarray) -> BaseGeometry:
    x_lo, x_hi, y_lo, y_hi = (float(v) for v in bounds)
    return box(x_lo, y_lo, x_hi, y_hi)


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
        outer_steps_per_slice: int = 2,
        projection: bool = True,
    ) -> None:
        self.model = model
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
        self.outer_steps = (self.n_slices - 1) * outer_steps_per_slice
        self.outer_steps_per_slice = outer_steps_per_slice
        stencil = self.card.raw.get("projection") or {}
        self.level = float(stencil.get("delta", self.card.delta))
        if self.use_projection:
            self.level = float(self.card.raw["projection_graph"]["delta"])
        self.max_nodes = max_nodes or (12000 if self.use_projection else 6000)
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
    def outer(self, v_start: float, bounds: np.ndarray) -> OuterBound:
        m = self.card.initial_set
        from models.contract import InitialSet

        initial = InitialSet(
            radius_m=m.get("radius_m", 0.5),
            speed_margin_mps=m.get("speed_margin_mps", 0.25),
            heading_margin_rad=m.get("heading_margin_rad", 0.05),
        )
        return outer_bound(
            v_start, np.asarray(bounds, float), self.horizon, self.outer_steps, 8, initial
        )

    def _interval_regions(self, polygons: list[BaseGeometry]) -> list[BaseGeometry]:
        """Per slice j, the union of the sweep polygons covering [s_j - dt/2, s_j + dt/2]."""
        k = self.outer_steps_per_slice
        regions = []
        for j in range(self.n_slices):
            lo, hi = max(j * k - k // 2, 0), min(j * k + (k + 1) // 2, len(polygons))
            regions.append(shapely.union_all(polygons[lo:hi]))
        return regions

    def conservative(self, pose: Pose, v_start: float, bounds: np.ndarray) -> FRTSet:
        """The outer bound as a set: contains the exact set, computed in well under a millisecond."""
        ob = self.outer(v_start, bounds)
        k = self.outer_steps_per_slice
        upto = [min(j * k + (k + 1) // 2, len(ob.sweep)) for j in range(self.n_slices)]
        return BoxTubeSet(
            pose=pose,
            slice_dt=self.slice_dt,
            horizon_s=self.horizon,
            slices=[],
            tubes=[],
            conservative=True,
            boxes=ob.sweep,
            boxes_until=np.array(upto),
            slice_boxes=np.array([min(j * k, len(ob.sweep) - 1) for j in range(self.n_slices)]),
        )

    # ----------------------------------------------------------------- exact set
    def _grid(self, region: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
        x_lo, x_hi, y_lo, y_hi = region
        pad = resolution
        xs = np.arange(x_lo - pad, x_hi + pad + resolution, resolution)
        ys = np.arange(y_lo - pad, y_hi + pad + resolution, resolution)
        return xs, ys

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
        k = int(np.argmin(np.abs(ob.times - s)))
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

    def exact(self, pose: Pose, v_start: float, bounds: np.ndarray) -> FRTSet:
        """The model's set {V <= delta}, projected on (x, y), per slice and as tubes."""
        bounds = np.asarray(bounds, dtype=np.float32)
        ob = self.outer(v_start, bounds)
        polygons = [shapely.Polygon(p) for p in ob.sweep_polygons()]
        boxes = self._interval_regions(polygons)
        k = self.outer_steps_per_slice
        regions = [ob.sweep[min(j * k, len(ob.sweep) - 1)] for j in range(self.n_slices)]
        areas = np.array([(r[1] - r[0] + 1) * (r[3] - r[2] + 1) for r in regions])
        resolution = max(self.resolution_m, math.sqrt(areas.sum() / self.max_nodes))
        grids = [self._grid(regions[j], resolution) for j in range(1, self.n_slices)]
        meshes = [np.meshgrid(xs, ys) for xs, ys in grids]
        times = [j * self.slice_dt for j in range(1, self.n_slices)]
        if self.use_projection:  # one runtime call for every slice
            px = np.concatenate([gx.ravel() for gx, _ in meshes])
            py = np.concatenate([gy.ravel() for _, gy in meshes])
            t = np.concatenate(
                [np.full(gx.size, s) for (gx, _), s in zip(meshes, times, strict=True)]
            )
            flat, evaluations = self.projected_value(t, px, py, v_start, bounds)
            split = np.split(flat, np.cumsum([gx.size for gx, _ in meshes])[:-1])
        else:
            split, evaluations = [], 0
            for (gx, gy), s in zip(meshes, times, strict=True):
                values, n = self.stencil_min(s, gx.ravel(), gy.ravel(), v_start, bounds, ob)
                split.append(values)
                evaluations += n
        slices: list[BaseGeometry] = [Point(0.0, 0.0).buffer(self.radius_m, quad_segs=16)]
        for j, ((xs, ys), (gx, _), values) in enumerate(zip(grids, meshes, split, strict=True), 1):
            k_set = _filled_contour(xs, ys, values.reshape(gx.shape), self.level)
            # Half a grid cell outward: a thin part of the set between nodes is not lost.
            k_set = k_set.buffer(resolution / 2, quad_segs=4) if not k_set.is_empty else k_set
            sweep = min(j * self.outer_steps_per_slice, len(ob.sweep) - 1)
            slices.append(k_set.intersection(polygons[sweep]))
        tubes: list[BaseGeometry] = []
        running: BaseGeometry = shapely.Polygon()
        for j, k_set in enumerate(slices):
            t_idx = int(np.argmin(np.abs(ob.times - j * self.slice_dt)))
            reach = float(ob.speed[min(t_idx + 1, len(ob.speed) - 1), 1]) * self.slice_dt / 2
            grown = k_set.buffer(reach, quad_segs=4) if not k_set.is_empty else k_set
            running = shapely.union(running, grown.intersection(boxes[j]))
            tubes.append(running)
        return FRTSet(
            pose,
            self.slice_dt,
            self.horizon,
            slices,
            tubes,
            conservative=False,
            evaluations=evaluations,
        )
