"""The compiled ring kernels against GEOS (``reach.distances.signed_distance``, shapely).

Polygons are random: star-shaped rings, some with a hole, some split into several parts, some
empty; points fall inside, outside and far away. The per-trajectory reductions of the surrogates
are compared with those of GEOS's distances.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry

from reach.batch import tubes_of
from reach.distances import signed_distance
from reach.frames import Pose, human_frames
from reach.packed_rings import (
    CHUNK,
    DIRECTIONS,
    pack_rings,
    signed_distances_packed,
    trajectory_surrogates,
)
from reach.sets import FRTSet


def star(rng: np.random.Generator, centre: tuple[float, float], size: float, n: int) -> Polygon:
    angles = np.sort(rng.uniform(0.0, 2.0 * math.pi, n))
    radii = size * rng.uniform(0.3, 1.0, n)
    return Polygon(
        np.column_stack([centre[0] + radii * np.cos(angles), centre[1] + radii * np.sin(angles)])
    )


def random_geometry(rng: np.random.Generator) -> BaseGeometry:
    kind = rng.integers(0, 4)
    n = int(rng.integers(3, 60))
    if kind == 0:
        return star(rng, (0.0, 0.0), 10.0, n)
    if kind == 1:  # a hole
        outer = star(rng, (0.0, 0.0), 10.0, n).buffer(3.0)
        return outer.difference(shapely.Point(0.0, 0.0).buffer(2.0))
    if kind == 2:  # several parts
        parts = [star(rng, (20.0 * k, 5.0 * k), 6.0, n).buffer(0) for k in range(3)]
        return shapely.union_all(parts)
    return Polygon()


def points_around(rng: np.random.Generator, count: int) -> np.ndarray:
    near = rng.uniform([-15.0, -15.0], [50.0, 25.0], size=(count, 2))
    far = rng.normal(0.0, 300.0, size=(count // 4, 2))
    return np.concatenate([near, far])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_signed_distances_are_geos(seed: int) -> None:
    rng = np.random.default_rng(seed)
    geometries = [random_geometry(rng) for _ in range(4)]
    packed = pack_rings(geometries)
    xy = points_around(rng, 200)
    which = rng.integers(0, len(geometries), len(xy))
    ours = signed_distances_packed(packed, which, xy)
    for g, geometry in enumerate(geometries):
        rows = which == g
        expected = signed_distance(geometry, xy[rows])
        if geometry.is_empty:
            assert np.isinf(ours[rows]).all()
        else:
            np.testing.assert_allclose(ours[rows], expected, rtol=0.0, atol=1e-9)


def test_chunks_hold_their_segments() -> None:
    rng = np.random.default_rng(7)
    geometries = [random_geometry(rng) for _ in range(6)]
    packed = pack_rings(geometries)
    for c in range(len(packed.chunk_boxes)):
        segments = packed.segments[packed.segment_starts[c] : packed.segment_starts[c + 1]]
        assert 1 <= len(segments) <= CHUNK
        x0, y0, x1, y1 = packed.chunk_boxes[c]
        assert (segments[:, [0, 2]] >= x0).all() and (segments[:, [0, 2]] <= x1).all()
        assert (segments[:, [1, 3]] >= y0).all() and (segments[:, [1, 3]] <= y1).all()
    rings = sum(
        len(shapely.get_coordinates(r)) - 1
        for g in geometries
        for r in shapely.get_rings(shapely.get_parts(g))
    )
    assert len(packed.segments) == rings


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), threshold=st.floats(-2.0, 6.0))
def test_surrogates_keep_each_trajectorys_least_value_and_first_collision(
    seed: int, threshold: float
) -> None:
    rng = np.random.default_rng(seed)
    geometries = [random_geometry(rng) for _ in range(3)]
    packed = pack_rings(geometries)
    lengths = rng.integers(1, 40, size=25)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    # Trajectories: random walks, so neighbouring points have neighbouring distances.
    steps = rng.normal(0.0, 1.5, size=(int(lengths.sum()), 2))
    origins = np.repeat(rng.uniform([-15.0, -15.0], [50.0, 25.0], size=(25, 2)), lengths, axis=0)
    walk = np.cumsum(steps, axis=0)
    xy = origins + walk - np.repeat(walk[starts], lengths, axis=0)
    which = rng.integers(0, len(geometries), len(xy))
    exact = signed_distances_packed(packed, which, xy)
    surrogate = trajectory_surrogates(packed, which, xy, starts, threshold)
    assert (surrogate <= exact + 1e-12).all()
    ends = np.append(starts[1:], len(xy))
    for a, b in zip(starts, ends, strict=True):
        assert surrogate[a:b].min() == exact[a:b].min()
        below_exact = np.flatnonzero(exact[a:b] < threshold)
        below_surrogate = np.flatnonzero(surrogate[a:b] < threshold)
        first = below_exact[0] if len(below_exact) else None
        assert (below_surrogate[0] if len(below_surrogate) else None) == first
        if first is not None:
            assert surrogate[a + first] == exact[a + first]


def test_a_point_on_the_boundary_is_at_distance_zero() -> None:
    square = Polygon([(0, 0), (4, 0), (4, 4), (0, 4)])
    packed = pack_rings([square, MultiPolygon()])
    xy = np.array([[4.0, 2.0], [2.0, 0.0], [0.0, 0.0], [2.0, 2.0], [6.0, 2.0]])
    ours = signed_distances_packed(packed, np.zeros(5, dtype=np.int64), xy)
    assert ours == pytest.approx([0.0, 0.0, 0.0, -2.0, 2.0])
    assert np.isinf(signed_distances_packed(packed, np.ones(1, dtype=np.int64), xy[:1])).all()


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    pose=st.tuples(st.floats(-50.0, 50.0), st.floats(-50.0, 50.0), st.floats(-4.0, 4.0)),
)
def test_world_points_are_moved_to_the_frame_as_human_frames_moves_them(
    seed: int, pose: tuple[float, float, float]
) -> None:
    rng = np.random.default_rng(seed)
    geometries = [random_geometry(rng) for _ in range(3)]
    packed = pack_rings(geometries)
    world = points_around(rng, 120) + np.array(pose[:2])
    which = rng.integers(0, len(geometries), len(world))
    x, y = human_frames(world, [Pose(*pose)])
    in_frame = np.stack([x[0], y[0]], axis=1)
    expected = signed_distances_packed(packed, which, in_frame)
    moved = signed_distances_packed(packed, which, world, pose)
    np.testing.assert_array_equal(moved, expected)
    starts = np.arange(0, len(world), 10)
    surrogate = trajectory_surrogates(packed, which, world, starts, 1.0, pose=pose)
    np.testing.assert_array_equal(
        surrogate, trajectory_surrogates(packed, which, in_frame, starts, 1.0)
    )


def test_the_support_bound_is_below_the_distance_and_tighter_than_the_box() -> None:
    """A thin diagonal strip: its box is a poor bound at the empty corners (the points lie inside
    the box), the support bound a close one; both stay below GEOS's signed distance, and a
    trajectory's least surrogate is GEOS's least distance."""
    strip = shapely.LineString([(0.0, 0.0), (20.0, 20.0)]).buffer(0.5)
    packed = pack_rings([strip])
    xy = np.array([[18.0, 2.0], [2.0, 18.0], [10.0, 10.0], [30.0, -5.0]])
    exact = signed_distance(strip, xy)
    support = (xy @ DIRECTIONS.T - packed.supports[0]).max(axis=1)
    assert (support <= exact).all()
    assert (support[:2] > 10.0).all() and (exact[:2] < 12.0).all()
    which = np.zeros(len(xy), dtype=np.int64)
    surrogate = trajectory_surrogates(packed, which, xy, np.array([0]), -10.0)
    assert surrogate.min() == pytest.approx(exact.min(), abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    grid=st.sampled_from([(0.1, 3.0, 31), (0.25, 3.0, 13), (0.1, 2.0, 21), (0.3, 3.0, 11)]),
)
def test_tubes_of_is_the_sets_tube_indices_made_distinct(
    seed: int, grid: tuple[float, float, int]
) -> None:
    rng = np.random.default_rng(seed)
    slice_dt, horizon, n_slices = grid
    frt = FRTSet(Pose(0.0, 0.0, 0.0), slice_dt, horizon, n_slices, conservative=False)
    # Times on and around the slices' instants, before the start and past the horizon.
    on_grid = slice_dt * rng.integers(-2, n_slices + 3, 200)
    times = np.concatenate([on_grid, on_grid + rng.normal(0.0, 1e-9, 200), rng.uniform(-1, 4, 200)])
    tubes, which = tubes_of(frt, times)
    expected_tubes, expected_which = frt.tubes_present(frt.tube_indices(times))
    np.testing.assert_array_equal(tubes, expected_tubes)
    np.testing.assert_array_equal(which, expected_which)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), threshold=st.floats(-2.0, 6.0), group=st.integers(2, 6))
def test_surrogates_of_points_of_several_probes_keep_the_least_and_first_collision(
    seed: int, threshold: float, group: int
) -> None:
    """A point is ``group`` probes (a footprint's discs) of one polygon; its value their least."""
    rng = np.random.default_rng(seed)
    geometries = [random_geometry(rng) for _ in range(3)]
    packed = pack_rings(geometries)
    lengths = rng.integers(1, 30, size=12)
    points = int(lengths.sum())
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    centres = rng.uniform([-15.0, -15.0], [50.0, 25.0], size=(points, 2))
    xy = (centres[:, None, :] + rng.normal(0.0, 1.5, size=(points, group, 2))).reshape(-1, 2)
    which = np.repeat(rng.integers(0, len(geometries), points), group)
    exact = signed_distances_packed(packed, which, xy).reshape(points, group).min(axis=1)
    probes = trajectory_surrogates(packed, which, xy, starts, threshold, group)
    assert (probes <= signed_distances_packed(packed, which, xy) + 1e-12).all()
    surrogate = probes.reshape(points, group).min(axis=1)
    for a, b in zip(starts, np.append(starts[1:], points), strict=True):
        assert surrogate[a:b].min() == exact[a:b].min()
        below_exact = np.flatnonzero(exact[a:b] < threshold)
        below_surrogate = np.flatnonzero(surrogate[a:b] < threshold)
        assert below_surrogate[:1].tolist() == below_exact[:1].tolist()
