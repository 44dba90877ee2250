"""Intervals whose dilated instants hold their outer polygon are that polygon (``outer_held``).

The reference is the contour construction every set had without the shortcut: the same fields,
contoured, grown by the corner chords and cut to the outer polygons. Where an interval is held,
the shortcut's K must contain the contour's (never less safe) and differ from it by at most what
the contour's chords cut off across the polygons' corners; tubes must stay nested.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest

from models.eval_settings import SETTINGS
from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.field_tube import FieldTubeSet
from reach.frames import Pose

MODEL = Path(__file__).resolve().parent.parent / "models" / "frt_unicycle.onnx"
pytestmark = pytest.mark.skipif(not MODEL.exists(), reason="no shipped model yet")

NAMES = ["urban_narrow", "fast_medium_asym", "left_turn", "braking_to_stop", "urban_wide"]


def contoured(frt: FieldTubeSet) -> FieldTubeSet:
    """The same set with every instant and interval contoured (no polygon taken whole)."""
    return FieldTubeSet(
        frt.pose,
        frt.slice_dt,
        frt.horizon_s,
        frt.lattice,
        frt.instant,
        frt.sweep,
        frt.bound,
        frt.bound_rows,
        frt.outer,
        coarse=frt.coarse,
        notch=frt.notch,
        notch_possible=frt.notch_possible,
    )


@pytest.fixture(scope="module", params=[False, True], ids=["network_off", "network_on"])
def engine(request: pytest.FixtureRequest):
    return engine_for(ValueModel.load(MODEL), network=request.param)


@pytest.mark.parametrize("name", NAMES)
def test_held_sets_hold_the_contoured_ones_and_stay_close(engine, name: str) -> None:
    setting = {s.name: s for s in SETTINGS}[name]
    frt = engine.exact(Pose(3.0, -2.0, 0.7), setting.v_start, setting.bounds())
    reference = contoured(frt)
    step = frt.lattice.step
    for j in range(frt.n_slices):
        for kind in ("tube", "interval", "slice"):
            fast, slow = getattr(frt, kind)(j), getattr(reference, kind)(j)
            assert fast.buffer(1e-6).contains(slow), (name, kind, j)
            if not slow.is_empty:
                # The chords across a corner that turns by up to 90 degrees cut at most a cell
                # diagonal: the polygon taken whole adds no more than that.
                assert fast.hausdorff_distance(slow) <= np.sqrt(2.0) * step + 1e-6, (name, kind, j)
    # (Tube 0, the initial disc grown by the chords and cut to its box, is outside the later
    # tubes' first window polygon by up to that growth, with or without the shortcut.)
    for j in range(2, frt.n_slices):
        assert frt.tube(j).buffer(1e-6).contains(frt.tube(j - 1)), (name, j)
    for j in range(1, frt.n_slices):
        assert frt.tube(j).buffer(1e-6).contains(frt.interval(j)), (name, j)


def test_a_car_driving_straight_takes_the_polygons_whole() -> None:
    """Without the network, the dilated instants hold every interval's polygon past the
    unresolved start: the tubes are the outer tubes, drawn without a contour."""
    engine = engine_for(ValueModel.load(MODEL), network=False)
    setting = {s.name: s for s in SETTINGS}["urban_narrow"]
    frt = engine.exact(Pose(0.0, 0.0, 0.0), setting.v_start, setting.bounds())
    assert frt.instants_uncut
    assert frt.outer_held[3:].all()
    for j in (5, 12, 29):
        assert frt.tube(j).symmetric_difference(frt.outer_tube(j)).area < 1e-9


@pytest.mark.parametrize("name", ["urban_narrow", "u_turn_like", "urban_wide"])
def test_a_set_sent_to_the_server_draws_what_it_did_before_from_the_fields_it_keeps(
    engine, name: str
) -> None:
    """A set crosses from a worker by pickle with only the fields something may still be drawn
    from: every slice, interval and tube drawn after the crossing is the one drawn before it."""
    setting = {s.name: s for s in SETTINGS}[name]
    frt = engine.exact(Pose(1.0, 2.0, -0.4), setting.v_start, setting.bounds(), tubes_upto=12)
    received = pickle.loads(pickle.dumps(frt, protocol=4))
    reference = engine.exact(Pose(1.0, 2.0, -0.4), setting.v_start, setting.bounds())
    for j in range(frt.n_slices):
        for kind in ("tube", "interval", "slice"):
            got, want = getattr(received, kind)(j), getattr(reference, kind)(j)
            assert got.symmetric_difference(want).area < 1e-9, (name, kind, j)
    kept = sum(v is not None for v in (*received.instant.values, *received.sweep.values))
    if received.instants_uncut and received.outer_held[2:].all():
        assert kept <= 2  # at most the initial instant's and its interval's
