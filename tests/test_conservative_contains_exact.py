"""The conservative set contains the exact set (API.md: a late answer comes "from a set that
contains it ... never less safe than the model's own set"), on the shipped model, for random
parameter settings: as geometry, and in the clearances the checks answer with.

The exact tube is cut to outer polygons that each span 0.1 s of sweeps; between sweeps whose
boxes step sideways such a polygon bulges past the conservative set's boxes (found by a black-box
audit: up to 0.1 m, a check answered clear conservatively and in collision exactly).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

from models.runtime import ValueModel
from models.sampling import sample_parameters
from models.value_fields import engine_for
from reach.contract import COL
from reach.engine import FRTEngine
from reach.frames import Pose, to_world_frame

MODEL = Path(__file__).resolve().parent.parent / "models" / "frt_unicycle.onnx"
pytestmark = pytest.mark.skipif(not MODEL.exists(), reason="no shipped model yet")

TUBES = (1, 3, 10, 20, 30)


@pytest.fixture(scope="module")
def engine() -> FRTEngine:
    return engine_for(ValueModel.load(MODEL))


@pytest.mark.parametrize("row", range(12))
def test_the_conservative_tubes_contain_the_exact_ones(engine: FRTEngine, row: int) -> None:
    params = sample_parameters(12, np.random.default_rng(7))[row]
    v_start, bounds = float(params[COL["v_start"]]), params[6:].astype(np.float32)
    pose = Pose(10.0, -5.0, 2.5)
    exact = engine.exact(pose, v_start, bounds)
    conservative = engine.conservative(pose, v_start, bounds)
    rng = np.random.default_rng(row)
    for j in TUBES:
        k_exact, k_conservative = exact.tube(j), conservative.tube(j)
        outside = k_exact.difference(k_conservative)
        if not outside.is_empty:
            vertices = shapely.points(shapely.get_coordinates(outside))
            assert shapely.distance(k_conservative, vertices).max() < 1e-9, (row, j)

        # The answers themselves: points on and around the exact tube's boundary, world frame.
        ring = shapely.get_coordinates(k_exact.boundary)
        near = ring[rng.integers(0, len(ring), 200)] + rng.normal(0, 0.3, (200, 2))
        xy = shapely.get_coordinates(to_world_frame(shapely.multipoints(near), pose))
        t = np.full(len(xy), j * engine.slice_dt)
        for t_rel in (None, t):
            d_exact = exact.clearance(xy, t_rel)
            d_conservative = conservative.clearance(xy, t_rel)
            # Inside the exact set the conservative one says inside too; outside, never farther.
            assert np.all(d_conservative <= np.maximum(d_exact, 0.0) + 1e-9), (row, j)
