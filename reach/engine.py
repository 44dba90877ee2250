"""The FRT engine: from (pose, v_start, control bounds) to the sets K and C and the answers on them.

Paper, "Safe Planning": K is the projection of the reachable set onto (x, y); C = K ⊕ R_col.
The value network has *set* semantics (reachable at exactly time s); the tube up to t is the union of
the sets over s <= t (API.md, "The model contract").

How a set is built (human frame: origin at the human, heading 0):

* time is cut into slices s_j = j * slice_dt; at each instant the guaranteed outer bound of
  ``reach.outer_bound`` gives a convex polygon (16 support directions) containing every reachable
  position, and one lattice of (x, y) nodes covers them all;
* the network's projection W (or, without the distilled projection, the minimum of V over a small
  heading/speed stencil around the arc-consistent guess) is evaluated only at the nodes inside each
  instant's polygon, in one runtime call; the field max(W - level, polygon) gives K at s_j;
* between instants a car moves at most v_max * slice_dt / 2 from the nearer one, so the tube is the
  union of the instants' fields dilated on the grid by that much, each cut to the outer polygons of
  its interval: a running minimum of fields, contoured once (``FieldTubeSet``) - no polygon unions
  of near-identical slices, which made GEOS crawl for a parked car;
* where no value field cuts and the outer bound alone shows every interval's polygon within reach
  of its instants' polygons (``reach.held``), the tube is the union of those polygons anyway: the
  set is built without its fields, which are computed only if something asks for them.

Every exact set is contained in the outer bound by construction, so the outer bound is a valid
conservative answer whenever the exact set is not ready (API.md: "conservative": true).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from reach.box_tubes import box_tubes, box_tubes_of
from reach.contract import BOUND_COLUMNS, HORIZON_S, INITIAL_SET, PARAM_RANGES, InitialSet
from reach.field_stack import FAR, WindowStack, block_reduce, dilate_discs, span_reduce
from reach.field_tube import (
    MIN_NODES_INSIDE,
    DeferredSliceFields,
    FieldTubeSet,
    Lattice,
    SliceFields,
)
from reach.frames import Pose
from reach.held import held_intervals
from reach.notch import NOTCH_HEADING, NOTCH_STAGES, NotchCut
from reach.outer_bound import SUPPORT_DIRECTIONS, OuterBound, outer_bound
from reach.partition import bin_headings, max_turn_rate, partition_supports
from reach.refine import coarse_to_fine
from reach.sets import SWEEPS_PER_WINDOW, BoxTubeSet
from reach.value_field import ValueField

#: Spacing of the instants s_j (the distilled projection's level is calibrated on a 0.05 s grid,
#: which contains this one).
SLICE_DT = 0.1


class OutOfRangeError(ValueError):
    """A parameter lies outside the range the sets are built for (answered with 422)."""

    def __init__(self, field: str, value: float, lo: float, hi: float) -> None:
        super().__init__(f"{field}={value:g} is outside the supported range [{lo:g}, {hi:g}]")
        self.field = field
        self.value = value
        self.lo = lo
        self.hi = hi


@dataclass(frozen=True)
class _InstantGrid:
    """One set's lattice and, per instant j (stacked [J, H, W] on windows of one shape): whether a
    node lies in the window (``valid``), the signed distance to the instant's outer polygon
    (``polygon``, float32) and to its interval's (``interval``), the nodes inside the polygon where
    a value field may cut (``inside``), and whether the polygon holds too few nodes for the grid
    to resolve it (``coarse`` [J])."""

    lattice: Lattice
    windows: WindowStack
    valid: np.ndarray
    polygon: np.ndarray
    interval: np.ndarray
    inside: np.ndarray
    coarse: np.ndarray

    def slices(self, stack: np.ndarray) -> SliceFields:
        """A stacked field cropped to each instant's window."""
        n = len(stack)
        return SliceFields(
            self.windows.k0, self.windows.i0, tuple(self.windows.crop(stack, j) for j in range(n))
        )


class FRTEngine:
    """Builds the tight and the conservative FRT sets of one setting from the certified geometry,
    cut by a value field where one is given (``value_field``, ``reach.value_field``)."""

    def __init__(
        self,
        value_field: ValueField | None = None,
        *,
        horizon_s: float = HORIZON_S,
        initial_set: InitialSet = INITIAL_SET,
        ranges: Mapping[str, tuple[float, float]] = PARAM_RANGES,
        slice_dt: float = SLICE_DT,
        resolution_m: float = 0.25,
        max_nodes: int = 6000,
        outer_step_s: float = 0.025,
        refine: bool = True,
        notch_cut: bool = False,
    ) -> None:
        #: Cuts each instant inside its outer polygon (None: the geometry alone).
        self.value_field = value_field
        #: Cut exact sets to the speed-coupled partition where a notch is possible (``NotchCut``)
        #: unless ``exact`` is told otherwise.
        self.notch_cut = notch_cut
        #: Evaluate the value field coarse-to-fine (``reach.refine``).
        self.refine = refine
        self.horizon = horizon_s
        self.initial_set = initial_set
        self.ranges = dict(ranges)
        self.slice_dt = slice_dt
        self.n_slices = round(self.horizon / self.slice_dt) + 1
        self.resolution_m = resolution_m
        # The outer bound's sweeps stay 0.025 s long whatever the slice spacing.
        self.outer_steps_per_slice = max(round(self.slice_dt / outer_step_s), 1)
        self.outer_steps = (self.n_slices - 1) * self.outer_steps_per_slice
        self.max_nodes = max_nodes
        self.radius_m = initial_set.radius_m

    # ----------------------------------------------------------------- validation
    def validate(self, v_start: float, bounds: np.ndarray) -> None:
        """Raise OutOfRangeError if a parameter lies outside the engine's ranges or a lower bound
        exceeds its upper bound."""
        values = {"v_start": float(v_start)}
        values.update(dict(zip(BOUND_COLUMNS, (float(b) for b in bounds), strict=True)))
        for name, value in values.items():
            lo, hi = self.ranges[name]
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
        return outer_bound(
            v_start,
            np.asarray(bounds, float),
            self.horizon,
            self.outer_steps,
            8,
            self.initial_set,
            support_directions=support_directions,
        )

    def conservative(self, pose: Pose, v_start: float, bounds: np.ndarray) -> BoxTubeSet:
        """The outer bound as a set: contains the exact set; its boxes alone, cheap enough for the
        request's thread (``reach.box_tubes``, which builds a frame's together)."""
        return box_tubes(self, [pose], [v_start], np.asarray(bounds, float).reshape(1, 8))[0]

    def _box_tube(self, pose: Pose, ob: OuterBound) -> BoxTubeSet:
        """The box tube of the outer bound ``ob`` (``reach.box_tubes``)."""
        return box_tubes_of(self, [pose], ob.sweep[None])[0]

    # ----------------------------------------------------------------- exact set
    def exact(
        self,
        pose: Pose,
        v_start: float,
        bounds: np.ndarray,
        notch_cut: bool | None = None,
        notch_stage: int | None = None,
        tubes_upto: int = -1,
    ) -> FieldTubeSet:
        """The model's set {W <= level} ∩ outer bound, sampled per slice (see FieldTubeSet); the
        tubes 0..``tubes_upto`` (in increasing order, each grown from the one before) and then the
        whole tube are built at once (collision checks need them first), the rest on demand.
        ``notch_cut`` (default: the engine's) also cuts it to the speed-coupled partition where
        a notch is possible (``NotchCut``), and then draws every tube at once: a set cut in a
        worker process (the service's background refinement) reaches the server with them, so a
        check there draws none on the event loop. ``notch_stage``: which of NOTCH_STAGES cuts it
        (1 for the first; default the last, the finest).

        Every instant's fields are computed together on windows padded to one shape
        (``reach.field_stack``), except where no field could change the set: uncut by a value
        field or the notch, with every interval held by its outer polygon as the outer bound
        alone shows (``reach.held``), the set is those polygons and its fields are computed only
        if something asks for them (``_held_set``)."""
        bounds = np.asarray(bounds, dtype=np.float32)
        ob = self.outer(v_start, bounds)
        rows = [j * self.outer_steps_per_slice for j in range(self.n_slices)]
        cut = self.notch_instants(ob, rows)
        cut_now = (self.notch_cut if notch_cut is None else notch_cut) and bool(cut.any())
        frt = None
        if not cut_now and not self.cuts(v_start, bounds):
            frt = self._held_set(pose, ob, rows, v_start, bounds)
        if frt is None:
            notch = None
            if cut_now:
                notch = self._notch(
                    ob, rows, v_start, bounds, cut, notch_stage or len(NOTCH_STAGES)
                )
            frt = self._fields_set(pose, ob, rows, v_start, bounds, notch)
        frt.notch_possible = bool(cut.any())
        last = self.n_slices - 1
        # In increasing order: each tube (and each cut region) grows from the one before.
        for j in range(last if frt.notch is not None else min(tubes_upto + 1, last)):
            frt.tube(j)
        frt.tube(last)
        return frt

    def _fields_set(
        self,
        pose: Pose,
        ob: OuterBound,
        rows: list[int],
        v_start: float,
        bounds: np.ndarray,
        notch: NotchCut | None,
    ) -> FieldTubeSet:
        """The set drawn from its fields: every instant's and every interval's, on the grid."""
        grid = self._grid(ob, rows)
        field, evaluations = self._instant_fields(grid, ob, rows, v_start, bounds)
        sweep, held = self._interval_fields(grid, field, ob)
        frt = FieldTubeSet(
            pose,
            self.slice_dt,
            self.horizon,
            grid.lattice,
            grid.slices(field),
            grid.slices(sweep),
            ob,
            rows,
            self._box_tube(pose, ob),
            coarse=grid.coarse,
            notch=notch,
            outer_held=held,
            instants_uncut=not self.cuts(v_start, bounds),
        )
        frt.evaluations = evaluations
        return frt

    def _held_set(
        self, pose: Pose, ob: OuterBound, rows: list[int], v_start: float, bounds: np.ndarray
    ) -> FieldTubeSet | None:
        """The set of an uncut setting whose every interval is its outer polygon, without its
        fields: None unless each interval is held by its polygon as the outer bound alone shows
        it (``reach.held``) or touches an instant the grid cannot resolve (``coarse``, counted on
        the grid as ``_grid`` counts it). Such a set's slices past the first, its intervals and
        its tubes are outer polygons and their unions, as the fields would make them; its first
        instant is the initial disc on the grid, as ``_grid`` draws it, and the other fields are
        computed if something asks for them (``DeferredSliceFields``)."""
        k = self.outer_steps_per_slice
        if k != SWEEPS_PER_WINDOW:  # the outer tube's windows are not the intervals
            return None
        lattice, windows = self._windows(ob, rows)
        xs, ys = windows.xs[0][: windows.w[0]], windows.ys[0][: windows.h[0]]
        first = (np.hypot(xs[None, :], ys[:, None]) - self.radius_m).astype(np.float32)
        inside = windows.nodes_inside(ob.directions, ob.support_at[rows], MIN_NODES_INSIDE)
        inside[0] = np.count_nonzero(first <= 0)
        coarse = inside < MIN_NODES_INSIDE
        intervals = block_reduce(ob.sweep_support, k, np.maximum)
        speed = block_reduce(ob.sweep_speed_max, k, np.maximum)
        held = held_intervals(
            ob.directions,
            ob.support_at[rows],
            np.concatenate([intervals[:1], intervals]),
            np.concatenate([[0.0], speed * (self.slice_dt / 2)]),
            self.radius_m,
            np.ones(self.n_slices, dtype=bool),
        )
        if not np.all(held[1:] | coarse[1:] | coarse[:-1]):
            return None
        fields = functools.cache(lambda: self._fields(ob, rows, v_start, bounds))
        known = (first, *[None] * (self.n_slices - 1))
        return FieldTubeSet(
            pose,
            self.slice_dt,
            self.horizon,
            lattice,
            DeferredSliceFields(windows.k0, windows.i0, known, lambda: fields()[0]),
            DeferredSliceFields(windows.k0, windows.i0, known, lambda: fields()[1]),
            ob,
            rows,
            self._box_tube(pose, ob),
            coarse=coarse,
            outer_held=held,
            instants_uncut=True,
        )

    def _fields(
        self, ob: OuterBound, rows: list[int], v_start: float, bounds: np.ndarray
    ) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """Every instant's and every interval's field values, as ``_fields_set`` draws them."""
        grid = self._grid(ob, rows)
        field, _ = self._instant_fields(grid, ob, rows, v_start, bounds)
        sweep, _ = self._interval_fields(grid, field, ob)
        return grid.slices(field).values, grid.slices(sweep).values  # type: ignore[return-value]

    def _windows(self, ob: OuterBound, rows: list[int]) -> tuple[Lattice, WindowStack]:
        """One lattice for every instant (the node budget spread over the instants' areas, an
        ellipse in each outer box) and each instant's window on it: the sweeps of
        [s_(j-1), s_(j+1)] (both neighbours' intervals fit in it)."""
        k = self.outer_steps_per_slice
        box_at = ob.box_at[rows[1:]]
        areas = (box_at[:, 1] - box_at[:, 0]) * (box_at[:, 3] - box_at[:, 2]) * (math.pi / 4)
        step = max(self.resolution_m, math.sqrt(areas.sum() / self.max_nodes))
        lattice = Lattice(
            x0=math.floor(ob.sweep[:, 0].min() / step) * step - 8 * step,
            y0=math.floor(ob.sweep[:, 2].min() / step) * step - 8 * step,
            step=step,
            nx=math.ceil((ob.sweep[:, 1].max() - ob.sweep[:, 0].min()) / step) + 17,
            ny=math.ceil((ob.sweep[:, 3].max() - ob.sweep[:, 2].min()) / step) + 17,
        )
        lo, hi = (
            np.stack(
                [span_reduce(block_reduce(ob.sweep[:, c], k, reduce), reduce) for c in columns],
                axis=1,
            )
            for columns, reduce in (((0, 2), np.minimum), ((1, 3), np.maximum))
        )
        windows = WindowStack.make(lo, hi, (lattice.x0, lattice.y0), step, (lattice.nx, lattice.ny))
        return lattice, windows

    def _grid(self, ob: OuterBound, rows: list[int]) -> _InstantGrid:
        """The lattice and windows (``_windows``) and the signed distances there to each
        instant's outer polygon and to its interval's (the support functions' maximum over
        [s_(j-1), s_j]); instant 0 is the initial disc."""
        k = self.outer_steps_per_slice
        lattice, windows = self._windows(ob, rows)
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
        return _InstantGrid(lattice, windows, valid, clip32, interval, inside, coarse)

    def _instant_fields(
        self,
        grid: _InstantGrid,
        ob: OuterBound,
        rows: list[int],
        v_start: float,
        bounds: np.ndarray,
    ) -> tuple[np.ndarray, int]:
        """Each instant's field, max(W - level, P) inside its outer polygon P where the value
        field cuts this setting, else P itself; and the value field's evaluations."""
        field = grid.polygon
        evaluations = 0
        if self.cuts(v_start, bounds):
            assert self.value_field is not None
            levels = self.value_field.levels(ob.box_at[rows])
            values, evaluations = self._values_inside(
                grid.windows, grid.inside, v_start, bounds, ob, levels, grid.lattice.step
            )
            at = np.nonzero(grid.inside)
            field[at] = np.maximum(values - levels[at[0]], field[at])
        field[~grid.valid] = FAR
        return field, evaluations

    def _interval_fields(
        self, grid: _InstantGrid, field: np.ndarray, ob: OuterBound
    ) -> tuple[np.ndarray, np.ndarray]:
        """Each interval's field: its two instants' minimum dilated on the grid by how far a car
        moves in half a slice (plus one node step for the node sampling), cut to the interval's
        outer polygon; interval 0 is instant 0. And per interval, whether the dilated instants
        hold its outer polygon (``FieldTubeSet.outer_held``): the interval field is <= 0 wherever
        the polygon's own field is, and equal to it within a cell diagonal of its zero
        (``WindowStack.interval_fields``). The two fields then have the same sign at every node,
        and the same value at every node of a cell where the sign changes (the polygon's field is
        1-Lipschitz), so their contours are one: K over the interval is the polygon."""
        k = self.outer_steps_per_slice
        speed = span_reduce(block_reduce(ob.sweep_speed_max, k, np.maximum), np.maximum)
        speed[0] = 0.0
        radii = speed * self.slice_dt / 2 / grid.lattice.step + 1.0
        grown = dilate_discs(field, radii, (grid.windows.h, grid.windows.w))
        band = np.float32(math.sqrt(2.0) * grid.lattice.step * (1.0 + 1e-6))
        return grid.windows.interval_fields(field, grown, grid.interval, grid.valid, band)

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

    def cuts(self, v_start: float, bounds: np.ndarray) -> bool:
        """Whether this engine's value field cuts the sets of this setting (it has one and was
        trained on the setting)."""
        return self.value_field is not None and self.value_field.covers(v_start, bounds)

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
        """The value field at the nodes inside each slice's outer polygon (``inside`` [J, H, W]),
        in the order of ``np.nonzero(inside)``, and the evaluations it took; with ``refine``, -inf
        at the nodes that ``reach.refine`` shows cannot be cut (the set can only grow)."""
        field = self.value_field
        assert field is not None
        times = np.arange(self.n_slices) * self.slice_dt

        def evaluate(mask: np.ndarray) -> tuple[np.ndarray, int]:
            jj, hh, ww = np.nonzero(mask)
            px, py = windows.xs[jj, ww], windows.ys[jj, hh]
            return field.values(times[jj], px, py, v_start, bounds, ob)

        if self.refine:
            refined = coarse_to_fine(
                inside, windows.k0, windows.i0, step, levels, lambda m: evaluate(m)[0]
            )
            return refined.values, refined.evaluated
        return evaluate(inside)
