"""reach.road_map on the shipped Argoverse 2 map archive (data/av2/, © Argo AI, LLC, CC BY-NC-SA
4.0, https://creativecommons.org/licenses/by-nc-sa/4.0/): parsing, errors naming the field, the
indexed region and the cut K ∩ R against the same cut computed on the whole map."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import shapely
from shapely import affinity

from reach.frames import Pose
from reach.road_map import MIN_TILE_M, TILE_VERTICES, MapFormatError, RoadMap

DATA = Path(__file__).resolve().parent.parent / "data" / "av2"
SCENARIO = "0a1e6f0a-1817-4a98-b02e-db8c9327d151"
ARCHIVE = DATA / f"log_map_archive_{SCENARIO}.json"


@pytest.fixture(scope="module")
def archive() -> dict:
    return json.loads(ARCHIVE.read_text())


@pytest.fixture(scope="module")
def road(archive: dict) -> RoadMap:
    return RoadMap.from_archive(archive)


def reference_cut(road: RoadMap, k_set: shapely.Geometry, margin: float) -> shapely.Geometry:
    """K ∩ ((D ⊕ margin) ∪ outside the extent), on the whole map at once."""
    grown = road.drivable.buffer(margin, quad_segs=4) if margin > 0 else road.drivable
    outside = shapely.box(-1e6, -1e6, 1e6, 1e6).difference(shapely.box(*road.extent))
    return k_set.intersection(shapely.union(grown, outside))


def test_the_shipped_archive_parses(road: RoadMap) -> None:
    summary = road.summary()
    assert (summary["drivable_areas"], summary["lane_segments"]) == (2, 71)
    assert summary["pedestrian_crossings"] == 6
    assert summary["drivable_area_m2"] == pytest.approx(3815.75, abs=0.01)
    assert summary["extent"] == pytest.approx([-461.86, 1290.0, -360.0, 1500.0], abs=0.01)
    assert road.drivable.is_valid
    lane = next(lane for lane in road.lanes if lane.id == "205119120")
    assert lane.lane_type == "BIKE" and lane.left.shape == (3, 2) and lane.centerline is not None
    assert {lane.lane_type for lane in road.lanes} == {"BIKE", "VEHICLE"}


def test_moving_vehicles_of_the_scenario_are_on_the_drivable_area(road: RoadMap) -> None:
    table = pq.read_table(DATA / f"scenario_{SCENARIO}.parquet").to_pydict()
    x, y = np.array(table["position_x"]), np.array(table["position_y"])
    speed = np.hypot(table["velocity_x"], table["velocity_y"])
    moving = (np.array(table["object_type"]) == "vehicle") & (speed > 1.0)
    assert moving.sum() > 500
    assert road.region(0.0).covers_xy(x[moving], y[moving]).all()
    assert road.on_road(-425.0, 1400.0, 0.0)
    assert not road.on_road(-419.9, 1377.8, 0.0)  # a parked car's spot off the road
    assert road.on_road(0.0, 0.0, 0.0)  # far outside the map: the map says nothing there


def _broken(archive: dict, path: list, value: object) -> dict:
    out = copy.deepcopy(archive)
    target = out
    for key in path[:-1]:
        target = target[key]
    if value is KeyError:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return out


DA = ["drivable_areas", "11055391"]
LANE = ["lane_segments", "205119120"]


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        (["colour"], "red", "colour"),
        (["drivable_areas"], KeyError, "drivable_areas"),
        (["drivable_areas"], [], "drivable_areas"),
        (["drivable_areas"], {}, "drivable_areas"),
        ([*DA], "square", "drivable_areas.11055391"),
        ([*DA, "area_boundary"], KeyError, "drivable_areas.11055391.area_boundary"),
        ([*DA, "area_boundary"], [{"x": 0, "y": 0}] * 2, "drivable_areas.11055391.area_boundary"),
        ([*DA, "area_boundary", 3, "x"], KeyError, "drivable_areas.11055391.area_boundary.3.x"),
        ([*DA, "area_boundary", 3, "x"], "1.0", "drivable_areas.11055391.area_boundary.3.x"),
        ([*DA, "area_boundary", 3, "y"], True, "drivable_areas.11055391.area_boundary.3.y"),
        ([*DA, "area_boundary", 3, "y"], math.nan, "drivable_areas.11055391.area_boundary.3.y"),
        ([*DA, "area_boundary", 3, "y"], 1e8, "drivable_areas.11055391.area_boundary.3.y"),
        ([*DA, "area_boundary", 3, "z"], None, "drivable_areas.11055391.area_boundary.3.z"),
        ([*DA, "area_boundary", 3], [1, 2], "drivable_areas.11055391.area_boundary.3"),
        ([*DA, "id"], 1.5, "drivable_areas.11055391.id"),
        (
            [*DA, "area_boundary"],
            [{"x": 0, "y": 0}, {"x": 1, "y": 1}, {"x": 2, "y": 2}],
            "drivable_areas.11055391.area_boundary",
        ),
        ([*LANE, "lane_type"], KeyError, "lane_segments.205119120.lane_type"),
        ([*LANE, "is_intersection"], "no", "lane_segments.205119120.is_intersection"),
        ([*LANE, "successors"], ["a"], "lane_segments.205119120.successors"),
        ([*LANE, "left_neighbor_id"], "x", "lane_segments.205119120.left_neighbor_id"),
        ([*LANE, "right_lane_boundary"], KeyError, "lane_segments.205119120.right_lane_boundary"),
        ([*LANE, "centerline", 0, "x"], None, "lane_segments.205119120.centerline.0.x"),
        (
            ["pedestrian_crossings", "13294505", "edge2"],
            [{"x": 0, "y": 0}],
            "pedestrian_crossings.13294505.edge2",
        ),
        (["pedestrian_crossings"], [], "pedestrian_crossings"),
    ],
)
def test_a_malformed_archive_is_refused_naming_the_field(
    archive: dict, path: list, value: object, field: str
) -> None:
    with pytest.raises(MapFormatError) as caught:
        RoadMap.from_archive(_broken(archive, path, value))
    assert caught.value.field == field, str(caught.value)
    assert str(caught.value).startswith(f"{field}: ")


def test_bodies_that_are_not_archives_name_the_body(archive: dict) -> None:
    for text in (b"{", b"[]", b"null", b'"map"'):
        with pytest.raises(MapFormatError) as caught:
            RoadMap.from_json(text)
        assert caught.value.field == "body"
    with pytest.raises(MapFormatError) as caught:
        RoadMap.from_archive(archive, max_points=100)
    assert "more than 100 points" in caught.value.message
    optional = {"drivable_areas": archive["drivable_areas"]}
    assert RoadMap.from_archive(optional).summary()["lane_segments"] == 0


def test_the_cut_is_the_cut_on_the_whole_map(road: RoadMap) -> None:
    """K ∩ R read from the tiles near K equals K ∩ R computed on the whole map, for discs and
    rotated boxes all over the map and across its extent's edge."""
    rng = np.random.default_rng(5)
    x0, y0, x1, y1 = road.extent
    for margin in (0.0, 1.0):
        for _ in range(60):
            cx, cy = rng.uniform(x0 - 20, x1 + 20), rng.uniform(y0 - 20, y1 + 20)
            if rng.random() < 0.5:
                k_set = shapely.Point(cx, cy).buffer(rng.uniform(1.0, 60.0))
            else:
                k_set = affinity.rotate(
                    shapely.box(cx - 30, cy - 4, cx + 40, cy + 4), rng.uniform(0, 360)
                )
            cut = road.cut(k_set, margin)
            expected = reference_cut(road, k_set, margin)
            assert cut.symmetric_difference(expected).area < 1e-6
            assert cut.difference(k_set).area < 1e-9


def test_nothing_is_cut_outside_the_extent(road: RoadMap) -> None:
    far = shapely.Point(0.0, 0.0).buffer(30.0)
    assert road.cut(far, 0.0).equals(far)
    straddling = shapely.box(-380.0, 1480.0, -330.0, 1520.0)
    cut = road.cut(straddling, 0.0)
    outside = straddling.difference(shapely.box(*road.extent))
    assert outside.area > 0 and outside.difference(cut).area < 1e-9
    assert cut.area < straddling.area


def test_the_region_in_a_human_frame_is_the_world_region_moved(road: RoadMap) -> None:
    pose = Pose(-430.0, 1390.0, 1.2)
    bounds = (-20.0, -30.0, 80.0, 30.0)
    local = road.region_in_frame(pose, bounds, 1.0)
    rng = np.random.default_rng(2)
    pts = rng.uniform([bounds[0], bounds[1]], [bounds[2], bounds[3]], size=(2000, 2))
    c, s = math.cos(pose.heading), math.sin(pose.heading)
    wx = pose.x + c * pts[:, 0] - s * pts[:, 1]
    wy = pose.y + s * pts[:, 0] + c * pts[:, 1]
    inside = shapely.intersects_xy(local, pts[:, 0], pts[:, 1])
    distance = shapely.distance(road.region(1.0).grown.boundary, shapely.points(wx, wy))
    clear = distance > 1e-6
    assert np.array_equal(inside[clear], road.region(1.0).covers_xy(wx, wy)[clear])


def test_a_large_map_is_split_in_small_tiles() -> None:
    """A city-sized grid of roads: every tile has at most TILE_VERTICES vertices (or is at the
    smallest size), the tiles make up D, and a cut reads only those near K."""
    lines = []
    for i in range(11):
        xs = np.linspace(0.0, 1000.0, 401)
        wiggle = 0.3 * np.sin(xs / 7.0)
        lines += [shapely.LineString(np.c_[xs, 100.0 * i + wiggle]),
                  shapely.LineString(np.c_[100.0 * i + wiggle, xs])]  # fmt: skip
    areas = {
        str(i): {"id": i, "area_boundary": [
            {"x": float(x), "y": float(y)}
            for x, y in line.buffer(5.0, quad_segs=4).exterior.coords[:-1]
        ]}
        for i, line in enumerate(lines)
    }  # fmt: skip
    road = RoadMap.from_archive({"drivable_areas": areas})
    region = road.region(0.0)
    assert len(road.drivable.interiors) == 100 and len(region.tiles) > 50
    tiles = region.tiles[: region.road_tiles]  # then the strips around the extent
    sizes = shapely.get_num_coordinates(tiles)
    widths = np.array([max(t.bounds[2] - t.bounds[0], t.bounds[3] - t.bounds[1]) for t in tiles])
    assert ((sizes <= TILE_VERTICES) | (widths <= 2 * MIN_TILE_M)).all()
    assert shapely.union_all(tiles).symmetric_difference(road.drivable).area < 1e-6
    k_set = shapely.Point(500.0, 500.0).buffer(40.0)
    assert road.cut(k_set, 0.0).symmetric_difference(reference_cut(road, k_set, 0.0)).area < 1e-6
