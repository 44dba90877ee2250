"""Clearances against many sets at once (conservative or exact) equal the sets' own, one by one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import reach.batch
from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.batch import (
    Reduction,
    box_clearances,
    run_on_threads,
    trajectory_reductions,
    trajectory_surrogates_of,
    tube_clearances,
    tubes_of,
    tubes_of_many,
)
from reach.footprint import disc_cover, footprint_distances
from reach.frames import Pose
from reach.sets import FRTSet

BOUNDS = np.array([-0.3, -2.0, -0.2, -1.0, 0.3, 1.5, 0.25, 2.0])


def random_sets(build, rng: np.random.Generator, count: int) -> list:
    """``build(pose, v_start, bounds)`` at random poses, speeds and bound widths."""
    return [
        build(Pose(float(x), float(y), float(h)), float(v), BOUNDS * float(scale))
        for x, y, h, v, scale in zip(
            rng.uniform(-10, 10, count),
            rng.uniform(-10, 10, count),
            rng.uniform(-3, 3, count),
            rng.uniform(0, 15, count),
            rng.uniform(0.2, 1.0, count),
            strict=True,
        )
    ]


def test_batched_box_clearances_equal_the_sets_own(analytic_model_path: Path) -> None:
    engine = engine_for(ValueModel.load(analytic_model_path))
    rng = np.random.default_rng(3)
    sets = random_sets(engine.conservative, rng, 8)
    xy = rng.uniform(-30, 60, size=(40, 2))
    t_rel = [None if i % 2 else rng.uniform(-0.5, 3.5, size=40) for i in range(len(sets))]
    together = box_clearances(sets, xy, t_rel)
    for frt, t, mine in zip(sets, t_rel, together, strict=True):
        alone = frt.clearance(xy, t)
        assert np.array_equal(mine, alone)
    assert any((c < 0).any() for c in together) and any((c > 0).any() for c in together)


def test_box_clearances_measured_in_slices_of_points_are_the_same(
    analytic_model_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    engine = engine_for(ValueModel.load(analytic_model_path))
    rng = np.random.default_rng(4)
    sets = random_sets(engine.conservative, rng, 5)
    xy = rng.uniform(-30, 60, size=(997, 2))
    t_rel = [None if i % 2 else rng.uniform(-0.5, 3.5, size=997) for i in range(len(sets))]
    whole = box_clearances(sets, xy, t_rel)
    monkeypatch.setattr(reach.batch, "BOX_PASS_ELEMENTS", 5 * len(sets[0].boxes) * 100)
    for mine, alone in zip(box_clearances(sets, xy, t_rel), whole, strict=True):
        assert np.array_equal(mine, alone)


def test_batched_exact_clearances_equal_the_sets_own(analytic_model_path: Path) -> None:
    engine = engine_for(ValueModel.load(analytic_model_path))
    rng = np.random.default_rng(4)
    sets = random_sets(engine.exact, rng, 6)
    sets.append(sets[0])  # one set twice: its tubes are shared
    near = np.array([[s.pose.x + 1.0, s.pose.y] for s in sets])
    xy = np.concatenate([rng.uniform(-30, 60, size=(30, 2)), near])
    t_rel = [None if i % 2 else rng.uniform(-0.5, 3.5, size=len(xy)) for i in range(len(sets))]
    together = tube_clearances(sets, xy, t_rel)
    for frt, t, mine in zip(sets, t_rel, together, strict=True):
        assert np.array_equal(mine, frt.clearance(xy, t))
    assert any((c < 0).any() for c in together) and any((c > 0).any() for c in together)
    assert tube_clearances([], xy, []) == []


def test_box_clearances_are_signed_distances_to_the_union_of_boxes(
    analytic_model_path: Path,
) -> None:
    """Against shapely's distance to the union of the boxes (an independent computation): equal
    outside; inside, negative and at most as deep as in the union (the deepest single box)."""
    import shapely

    from reach.distances import signed_distance
    from reach.frames import to_human_frame

    engine = engine_for(ValueModel.load(analytic_model_path))
    rng = np.random.default_rng(5)
    sets = random_sets(engine.conservative, rng, 6)
    xy = rng.uniform(-30, 60, size=(60, 2))
    for frt, mine in zip(sets, box_clearances(sets, xy, [None] * len(sets)), strict=True):
        b = frt.boxes
        union = shapely.union_all(shapely.box(b[:, 0], b[:, 2], b[:, 1], b[:, 3]))
        truth = signed_distance(union, to_human_frame(xy, frt.pose))
        outside = truth > 0
        np.testing.assert_allclose(mine[outside], truth[outside], rtol=0, atol=1e-9)
        assert np.all(mine[~outside] <= 0) and np.all(mine[~outside] >= truth[~outside] - 1e-9)
    assert any((c < 0).any() for c in box_clearances(sets, xy, [None] * len(sets)))


def test_trajectory_reductions_equal_the_clearance_arithmetic() -> None:
    """The compiled reductions against numpy's: a footprint's least disc (NaN if one is), less
    the discs' radius and R_col, NaN counted as -limit, clipped; per trajectory the least and the
    first row below zero. Random distances with NaN, infinities and values beyond the limit."""
    rng = np.random.default_rng(11)
    limit = 1e9
    for trial in range(300):
        lengths = rng.integers(1, 8, rng.integers(1, 20))
        n = int(lengths.sum())
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.intp)
        cover = None if trial % 2 else disc_cover(rng.uniform(1, 6), rng.uniform(0.5, 3), 0.0)
        group = 1 if cover is None else cover.count
        probed = rng.normal(0.0, 3.0, n * group)
        for value, share in ((np.nan, 0.05), (np.inf, 0.02), (-np.inf, 0.01), (2 * limit, 0.02)):
            probed[rng.random(len(probed)) < share] = value
        radius = float(rng.uniform(0.0, 2.0))
        points = probed if cover is None else footprint_distances(probed, cover)
        clearance = np.clip(
            np.where(np.isnan(points - radius), -limit, points - radius), -limit, limit
        )
        least = np.minimum.reduceat(clearance, starts)
        first = np.minimum.reduceat(np.where(clearance < 0.0, np.arange(n), n), starts)
        offset = 0.0 if cover is None else cover.radius
        got = trajectory_reductions(probed, starts, group, offset, radius, limit)
        assert np.array_equal(got[0], least) and np.array_equal(got[1], first)


def test_tubes_of_runs_of_equal_times_are_those_of_every_time(analytic_model_path: Path) -> None:
    """A footprint's discs share their point's time: the tubes found once a run are those found
    for every probe."""
    engine = engine_for(ValueModel.load(analytic_model_path))
    frt = random_sets(engine.exact, np.random.default_rng(6), 1)[0]
    times = np.repeat(np.random.default_rng(7).uniform(-0.5, 3.5, size=40), 6)
    whole = reach.batch.tubes_of(frt, times)
    runs = reach.batch.tubes_of(frt, times, 6)
    assert np.array_equal(whole[0], runs[0]) and np.array_equal(whole[1], runs[1])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_batch_measured_on_threads_equals_it_on_one(analytic_model_path: Path, seed: int) -> None:
    """Each set's surrogates are the same on one thread or several, bit for bit, and their least
    per trajectory is that of the set's own clearances (time-indexed, random sets, points and
    thresholds; with and without footprint discs)."""
    engine = engine_for(ValueModel.load(analytic_model_path))
    rng = np.random.default_rng(seed)
    sets = random_sets(engine.exact, rng, 7)
    lengths = rng.integers(1, 30, size=40)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    xy = rng.uniform(-25, 25, size=(int(lengths.sum()), 2))
    times = np.concatenate([np.sort(rng.uniform(0.0, 3.5, n)) for n in lengths])
    t_rel = [times - rng.choice([0.0, 0.3]) for _ in sets]
    for group, every_point in ((1, False), (1, True), (3, False)):
        probes = np.repeat(xy, group, axis=0) + rng.normal(0.0, 0.5, (len(xy) * group, 2))
        probe_times = [np.repeat(t, group) for t in t_rel]
        reduction = Reduction(
            starts, rng.uniform(-1.0, 4.0, len(sets)).tolist(), group, every_point
        )
        one = trajectory_surrogates_of(sets, probes, probe_times, reduction, threads=1)
        for threads in (2, 3):
            many = trajectory_surrogates_of(sets, probes, probe_times, reduction, threads=threads)
            assert all(np.array_equal(a, b) for a, b in zip(one, many, strict=True))
        for frt, t, values in zip(sets, probe_times, one, strict=True):
            own = frt.clearance(probes, t).reshape(-1, group).min(axis=1)
            least = np.minimum.reduceat(values.reshape(-1, group).min(axis=1), starts)
            np.testing.assert_allclose(least, np.minimum.reduceat(own, starts), atol=1e-9)


def test_calls_on_threads_are_each_made_once_and_raise_what_they_raise() -> None:
    made: list[int] = []

    def call(k: int) -> int:
        made.append(k)
        return k * k

    assert run_on_threads([lambda k=k: call(k) for k in range(50)], 2) == [k * k for k in range(50)]
    assert sorted(made) == list(range(50))
    assert run_on_threads([], 2) == [] and run_on_threads([lambda: 1], 4) == [1]

    def fails() -> int:
        raise ValueError("a call's")

    with pytest.raises(ValueError, match="a call's"):
        run_on_threads([lambda: 1, fails, lambda: 2], 2)


class OwnIndices(FRTSet):
    """A set with tube indices of its own: its tubes are found for it alone."""

    def tube_indices(self, t_rel: np.ndarray) -> np.ndarray:
        return np.zeros(np.asarray(t_rel).size, dtype=int)


@pytest.mark.parametrize("group", [1, 4])
def test_tubes_found_once_for_equal_times_are_each_sets_own(group: int) -> None:
    """Sets on one grid with equal times share their tubes; every set's are its own."""
    rng = np.random.default_rng(9)
    grids = [(0.1, 3.0, 31), (0.1, 3.0, 31), (0.25, 3.0, 13), (0.1, 3.0, 31), (0.1, 3.0, 31)]
    sets: list[FRTSet] = [FRTSet(Pose(0.0, 0.0, 0.0), *g, conservative=False) for g in grids]
    sets.append(OwnIndices(Pose(0.0, 0.0, 0.0), 0.1, 3.0, 31, conservative=False))
    times = np.repeat(rng.uniform(-0.5, 3.5, 50), group)
    t_rel = [times, times.copy(), times, times - 0.3, times, times]
    found = tubes_of_many(sets, t_rel, group)
    for frt, t, (tubes, which) in zip(sets, t_rel, found, strict=True):
        expected = tubes_of(frt, t, group)
        assert np.array_equal(tubes, expected[0]) and np.array_equal(which, expected[1])
    assert found[1] is found[0] and found[4] is found[0]
    assert found[2] is not found[0] and found[3] is not found[0] and found[5] is not found[0]
