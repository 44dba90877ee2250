"""The tight set: per-instant fields on one lattice, contoured, cut to the outer polygons.

Each instant's field is max(W - level, P) with P the signed distance to the instant's outer polygon
(W the value field where one cuts, else -inf: the polygon alone). Between instants a car moves at
most v_max * slice_dt / 2 from the nearer one, so the interval's field is the two instants' minimum
dilated by that much on the grid and cut to the interval's outer polygon; a tube is the running
minimum of the intervals' fields, contoured once; where a field's zero contour is its polygon's,
the polygon is taken whole instead. Every set drawn is inside the union of outer polygons and,
where it is cut (``reach.notch``), inside the partition's region.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, overload

import contourpy
import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from reach.field_stack import FAR
from reach.frames import Pose
from reach.memo import Memo
from reach.notch import NotchCut
from reach.outer_bound import OuterBound
from reach.partition import bins_union, grown_to_hold, swept_supports
from reach.polygons import convex_polygons, half_plane_polygons
from reach.sets import SWEEPS_PER_WINDOW, BoxTubeSet, FRTSet


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
        x, y = lattice_nodes(lattice, self.k0, self.i0, ny, nx)
        return _filled_contour(x, y, self.values, 0.0)


def lattice_nodes(
    lattice: Lattice, k0: int, i0: int, ny: int, nx: int
) -> tuple[np.ndarray, np.ndarray]:
    """The x and y of the nodes of the window [k0:k0+ny, i0:i0+nx] as [ny, nx] arrays: views of
    the whole lattice's, made once per lattice (a set contours tens of windows of one lattice),
    the same values as ``np.meshgrid(lattice.xs(i0, i0 + nx), lattice.ys(k0, k0 + ny))``."""
    if k0 < 0 or i0 < 0 or k0 + ny > lattice.ny or i0 + nx > lattice.nx:
        return np.meshgrid(lattice.xs(i0, i0 + nx), lattice.ys(k0, k0 + ny))
    x, y = _whole_lattice(lattice)
    return x[k0 : k0 + ny, i0 : i0 + nx], y[k0 : k0 + ny, i0 : i0 + nx]


@functools.lru_cache(maxsize=8)
def _whole_lattice(lattice: Lattice) -> tuple[np.ndarray, np.ndarray]:
    """Every node's x and y of ``lattice`` [ny, nx], read-only (shared by the contours drawn)."""
    x, y = np.meshgrid(lattice.xs(0, lattice.nx), lattice.ys(0, lattice.ny))
    x.flags.writeable = False
    y.flags.writeable = False
    return x, y


class SliceFields:
    """The fields of every slice of one set, held as few objects: offsets in two integer arrays and
    the values in a tuple of arrays (neither is traversed by the garbage collector, whose full
    collections would otherwise walk tens of small objects per cached exact set, a pause that
    grows with the cache). Indexing gives :class:`SliceField` views. A slice whose values were
    dropped (:meth:`keeping`: nothing will be drawn from it) holds None and raises when asked
    for."""

    def __init__(
        self, k0: np.ndarray, i0: np.ndarray, values: tuple[np.ndarray | None, ...]
    ) -> None:
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
        values = self.values[j]
        if values is None:
            raise LookupError(f"the field of slice {j} was dropped: nothing is drawn from it")
        return SliceField(int(self.k0[j]), int(self.i0[j]), values)

    def keeping(self, needed: np.ndarray) -> SliceFields:
        """The same fields with the values of the slices not ``needed`` dropped."""
        values = tuple(v if keep else None for v, keep in zip(self.values, needed, strict=True))
        return SliceFields(self.k0, self.i0, values)


class DeferredSliceFields(SliceFields):
    """Slice fields of which only some are computed: the others (None) are computed, all at once,
    by ``complete()`` the first time one of them is asked for (or kept, :meth:`keeping`). A set
    held by its outer polygons draws nothing from them (``FRTEngine.exact``): they are there for
    what is drawn from the fields themselves (a reference contour). Two threads asking at once
    may both compute them; either result is the same."""

    def __init__(
        self,
        k0: np.ndarray,
        i0: np.ndarray,
        values: tuple[np.ndarray | None, ...],
        complete: Callable[[], tuple[np.ndarray, ...]],
    ) -> None:
        super().__init__(k0, i0, values)
        self._complete: Callable[[], tuple[np.ndarray, ...]] | None = complete

    def _fill(self) -> None:
        complete = self._complete
        if complete is not None:
            self.values = tuple(complete())
            self._complete = None

    @overload
    def __getitem__(self, j: int) -> SliceField: ...

    @overload
    def __getitem__(self, j: slice) -> list[SliceField]: ...

    def __getitem__(self, j: int | slice) -> SliceField | list[SliceField]:
        if isinstance(j, slice) or self.values[j] is None:
            self._fill()
        return super().__getitem__(j)

    def keeping(self, needed: np.ndarray) -> SliceFields:
        if any(keep and v is None for v, keep in zip(self.values, needed, strict=True)):
            self._fill()
        return super().keeping(needed)


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


#: The memos of a :class:`FieldTubeSet` by attribute, with their size bound: the tubes, slices and
#: intervals drawn; the outer polygons of the windows by window length (SWEEPS_PER_WINDOW) and
#: their unions by window count; the sweeps' hulls; the notch cut's regions and tubes; and the last
#: running minimum of the sweeps' fields taken (``_sweeps_minimum``), by the last sweep it covers.
_MEMOS: dict[str, int | None] = {
    "_tubes": None,
    "_slices": None,
    "_intervals": None,
    "_outer_windows": None,
    "_outer_unions": None,
    "_hulls": None,
    "_notch_regions": None,
    "_notch_tubes": None,
    "_last_minimum": 1,
}
#: The memos a set sent to another process leaves behind (rebuilt there on demand).
_REBUILT_MEMOS = frozenset(
    {"_outer_windows", "_outer_unions", "_notch_regions", "_notch_tubes", "_last_minimum"}
)


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

    Where nothing cuts an instant (``instants_uncut``) its slice is its outer polygon, and where
    interval j's field has its outer polygon's zero contour (``outer_held``) the interval is that
    polygon; a tube of such intervals is their union, the outer tube (``_tube_is_outer``), and a
    tube with other intervals too holds the polygons of these.
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
        outer_held: np.ndarray | None = None,
        instants_uncut: bool = False,
    ) -> None:
        super().__init__(pose, slice_dt, horizon_s, len(instant), conservative=False)
        #: If set, every set drawn is also cut to the partition (``_notch_*``).
        self.notch = notch
        #: Whether some instant's heading interval passes +-NOTCH_HEADING: a cut could tighten
        #: this set (``FRTEngine.exact(notch_cut=True)``).
        self.notch_possible = notch_possible
        self.lattice = lattice
        self.instant = instant
        self.sweep = sweep
        self.bound = bound
        self.bound_rows = bound_rows
        self.outer = outer
        #: Instants whose outer polygon holds fewer than MIN_NODES_INSIDE lattice nodes: the grid
        #: cannot resolve K there, so the outer polygon stands for it.
        self.coarse = np.zeros(len(instant), dtype=bool) if coarse is None else coarse
        #: Per interval j >= 1, whether {sweep_j <= 0} is its outer polygon's own zero set on the
        #: grid (the dilated instants hold that polygon), or, for a set made without its fields,
        #: whether the outer bound shows the polygon within reach of its instants
        #: (``reach.held``): K over the interval is the polygon.
        self.outer_held = np.zeros(len(instant), dtype=bool) if outer_held is None else outer_held
        if len(bound_rows) > 1 and bound_rows[1] - bound_rows[0] != SWEEPS_PER_WINDOW:
            self.outer_held[:] = False  # the outer tube's windows are not the intervals
        #: Whether no value field cuts any instant: each instant's field is its outer polygon's.
        self.instants_uncut = instants_uncut

    def __getstate__(self) -> dict[str, Any]:
        """What crosses a process boundary: everything but the caches rebuilt on demand (the
        outer windows' polygons and their unions, and the notch cut's polygons, which would stay
        in the receiver's cache as objects its garbage collector walks and cost pickling both
        ways; the tubes checks ask for are drawn before a set is sent, and a cut set's are all
        drawn, so what they were drawn from is seldom needed there)."""
        instant, sweep = self._fields_needed()
        state = {
            name: value
            for name, value in vars(self).items()
            if name not in _MEMOS or (name not in _REBUILT_MEMOS and len(value))
        }
        state.update(instant=self.instant.keeping(instant), sweep=self.sweep.keeping(sweep))
        return state

    def __getattr__(self, name: str) -> Any:
        """A memo of :data:`_MEMOS`, made on first use (a set received from a worker carries only
        the memos that hold values: each one is an object its garbage collector walks)."""
        if name not in _MEMOS:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        return self.__dict__.setdefault(name, Memo(maxsize=_MEMOS[name]))

    def _fields_needed(self) -> tuple[np.ndarray, np.ndarray]:
        """Which instants' and which intervals' fields a slice, interval or tube not drawn yet
        may still be drawn from (the others are taken whole from outer polygons, or drawn)."""
        n = self.n_slices
        slices, intervals, tubes = (
            self._slices.key_set(),
            self._intervals.key_set(),
            self._tubes.key_set(),
        )
        instant = ~(self.coarse | (self.instants_uncut & (np.arange(n) >= 1)))
        instant[list(slices)] = False
        sweep = np.zeros(n, dtype=bool)
        for j in range(1, n):
            whole = self.coarse[j] or self.coarse[j - 1] or self.outer_held[j]
            sweep[j] = not whole and j not in intervals
        outer = self._outer_tubes()
        contoured = [j for j in range(n) if j not in tubes and not outer[j]]
        if contoured:
            sweep[: max(contoured) + 1] = True  # a tube is the minimum of the sweeps up to it
        return instant, sweep

    def __setstate__(self, state: dict[str, Any]) -> None:
        vars(self).update(state)

    def _grow(self, k_set: BaseGeometry) -> BaseGeometry:
        return k_set.buffer(self.lattice.step / 2, quad_segs=4) if not k_set.is_empty else k_set

    def tube(self, j: int) -> BaseGeometry:
        return self._tubes.get_or_compute(j, lambda: self._draw_tube(j))

    def _draw_tube(self, j: int) -> BaseGeometry:
        outer = self.outer_tube(j)
        if self._tube_is_outer(j):
            return outer
        k_set = self._sweeps_minimum(j).contour(self.lattice)
        if not k_set.is_empty:
            # The grid dilation already covers the node sampling; this covers the chords that
            # linear interpolation draws across the outer polygons' corners, and the cut to the
            # outer polygons (exact geometry, not sampled) takes the excess back along their edges.
            k_set = k_set.buffer(CORNER_CHORD * self.lattice.step, quad_segs=4)
            k_set = k_set.intersection(outer)
        unresolved = self._unresolved_sweeps(j)
        if unresolved:
            hull = self._unresolved_hull(unresolved)
            if not _one_window(unresolved):
                hull = hull.intersection(outer)
            k_set = shapely.union(k_set, hull)
        held = [i - 1 for i in range(1, j + 1) if self.outer_held[i]]
        if held:
            # Those intervals' K are their outer polygons: the tube holds them whole (and so
            # each tube holds the one before, and every interval up to it).
            k_set = shapely.union_all([k_set, *self._window_polygons()[held]])
        if self.notch is not None:
            k_set = k_set.intersection(self._notch_tube(j))
        return k_set

    def _tube_is_outer(self, j: int) -> bool:
        """Whether tube j is its outer tube: uncut by the notch, and every interval up to s_j
        is its outer polygon (``outer_held``, or an unresolved instant at either end, whose
        sweeps' hull is taken whole). The contour of the sweeps' minimum then holds each
        interval's contour (linear interpolation of a minimum lies below the minimum of the
        interpolations), each of which grown by the corner chords holds its polygon, so the cut
        to the outer tube leaves the outer tube."""
        return bool(self._outer_tubes()[j])

    def _outer_tubes(self) -> np.ndarray:
        """:meth:`_tube_is_outer` of every tube ([n_slices] bool): each interval up to it is its
        outer polygon, a running AND over the intervals."""
        outer = np.zeros(self.n_slices, dtype=bool)
        if self.notch is None and self.n_slices > 1:
            whole = self.outer_held[1:] | self.coarse[1:] | self.coarse[:-1]
            outer[1:] = np.logical_and.accumulate(whole)
        return outer

    def _sweeps_minimum(self, j: int) -> SliceField:
        """``running_minimum(self.sweep[: j + 1])``, from the last one taken before j when there
        is one (checks and workers draw a set's tubes mostly in increasing order)."""
        start, below = next(iter(self._last_minimum.snapshot().items()), (0, None))
        if below is None or start > j:
            below, start = self.sweep[0], 0
        for i in range(start + 1, j + 1):
            below = running_minimum([below, self.sweep[i]])
        return self._last_minimum.put(j, below)

    def _notch_region(self, j: int, before: bool = True, after: bool = True) -> BaseGeometry:
        """Every position reachable within half an instant of s_j, ``before`` and/or ``after`` it
        (neither: at s_j itself): where the set is cut at s_j, the partition's bins each swept
        along its headings by how far a car moves in half an instant (``swept_supports``); else
        the instant's convex outer polygon grown by as much either way."""
        notch = self.notch
        assert notch is not None
        key = (j, before, after) if notch.cut[j] else (j, True, True)
        return self._notch_regions.get_or_compute(
            key, lambda: self._draw_notch_region(notch, j, before, after)
        )

    def _draw_notch_region(
        self, notch: NotchCut, j: int, before: bool, after: bool
    ) -> BaseGeometry:
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
        return region

    def _notch_tube(self, j: int) -> BaseGeometry:
        """Every position reached during [0, s_j]: the tube to s_(j-1), the half instant after
        s_(j-1) and the half instant before s_j (grown from the largest tube already built;
        nothing after s_j, and each instant's two halves apart, which is thinner than both
        together where the car heads away from the set)."""
        built = self._notch_tubes.snapshot()
        if j in built:
            return built[j]
        start = max((i for i in built if i < j), default=-1)
        tube = built[start] if start >= 0 else self._notch_region(0, after=False)
        for i in range(max(start, 0) + 1, j + 1):
            tube = shapely.union_all(
                [tube, self._notch_region(i - 1, before=False), self._notch_region(i, after=False)]
            )
        return self._notch_tubes.put(j, tube)

    def missing_tubes(self, indices: list[int]) -> list[int]:
        return sorted(set(indices).difference(self._tubes.key_set()))

    def nearest_built_tube(self, j: int) -> int:
        later = [i for i in self._tubes.key_set() if i >= j]
        return min(later) if later else self.n_slices - 1

    def _unresolved_hull(self, sweeps: list[int]) -> BaseGeometry:
        """The polygon of the support functions' maximum over ``sweeps``, which contains their
        hull (the same for every tube past the last unresolved instant: built once). The lists of
        one set are prefixes of each other (``_unresolved_sweeps``), so their length names them."""
        return self._hulls.get_or_compute(len(sweeps), lambda: self._sweeps_polygon(sweeps))

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
        chunk = SWEEPS_PER_WINDOW
        support = self.bound.sweep_support
        if n == 0:  # the first sweep's polygon: inside window 0's, so every later tube holds it
            return shapely.union_all(convex_polygons(self.bound.directions, support[:1]))
        if n % chunk:  # a partial last window: not one of the shared windows
            windows = np.stack(
                [support[a : min(a + chunk, n)].max(axis=0) for a in range(0, n, chunk)]
            )
            return shapely.union_all(convex_polygons(self.bound.directions, windows))
        count = n // chunk
        polygons = self._window_polygons()
        built = self._outer_unions.snapshot()
        if count in built:
            union = built[count]
        else:
            start = max((c for c in built if c < count), default=0)
            union = grown_union(built[start] if start else None, list(polygons[start:count]))
        return self._outer_unions.put(count, union)

    def _window_polygons(self) -> np.ndarray:
        """The outer polygon of each whole window of ``SWEEPS_PER_WINDOW`` sweeps (window i - 1
        spans interval i), built once per set."""
        return self._outer_windows.get_or_compute(SWEEPS_PER_WINDOW, self._draw_window_polygons)

    def _draw_window_polygons(self) -> np.ndarray:
        chunk = SWEEPS_PER_WINDOW
        support = self.bound.sweep_support
        full = len(support) // chunk
        windows = support[: full * chunk].reshape(full, chunk, -1).max(axis=1)
        return convex_polygons(self.bound.directions, windows)

    def slice(self, j: int) -> BaseGeometry:
        return self._slices.get_or_compute(j, lambda: self._draw_slice(j))

    def _draw_slice(self, j: int) -> BaseGeometry:
        polygon_only = self.coarse[j] or (self.instants_uncut and j >= 1)
        k_set = (
            shapely.Polygon() if polygon_only else self._grow(self.instant[j].contour(self.lattice))
        )
        if polygon_only or not k_set.is_empty:
            polygon = shapely.Polygon(self.bound.polygons_at([self.bound_rows[j]])[0])
            # An uncut instant's field is its polygon's: its contour grown by half a node step
            # (more than the corner chords) holds the polygon, and the cut leaves the polygon.
            k_set = polygon if polygon_only else k_set.intersection(polygon)
        if self.notch is not None and self.notch.cut[j]:
            k_set = k_set.intersection(self._notch_region(j, before=False, after=False))
        return k_set

    def interval(self, j: int) -> BaseGeometry:
        """K over [s_(j-1), s_j]: {sweep_j <= 0} grown by the contour's corner chords and cut to
        the outer polygon of that window, or that polygon if either instant is unresolved."""
        j = max(j, 1)
        return self._intervals.get_or_compute(j, lambda: self._draw_interval(j))

    def _draw_interval(self, j: int) -> BaseGeometry:
        polygon = self._sweeps_polygon(slice(self.bound_rows[j - 1], self.bound_rows[j]))
        if self.coarse[j] or self.coarse[j - 1] or self.outer_held[j]:
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
        return k_set


def grown_union(built: BaseGeometry | None, parts: list[BaseGeometry]) -> BaseGeometry:
    """The union of ``built`` (None: nothing yet) and ``parts``: one part added to a built union by
    GEOS's binary overlay (faster than the unary union of the two; the same region, its ring
    possibly starting elsewhere), else the unary union of them all."""
    if built is not None and len(parts) == 1:
        return shapely.union(built, parts[0])
    return shapely.union_all(parts if built is None else [built, *parts])


def _one_window(sweeps: list[int]) -> bool:
    """Whether ``sweeps`` are exactly the sweeps of one window of ``SWEEPS_PER_WINDOW`` (the
    usual case: only the initial instant is unresolved). Their polygon is then that window's
    polygon in ``FieldTubeSet.outer_tube`` (the same support maximum, the same vertices), which
    lies in every outer tube past it: cutting it to the outer tube changes nothing."""
    first = sweeps[0]
    return (
        first % SWEEPS_PER_WINDOW == 0
        and len(sweeps) == SWEEPS_PER_WINDOW
        and sweeps == list(range(first, first + SWEEPS_PER_WINDOW))
    )


def _filled_contour(x: np.ndarray, y: np.ndarray, z: np.ndarray, level: float) -> BaseGeometry:
    """The region {z <= level} of a node grid (nodes at ``x``, ``y`` [ny, nx]) as a shapely
    geometry."""
    points, offsets = _contour_generator(x, y, z).filled(-np.inf, level)
    polygons = []
    for pts, off in zip(points, offsets, strict=True):
        rings = [pts[off[i] : off[i + 1]] for i in range(len(off) - 1)]
        rings = [r for r in rings if len(r) >= 4]
        if rings:
            polygons.append(shapely.Polygon(rings[0], rings[1:]))
    if not polygons:
        return shapely.Polygon()
    return shapely.make_valid(shapely.union_all(polygons))


def _contour_generator(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> contourpy.ContourGenerator:
    """contourpy's default ("serial") filled-contour generator of ``z`` on the nodes ``x``, ``y``
    [ny, nx]. Fields of finite values (every field of a set: nodes outside a window hold ``FAR``)
    skip the masked-array scan of ``contourpy.contour_generator``, which costs more than the
    contour of a lattice window; the generator and its arguments are the same."""
    z = np.asarray(z, dtype=np.float64)
    if not np.isfinite(z).all():
        return contourpy.contour_generator(x, y, z, fill_type="OuterOffset")
    return contourpy.SerialContourGenerator(
        x,
        y,
        z,
        None,
        corner_mask=True,
        line_type=contourpy.LineType.SeparateCode,
        fill_type=contourpy.FillType.OuterOffset,
        quad_as_tri=False,
        z_interp=contourpy.ZInterp.Linear,
    )
