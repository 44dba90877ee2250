"""A set's outer tubes grow by one window at a time (``reach.field_tube.grown_union``): the region
must be the unary union's, whichever overlay computes it."""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import MultiPoint

from reach.field_tube import grown_union


def convex(rng: np.random.Generator, centre: np.ndarray) -> shapely.Polygon:
    """The hull of a dozen points around ``centre``: a convex polygon a few metres across."""
    return MultiPoint(centre + rng.normal(0.0, 2.0, size=(12, 2))).convex_hull


def test_a_window_added_to_a_built_union_covers_the_unary_unions_region() -> None:
    rng = np.random.default_rng(7)
    for _ in range(200):
        path = np.cumsum(rng.normal(0.0, 1.5, size=(8, 2)), axis=0)  # windows along a path
        windows = [convex(rng, c) for c in path]
        built = shapely.union_all(windows[:-1])
        grown = grown_union(built, windows[-1:])
        expected = shapely.union_all(windows)
        assert grown.is_valid
        assert grown.symmetric_difference(expected).area <= 1e-9 * expected.area
        assert abs(grown.area - expected.area) <= 1e-9 * expected.area


def test_several_parts_or_nothing_built_take_the_unary_union() -> None:
    rng = np.random.default_rng(8)
    windows = [convex(rng, c) for c in np.cumsum(rng.normal(0.0, 1.5, size=(6, 2)), axis=0)]
    assert grown_union(None, windows).equals_exact(shapely.union_all(windows), 0.0)
    built = shapely.union_all(windows[:2])
    assert grown_union(built, windows[2:]).equals_exact(
        shapely.union_all([built, *windows[2:]]), 0.0
    )
