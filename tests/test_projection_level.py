"""The projection network's level: offset plus slope times the set's size, containing every sample."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from models.eval_settings import SETTINGS
from models.projection import LEVEL_SLOPES, affine_level
from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.frames import Pose

MODEL = Path(__file__).resolve().parent.parent / "models" / "frt_unicycle.onnx"


def test_the_level_contains_every_sample_at_the_least_mean_level() -> None:
    rng = np.random.default_rng(0)
    scale = rng.uniform(1.0, 100.0, 5000)
    w = rng.normal(0.0, 0.3, 5000) + 0.02 * scale * rng.uniform(0, 1, 5000)
    offset, slope = affine_level(w, scale)
    assert np.all(w <= offset + slope * scale + 1e-12)
    # No other candidate slope (with its own smallest containing offset) has a lower mean level.
    for other in LEVEL_SLOPES:
        other_offset = np.max(w - other * scale)
        assert offset + slope * scale.mean() <= other_offset + other * scale.mean() + 1e-9


def test_errors_that_grow_with_the_set_get_a_slope_and_constant_ones_an_offset() -> None:
    rng = np.random.default_rng(1)
    scale = rng.uniform(1.0, 100.0, 5000)
    growing = 0.05 * scale * rng.uniform(0.9, 1.0, 5000)
    offset, slope = affine_level(growing, scale)
    assert slope == 0.05 and abs(offset) < 0.05
    constant = rng.uniform(-0.5, 0.5, 5000)
    offset, slope = affine_level(constant, scale)
    assert slope == 0.0 and offset == constant.max()


@pytest.mark.skipif(not MODEL.exists(), reason="no shipped model yet")
def test_the_engine_adds_the_level_offset_and_a_higher_level_gives_a_larger_set() -> None:
    """At a slope where the shipped network cuts the outer polygons, 0.5 m of offset keeps every
    tube inside the larger one and grows the tube where the network cuts."""
    model = ValueModel.load(MODEL)
    low, high = engine_for(model), engine_for(model)
    for engine, offset in ((low, 0.0), (high, 0.5)):
        engine.value_field.level_per_scale, engine.value_field.level_offset_m = -0.05, offset
    setting = SETTINGS[5]
    ob = low.outer(setting.v_start, setting.bounds())
    rows = [10, 20, 30]
    boxes = ob.box_at[rows]
    np.testing.assert_allclose(high.value_field.levels(boxes) - low.value_field.levels(boxes), 0.5)
    a = low.exact(Pose(0.0, 0.0, 0.0), setting.v_start, setting.bounds())
    b = high.exact(Pose(0.0, 0.0, 0.0), setting.v_start, setting.bounds())
    for j in (10, 20, 30):
        assert a.tube(j).difference(b.tube(j)).area < 1e-6
    assert a.tube(30).area < a.outer_tube(30).area - 1.0  # the network cuts there ...
    assert b.tube(30).area > a.tube(30).area + 0.1  # ... and the offset moves the cut outwards
