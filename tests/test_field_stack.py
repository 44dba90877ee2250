"""The stacked per-instant field operations against plain per-window ones."""

from __future__ import annotations

import math

import numpy as np
import shapely

from reach.field_stack import (
    FAR,
    WindowStack,
    block_reduce,
    dilate_discs,
    span_reduce,
)
from reach.outer_bound import SUPPORT_DIRECTIONS
from reach.polygons import convex_polygons


def _disc_min(values: np.ndarray, radius: float) -> np.ndarray:
    """The per-node minimum over a Euclidean disc, node by node."""
    ny, nx = values.shape
    out = np.empty_like(values)
    for k in range(ny):
        for i in range(nx):
            best = FAR
            for kk in range(ny):
                for ii in range(nx):
                    if (kk - k) ** 2 + (ii - i) ** 2 <= radius * radius:
                        best = min(best, values[kk, ii])
            out[k, i] = best
    return out


def test_dilation_uses_each_instants_own_radius() -> None:
    rng = np.random.default_rng(0)
    values = rng.normal(size=(3, 7, 6)).astype(np.float32)
    radii = np.array([1.0, 1.6, 2.3])
    grown = dilate_discs(values, radii)
    for j, r in enumerate(radii):
        np.testing.assert_array_equal(grown[j], _disc_min(values[j], r))


def test_span_reduce_covers_both_neighbouring_blocks() -> None:
    values = np.array([3.0, 1.0, 4.0, 1.0, 5.0, 9.0])  # three blocks of two
    blocks = block_reduce(values, 2, np.maximum)
    np.testing.assert_array_equal(blocks, [3.0, 4.0, 9.0])
    np.testing.assert_array_equal(span_reduce(blocks, np.maximum), [3.0, 4.0, 9.0, 9.0])


def test_windows_are_padded_and_shifted_between_instants() -> None:
    lo = np.array([[0.0, 0.0], [1.0, 0.5]])
    hi = np.array([[1.0, 1.0], [3.0, 2.0]])
    stack = WindowStack.make(lo, hi, origin=(-2.0, -2.0), step=0.5, size=(40, 40))
    assert stack.shape[1:] == (int(stack.h.max()), int(stack.w.max()))
    valid = stack.valid()
    assert valid[0].sum() == stack.h[0] * stack.w[0]
    values = np.where(valid, np.arange(valid.size).reshape(valid.shape), FAR)
    seen = stack.shifted(values, 0, 1)
    # A node of window 1 shows window 0's value at the same lattice node, FAR where 0 has none.
    for r in range(stack.shape[1]):
        for c in range(stack.shape[2]):
            k = stack.k0[1] + r - stack.k0[0]
            i = stack.i0[1] + c - stack.i0[0]
            inside = 0 <= k < stack.h[0] and 0 <= i < stack.w[0]
            assert seen[r, c] == (values[0, k, i] if inside else FAR)


def test_polygon_field_is_negative_exactly_inside_the_polygon() -> None:
    directions = np.linspace(0, 2 * math.pi, SUPPORT_DIRECTIONS, endpoint=False)
    supports = np.array([np.full(SUPPORT_DIRECTIONS, 1.0), 1.5 + 0.5 * np.cos(directions)])
    stack = WindowStack.make(
        np.full((2, 2), -3.0), np.full((2, 2), 3.0), origin=(-4.0, -4.0), step=0.25, size=(40, 40)
    )
    (field,) = stack.polygon_fields(directions, [supports], stack.valid())
    polygons = convex_polygons(directions, supports)
    for j in range(2):
        xs, ys = np.meshgrid(stack.xs[j], stack.ys[j])
        inside = shapely.contains_xy(polygons[j], xs, ys)
        on_edge = np.abs(field[j]) < 1e-9
        assert np.array_equal((field[j] < 0)[~on_edge], inside[~on_edge])


def test_polygon_fields_are_the_largest_half_plane_distance_at_valid_nodes_only() -> None:
    """The compiled kernel against the formula evaluated at once by numpy broadcasting, on windows
    of unequal shapes (padded nodes must stay +inf)."""
    rng = np.random.default_rng(3)
    count = 7
    lo = rng.uniform(-5.0, 0.0, (count, 2))
    hi = lo + rng.uniform(1.0, 6.0, (count, 2))
    stack = WindowStack.make(lo, hi, origin=(-8.0, -8.0), step=0.3, size=(60, 60))
    valid = stack.valid()
    directions = np.linspace(0, 2 * math.pi, SUPPORT_DIRECTIONS, endpoint=False)
    supports = [rng.uniform(0.0, 4.0, (count, SUPPORT_DIRECTIONS)) for _ in range(2)]
    fields = stack.polygon_fields(directions, supports, valid)
    x = stack.xs[:, None, :, None]
    y = stack.ys[:, :, None, None]
    along = x * np.cos(directions) + y * np.sin(directions)  # [J, H, W, M]
    for field, support in zip(fields, supports, strict=True):
        expected = (along - support[:, None, None, :]).max(axis=-1)
        assert np.allclose(field[valid], expected[valid], rtol=0.0, atol=1e-12)
        assert np.all(np.isposinf(field[~valid]))
