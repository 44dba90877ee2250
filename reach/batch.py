"""Clearances of one trajectory (or a batch) against many sets at once: conservative and exact.

A planner's check of 50 agents whose exact sets are late answers from 50 :class:`BoxTubeSet`\\ s;
``BoxTubeSet.clearance`` one by one is a dozen small numpy calls per agent. Here the agents'
boxes are stacked ([A, M, 4]) and the distances of every point to every box of every agent come
from one compiled pass (``reach.distances.box_union_distances_until``) with the arithmetic of
``box_union_distances``, so the values are the same.
"""

from __future__ import annotations

import itertools
import os
import queue
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import TypeVar

import numba
import numpy as np
from shapely.geometry.base import BaseGeometry

from reach.distances import (
    box_union_distances_until,
    compile_distance_kernels,
    signed_distances,
    union_box_distances_until,
)
from reach.frames import human_frames
from reach.packed_rings import point_columns, signed_distances_packed, trajectory_surrogates
from reach.sets import BoxTubeSet, FRTSet
from reach.thread_placement import forget_helpers, keep_helpers_off_caller, register


def box_clearances(
    sets: Sequence[BoxTubeSet], xy_world: np.ndarray, t_rel: Sequence[np.ndarray | None]
) -> list[np.ndarray]:
    """``[s.clearance(xy_world, t) for s, t in zip(sets, t_rel)]``, computed together for the sets
    with the same number of boxes."""
    xy_world = np.asarray(xy_world, dtype=float).reshape(-1, 2)
    out: list[np.ndarray | None] = [None] * len(sets)
    groups: dict[int, list[int]] = {}
    for i, s in enumerate(sets):
        groups.setdefault(len(s.boxes), []).append(i)
    for members in groups.values():
        for i, result in zip(
            members,
            _same_size([sets[i] for i in members], xy_world, [t_rel[i] for i in members]),
            strict=True,
        ):
            out[i] = result
    return out  # type: ignore[return-value]


def least_member_clearances(
    groups: Sequence[Sequence[BoxTubeSet]],
    xy_world: np.ndarray,
    t_rel: Sequence[np.ndarray | None],
) -> list[np.ndarray]:
    """Per group of box sets (one agent's: its set alone, or a union's members), the least of
    ``[s.clearance(xy_world, t_rel[g]) for s in groups[g]]`` at each point: the same values bit
    for bit. The sets alone go through :func:`box_clearances` together; a union of at least
    :data:`TREE_UNION_PROBES` point-member pairs whose members share their frame and layout of
    boxes (one engine's sets of one pose do) is measured by
    ``reach.distances.union_box_distances_until``, which searches all of its members' boxes
    together; any other union member by member with them."""
    xy_world = np.asarray(xy_world, dtype=float).reshape(-1, 2)
    out: list[np.ndarray | None] = [None] * len(groups)
    unions: dict[tuple[int, int], list[int]] = {}
    alone: list[tuple[int, BoxTubeSet]] = []
    for g, members in enumerate(groups):
        if len(members) * len(xy_world) >= TREE_UNION_PROBES and _shared_layout(members):
            unions.setdefault((len(members), len(members[0].boxes)), []).append(g)
        else:
            alone += [(g, s) for s in members]
    measured = box_clearances([s for _, s in alone], xy_world, [t_rel[g] for g, _ in alone])
    for (g, _), found in zip(alone, measured, strict=True):
        previous = out[g]
        out[g] = found if previous is None else np.minimum(previous, found)
    for same in unions.values():
        found = _union_pass([groups[g] for g in same], xy_world, [t_rel[g] for g in same])
        for g, row in zip(same, found, strict=True):
            out[g] = row
    return out  # type: ignore[return-value]


def _shared_layout(members: Sequence[BoxTubeSet]) -> bool:
    """Whether box sets share their pose, grid of slices and layout of boxes."""
    first = members[0]
    grid = (first.pose, first.slice_dt, first.horizon_s, first.n_slices, first.boxes.shape)
    return all(
        (m.pose, m.slice_dt, m.horizon_s, m.n_slices, m.boxes.shape) == grid
        and (m.boxes_until is first.boxes_until or np.array_equal(m.boxes_until, first.boxes_until))
        for m in members[1:]
    )


def _union_pass(
    unions: list[Sequence[BoxTubeSet]], xy_world: np.ndarray, t_rel: list[np.ndarray | None]
) -> list[np.ndarray]:
    """:func:`least_member_clearances` of unions with the same numbers of members and boxes,
    each sharing its members' layout: their boxes as [A, W, K, 4] (window w of member k)."""
    firsts = [members[0] for members in unions]
    x, y = human_frames(xy_world, [s.pose for s in firsts])  # [A, N]
    boxes = np.stack([np.stack([m.boxes for m in members], axis=1) for members in unions])
    if any(t is not None for t in t_rel):
        index = _tube_indices(firsts, t_rel, len(xy_world))  # [A, N]
        until = np.stack([frt.boxes_until[row] for frt, row in zip(firsts, index, strict=True)])
    else:
        until = np.full(x.shape, boxes.shape[1])
    threads = KERNEL_THREADS if x.size * boxes.shape[2] >= THREADED_UNION_PROBES else 1
    edges = np.linspace(0, x.shape[1], threads + 1).round().astype(int)
    calls = [
        partial(union_box_distances_until, x[:, a:b], y[:, a:b], boxes, until[:, a:b])
        for a, b in itertools.pairwise(edges.tolist())
    ]
    return list(np.concatenate(run_on_threads(calls, threads), axis=1))


#: Elements of the [A, N, M] arrays one pass of the box kernel holds: a batch of points is measured
#: in slices of points so that its temporaries stay within a few tens of megabytes.
BOX_PASS_ELEMENTS = 1 << 21


def _same_size(
    sets: list[BoxTubeSet], xy_world: np.ndarray, t_rel: list[np.ndarray | None]
) -> list[np.ndarray]:
    """:func:`box_clearances` of sets with the same number of boxes, in slices of points."""
    n = len(xy_world)
    step = max(1, BOX_PASS_ELEMENTS // (len(sets) * len(sets[0].boxes)))
    if n <= step:
        return _same_size_pass(sets, xy_world, t_rel)
    parts = [
        _same_size_pass(
            sets, xy_world[a : a + step], [None if t is None else t[a : a + step] for t in t_rel]
        )
        for a in range(0, n, step)
    ]
    return [np.concatenate([part[i] for part in parts]) for i in range(len(sets))]


def _same_size_pass(
    sets: list[BoxTubeSet], xy_world: np.ndarray, t_rel: list[np.ndarray | None]
) -> list[np.ndarray]:
    x, y = human_frames(xy_world, [s.pose for s in sets])  # [A, N]
    b = np.concatenate([s.boxes for s in sets]).reshape(len(sets), -1, 4)  # [A, M, 4]
    if any(t is not None for t in t_rel):  # time-indexed: the boxes up to each point's tube
        index = _tube_indices(sets, t_rel, len(xy_world))  # [A, N]
        first = sets[0].boxes_until
        if all(frt.boxes_until is first for frt in sets):  # one engine's sets share it
            until = first[index]
        else:
            until = np.take_along_axis(np.stack([frt.boxes_until for frt in sets]), index, axis=1)
    else:
        until = np.full(x.shape, b.shape[1])
    return list(box_union_distances_until(x, y, b, until))


def _tube_indices(sets: list[BoxTubeSet], t_rel: list[np.ndarray | None], n: int) -> np.ndarray:
    """``FRTSet.tube_indices`` of each set's times ([A, N]; the last tube where a time is None),
    found once per array of times where the sets share their slices (one engine's sets do; the
    agents of a frame share their array of times)."""
    first = sets[0]
    grid = (first.slice_dt, first.horizon_s, first.n_slices)
    if all(t is not None for t in t_rel) and all(
        (s.slice_dt, s.horizon_s, s.n_slices) == grid for s in sets
    ):
        out = np.empty((len(sets), n), dtype=int)
        found: dict[int, np.ndarray] = {}
        for a, t in enumerate(t_rel):
            row = found.get(id(t))
            if row is None:
                row = found[id(t)] = first.tube_indices(t)  # type: ignore[arg-type]
            out[a] = row
        return out
    return np.stack(
        [
            np.full(n, frt.n_slices - 1) if t is None else frt.tube_indices(t)
            for frt, t in zip(sets, t_rel, strict=True)
        ]
    )


#: Threads a batch check's ring kernels run on (which release the GIL): the calling thread and
#: ``KERNEL_THREADS - 1`` helper threads kept for them; two where the process may use two CPUs.
KERNEL_THREADS = min(
    2, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
)
#: Probe-agent pairs below which a batch is measured on the calling thread alone: handing a share
#: to another thread costs more than it saves.
THREADED_PROBES = 20_000
#: Point-member pairs of unions (points of each union times its members) below which unions are
#: measured on the calling thread alone (:func:`least_member_clearances`).
THREADED_UNION_PROBES = 64_000
#: Point-member pairs of a union from which its boxes are searched in a tree
#: (:func:`least_member_clearances`); below, member by member with the other sets, which costs
#: less than building the tree (a 3-mode agent checked along 20 points).
TREE_UNION_PROBES = 2_048

T = TypeVar("T")
#: Where a job's outcome goes: None, or what it raised.
Outcomes = queue.SimpleQueue[BaseException | None]
#: What the helper threads run: a function, and where its outcome goes.
_jobs: queue.SimpleQueue[tuple[Callable[[], None], Outcomes]] = queue.SimpleQueue()
_helpers = 0
_helpers_lock = threading.Lock()


def _helper() -> None:
    while True:
        work, done = _jobs.get()
        try:
            work()
        except BaseException as error:  # handed to the thread that waits for it
            done.put(error)
        else:
            done.put(None)


def _start_helpers(count: int) -> None:
    global _helpers
    with _helpers_lock:
        while _helpers < count:
            thread = threading.Thread(target=_helper, name="frt-kernel", daemon=True)
            thread.start()
            if thread.native_id is not None:
                register(thread.native_id)
            _helpers += 1


def _forget_helpers() -> None:
    """In a forked child, which holds none of the parent's threads: helpers of its own."""
    global _jobs, _helpers, _helpers_lock
    _jobs, _helpers, _helpers_lock = queue.SimpleQueue(), 0, threading.Lock()
    forget_helpers()


os.register_at_fork(after_in_child=_forget_helpers)


def run_on_threads(calls: Sequence[Callable[[], T]], threads: int) -> list[T]:
    """``[call() for call in calls]``, on up to ``threads`` threads: the calling one and helper
    threads kept for this (off the calling one's CPU: ``reach.thread_placement``), each taking
    the next call no thread has taken until none is left. An exception of a call is raised once
    every thread has stopped."""
    helpers = min(threads, len(calls)) - 1
    if helpers <= 0:
        return [call() for call in calls]
    _start_helpers(helpers)
    keep_helpers_off_caller()
    out: list[T | None] = [None] * len(calls)
    taken = itertools.count()  # next() on it is atomic: each call is taken once

    def work() -> None:
        while (k := next(taken)) < len(calls):
            out[k] = calls[k]()

    done: Outcomes = queue.SimpleQueue()
    for _ in range(helpers):
        _jobs.put((work, done))
    try:
        work()
    finally:
        errors = [done.get() for _ in range(helpers)]
    for error in errors:
        if error is not None:
            raise error
    return out  # type: ignore[return-value]


@dataclass(frozen=True)
class Reduction:
    """What a batch check reads of each agent's distances: per trajectory (points
    ``starts[k]:starts[k + 1]``) the least one and the first point below ``thresholds[a]`` (agent
    a's), a point being ``group`` consecutive probes (a footprint's discs) whose least counts."""

    starts: np.ndarray
    thresholds: Sequence[float]
    group: int = 1
    #: Every point's distance is read (a batch's per-point clearances): no reduction.
    every_point: bool = False


def trajectory_surrogates_of(
    sets: Sequence[FRTSet],
    xy_world: np.ndarray,
    t_rel: Sequence[np.ndarray | None],
    reduction: Reduction,
    places: Sequence[tuple[np.ndarray, np.ndarray] | None] | None = None,
    threads: int | None = None,
) -> list[np.ndarray]:
    """Per set, surrogates of its :meth:`FRTSet.clearance` values (``reach.packed_rings``): the
    same least value and first value below the set's threshold per trajectory, the signed
    distances computed only where those need them (with ``every_point``, every one of them, by
    the same kernel). The kernels move the world points into each set's human frame by the
    arithmetic of ``reach.frames.human_frames``. ``places[a]``, where given, is
    ``tubes_of(sets[a], t_rel[a])``, found already. The sets are measured on up to ``threads``
    threads (:func:`run_on_threads`; None: :data:`KERNEL_THREADS` from :data:`THREADED_PROBES`
    probe-set pairs, else one), each set's values by one thread alone: the same on any number."""
    columns = point_columns(np.asarray(xy_world, dtype=np.float64).reshape(-1, 2))
    n = len(columns[0])
    calls = []
    for a, (frt, t) in enumerate(zip(sets, t_rel, strict=True)):
        known = None if places is None else places[a]
        if t is None:
            tubes, which = np.array([frt.n_slices - 1]), np.zeros(n, dtype=np.int64)
        elif known is not None:
            tubes, which = known
        else:
            tubes, which = tubes_of(frt, t)
        packed = frt.packed_tubes(tuple(tubes.tolist()))
        pose = (frt.pose.x, frt.pose.y, frt.pose.heading)
        if reduction.every_point:
            calls.append(partial(signed_distances_packed, packed, which, columns, pose))
            continue
        calls.append(
            partial(
                trajectory_surrogates,
                packed,
                which,
                columns,
                reduction.starts,
                reduction.thresholds[a],
                reduction.group,
                pose,
            )
        )
    if threads is None:
        threads = KERNEL_THREADS if n * len(calls) >= THREADED_PROBES else 1
    return run_on_threads(calls, threads)


def tubes_of(frt: FRTSet, t_rel: np.ndarray, group: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``frt.tubes_present(frt.tube_indices(t_rel))``: the tubes the times need (increasing) and
    each time's place among them; in one compiled pass (the same arithmetic) where the set keeps
    :class:`FRTSet`'s definitions of both. ``group``: the times come in runs of that many equal
    ones (a footprint's discs at a point), found once a run."""
    if group > 1:
        tubes, which = tubes_of(frt, np.asarray(t_rel).reshape(-1)[::group])
        return tubes, np.repeat(which, group)
    kind = type(frt)
    if kind.tube_indices is FRTSet.tube_indices and kind.tubes_present is FRTSet.tubes_present:
        times = np.asarray(t_rel, dtype=np.float64).reshape(-1)
        which = np.empty(len(times), dtype=np.int64)
        present = _tubes_present(times, frt.slice_dt, frt.horizon_s, frt.n_slices, which)
        return np.flatnonzero(present), which
    return frt.tubes_present(frt.tube_indices(t_rel))


def tubes_of_many(
    sets: Sequence[FRTSet], t_rel: Sequence[np.ndarray], group: int = 1
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``[tubes_of(s, t, group) for s, t in zip(sets, t_rel)]``, found once for the sets that keep
    :class:`FRTSet`'s tube definitions on one grid of slices and have equal times (the agents of
    one frame: the same points, the same time of observation), the later ones given the first's
    arrays (the kernels only read them)."""
    out = []
    found: list[tuple[tuple[float, float, int], np.ndarray, tuple[np.ndarray, np.ndarray]]] = []
    for frt, t in zip(sets, t_rel, strict=True):
        kind = type(frt)
        if kind.tube_indices is not FRTSet.tube_indices or (
            kind.tubes_present is not FRTSet.tubes_present
        ):
            out.append(tubes_of(frt, t, group))
            continue
        grid = (frt.slice_dt, frt.horizon_s, frt.n_slices)
        times = np.asarray(t)
        same = (
            place
            for key, seen, place in found
            if key == grid and (seen is times or _equal_times(seen, times))
        )
        place = next(same, None)
        if place is None:
            place = tubes_of(frt, times, group)
            found.append((grid, times, place))
        out.append(place)
    return out


def _equal_times(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two arrays of times are equal element by element (the first elements compared
    first: times after different observations differ there)."""
    return a.shape == b.shape and (a.size == 0 or a.flat[0] == b.flat[0]) and np.array_equal(a, b)


def compile_batch_kernels() -> None:
    """Compile (or load from numba's cache) this module's kernels before a check needs them: a
    first call takes a few hundred milliseconds, which a check's deadline cannot hold."""
    _tubes_present(np.zeros(1), 0.1, 3.0, 30, np.empty(1, dtype=np.int64))
    compile_distance_kernels()
    trajectory_reductions(np.zeros(2), np.zeros(1, dtype=np.intp), 2, 0.5, 1.0, 1e9)


@numba.njit(cache=True)
def _tubes_present(times, slice_dt, horizon_s, n_slices, which):
    """``FRTSet.tube_indices`` (clip to [0, horizon], ceil(t / dt - 1e-9), at most the last) and
    ``FRTSet.tubes_present`` of ``times``: the mask of tubes present, each time's place among
    them into ``which``."""
    present = np.zeros(n_slices, dtype=np.bool_)
    for i in range(len(times)):
        t = min(max(times[i], 0.0), horizon_s)
        which[i] = int(min(np.ceil(t / slice_dt - 1e-9), n_slices - 1))
        present[which[i]] = True
    rank = np.cumsum(present) - 1
    for i in range(len(times)):
        which[i] = rank[which[i]]
    return present


def tube_clearances(
    sets: Sequence[FRTSet], xy_world: np.ndarray, t_rel: Sequence[np.ndarray | None]
) -> list[np.ndarray]:
    """``[s.clearance(xy_world, t) for s, t in zip(sets, t_rel)]`` for sets that answer with
    ``FRTSet.clearance`` (the exact sets): every agent's points against their tubes in one
    vectorised call each; the same values (the same GEOS operations on the same geometries and
    points, the human frame by the same arithmetic)."""
    xy_world = np.asarray(xy_world, dtype=float).reshape(-1, 2)
    if not sets:
        return []
    n = xy_world.shape[0]
    x, y = (v.reshape(-1) for v in human_frames(xy_world, [s.pose for s in sets]))
    tubes_list: list[BaseGeometry] = []  # each tube once (by identity)
    position: dict[int, int] = {}
    which: list[int] = []  # per point, its tube's place in tubes_list
    for frt, t in zip(sets, t_rel, strict=True):
        if t is None:
            index = [frt.n_slices - 1] * n
        else:
            index = frt.tube_indices(t).tolist()
            if len(index) != n:
                raise ValueError("t_rel needs one time per point")
        places = {}
        for j in set(index):
            tube = frt.tube(j)
            place = position.setdefault(id(tube), len(tubes_list))
            if place == len(tubes_list):
                tubes_list.append(tube)
            places[j] = place
        which += [places[j] for j in index]
    tubes = np.empty(len(tubes_list), dtype=object)
    tubes[:] = tubes_list
    signed = signed_distances(tubes, np.array(which, dtype=np.intp), np.stack([x, y], axis=1))
    return list(signed.reshape(len(sets), n))


def trajectory_reductions(
    probed: np.ndarray,
    starts: np.ndarray,
    group: int,
    offset: float,
    radius: float,
    limit: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Per trajectory (points ``starts[k]:starts[k + 1]``), the least clearance and the row of the
    first point whose clearance is below zero (the number of points if none), the clearances
    being those of the probe distances ``probed``: a point's is the least of its ``group``
    probes' less ``offset`` (numpy's minimum: NaN if one is), less ``radius``, NaN counted as
    ``-limit`` and clipped to +-``limit``; the same floating-point operations in the same order
    as ``CheckPoints.point_distances`` and ``service.flows.checks.clearance_rows``."""
    points = len(probed) // group
    begins = np.asarray(starts, dtype=np.int64)
    least = np.empty(len(begins), dtype=np.float64)
    first = np.empty(len(begins), dtype=np.int64)
    _reduce(probed, begins, points, group, offset, radius, limit, least, first)
    return least, first


@numba.njit(cache=True, inline="always")
def _point_value(probed, p, group):
    """Point p's least probe distance, NaN if one of its probes' is (numpy's minimum)."""
    d = probed[p * group]
    for i in range(p * group + 1, (p + 1) * group):
        if d == d and (probed[i] < d or probed[i] != probed[i]):
            d = probed[i]
    return d


@numba.njit(cache=True, inline="always")
def _clearance(d, offset, radius, limit):
    c = (d - offset) - radius
    return -limit if c != c else min(max(c, -limit), limit)


@numba.njit(cache=True)
def _reduce(probed, begins, points, group, offset, radius, limit, least, first):
    # A clearance is a non-decreasing function of its point's value (NaN its least): the least
    # clearance is the least value's, and only where that is below zero is a point below zero.
    for k in range(len(begins)):
        end = begins[k + 1] if k + 1 < len(begins) else points
        smallest, undefined = np.inf, False
        for p in range(begins[k], end):
            d = _point_value(probed, p, group)
            if d < smallest:
                smallest = d
            elif d != d:
                undefined = True
        least[k] = -limit if undefined else _clearance(smallest, offset, radius, limit)
        first[k] = points
        if least[k] < 0.0:
            for p in range(begins[k], end):
                if _clearance(_point_value(probed, p, group), offset, radius, limit) < 0.0:
                    first[k] = p
                    break
