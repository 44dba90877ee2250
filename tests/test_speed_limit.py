"""The ``speed_limit`` assumption: lane speed limits read from Lanelet2 maps
(``reach.lanelet2_map``), v_cap from the lanes a car reaches (``reach.lanes``), and sets cut to the
discs of radius r₀ + L(t) (``reach.speed_limit``, ``reach.road_cut``).

Against independent rollouts of the dynamics (``models.rollout``, RK4 under the bounds): every
rollout whose speed stays at most v_cap (and, with the lanes, whose position keeps to R ∩ L) is
inside the cut set, tube, slice and interval alike; every cut set is inside its uncut one; a car
faster than v_cap is not cut. Made-up maps only: Argoverse 2 archives carry no limits.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import shapely
from fastapi.testclient import TestClient
from shapely.geometry import shape

from models.rollout import sample_reference_schedules
from reach.contract import INITIAL_SET
from reach.frames import Pose, covers_box
from reach.lanelet2_map import road_map_from_osm
from reach.road_cut import (
    CutSet,
    assumption_cut,
    observation_box,
    padded_extent,
    speed_discs,
)
from reach.road_map import MapFormatError, RoadMap, world_box
from reach.speed_limit import SPEED_LIMIT, reach_radii
from service.api.app import create_app
from tests.fixtures.trajectories import simulate
from tests.test_agent_maps import observe
from tests.test_lanelet2_map import OsmWriter, error_of, lanelet_map, put_osm
from tests.test_lanes import _road
from tests.test_maps_api import RAW, WIDE, put, settings_for, wait_ready
from tests.test_road_cut import (
    _inside,
    _world,
    assert_rollouts_inside,
    engine,  # noqa: F401 (a fixture)
)

KMH = 1.0 / 3.6
ALL = ("drivable_area", "reachable_lanes", SPEED_LIMIT)
#: u1 within ±0.3 rad/s, u2 within [-4, 4] m/s²: a car that may speed up well past its limit.
BOUNDS = np.array([-0.3, -4.0, -0.3, -4.0, 0.3, 4.0, 0.3, 4.0])


def _limit_of(tags: str = "", rules: str = "", members: str = "") -> float | None:
    """The speed limit of lanelet 1 (bounds y=4 and y=0 along x), tagged with ``tags``,
    referencing ``members`` (regulatory elements ``rules``)."""
    raw = lanelet_map([[10, 11]], [[0, 1]], tags).decode()
    raw = raw.replace('<tag k="type" v="lanelet"/>', members + '<tag k="type" v="lanelet"/>')
    road = road_map_from_osm(raw.replace("</osm>", rules + "</osm>").encode())
    return road.lanes[0].speed_limit


def _rule(key: int, tags: str, members: str = "") -> str:
    return (f'<relation id="{key}">{members}<tag k="type" v="regulatory_element"/>'
            f'<tag k="subtype" v="speed_limit"/>{tags}</relation>')  # fmt: skip


def _refers(key: int) -> str:
    return f'<member type="relation" ref="{key}" role="regulatory_element"/>'


@pytest.mark.parametrize(
    ("value", "expected"),
    [("50", 50 * KMH), ("50 km/h", 50 * KMH), ("50kmh", 50 * KMH), ("30 mph", 30 * 0.44704),
     ("13.9 m/s", 13.9), ("20 mps", 20.0), ("de274-60", 60 * KMH)],
)  # fmt: skip
def test_a_lanelet_speed_limit_tag_is_read_in_its_unit(value: str, expected: float) -> None:
    assert _limit_of(f'<tag k="speed_limit" v="{value}"/>') == pytest.approx(expected)


def test_regulatory_elements_come_before_the_tag_and_the_highest_is_taken() -> None:
    assert _limit_of() is None
    tag = '<tag k="speed_limit" v="50"/>'
    assert _limit_of(tag + '<tag k="speed_limit_mandatory" v="no"/>') is None
    assert _limit_of(tag + '<tag k="speed_limit:vehicle" v="80"/>') == pytest.approx(80 * KMH)
    sign = _rule(50, '<tag k="sign_type" v="60 km/h"/>')
    assert _limit_of(tag, sign, _refers(50)) == pytest.approx(60 * KMH)
    # A rule's sign (a way it refers to) gives its value by its subtype, before sign_type.
    signed = _rule(51, '<tag k="sign_type" v="20"/>', '<member type="way" ref="1" role="refers"/>')
    way = '<way id="1"><nd ref="0"/><nd ref="1"/><tag k="subtype" v="de274-70"/></way>'
    raw = lanelet_map([[10, 11]], [[0, 1]]).decode().replace('<way id="1">', '<way id="91">')
    raw = raw.replace('ref="1" role="left"', 'ref="91" role="left"')
    raw = raw.replace(
        '<tag k="type" v="lanelet"/>', _refers(51) + _refers(50) + '<tag k="type" v="lanelet"/>'
    )
    road = road_map_from_osm(raw.replace("</osm>", way + signed + sign + "</osm>").encode())
    assert road.lanes[0].speed_limit == pytest.approx(70 * KMH)  # max(70, 60)
    two_way = lanelet_map([[10, 11]], [[0, 1]], tag + '<tag k="one_way" v="no"/>')
    assert [lane.speed_limit for lane in road_map_from_osm(two_way).lanes] == [50 * KMH] * 2


@pytest.mark.parametrize(
    ("tags", "rules", "members", "error"),
    [('<tag k="speed_limit" v="fast"/>', "", "", r"relation\.1\.tag\.speed_limit: must be a speed"),
     ('<tag k="speed_limit" v="0"/>', "", "", r"relation\.1\.tag\.speed_limit: must be above 0"),
     ('<tag k="speed_limit" v="50 knots"/>', "", "", r"relation\.1\.tag\.speed_limit: must be"),
     ("", _rule(50, '<tag k="sign_type" v="fifty"/>'), _refers(50), r"relation\.50\.tag\.sign_type"),
     ("", _rule(50, ""), _refers(50), r"^relation\.50: a speed limit needs"),
     ("", "", _refers(77), r"relation\.1\.member\.regulatory_element: relation 77 not found")],
)  # fmt: skip
def test_a_malformed_limit_is_refused_naming_the_element(tags, rules, members, error) -> None:
    with pytest.raises(MapFormatError, match=error):
        _limit_of(tags, rules, members)


def limited(limits: dict[str, float | None]) -> RoadMap:
    """``tests.test_lanes._road(True)`` (eastbound lane 1, its successor 2 beyond x = 40, the
    oncoming lane 3, the unlinked lane 4) with these limits (m/s) per lane id."""
    road = _road(True)
    lanes = [dataclasses.replace(lane, speed_limit=limits.get(lane.id)) for lane in road.lanes]
    return RoadMap([road.drivable], lanes, [])


def test_v_cap_is_the_highest_limit_of_the_lanes_reached() -> None:
    pose, box = Pose(0.0, 0.0, 0.0), (-10.0, -10.0, 50.0, 10.0)
    road = limited({"1": 10.0, "2": 14.0, "3": 30.0, "4": None})
    assert road.speed_cap(pose, box, 0.0, 1.2) == pytest.approx(1.2 * 14.0)  # not 3's or 4's
    assert road.speed_cap(pose, (-10.0, -10.0, 30.0, 10.0), 0.0, 1.2) == pytest.approx(12.0)
    assert limited({"1": 10.0}).speed_cap(pose, box, 0.0, 1.2) is None  # lane 2 has none
    assert road.speed_cap(pose, (-10.0, -10.0, 130.0, 10.0), 0.0, 1.2) is None  # past the extent
    assert road.speed_cap(Pose(0.0, 0.0, math.pi), box, 0.0, 1.2) is None  # against its lane


def test_the_radius_is_the_capped_speed_integrated() -> None:
    """a_hi = 0: ρ = r₀ + min(v_start + e_v, v_cap)·t; a_hi = 2 from 8 m/s under a cap of 12: the
    cap is reached at (12 - 8.25)/2 s."""
    r0, e_v = INITIAL_SET.radius_m, INITIAL_SET.speed_margin_mps
    t = np.arange(31) * 0.1
    flat = np.array([0, -1, 0, -1, 0, 0, 0, 0.0])
    # Rounded outward by at most 1e-9 relative and 1e-6 m.
    assert reach_radii(8.0, flat, 12.0, 0.1, 31, 3.0) == pytest.approx(r0 + (8 + e_v) * t, abs=1e-5)
    assert reach_radii(8.0, flat, 5.0, 0.1, 31, 3.0) == pytest.approx(r0 + 5.0 * t, abs=1e-5)
    ramp = np.array([0, -1, 0, -1, 0, 2, 0, 2.0])
    reached = (12.0 - 8.0 - e_v) / 2.0
    expected = np.where(t < reached, (8 + e_v) * t + t * t, 12.0 * t - reached * reached)
    # The grid's step takes each step's larger acceleration: at most 2 m/s² × h more speed.
    assert np.all(reach_radii(8.0, ramp, 12.0, 0.1, 31, 3.0) >= r0 + expected)
    assert reach_radii(8.0, ramp, 12.0, 0.1, 31, 3.0) == pytest.approx(r0 + expected, abs=0.02)
    two = np.stack([flat, ramp])
    assert np.array_equal(reach_radii(8.0, two, 12.0, 0.1, 31, 3.0),
                          reach_radii(8.0, ramp, 12.0, 0.1, 31, 3.0))  # fmt: skip


@pytest.mark.parametrize("assumptions", [(SPEED_LIMIT,), ALL])
def test_every_rollout_below_v_cap_is_in_the_cut_set(engine, assumptions) -> None:  # noqa: F811
    road = limited({"1": 10.0, "2": 10.0})
    pose, v_start = Pose(0.0, 0.0, 0.0), 8.0
    uncut = engine.exact(pose, v_start, BOUNDS)
    cut = assumption_cut(uncut, road, 1.0, assumptions, (v_start, BOUNDS))
    assert cut is not None and cut.assumptions == assumptions and cut.discs is not None
    assert cut.discs.v_cap == pytest.approx(12.0)
    _, trace = simulate(v_start, BOUNDS, 3000, np.random.default_rng(7), sample_reference_schedules)
    dt = float(trace[1][0][0] - trace[0][0][0])
    kept = np.ones(len(trace[0][1][0]), dtype=bool)
    for _, state in trace:  # below v_cap at every step, so between steps too (|u2| <= 4)
        kept &= state[3] <= cut.discs.v_cap - 4.0 * dt
        if len(assumptions) > 1:
            kept &= cut.source.covers_xy(*_world(pose, state[0], state[1]))
    assert 50 < kept.sum() < len(kept)  # some keep below the cap, some do not
    assert_rollouts_inside(cut, trace, kept)
    last = cut.n_slices - 1
    assert cut.tube(last).area < 0.9 * uncut.tube(last).area  # the cap cuts the front off


def test_the_cut_lies_inside_the_uncut_set_and_a_faster_car_is_not_cut(engine) -> None:  # noqa: F811
    road = limited({"1": 10.0, "2": 10.0})
    pose = Pose(0.0, 0.0, 0.0)
    for uncut in (engine.exact(pose, 8.0, BOUNDS), engine.conservative(pose, 8.0, BOUNDS)):
        for assumptions in ((SPEED_LIMIT,), ALL):
            cut = assumption_cut(uncut, road, 1.0, assumptions, (8.0, BOUNDS))
            assert cut is not None and cut.conservative == uncut.conservative
            outers = [uncut]  # and the set cut by the other assumptions alone
            outers += [assumption_cut(uncut, road, 1.0, ALL[:2])] if len(assumptions) > 1 else []
            for j in range(cut.n_slices):
                i = max(j, 1)
                for outer in outers:
                    assert _inside(outer.tube(j), cut.tube(j)), j
                    assert _inside(outer.slice(j), cut.slice(j)), j
                    assert _inside(outer.interval(i), cut.interval(i)), j
    fast = engine.exact(pose, 12.5, BOUNDS)  # above v_cap = 12 at the observation
    assert speed_discs(fast, road, 1.0, (12.5, BOUNDS)) is None
    assert assumption_cut(fast, road, 1.0, (SPEED_LIMIT,), (12.5, BOUNDS)) is None
    assert assumption_cut(fast, road, 1.0, ALL, (12.5, BOUNDS)).assumptions == ALL[:2]
    unlimited = limited({"1": 10.0})  # lane 2, reached, has no limit
    assert speed_discs(engine.exact(pose, 8.0, BOUNDS), unlimited, 1.0, (8.0, BOUNDS)) is None
    box = world_box(pose, padded_extent(fast))
    assert road.speed_cap(pose, box, 1.0, 1.2) == pytest.approx(12.0)
    assert isinstance(CutSet(fast, None).tube(3), type(fast.tube(3)))  # no region, no discs


def test_the_observation_box_holds_every_set_box(engine) -> None:  # noqa: F811
    """The box an observation's speed test reads the lanes over holds the box each set's v_cap
    is read over, whatever the bounds within the hard limits: random ones and the fastest (so
    its v_cap is at least the set's, and a car it finds too fast is too fast for the set)."""
    rng = np.random.default_rng(1)
    fastest = np.array([0.0, 10.0, 0.0, 10.0, 0.0, 10.0, 0.0, 10.0])
    for k in range(200):
        v = 20.0 if k == 0 else float(rng.uniform(0.0, 20.0))
        ends = np.sort(rng.uniform(-1.0, 1.0, (2, 4)), axis=0) * [2.0, 10.0, 2.0, 10.0]
        bounds = fastest if k == 0 else ends.reshape(-1)
        pose = Pose(*rng.uniform(-50.0, 50.0, 2), float(rng.uniform(-math.pi, math.pi)))
        for frt in [engine.conservative(pose, v, bounds)] + (
            [engine.exact(pose, v, bounds)] if k < 3 else []
        ):
            outer = observation_box(pose, v, frt.horizon_s)
            assert covers_box(outer, world_box(pose, padded_extent(frt))), (v, bounds)


def limits_osm(speed_limit: str = "36") -> bytes:
    """A Lanelet2 map: an eastbound lanelet along y in [-2, 2] from x = -30 to 40 and its
    successor on to 120, both tagged ``speed_limit`` (km/h), and two far road areas (y = -100,
    y = 100, x from -130 to 220) so the extent holds the box of every set of a car near the
    origin (the observation's test reads the lanes over one, ``reach.road_cut.observation_box``)."""
    writer = OsmWriter()
    tags = {"type": "lanelet", "subtype": "road", "speed_limit": speed_limit}
    for key, (x0, x1) in enumerate([(-30.0, 40.0), (40.0, 120.0)], start=1):
        left = writer.way([{"x": x0, "y": 2.0}, {"x": x1, "y": 2.0}])
        right = writer.way([{"x": x0, "y": -2.0}, {"x": x1, "y": -2.0}])
        writer.relation(key, [(left, "left"), (right, "right")], tags)
    for key, y in ((10, -100.0), (11, 100.0)):
        ring = [{"x": -130.0, "y": y}, {"x": 220.0, "y": y}, {"x": 220.0, "y": y + 1.0}]
        outer = writer.way(ring, closed=True)
        writer.relation(key, [(outer, "outer")], {"type": "multipolygon", "subtype": "road"})
    return writer.xml()


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    app = create_app(settings_for(analytic_model_path))
    with TestClient(app, raise_server_exceptions=False) as test_client:
        wait_ready(test_client)
        answer = put_osm(test_client, "limits", limits_osm())
        assert answer.status_code == 200 and answer.json()["speed_limited_lanes"] == 2
        yield test_client


def _reach(client: TestClient, agent_id: str) -> tuple[float, list[str]]:
    """How far the agent's whole-horizon K reaches from its position (the origin), and the
    assumptions of the contours."""
    answer = client.get(f"/v1/agents/{agent_id}/frt?slices=1.0").json()
    k = shape(answer["tube"]["K"])
    return float(shapely.hausdorff_distance(k, shapely.Point(0.0, 0.0))), answer["assumptions"]


def _violations(client: TestClient) -> float:
    prefix = 'frt_assumption_violations_total{agent_class="car",assumption="speed_limit"} '
    lines = [ln for ln in client.get("/metrics").text.splitlines() if ln.startswith(prefix)]
    return float(lines[0].split()[-1]) if lines else 0.0


def test_a_car_below_v_cap_is_answered_under_speed_limit(client: TestClient) -> None:
    """v_cap = 1.2 × 36 km/h = 12 m/s: from 10 m/s K reaches at most r₀ + 12·3 m; the same car
    under the road's assumptions alone reaches farther."""
    state = {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 10.0}
    observe(client, "capped", 0.0, state, map_id="limits")
    observe(client, "uncapped", 0.0, state, map_id="limits", config={"assumptions": list(ALL[:2])})
    assert client.get("/v1/agents/capped").json()["assumptions"] == list(ALL)
    capped, labels = _reach(client, "capped")
    uncapped, other = _reach(client, "uncapped")
    assert labels == list(ALL) and other == list(ALL[:2])
    assert capped <= INITIAL_SET.radius_m + 12.0 * 3.0 + 0.01 < uncapped
    answer = client.post("/v1/frt", json={"state": state, "control_bounds": WIDE,
                                          "map_id": "limits"}).json()  # fmt: skip
    assert answer["assumptions"] == list(ALL)


def test_a_car_faster_than_v_cap_loses_the_assumption_for_the_relax_time(client) -> None:
    before = _violations(client)
    fast = {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 13.0}
    observe(client, "speeder", 10.0, fast, map_id="limits")
    agent = client.get("/v1/agents/speeder").json()
    assert agent["assumptions"] == list(ALL[:2])
    assert agent["relaxed_assumptions"] == [{"assumption": SPEED_LIMIT, "until": 15.0}]
    assert _violations(client) == before + 1
    assert _reach(client, "speeder")[1] == list(ALL[:2])
    observe(client, "speeder", 15.0, {**fast, "speed": 10.0})
    agent = client.get("/v1/agents/speeder").json()
    assert agent["assumptions"] == list(ALL) and agent["relaxed_assumptions"] == []


def test_a_malformed_limit_over_the_api_is_a_422_naming_it(client: TestClient) -> None:
    field, msg = error_of(put_osm(client, "bad", limits_osm("fast")))
    assert field == "relation.1.tag.speed_limit" and msg.startswith("must be a speed")
    assert client.get("/v1/maps/bad").status_code == 404
    assert put(client, "archive", RAW).json()["speed_limited_lanes"] == 0  # archives give none
