"""Tubes of one exact set built in any order equal the tube built alone on a fresh set: the
outer-polygon unions and unresolved hulls an exact set caches change no answer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

from models.eval_settings import SETTINGS
from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.frames import Pose
from reach.polygons import convex_polygons
from reach.sets import SWEEPS_PER_WINDOW, FRTSet

MODEL = Path(__file__).resolve().parent.parent / "models" / "frt_unicycle.onnx"
pytestmark = pytest.mark.skipif(not MODEL.exists(), reason="no shipped model yet")


@pytest.mark.parametrize("name", ["stationary_wide_limits", "urban_wide", "growing_narrow_to_wide"])
def test_tubes_do_not_depend_on_the_order_they_are_asked_in(name: str) -> None:
    setting = {s.name: s for s in SETTINGS}[name]
    engine = engine_for(ValueModel.load(MODEL))
    pose = Pose(-4.0, 7.0, 2.5)

    def fresh():
        return engine.exact(pose, setting.v_start, setting.bounds())

    order = np.random.default_rng(0).permutation(np.arange(1, engine.n_slices))
    ascending, descending, shuffled = fresh(), fresh(), fresh()
    for j in range(1, engine.n_slices):
        ascending.tube(j)
    for j in range(engine.n_slices - 1, 0, -1):
        descending.tube(j)
    for j in order:
        shuffled.tube(int(j))
    for j in (1, 2, 7, 15, 16, 29):
        alone = fresh()
        alone._tubes.clear()  # the whole tube was built eagerly: ask for tube j on an empty cache
        alone._outer_unions.clear()
        alone._hulls.clear()
        reference = alone.tube(j)
        for built in (ascending, descending, shuffled):
            assert built.tube(j).symmetric_difference(reference).area < 1e-9, (name, j)


def test_the_outer_tube_is_the_union_of_its_windows() -> None:
    setting = {s.name: s for s in SETTINGS}["shrinking_wide_to_narrow"]
    frt = engine_for(ValueModel.load(MODEL)).exact(
        Pose(0.0, 0.0, 0.0), setting.v_start, setting.bounds()
    )
    support = frt.bound.sweep_support
    for j in (30, 3, 12, 11, 29):
        n = frt.bound_rows[j]
        windows = np.stack(
            [
                support[a : min(a + SWEEPS_PER_WINDOW, n)].max(axis=0)
                for a in range(0, n, SWEEPS_PER_WINDOW)
            ]
        )
        direct = shapely.union_all(convex_polygons(frt.bound.directions, windows))
        assert frt.outer_tube(j).symmetric_difference(direct).area < 1e-9


def test_tube_indices_match_tube_index_point_by_point() -> None:
    frt = FRTSet(Pose(0.0, 0.0, 0.0), 0.1, 3.0, 31, conservative=False)
    times = np.concatenate(
        [np.random.default_rng(0).uniform(-1, 4, 5000), np.arange(-5, 40) * 0.1, [0.0, 3.0]]
    )
    expected = [frt.tube_index(float(t)) for t in times]
    assert frt.tube_indices(times).tolist() == expected
