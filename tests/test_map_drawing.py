"""Drawing a map and the uncut set beside the cut one, in-process on the shipped Argoverse 2 map
archive (data/av2/, © Argo AI, LLC, CC BY-NC-SA 4.0,
https://creativecommons.org/licenses/by-nc-sa/4.0/).

``GET /v1/maps/{map_id}/geojson`` is checked against the archive read here with shapely (the
drivable area's rings and each lane's boundaries), not against the service's own parse; the
uncut contours of ``GET /v1/agents/{id}/frt?include_uncut=true`` against the contours of the
same car observed without the map, and the cut ones must lie within them."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import shapely
from fastapi.testclient import TestClient
from frt_client import calls
from frt_client.models import AgentContours
from shapely.geometry import Polygon, shape

from service.flows import maps as map_flows
from tests.test_agent_maps import BOTH, observe
from tests.test_maps_api import ON_ROAD, RAW, client_with_map

ARCHIVE = json.loads(RAW)
#: D from the archive's drivable-area rings.
D = shapely.union_all(
    [
        Polygon([(p["x"], p["y"]) for p in area["area_boundary"]])
        for area in ARCHIVE["drivable_areas"].values()
    ]
)
#: A box over the middle of the map: part of the road, part off it, some lanes cut by its edges.
BOX = (-440.0, 1380.0, -390.0, 1440.0)


def _lane_polygon(lane: dict) -> shapely.Geometry:
    """A lane's area: its left boundary and its right one reversed, made valid."""
    left = [(p["x"], p["y"]) for p in lane["left_lane_boundary"]]
    right = [(p["x"], p["y"]) for p in lane["right_lane_boundary"]]
    return shapely.make_valid(Polygon(left + right[::-1]))


LANES = {key: _lane_polygon(lane) for key, lane in ARCHIVE["lane_segments"].items()}


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    yield from client_with_map(analytic_model_path)


def geojson(client: TestClient, **query: Any) -> dict:
    r = client.get("/v1/maps/austin/geojson", params=query)
    assert r.status_code == 200, r.text
    return r.json()


def _box_query(box: tuple[float, ...]) -> str:
    return ",".join(f"{v:g}" for v in box)


def of_kind(answer: dict, kind: str) -> list[dict]:
    return [f for f in answer["features"] if f["properties"]["kind"] == kind]


def test_the_drivable_area_in_a_box_is_the_archives(client: TestClient) -> None:
    answer = geojson(client, bbox=_box_query(BOX), simplify_m=0.0)
    assert answer["type"] == "FeatureCollection" and answer["bbox"] == list(BOX)
    (drivable,) = of_kind(answer, "drivable_area")
    drawn = shape(drivable["geometry"])
    want = shapely.clip_by_rect(D, *BOX)
    assert want.area > 100.0 and want.area < 0.9 * shapely.box(*BOX).area  # road and not road
    assert drawn.symmetric_difference(want).area < 1e-3 * want.length  # millimetre rounding
    vertices = sum(shapely.get_num_coordinates(shape(f["geometry"])) for f in answer["features"])
    assert answer["vertices"] >= vertices > 0


def test_the_lanes_in_a_box_are_the_archives_lanes_meeting_it(client: TestClient) -> None:
    answer = geojson(client, bbox=_box_query(BOX), simplify_m=0.0)
    rect = shapely.box(*BOX)
    drawn = {f["properties"]["lane_id"]: shape(f["geometry"]) for f in of_kind(answer, "lane")}
    meeting = {k for k, p in LANES.items() if p.intersection(rect).area > 0.01}
    assert meeting and meeting <= set(drawn) <= {k for k, p in LANES.items() if p.intersects(rect)}
    assert len(meeting) < len(LANES)  # the box leaves lanes out
    for key, polygon in drawn.items():
        want = LANES[key].intersection(rect)
        assert polygon.symmetric_difference(want).area < 1e-3 * max(want.length, 1.0), key
        lane = ARCHIVE["lane_segments"][key]
        props = next(f["properties"] for f in of_kind(answer, "lane") if f["properties"]["lane_id"] == key)  # fmt: skip
        assert props["lane_type"] == lane["lane_type"]
    for f in of_kind(answer, "centerline"):
        line = shape(f["geometry"])
        assert line.geom_type == "MultiLineString"
        assert line.difference(rect.buffer(1e-3)).length == 0.0
        assert LANES[f["properties"]["lane_id"]].buffer(0.05).contains(line)


def test_without_a_box_the_whole_map_and_without_lanes_only_the_road(client: TestClient) -> None:
    whole = geojson(client)
    extent = client.get("/v1/maps/austin").json()["extent"]
    assert whole["bbox"] == extent == whole["extent"]
    assert {f["properties"]["lane_id"] for f in of_kind(whole, "lane")} == set(LANES)
    (drivable,) = of_kind(whole, "drivable_area")
    assert shape(drivable["geometry"]).area == pytest.approx(D.area, rel=1e-3)
    road_only = geojson(client, lanes="false")
    assert [f["properties"]["kind"] for f in road_only["features"]] == ["drivable_area"]
    far = geojson(client, bbox="0,0,100,100")
    assert far["features"] == [] and far["vertices"] == 0


def test_the_answer_is_simplified_to_fit_the_vertex_cap(
    client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    full = geojson(client, simplify_m=0.0)
    cap = full["vertices"] // 3
    monkeypatch.setattr(map_flows, "MAX_VERTICES", cap)
    small = geojson(client, simplify_m=0.0)
    assert 0 < small["vertices"] <= cap and small["simplify_m"] > 0.0
    (drivable,) = of_kind(small, "drivable_area")
    # Simplified within its tolerance: no point of either further than it from the other.
    distance = shapely.hausdorff_distance(shape(drivable["geometry"]), D)
    assert distance <= small["simplify_m"] + 1e-3
    monkeypatch.setattr(map_flows, "MAX_VERTICES", 3)
    r = client.get("/v1/maps/austin/geojson")
    assert r.status_code == 422 and r.json()["field"] == "bbox"


@pytest.mark.parametrize(
    "bbox",
    [
        "1,2,3",
        "a,b,c,d",
        "0,0,-1,1",
        "0,0,1,0",
        "nan,0,1,1",
        "0,0,1,inf",
        "0,0,2001,10",
        "1e8,0,2e8,1",
    ],
)
def test_a_bad_box_is_a_422_naming_bbox(client: TestClient, bbox: str) -> None:
    r = client.get("/v1/maps/austin/geojson", params={"bbox": bbox})
    assert r.status_code == 422 and r.json()["field"] == "bbox", r.text


def test_an_unknown_map_is_a_404_and_bad_parameters_are_422s(client: TestClient) -> None:
    assert client.get("/v1/maps/nowhere/geojson").status_code == 404
    for query, field in (("simplify_m=-1", "simplify_m"), ("simplify_m=11", "simplify_m"),
                         ("bbox=" + "1" * 300, "bbox"), ("zoom=3", "zoom")):  # fmt: skip
        r = client.get(f"/v1/maps/austin/geojson?{query}")
        assert r.status_code == 422 and r.json()["field"] == field, query


# ------------------------------------------------------------------- the uncut set beside the cut


@pytest.fixture(scope="module")
def cars(client: TestClient) -> dict[str, str]:
    """The same car, named with the map and not."""
    observe(client, "drawn-road-car", 0.0, ON_ROAD, map_id="austin")
    observe(client, "drawn-plain-car", 0.0, ON_ROAD)
    return {"road": "drawn-road-car", "plain": "drawn-plain-car"}


def contours(client: TestClient, agent: str, **query: Any) -> dict:
    r = client.get(f"/v1/agents/{agent}/frt", params={"slices": "1.0,2.5", **query})
    assert r.status_code == 200, r.text
    return r.json()


def _pairs(answer: dict) -> list[dict]:
    return [answer["tube"], *answer["slices"]]


def test_the_uncut_contours_are_those_without_the_map_and_hold_the_cut_ones(
    client: TestClient, cars: dict[str, str]
) -> None:
    answer = contours(client, cars["road"], include_uncut="true")
    plain = contours(client, cars["plain"])
    assert answer["assumptions"] == BOTH and plain["assumptions"] == []
    uncut = answer["uncut"]
    assert [s["t"] for s in uncut["slices"]] == [s["t"] for s in answer["slices"]] == [1.0, 2.5]
    for cut, whole, reference in zip(_pairs(answer), _pairs(uncut), _pairs(plain), strict=True):
        for part in ("K", "C"):
            cut_set, whole_set = shape(cut[part]), shape(whole[part])
            # The set before the cut is the car's set without the map.
            assert whole_set.symmetric_difference(shape(reference[part])).area < 1e-6
            # ... and holds the cut one (up to the contours' millimetre rounding).
            assert cut_set.difference(whole_set.buffer(0.01)).area == 0.0
    assert shape(answer["tube"]["K"]).area < 0.5 * shape(uncut["tube"]["K"]).area


def test_without_the_flag_nothing_changes_and_without_assumptions_uncut_is_null(
    client: TestClient, cars: dict[str, str]
) -> None:
    with_flag = contours(client, cars["road"], include_uncut="true")
    without = contours(client, cars["road"])
    assert "uncut" not in without
    assert without == {k: v for k, v in with_flag.items() if k != "uncut"}
    assert "uncut" not in contours(client, cars["road"], include_uncut="false")
    plain = contours(client, cars["plain"], include_uncut="true")
    assert plain["uncut"] is None and plain["assumptions"] == []
    only_k = contours(client, cars["road"], include_uncut="true", include="K", tube="false")
    assert only_k["uncut"]["tube"] is None
    assert all(s["C"] is None and s["K"] is not None for s in only_k["uncut"]["slices"])


def test_the_stream_frt_op_takes_include_uncut(client: TestClient, cars: dict[str, str]) -> None:
    """The stream answers as the route does, flag or not; a flag that is not a boolean is a 422
    naming it; the SDK sends it both ways."""
    http = contours(client, cars["road"], include_uncut="true")
    message = {"op": "frt", "agent_id": cars["road"], "slices": [1.0, 2.5]}
    with client.websocket_connect("/v1/stream") as ws:
        answers = []
        for i, extra in enumerate(({"include_uncut": True}, {}, {"include_uncut": "yes"})):
            ws.send_json({"id": i, **message, **extra})
            answers.append(ws.receive_json())
    flagged, plain, refused = answers
    assert flagged["ok"] and flagged["result"] == http
    assert plain["ok"] and "uncut" not in plain["result"]
    assert not refused["ok"] and refused["error"]["field"] == "include_uncut"
    call = calls.contours(cars["road"], slices=[1.0], include_uncut=True)
    assert call.params["include_uncut"] == "true" and call.message["include_uncut"] is True  # type: ignore[index]
    assert "include_uncut" not in calls.contours(cars["road"]).message  # type: ignore[operator]
    answer = AgentContours.model_validate(http)
    assert answer.uncut is not None and answer.uncut.tube is not None
