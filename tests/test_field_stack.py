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


def _numpy_dilate_discs(values: np.ndarray, radii_nodes: np.ndarray) -> np.ndarray:
    """The dilation by numpy minima over the whole array, offset by offset (the reference the
    compiled kernel keeps bit for bit)."""
    count, height, width = values.shape
    r = math.floor(float(radii_nodes.max())) if count else 0
    padded = np.full((count, height + 2 * r, width + 2 * r), FAR, dtype=values.dtype)
    padded[:, r : r + height, r : r + width] = values
    out = values.copy()
    squared = radii_nodes * radii_nodes
    for dk in range(-r, r + 1):
        for di in range(-r, r + 1):
            d2 = dk * dk + di * di
            if d2 == 0:
                continue
            applies = d2 <= squared
            if not applies.any():
                continue
            shifted = padded[:, r + dk : r + dk + height, r + di : r + di + width]
            if applies.all():
                np.minimum(out, shifted, out=out)
            else:
                rows = np.flatnonzero(applies)
                out[rows] = np.minimum(out[rows], shifted[rows])
    return out


def _awkward_values(rng: np.random.Generator, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """Random values with ties, zeros of both signs, FAR and a few NaNs among them."""
    values = rng.normal(size=shape).round(1).astype(dtype)
    picks = rng.uniform(size=shape)
    values[picks < 0.1] = 0.0
    values[(picks >= 0.1) & (picks < 0.2)] = -0.0
    values[(picks >= 0.2) & (picks < 0.3)] = FAR
    values[picks > 0.997] = np.nan
    return values


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def test_compiled_dilation_is_numpy_minima_bit_for_bit() -> None:
    rng = np.random.default_rng(11)
    for case in range(40):
        dtype = np.float32 if case % 3 else np.float64
        shape = (int(rng.integers(1, 6)), int(rng.integers(1, 12)), int(rng.integers(1, 12)))
        values = _awkward_values(rng, shape, dtype)
        # Radii on and between the squared offsets (d^2 <= r^2 exactly), as float64 and float32.
        radii = rng.choice([0.5, 1.0, 1.5, math.sqrt(2.0), 2.0, 2.3, math.sqrt(5.0), 3.1], shape[0])
        if case % 4 == 0:
            radii = radii.astype(np.float32)
        assert _same_bits(dilate_discs(values, radii), _numpy_dilate_discs(values, radii))


def test_dilation_within_extents_is_the_dilation_of_the_windows_alone() -> None:
    """Nodes outside an instant's extent count as FAR and come out FAR: the whole-array dilation
    of the values with FAR there, at the nodes within."""
    rng = np.random.default_rng(12)
    for _ in range(20):
        shape = (4, int(rng.integers(3, 12)), int(rng.integers(3, 12)))
        values = _awkward_values(rng, shape, np.float32)
        heights = rng.integers(1, shape[1] + 1, shape[0])
        widths = rng.integers(1, shape[2] + 1, shape[0])
        inside = (np.arange(shape[1])[None, :, None] < heights[:, None, None]) & (
            np.arange(shape[2])[None, None, :] < widths[:, None, None]
        )
        radii = rng.uniform(0.5, 3.0, shape[0])
        expected = _numpy_dilate_discs(np.where(inside, values, np.float32(FAR)), radii)
        expected[~inside] = FAR
        assert _same_bits(dilate_discs(values, radii, (heights, widths)), expected)


def _numpy_interval_fields(
    stack: WindowStack, field: np.ndarray, grown: np.ndarray, interval: np.ndarray, band: float
) -> tuple[np.ndarray, np.ndarray]:
    """The interval fields and held flags by numpy, window by window (the compiled kernel's
    reference)."""
    valid = stack.valid()
    grown = grown.copy()
    grown[~valid] = FAR
    sweep = np.empty_like(field)
    sweep[0] = field[0]
    held = np.zeros(len(field), dtype=bool)
    for j in range(1, len(field)):
        near = np.minimum(grown[j], stack.shifted(grown, j - 1, j))
        inside = valid[j] & (interval[j] <= 0)
        edge = valid[j] & (np.abs(interval[j]) <= band)
        held[j] = bool(np.all(near[inside] <= 0) and np.all(near[edge] <= interval[j][edge]))
        np.maximum(near, interval[j], out=sweep[j])
    sweep[~valid] = FAR
    return sweep, held


def test_compiled_interval_fields_are_numpy_bit_for_bit() -> None:
    rng = np.random.default_rng(13)
    held_seen = 0
    for case in range(30):
        count = int(rng.integers(2, 7))
        lo = rng.uniform(-3.0, 0.0, (count, 2))
        hi = lo + rng.uniform(0.5, 3.0, (count, 2))
        stack = WindowStack.make(lo, hi, origin=(-5.0, -5.0), step=0.5, size=(30, 30))
        shape = stack.shape
        field = _awkward_values(rng, shape, np.float32)
        interval = rng.normal(size=shape).astype(np.float32)
        grown = _awkward_values(rng, shape, np.float32)
        if case % 2:  # instants that hold their intervals' polygons
            grown = (interval - np.abs(rng.normal(size=shape))).astype(np.float32)
        band = np.float32(rng.uniform(0.1, 1.0))
        expected_sweep, expected_held = _numpy_interval_fields(stack, field, grown, interval, band)
        sweep, held = stack.interval_fields(field, grown.copy(), interval, stack.valid(), band)
        assert _same_bits(sweep, expected_sweep)
        np.testing.assert_array_equal(held, expected_held)
        held_seen += int(held.sum())
    assert held_seen > 0


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
