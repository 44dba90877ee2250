"""The audit's misses per map assumption (docs/maps.md, "What the audit counts"), on the shipped
Argoverse 2 map archive (data/av2/, © Argo AI, LLC, CC BY-NC-SA 4.0,
https://creativecommons.org/licenses/by-nc-sa/4.0/).

A car whose later position is inside the uncut K of an earlier version but off the drivable area
has that miss counted for ``drivable_area`` (and ``reachable_lanes``: no lane is there); one on the
drivable area but off every vehicle lane for ``reachable_lanes`` alone; a car that keeps to its
lane has none; a car without a map has none. The regions are checked against the archive read
with shapely here; ``VersionRoad`` reads the same regions whether a check cut the set or not.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import shapely
from fastapi.testclient import TestClient
from frt_client.models import Agent
from shapely.geometry import Point, Polygon

from reach.road_cut import lane_cut
from service.runtime.maps import MapRegistry, VersionRoad
from tests.test_agent_maps import (
    BOTH,
    EXTENT,
    MARGIN,
    R,
    observe,
    shipped_engine,  # noqa: F401 (a fixture)
)
from tests.test_maps_api import ON_ROAD, RAW, client_with_map
from tests.test_road_cut import scenario_settings


def _vehicle_lanes() -> shapely.Geometry:
    """Every vehicle lane of the archive grown by the margin, read here and not by the service."""
    lanes = []
    for lane in json.loads(RAW)["lane_segments"].values():
        if lane["lane_type"] in ("VEHICLE", "BUS"):
            left = [(p["x"], p["y"]) for p in lane["left_lane_boundary"]]
            right = [(p["x"], p["y"]) for p in lane["right_lane_boundary"]]
            lanes.append(shapely.make_valid(Polygon(left + right[::-1])).buffer(MARGIN))
    return shapely.union_all(lanes)


LANES = _vehicle_lanes()


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    yield from client_with_map(analytic_model_path)


def _inside(k: shapely.Geometry, region: shapely.Geometry) -> Point:
    """A point well inside ``k`` and the map's extent, and inside ``region``."""
    found = k.buffer(-0.5).intersection(EXTENT.buffer(-1.0)).intersection(region)
    assert found.area > 0.5
    return found.representative_point()


def _audit(client: TestClient, agent_id: str) -> dict:
    agent = client.get(f"/v1/agents/{agent_id}").json()
    Agent.model_validate(agent)  # the SDK reads it
    return agent["audit"]


def _misses(client: TestClient) -> dict[str, float]:
    prefix = 'frt_assumption_misses_total{agent_class="car",assumption="'
    lines = [ln for ln in client.get("/metrics").text.splitlines() if ln.startswith(prefix)]
    return {ln[len(prefix) :].split('"')[0]: float(ln.split()[-1]) for ln in lines}


def _later(client: TestClient, agent_id: str, point: Point, **extra: object) -> dict:
    """Observe the agent 3 s on (its first version's whole horizon) at ``point``; its audit."""
    observe(client, agent_id, 3.0, {**ON_ROAD, "x": point.x, "y": point.y}, **extra)
    return _audit(client, agent_id)


def test_a_position_off_the_road_is_a_miss_of_both_assumptions(client) -> None:
    observe(client, "leaves-road", 0.0, ON_ROAD, map_id="austin")
    k_uncut = _uncut(client, "leaves-road")
    before = _misses(client)
    point = _inside(k_uncut, EXTENT.difference(R.buffer(1.0)))  # off R by the archive itself
    audit = _later(client, "leaves-road", point)
    assert audit["audited"] >= 1 and audit["missed_k"] == 0  # inside the uncut set
    assert audit["assumption_misses"] == {"drivable_area": 1, "reachable_lanes": 1}
    after = _misses(client)
    for name in BOTH:
        assert after[name] == before.get(name, 0.0) + 1


def test_a_position_on_the_road_off_every_lane_is_a_miss_of_the_lanes(client) -> None:
    observe(client, "leaves-lanes", 0.0, ON_ROAD, map_id="austin")
    k_uncut = _uncut(client, "leaves-lanes")
    point = _inside(k_uncut, R.buffer(-0.5).difference(LANES.buffer(0.5)))
    audit = _later(client, "leaves-lanes", point)
    assert audit["assumption_misses"] == {"reachable_lanes": 1}


def test_a_car_keeping_to_its_lane_has_no_misses(client) -> None:
    observe(client, "keeps-lane", 0.0, ON_ROAD, map_id="austin")
    k_uncut = _uncut(client, "keeps-lane")
    own = [
        lane for lane in shapely.get_parts(LANES) if lane.covers(Point(ON_ROAD["x"], ON_ROAD["y"]))
    ]
    point = _inside(k_uncut, own[0].buffer(-1.5))
    audit = _later(client, "keeps-lane", point)
    assert audit["audited"] >= 1 and audit["assumption_misses"] == {}


def test_a_car_without_a_map_has_no_misses_per_assumption(client) -> None:
    observe(client, "no-map", 0.0, ON_ROAD)
    k_uncut = _uncut(client, "no-map")
    point = _inside(k_uncut, EXTENT.difference(R.buffer(1.0)))
    audit = _later(client, "no-map", point)
    assert audit["audited"] >= 1 and audit["assumption_misses"] == {}


def _uncut(client: TestClient, agent_id: str) -> shapely.Geometry:
    """The agent's whole-horizon K before any cut (``include_uncut``, else its own K)."""
    answer = client.get(f"/v1/agents/{agent_id}/frt?include_uncut=true").json()
    tube = (answer.get("uncut") or answer)["tube"]
    return shapely.geometry.shape(tube["K"])


@pytest.mark.parametrize("index", range(3))
def test_the_regions_read_are_those_of_the_cut(shipped_engine, index) -> None:  # noqa: F811
    """Before a check cut the set (read as the cut reads them, lane by lane) and after (its cut's
    own region): a point is off some assumption's region exactly where the cut's region (the
    union of its lanes cut to R) does not hold it, and off ``drivable_area``'s where it is off
    R."""
    registry = MapRegistry(2, MARGIN, 2_000_000)
    entry, _ = registry.put("austin", registry.parse(RAW), "api", len(RAW))
    pose, v_start, bounds = scenario_settings()[index]
    for frt in (shipped_engine.exact(pose, v_start, bounds),
                shipped_engine.conservative(pose, v_start, bounds)):  # fmt: skip
        read = VersionRoad(registry, entry, ("car", index), tuple(BOTH))
        cut = lane_cut(frt, entry.road, MARGIN)
        assert cut is not None
        x0, y0, x1, y1 = cut.source.near(frt.tube(frt.n_slices - 1).bounds).bounds
        rng = np.random.default_rng(index)
        points = rng.uniform((x0 - 5, y0 - 5), (x1 + 5, y1 + 5), (400, 2)).tolist()
        before = [read.off(frt, read.probe(x, y)) for x, y in points]
        kept = registry.cut_for(entry, (("car", index), frt.conservative), frt, tuple(BOTH))
        after = VersionRoad(registry, entry, ("car", index), tuple(BOTH))
        assert [after.off(frt, after.probe(x, y)) for x, y in points] == before
        held = [kept.source.covers(x, y) for x, y in points]  # type: ignore[union-attr]
        assert [not off for off in before] == held
        assert any(held) and not all(held)
        on_road = [entry.road.on_road(x, y, MARGIN) for x, y in points]
        assert [("drivable_area" in off) for off in before] == [not r for r in on_road]
