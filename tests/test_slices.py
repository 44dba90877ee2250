"""Time slices of the shipped model's sets: a slice at time t holds every position reachable at
exactly t, on the slices' 0.1 s grid or between its instants (a black-box audit found t = 0.05 s
answered with the set at t = 0, which the moving car has already left), and the tube up to t holds
the slice (the audit found slice 0 sticking 0.12 m out of the tube)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

from models.eval_settings import SETTINGS
from models.rollout import (
    EDGE_SHARE,
    rk4_rollout,
    sample_initial_states,
    sample_reference_schedules,
)
from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.contract import COL, HORIZON_S, N_INPUTS
from reach.engine import FRTEngine
from reach.frames import Pose

MODEL = Path(__file__).resolve().parent.parent / "models" / "frt_unicycle.onnx"
pytestmark = pytest.mark.skipif(not MODEL.exists(), reason="no shipped model yet")

NAMES = ("fast_narrow", "urban_wide", "shrinking_wide_to_narrow", "stationary_narrow")
TIMES = (0.0, 0.05, 0.1, 0.37, 1.0, 1.234, 2.95, 3.0)


@pytest.fixture(scope="module")
def engine() -> FRTEngine:
    return engine_for(ValueModel.load(MODEL))


def positions_at(v_start: float, bounds: np.ndarray, t: float, n: int = 4000) -> np.ndarray:
    """Positions reached at exactly t by rollouts of the true dynamics (the evaluation's mix)."""
    rng = np.random.default_rng(round(1000 * t))
    params = np.zeros((n, N_INPUTS))
    params[:, COL["v_start"]] = v_start
    params[:, 6:] = bounds
    start = sample_initial_states(params[:, COL["v_start"]], rng, on_boundary=EDGE_SHARE)
    if t == 0.0:
        return np.stack(start[:2], axis=1)
    a1, a2, switches = sample_reference_schedules(n, HORIZON_S, rng)
    end, _ = rk4_rollout(
        start, params, np.full(n, t), a1, a2, switches * (t / HORIZON_S), max(2, round(t / 0.01))
    )
    return np.stack(end[:2], axis=1)


@pytest.mark.parametrize("name", NAMES)
def test_a_slice_holds_the_positions_reachable_at_its_time(engine: FRTEngine, name: str) -> None:
    setting = {s.name: s for s in SETTINGS}[name]
    bounds = setting.bounds()
    exact = engine.exact(Pose(0.0, 0.0, 0.0), setting.v_start, bounds)
    conservative = engine.conservative(Pose(0.0, 0.0, 0.0), setting.v_start, bounds)
    for t in TIMES:
        xy = positions_at(setting.v_start, bounds, t)
        for frt in (exact, conservative):
            k_set = frt.geometry("slice", t)
            distance = shapely.distance(k_set, shapely.points(xy))
            assert distance.max() < 1e-6, (name, t, frt.conservative, float(distance.max()))


@pytest.mark.parametrize("name", NAMES)
def test_the_tube_holds_every_slice(engine: FRTEngine, name: str) -> None:
    setting = {s.name: s for s in SETTINGS}[name]
    frt = engine.exact(Pose(0.0, 0.0, 0.0), setting.v_start, setting.bounds())
    for t in TIMES:
        k_slice, k_tube = frt.geometry("slice", t), frt.geometry("tube", t)
        outside = k_slice.difference(k_tube)
        if not outside.is_empty:
            vertices = shapely.points(shapely.get_coordinates(outside))
            assert shapely.distance(k_tube, vertices).max() < 1e-6, (name, t)
