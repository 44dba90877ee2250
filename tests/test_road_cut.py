"""reach.road_cut.CutSet: exact sets of the shipped model's geometry cut by the road.

Against independent rollouts of the dynamics (``models.rollout``, RK4 under the bounds): every
rollout that keeps to R = (D ⊕ margin) ∪ outside the extent is inside the cut set, tube, slice and
interval alike; every cut set is inside its uncut one; a road reachable only across the off-road
is dropped. Poses from the recorded Argoverse 2 scenario and its map (data/av2/, © Argo AI, LLC,
CC BY-NC-SA 4.0, https://creativecommons.org/licenses/by-nc-sa/4.0/)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

from experiments import av2
from models.rollout import sample_reference_schedules
from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.dynamics import wrap_angle
from reach.engine import FRTEngine
from reach.frames import Pose
from reach.road_cut import DRIVABLE_AREA, CutSet, connected_to
from reach.road_map import RoadMap
from tests.fixtures.trajectories import simulate

MODEL = Path(__file__).resolve().parent.parent / "models" / "frt_unicycle.onnx"
MARGIN = 1.0


@pytest.fixture(scope="module")
def engine() -> FRTEngine:
    return engine_for(ValueModel.load(MODEL, threads=1), network=False)


@pytest.fixture(scope="module")
def road() -> RoadMap:
    return RoadMap.load(av2.DATA_DIR / av2.MAP_FILE)


def wide_bounds(omega: float) -> np.ndarray:
    """u1 within omega ± 0.5 rad/s, u2 within [-4, 2] m/s²: turns into side streets and off-road."""
    return np.array([omega - 0.5, -4.0, omega - 0.5, -4.0, omega + 0.5, 2.0, omega + 0.5, 2.0])


def scenario_settings() -> list[tuple[Pose, float, np.ndarray]]:
    """Three moving cars of the scenario inside the map's extent, at different places."""
    out = []
    for track in av2.load_tracks():
        for i in track.observation_indices()[::4]:
            inside = -455 < track.x[i] < -365 and 1300 < track.y[i] < 1490
            if inside and 3.0 < track.speed[i] < 15.0 and len(out) < 3:
                pose = Pose(
                    float(track.x[i]), float(track.y[i]), float(wrap_angle(track.heading[i]))
                )
                out.append((pose, float(track.speed[i]), wide_bounds(track.action(i)[0])))
                break
    assert len(out) == 3
    return out


def _world(pose: Pose, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(pose.heading), np.sin(pose.heading)
    return pose.x + c * x - s * y, pose.y + s * x + c * y


def _covered(geometry: shapely.Geometry, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return shapely.covers(geometry, shapely.points(np.stack([x, y], axis=1)))


def assert_rollouts_inside(cut: CutSet, trace: list, kept: np.ndarray) -> None:
    """Every rollout of ``trace`` (``simulate``'s, human frame) that ``kept`` marks inside the
    cut tube of its time, the slice of its instant and, between instants, the interval."""
    per_instant = round(cut.slice_dt / float(trace[0][0][0]))
    for k, (tau, state) in enumerate(trace, start=1):
        x, y = state[0][kept], state[1][kept]
        assert _covered(cut.tube(cut.tube_index(float(tau[0]))), x, y).all(), k
        if k % per_instant == 0:
            assert _covered(cut.slice(k // per_instant), x, y).all(), k
        elif k % 5 == 0:
            assert _covered(cut.interval(k // per_instant + 1), x, y).all(), k


def _inside(outer: shapely.Geometry, inner: shapely.Geometry) -> bool:
    return inner.difference(outer).area < 1e-9


@pytest.mark.parametrize("index", range(3))
def test_every_rollout_that_keeps_to_the_road_is_in_the_cut_set(engine, road, index) -> None:
    pose, v_start, bounds = scenario_settings()[index]
    uncut = engine.exact(pose, v_start, bounds)
    cut = CutSet(uncut, road, MARGIN)
    assert cut.assumptions == (DRIVABLE_AREA,)
    _, trace = simulate(v_start, bounds, 3000, np.random.default_rng(index),
                        sample_reference_schedules)  # fmt: skip
    region = road.region(MARGIN)
    on_road = np.ones(len(trace[0][1][0]), dtype=bool)
    for _, state in trace:
        on_road &= region.covers_xy(*_world(pose, state[0], state[1]))
    assert 50 < on_road.sum() < len(on_road)  # some keep to the road, some leave it
    assert_rollouts_inside(cut, trace, on_road)
    last = cut.n_slices - 1
    assert cut.tube(last).area < 0.9 * uncut.tube(last).area  # the road cuts


@pytest.mark.parametrize("index", range(3))
def test_the_uncut_set_contains_the_cut_one(engine, road, index) -> None:
    pose, v_start, bounds = scenario_settings()[index]
    for uncut in (engine.exact(pose, v_start, bounds), engine.conservative(pose, v_start, bounds)):
        cut = CutSet(uncut, road, MARGIN)
        assert cut.conservative == uncut.conservative
        for j in range(cut.n_slices):
            assert _inside(uncut.tube(j), cut.tube(j)), j
            assert _inside(uncut.slice(j), cut.slice(j)), j
            i = max(j, 1)
            assert _inside(uncut.interval(i), cut.interval(i)), j
            assert _inside(cut.tube(j), cut.slice(j)) and _inside(cut.tube(i), cut.interval(i))
        xy = np.array([[pose.x + 5.0, pose.y + 3.0], [pose.x - 30.0, pose.y + 40.0]])
        assert (cut.clearance(xy) >= uncut.clearance(xy) - 1e-9).all()


def _strip_archive(strips: list[tuple[float, float]]) -> dict:
    """Straight roads along x in [-30, 120], one per (y_lo, y_hi) strip."""
    areas = {}
    for i, (lo, hi) in enumerate(strips):
        ring = [(-30.0, lo), (120.0, lo), (120.0, hi), (-30.0, hi)]
        areas[str(i)] = {"id": i, "area_boundary": [{"x": x, "y": y} for x, y in ring]}
    return {"drivable_areas": areas}


def test_a_road_reached_only_across_the_off_road_is_dropped(engine) -> None:
    """Two parallel roads 6 m apart (a verge between them, and a box around the extent so that
    nothing is outside it nearby): the car's set reaches the far road only across the verge."""
    archive = _strip_archive([(-3.0, 3.0), (9.0, 15.0), (-60.0, -59.0), (60.0, 61.0)])
    road = RoadMap.from_archive(archive)
    bounds = wide_bounds(0.0)
    uncut = engine.exact(Pose(0.0, 0.0, 0.0), 10.0, bounds)
    cut = CutSet(uncut, road, 0.0)
    last = cut.n_slices - 1
    far = shapely.box(-30.0, 9.0, 120.0, 15.0)
    assert uncut.tube(last).intersection(far).area > 50.0
    assert road.cut(uncut.tube(last), 0.0).intersection(far).area > 50.0  # plain K ∩ R keeps it
    assert cut.tube(last).intersection(far).area == 0.0  # not reachable on the road
    assert cut.tube(last).difference(shapely.box(-30.0, -3.0, 120.0, 3.0)).area < 1e-9


def test_touching_parts_are_one_component() -> None:
    a, c = shapely.box(0, 0, 1, 1), shapely.box(5, 5, 6, 6)
    parts = shapely.GeometryCollection([a, shapely.LineString([(1, 0.5), (3, 0.5)]), c])
    start = shapely.Point(0.5, 0.5).buffer(0.1)
    assert connected_to(shapely.MultiPolygon([a, c]), start).equals(a)
    kept = connected_to(parts, start)
    assert kept.covers(shapely.Point(2.5, 0.5)) and not kept.intersects(c)
    touching = shapely.MultiPolygon(
        [a, shapely.box(1, 1, 2, 2), c]
    )  # a and its neighbour meet at a point
    assert connected_to(touching, start).area == pytest.approx(2.0)
    assert connected_to(a, shapely.Point(9, 9)).is_empty
