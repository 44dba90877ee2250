"""reach.lanes and reach.road_cut.lane_cut: exact sets cut to the lanes their car can reach.

Against independent rollouts of the dynamics (``models.rollout``, RK4 under the bounds): every
rollout that keeps its position in the region of the reachable lanes (R ∩ L, and L alone) is
inside the cut set, tube, slice and interval alike; the lane cut lies inside the drivable-area cut
and that inside the uncut set; on a made-up road the oncoming lane and a lane the graph does not
reach are dropped, a successor kept. Poses from the recorded Argoverse 2 scenario and its map
(data/av2/, © Argo AI, LLC, CC BY-NC-SA 4.0, https://creativecommons.org/licenses/by-nc-sa/4.0/).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from models.rollout import sample_reference_schedules
from reach import lanes as lanes_module
from reach.frames import Pose
from reach.lanes import DRIVABLE_AREA, REACHABLE_LANES, VEHICLE_LANE_TYPES, direction_at
from reach.road_cut import CutSet, connected_to, lane_cut, padded_extent
from reach.road_map import RoadMap, world_box
from tests.fixtures.trajectories import simulate
from tests.test_road_cut import (
    _inside,
    _world,
    assert_rollouts_inside,
    engine,  # noqa: F401 (a fixture)
    road,  # noqa: F401 (a fixture)
    scenario_settings,
    wide_bounds,
)

MARGIN = 1.0


def _lane_region(road_map: RoadMap, frt, drivable: bool):
    box = world_box(frt.pose, padded_extent(frt))
    return road_map.lane_region(frt.pose, box, MARGIN, drivable=drivable)


@pytest.mark.parametrize(("index", "drivable"), [(0, True), (1, True), (2, True), (0, False)])
def test_every_rollout_that_keeps_to_its_lanes_is_in_the_cut_set(
    engine,  # noqa: F811
    road,  # noqa: F811
    index,
    drivable,
) -> None:
    pose, v_start, bounds = scenario_settings()[index]
    uncut = engine.exact(pose, v_start, bounds)
    cut = lane_cut(uncut, road, MARGIN, drivable=drivable)
    assert cut is not None
    region = _lane_region(road, uncut, drivable)
    assert cut.assumptions == ((DRIVABLE_AREA,) if drivable else ()) + (REACHABLE_LANES,)
    _, trace = simulate(v_start, bounds, 3000, np.random.default_rng(10 + index),
                        sample_reference_schedules)  # fmt: skip
    kept = np.ones(len(trace[0][1][0]), dtype=bool)
    for _, state in trace:
        kept &= region.covers_xy(*_world(pose, state[0], state[1]))
    assert 50 < kept.sum() < len(kept)  # some keep to the lanes, some leave them
    assert_rollouts_inside(cut, trace, kept)


@pytest.mark.parametrize("index", range(3))
def test_the_drivable_cut_contains_the_lane_cut(engine, road, index) -> None:  # noqa: F811
    pose, v_start, bounds = scenario_settings()[index]
    for uncut in (engine.exact(pose, v_start, bounds), engine.conservative(pose, v_start, bounds)):
        drivable = CutSet(uncut, road, MARGIN)
        lanes = lane_cut(uncut, road, MARGIN)
        assert lanes is not None and lanes.conservative == uncut.conservative
        for j in range(lanes.n_slices):
            i = max(j, 1)
            for outer in (uncut, drivable):
                assert _inside(outer.tube(j), lanes.tube(j)), j
                assert _inside(outer.slice(j), lanes.slice(j)), j
                assert _inside(outer.interval(i), lanes.interval(i)), j
        last = lanes.n_slices - 1
        assert lanes.tube(last).area < drivable.tube(last).area  # the lanes cut further


def _lane(lane_id: int, y_right: float, y_left: float, x0: float, x1: float, **links) -> dict:
    """A straight lane between x0 and x1 (driven from x0 to x1), its right boundary at
    ``y_right`` and its left at ``y_left``."""
    return {
        "id": lane_id, "lane_type": links.pop("lane_type", "VEHICLE"), "is_intersection": False,
        "left_lane_boundary": [{"x": x0, "y": y_left}, {"x": x1, "y": y_left}],
        "right_lane_boundary": [{"x": x0, "y": y_right}, {"x": x1, "y": y_right}],
        "successors": links.pop("successors", []), "predecessors": [],
        "left_neighbor_id": links.pop("left", None), "right_neighbor_id": links.pop("right", None),
    }  # fmt: skip


def _road(successor: bool) -> RoadMap:
    """A carriageway along x in [-30, 120] (y in [-6, 6], boxes far off so nothing near is outside
    the extent): eastbound lane 1 (y in [-2, 2], x < 40), its successor 2 beyond x = 40 (linked
    if ``successor``), westbound lane 3 beside it (y in [2, 6], lane 1's left neighbour) and an
    eastbound lane 4 (y in [-6, -2]) that no lane links to."""
    ring = [(-30.0, -6.0), (120.0, -6.0), (120.0, 6.0), (-30.0, 6.0)]
    far = [
        [(-30.0, -60.0), (120.0, -60.0), (120.0, -59.0)],
        [(-30.0, 60.0), (120.0, 61.0), (-30.0, 61.0)],
    ]
    areas = {
        str(i): {"id": i, "area_boundary": [{"x": x, "y": y} for x, y in r]}
        for i, r in enumerate([ring, *far])
    }
    lanes = [
        _lane(1, -2.0, 2.0, -30.0, 40.0, successors=[2, 99] if successor else [99], left=3),
        _lane(2, -2.0, 2.0, 40.0, 120.0),
        _lane(3, 6.0, 2.0, 120.0, -30.0, left=1),
        _lane(4, -6.0, -2.0, -30.0, 120.0),
    ]
    return RoadMap.from_archive({
        "drivable_areas": areas, "lane_segments": {str(lane["id"]): lane for lane in lanes}
    })  # fmt: skip


@pytest.mark.parametrize("successor", [True, False])
def test_oncoming_and_unlinked_lanes_are_dropped_successors_kept(engine, successor) -> None:  # noqa: F811
    road_map = _road(successor)
    uncut = engine.exact(Pose(0.0, 0.0, 0.0), 12.0, wide_bounds(0.0))
    drivable = CutSet(uncut, road_map, 0.0)
    cut = lane_cut(uncut, road_map, 0.0)
    assert cut is not None
    last = cut.n_slices - 1
    own = shapely.box(-30.0, -2.0, 120.0 if successor else 40.0, 2.0)
    for other in (shapely.box(-30.0, 2.0, 120.0, 6.0), shapely.box(-30.0, -6.0, 120.0, -2.0)):
        assert drivable.tube(last).intersection(other).area > 20.0  # the road alone keeps it
    assert cut.tube(last).difference(own).area < 1e-9
    beyond = cut.tube(last).intersection(shapely.box(40.0, -2.0, 120.0, 2.0)).area
    assert (beyond > 1.0) == successor
    assert set(road_map.lane_region(uncut.pose, world_box(uncut.pose, padded_extent(uncut)),
                                    0.0).lanes) == ({"1", "2"} if successor else {"1"})  # fmt: skip


@pytest.mark.parametrize(
    ("x", "y", "heading_deg", "applies"),
    [(0.0, 0.0, 0.0, True), (0.0, 0.0, 20.0, True), (0.0, 0.0, -25.0, True),
     (0.0, 0.0, 45.0, False), (0.0, 0.0, 180.0, False), (0.0, 4.0, 180.0, True),
     (0.0, 4.0, 0.0, False), (-40.0, 0.0, 0.0, False)],
)  # fmt: skip
def test_the_assumption_applies_to_a_car_in_a_lane_heading_its_way(
    engine,  # noqa: F811
    x,
    y,
    heading_deg,
    applies,
) -> None:
    """Within 30° of a lane holding it; against its lane, across it, or off every lane: not."""
    road_map = _road(True)
    uncut = engine.exact(Pose(x, y, math.radians(heading_deg)), 5.0, wide_bounds(0.0))
    assert (lane_cut(uncut, road_map, 0.0) is not None) == applies


def test_the_lane_graph_follows_successors_and_same_direction_neighbours() -> None:
    graph = _road(True).lane_graph
    follows = {graph.ids[i]: {graph.ids[j] for j in nexts} for i, nexts in enumerate(graph.follow)}
    assert follows == {"1": {"2"}, "2": set(), "3": set(), "4": set()}  # 3 is oncoming, 99 unknown
    lane = _road(True).lanes[0]
    assert (lane.left_neighbor, lane.right_neighbor, lane.successors) == (3, None, (2, 99))


def test_the_indexed_start_search_is_the_definition(road) -> None:  # noqa: F811
    """The lane graph's start lanes (centre-line segments kept per lane) and the one-point region
    tests are their definitions evaluated directly: the lanes of the types whose grown area holds
    the point and whose ``direction_at`` is within the tolerance; ``covers_xy`` of one point."""
    graph = road.lane_graph
    index = graph.index(MARGIN, road.region(MARGIN))
    x0, y0, x1, y1 = road.extent
    rng = np.random.default_rng(3)
    starts = 0
    poses = rng.uniform((x0 - 10, y0 - 10, -math.pi), (x1 + 10, y1 + 10, math.pi), (2000, 3))
    for x, y, heading in poses.tolist():
        holding = np.flatnonzero(shapely.intersects_xy(index.grown, x, y))
        expected = [
            int(i)
            for i in holding
            if graph.types[i] in VEHICLE_LANE_TYPES
            and abs((direction_at(graph.lines[i], x, y) - heading + math.pi) % math.tau - math.pi)
            <= math.radians(30.0)
        ]
        found = graph.start(index, (x, y), heading, VEHICLE_LANE_TYPES, math.radians(30.0))
        assert found == expected, (x, y, heading)
        for i in holding:
            assert graph.segments.direction(int(i), x, y) == direction_at(graph.lines[i], x, y)
        assert road.on_road(x, y, MARGIN) == road.region(MARGIN).covers_xy([x], [y])[0]
        box = (x - 40.0, y - 40.0, x + 40.0, y + 40.0)
        region = road.lane_region(Pose(x, y, heading), box, MARGIN)
        if region is not None:
            starts += 1
            assert region.covers(x, y) == region.covers_xy([x], [y])[0]
    assert starts > 20  # enough poses in a lane of their heading


def test_lanes_near_a_point_or_box_are_found_alike_by_scan_and_tree(road, monkeypatch) -> None:  # noqa: F811
    """Past ``SCAN_LANES`` the STRtree finds the lanes holding a point and those whose box meets
    a box; below it one pass over their boxes does: the same lanes."""
    index = road.lane_graph.index(MARGIN, road.region(MARGIN))
    x0, y0, x1, y1 = road.extent
    points = np.random.default_rng(4).uniform((x0, y0), (x1, y1), (3000, 2)).tolist()
    boxes = [(x - 20.0, y - 30.0, x + 40.0, y + 10.0) for x, y in points[:300]]
    scanned = [index.holding(x, y).tolist() for x, y in points]
    met = [index.meeting(box).tolist() for box in boxes]
    monkeypatch.setattr(lanes_module, "SCAN_LANES", 0)
    assert [index.holding(x, y).tolist() for x, y in points] == scanned
    assert [index.meeting(box).tolist() for box in boxes] == met
    assert sum(map(bool, scanned)) > 300 and sum(map(bool, met)) > 100


def test_one_polygon_is_one_component() -> None:
    """A polygon is kept whole where it meets the start and dropped where it does not."""
    polygon = shapely.Polygon([(0, 0), (4, 0), (4, 1), (1, 1), (1, 3), (0, 3)])
    assert connected_to(polygon, shapely.box(3.5, 0.5, 5.0, 2.0)) is polygon
    assert connected_to(polygon, shapely.Point(0.5, 2.5)) is polygon
    assert connected_to(polygon, shapely.box(2.0, 2.0, 3.0, 3.0)).is_empty
