"""The compiled distance to a union of boxes (``reach.distances.box_union_distances_until``)
against the numpy kernel it stands for, and against shapely."""

from __future__ import annotations

import numpy as np
import shapely

from reach.distances import box_union_distances, box_union_distances_until


def _boxes(rng: np.random.Generator, a: int, m: int) -> np.ndarray:
    lo = rng.uniform(-20.0, 20.0, size=(a, m, 2))
    size = rng.uniform(0.0, 8.0, size=(a, m, 2))
    return np.stack(
        [lo[..., 0], lo[..., 0] + size[..., 0], lo[..., 1], lo[..., 1] + size[..., 1]], -1
    )


def test_the_compiled_kernel_gives_the_numpy_kernels_values_bit_for_bit() -> None:
    rng = np.random.default_rng(7)
    for a, n, m in ((1, 1, 1), (5, 17, 9), (40, 20, 31)):
        boxes = _boxes(rng, a, m)
        x, y = rng.uniform(-30.0, 30.0, size=(2, a, n))
        x[:, 0], y[:, 0] = boxes[:, 0, 0], boxes[:, 0, 2]  # a corner, on the boundary
        until = rng.integers(0, m + 2, size=(a, n))  # none, some, all, and past the last
        counted = np.arange(m)[None, None, :] < until[:, :, None]
        want = box_union_distances(x[..., None], y[..., None], boxes[:, None], counted)
        got = box_union_distances_until(x, y, boxes, until)
        assert np.array_equal(got, want)
        every = box_union_distances_until(x, y, boxes, np.full((a, n), m))
        assert np.array_equal(
            every, box_union_distances(x[..., None], y[..., None], boxes[:, None])
        )


def test_outside_the_union_it_is_the_euclidean_distance_and_inside_at_most_zero() -> None:
    rng = np.random.default_rng(11)
    boxes = _boxes(rng, 1, 6)
    union = shapely.union_all([shapely.box(b[0], b[2], b[1], b[3]) for b in boxes[0]])
    x, y = rng.uniform(-30.0, 30.0, size=(2, 1, 400))
    got = box_union_distances_until(x, y, boxes, np.full((1, 400), 6))[0]
    inside = shapely.contains_xy(union, x[0], y[0]) | shapely.touches(
        union, shapely.points(x[0], y[0])
    )
    assert np.all(got[inside] <= 0.0)
    outside = ~inside
    reference = shapely.distance(union, shapely.points(x[0][outside], y[0][outside]))
    assert np.allclose(got[outside], reference, rtol=0.0, atol=1e-9)
