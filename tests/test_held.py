"""Intervals held by their outer polygons as the outer bound alone shows (``reach.held``), and the
sets built without their fields on that ground (``FRTEngine._held_set``).

Each interval found held must be held: every point of its polygon within the car's half-interval
reach of one of its instants' polygons (checked here on dense samples with shapely, independently
of the kernel). A set built without its fields must serve what the set drawn from its fields
serves: the same tubes, intervals and slices, the same unresolved instants, and, when asked, the
same fields bit for bit.
"""

from __future__ import annotations

import math
import pickle
from pathlib import Path

import numpy as np
import pytest
import shapely

from models.runtime import ValueModel
from models.sampling import sample_parameters
from models.value_fields import engine_for
from reach.contract import COL
from reach.engine import FRTEngine
from reach.field_stack import block_reduce
from reach.field_tube import DeferredSliceFields, FieldTubeSet
from reach.frames import Pose
from reach.held import held_intervals
from reach.polygons import half_plane_polygons

MODEL = Path(__file__).resolve().parent.parent / "models" / "frt_unicycle.onnx"
DIRECTIONS = np.arange(16) * (2 * math.pi / 16)
#: A car driving on: small steering and acceleration bounds (contract order).
MOVING = np.array([-0.15, -1.5, -0.15, -1.5, 0.15, 1.5, 0.15, 1.5])


def _square_supports(cx: float, cy: float, half: float) -> np.ndarray:
    """Supports of the 16-direction polygon around the square of side 2 ``half`` at (cx, cy)."""
    c, s = np.cos(DIRECTIONS), np.sin(DIRECTIONS)
    return cx * c + cy * s + half * (np.abs(c) + np.abs(s))


@pytest.mark.parametrize(("reach", "held"), [(0.31, True), (0.29, False)])
def test_a_translated_square_is_held_within_half_the_gap(reach: float, held: bool) -> None:
    """A square of side 0.4 moved by 1 m between two instants: the polygon of both (their
    supports' maximum, the rectangle [-0.2, 1.2] x [-0.2, 0.2]) lies within 0.3 m of one of them
    (its middle is 0.3 m from either), and no nearer. The first instant is not the initial disc
    here (interval 2)."""
    before, after = _square_supports(0.0, 0.0, 0.2), _square_supports(1.0, 0.0, 0.2)
    instants = np.stack([before, before, after])
    intervals = np.stack([before, before, np.maximum(before, after)])
    reach_m = np.array([0.0, 0.0, reach])
    found = held_intervals(DIRECTIONS, instants, intervals, reach_m, 0.5, np.ones(3, bool))
    assert found[2] == held


def test_a_polygon_inside_its_later_instant_is_held_without_any_reach() -> None:
    grown = _square_supports(0.0, 0.0, 1.0)
    instants = np.stack([grown * 0.5, grown * 0.5, grown])
    intervals = np.stack([grown, grown, grown])
    found = held_intervals(DIRECTIONS, instants, intervals, np.zeros(3), 0.5, np.ones(3, bool))
    assert found[2]


def _within_reach(q: shapely.Polygon, near: list, reach: float) -> bool:
    """Every sample of ``q`` (its boundary every 2 cm and a grid inside it) within ``reach`` of
    one of the ``near`` geometries, up to 1e-3 m."""
    boundary = shapely.get_coordinates(shapely.segmentize(q.exterior, 0.02))
    x0, y0, x1, y1 = q.bounds
    xs, ys = np.meshgrid(np.linspace(x0, x1, 40), np.linspace(y0, y1, 40))
    grid = np.stack([xs.ravel(), ys.ravel()], axis=1)
    grid = grid[shapely.contains_xy(q, grid[:, 0], grid[:, 1])]
    points = shapely.points(np.concatenate([boundary, grid]))
    distance = np.min([shapely.distance(g, points) for g in near], axis=0)
    return bool(np.all(distance <= reach + 1e-3))


@pytest.fixture(scope="module")
def engine() -> FRTEngine:
    if not MODEL.exists():
        pytest.skip("no shipped model yet")
    return engine_for(ValueModel.load(MODEL), network=False)


def _settings(count: int, seed: int) -> list[tuple[float, np.ndarray]]:
    """Random settings of the trained ranges, a third of them with bounds shrunk tenfold (cars
    driving on, as most observed ones do)."""
    rng = np.random.default_rng(seed)
    out = []
    for row in sample_parameters(count, np.random.default_rng(seed)):
        bounds = row[6:].astype(np.float32)
        if rng.uniform() < 1 / 3:
            bounds = (bounds * 0.1).astype(np.float32)
        out.append((float(row[COL["v_start"]]), bounds))
    return out


@pytest.mark.parametrize("seed", [1, 2])
def test_every_interval_found_held_is_within_reach_of_its_instants(
    engine: FRTEngine, seed: int
) -> None:
    checked = 0
    for v_start, bounds in _settings(8, seed):
        ob = engine.outer(v_start, bounds)
        k = engine.outer_steps_per_slice
        rows = [j * k for j in range(engine.n_slices)]
        intervals = block_reduce(ob.sweep_support, k, np.maximum)
        reach = block_reduce(ob.sweep_speed_max, k, np.maximum) * (engine.slice_dt / 2)
        held = held_intervals(
            ob.directions,
            ob.support_at[rows],
            np.concatenate([intervals[:1], intervals]),
            np.concatenate([[0.0], reach]),
            engine.radius_m,
            np.ones(engine.n_slices, dtype=bool),
        )
        instants = [
            shapely.Polygon(p) for p in half_plane_polygons(ob.directions, ob.support_at[rows])
        ]
        instants[0] = shapely.Point(0.0, 0.0).buffer(engine.radius_m, quad_segs=64)
        polygons = half_plane_polygons(ob.directions, intervals)
        for j in np.flatnonzero(held)[::3]:
            q = shapely.Polygon(polygons[j - 1])
            assert _within_reach(q, [instants[j - 1], instants[j]], reach[j - 1]), (v_start, j)
            checked += 1
    assert checked > 20


def _fields_set(engine: FRTEngine, v_start: float, bounds: np.ndarray) -> FieldTubeSet:
    """The same setting's set drawn from its fields (what ``exact`` builds when it cannot show
    the intervals held)."""
    ob = engine.outer(v_start, bounds)
    rows = [j * engine.outer_steps_per_slice for j in range(engine.n_slices)]
    return engine._fields_set(Pose(2.0, -1.0, 0.4), ob, rows, v_start, bounds, None)


def test_a_set_without_fields_serves_what_the_fields_would(engine: FRTEngine) -> None:
    without = 0
    for v_start, bounds in _settings(24, 3):
        frt = engine.exact(Pose(2.0, -1.0, 0.4), v_start, bounds)
        reference = _fields_set(engine, v_start, bounds)
        np.testing.assert_array_equal(frt.coarse, reference.coarse)
        if not isinstance(frt.instant, DeferredSliceFields):
            continue
        without += 1
        for j in range(frt.n_slices):
            for kind in ("tube", "interval", "slice"):
                got, want = getattr(frt, kind)(j), getattr(reference, kind)(j)
                assert got.symmetric_difference(want).area < 1e-9, (v_start, kind, j)
            assert frt.outer_tube(j).buffer(1e-6).contains(frt.tube(j))
        for mine, theirs in ((frt.instant, reference.instant), (frt.sweep, reference.sweep)):
            for j in range(frt.n_slices):  # asked for, the fields are the grid's, bit for bit
                np.testing.assert_array_equal(mine[j].values, theirs[j].values)
                assert (mine[j].k0, mine[j].i0) == (theirs[j].k0, theirs[j].i0)
    assert without >= 16


def test_a_set_without_fields_sends_only_its_first_instant(engine: FRTEngine) -> None:
    frt = engine.exact(Pose(0.0, 0.0, 0.0), 8.0, MOVING)
    assert isinstance(frt.instant, DeferredSliceFields)
    received = pickle.loads(pickle.dumps(frt, protocol=4))
    kept = [
        j for j, v in enumerate((*received.instant.values, *received.sweep.values)) if v is not None
    ]
    assert set(kept) <= {0, frt.n_slices}
    points = np.random.default_rng(0).uniform(-10.0, 40.0, (200, 2))
    times = np.random.default_rng(1).uniform(0.0, 3.0, 200)
    np.testing.assert_array_equal(received.clearance(points, times), frt.clearance(points, times))
    for j in (0, 1, 15, 30):
        assert received.slice(j).symmetric_difference(frt.slice(j)).area < 1e-12


def test_a_value_field_that_cuts_keeps_the_fields() -> None:
    if not MODEL.exists():
        pytest.skip("no shipped model yet")
    engine = engine_for(ValueModel.load(MODEL), network=True)
    frt = engine.exact(Pose(0.0, 0.0, 0.0), 8.0, MOVING)
    assert not frt.instants_uncut
    assert not isinstance(frt.instant, DeferredSliceFields)
