"""The interval outer bound contains every simulated reachable position (independent rollouts)."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from models.eval_settings import SETTINGS
from models.rollout import (
    sample_control_schedules,
    sample_reference_schedules,
)
from models.sampling import sample_parameters
from reach.contract import COL
from reach.outer_bound import cos_max_towards, cos_range, outer_bound
from reach.polygons import convex_polygons, half_plane_polygons
from tests.fixtures.trajectories import simulate


def test_cos_range_is_exact_on_dense_samples() -> None:
    rng = np.random.default_rng(0)
    lo = rng.uniform(-10, 10, 300)
    hi = lo + rng.uniform(0, 7, 300)
    c_lo, c_hi = cos_range(lo, hi)
    dense = np.cos(np.linspace(lo, hi, 20001))
    np.testing.assert_allclose(c_lo, dense.min(axis=0), atol=1e-6)
    np.testing.assert_allclose(c_hi, dense.max(axis=0), atol=1e-6)


def test_cos_max_towards_directions_is_exact_on_dense_samples() -> None:
    rng = np.random.default_rng(1)
    lo = rng.uniform(-10, 10, 200)
    hi = lo + np.concatenate([rng.uniform(0, 7, 190), np.zeros(5), np.full(5, 2 * np.pi)])
    directions = np.arange(16) * (2 * np.pi / 16)
    dense = np.cos(np.linspace(lo, hi, 20001)[:, :, None] - directions).max(axis=0)
    got = cos_max_towards(lo, hi, directions)
    assert got.shape == (200, 16)
    np.testing.assert_allclose(got, dense, atol=1e-6)
    assert np.all(got >= dense - 1e-12)  # never below a sampled value: the bound stays outward


@pytest.mark.parametrize("n_directions", [16, 32])
def test_half_plane_polygons_are_the_intersections_of_their_half_planes(n_directions: int) -> None:
    """Each polygon equals shapely's intersection of its half-planes (each a large box clipped
    to one side of its line), with redundant constraints (supports raised far beyond the rest)
    that must cut no corner off, and its vertices run counter-clockwise."""
    rng = np.random.default_rng(n_directions)
    directions = np.arange(n_directions) * (2 * np.pi / n_directions)
    supports = rng.uniform(2.0, 6.0, (40, n_directions)) + rng.normal(0, 3, (40, 1)) * np.cos(
        directions - rng.uniform(0, 2 * np.pi, (40, 1))
    )
    redundant = rng.uniform(size=supports.shape) < 0.2
    supports = np.where(redundant, supports + rng.uniform(1, 30, supports.shape), supports)
    polygons = half_plane_polygons(directions, supports)
    shapes = convex_polygons(directions, supports)  # the same, built as shapely polygons at once
    for support, vertices, shape in zip(supports, polygons, shapes, strict=True):
        want = shapely.box(-100, -100, 100, 100)
        for phi, h in zip(directions, support, strict=True):
            c, s = np.cos(phi), np.sin(phi)
            # The half-plane p . (c, s) <= h, as a big rectangle behind its line.
            base = np.array([h * c, h * s])
            along, back = np.array([-s, c]) * 300, -np.array([c, s]) * 300
            want = want.intersection(
                shapely.Polygon(
                    [base - along, base + along, base + along + back, base - along + back]
                )
            )
        got = shapely.Polygon(vertices)
        assert got.is_valid and shapely.Polygon(vertices).exterior.is_ccw
        assert got.symmetric_difference(want).area < 1e-6 * want.area
        assert shape.is_valid and shape.symmetric_difference(want).area < 1e-6 * want.area


@pytest.mark.parametrize(
    ("seed", "schedules"), [(0, sample_control_schedules), (1, sample_reference_schedules)]
)
def test_rollouts_stay_inside_the_outer_bound(seed: int, schedules) -> None:
    rng = np.random.default_rng(seed)
    settings = [(s.v_start, s.bounds()) for s in SETTINGS[::3]]
    settings += [(float(p[COL["v_start"]]), p[6:]) for p in sample_parameters(6, rng)]
    n = 2000
    for v_start, bounds in settings:
        ob = outer_bound(v_start, bounds)
        _, trace = simulate(v_start, bounds, n, rng, schedules)
        for tau, (px, py, _heading, v) in trace[::5]:
            t = float(tau[0])
            x_lo, x_hi, y_lo, y_hi = ob.box_containing_slice(t)
            k = ob.slice_index(t)
            assert np.all(px >= x_lo - 1e-6) and np.all(px <= x_hi + 1e-6)
            assert np.all(py >= y_lo - 1e-6) and np.all(py <= y_hi + 1e-6)
            assert np.all(np.hypot(px, py) <= ob.radius[k + 1] + 1e-6)
            polygon = ob.sweep_polygon(k)
            normals = np.stack([np.cos(ob.directions), np.sin(ob.directions)], axis=1)
            projections = np.stack([px, py], axis=1) @ normals.T
            assert np.all(projections <= ob.sweep_support[k] + 1e-6)
            assert shapely.contains_xy(shapely.Polygon(polygon).buffer(1e-6), px, py).all()
            assert np.all(v >= ob.speed[k : k + 2, 0].min() - 1e-6)
            assert np.all(v <= ob.speed[k : k + 2, 1].max() + 1e-6)


def test_polygon_is_inside_the_box_and_tighter_for_a_turn() -> None:
    bounds = next(s for s in SETTINGS if s.name == "left_turn").bounds()
    ob = outer_bound(6.0, bounds)
    for k in (10, 30, 59):
        polygon = shapely.Polygon(ob.sweep_polygon(k))
        x_lo, x_hi, y_lo, y_hi = ob.sweep[k]
        assert shapely.box(x_lo, y_lo, x_hi, y_hi).buffer(1e-6).contains(polygon)
    assert polygon.area < 0.9 * (x_hi - x_lo) * (y_hi - y_lo)


def test_outer_bound_is_not_vacuous_for_a_narrow_setting() -> None:
    bounds = next(s for s in SETTINGS if s.name == "urban_narrow").bounds()
    ob = outer_bound(8.0, bounds)
    x_lo, x_hi, y_lo, y_hi = ob.box_at[-1]
    assert 20 < x_lo < x_hi < 28
    assert y_hi - y_lo < 8
