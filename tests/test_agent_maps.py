"""Agents that name a map (docs/maps.md), in-process on the shipped Argoverse 2 map archive
(data/av2/, © Argo AI, LLC, CC BY-NC-SA 4.0, https://creativecommons.org/licenses/by-nc-sa/4.0/):
their answers list the assumptions they hold under and come from the set cut to the road (checked
against R = D ⊕ 1 m built with shapely from the archive's own polygons); an agent observed
breaking an assumption loses it for FRT_ASSUMPTION_RELAX_S on its clock; unknown maps are 422s
that store nothing; without a map the answers are those of an agent without one."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import shapely
from fastapi.testclient import TestClient
from frt_client import calls
from frt_client.models import Agent, CollisionCheck
from shapely.geometry import Point, Polygon, shape

from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.engine import FRTEngine
from reach.road_cut import CutSet, lane_cut
from reach.road_map import RoadMap
from service.api.app import create_app
from tests.fixtures.payloads import observation, prediction
from tests.test_maps_api import (
    OFF_ROAD,
    ON_ROAD,
    RAW,
    client_with_map,
    put,
    settings_for,
    wait_ready,
)
from tests.test_road_cut import MODEL, scenario_settings

BOTH = ["drivable_area", "reachable_lanes"]
#: The server's default: the archive has no speed limits, so ``speed_limit`` is never in force.
CONFIGURED = [*BOTH, "speed_limit"]
RADIUS = 1.5
MARGIN = 1.0


def _drivable_grown() -> shapely.Geometry:
    """D ⊕ margin from the archive's drivable-area rings, read here and not by the service."""
    archive = json.loads(RAW)
    rings = [
        Polygon([(p["x"], p["y"]) for p in area["area_boundary"]])
        for area in archive["drivable_areas"].values()
    ]
    return shapely.union_all(rings).buffer(MARGIN)


def _extent() -> shapely.Geometry:
    """The map's extent (every element's bounding box), from the archive."""
    archive = json.loads(RAW)
    xy = [
        (p["x"], p["y"])
        for area in archive["drivable_areas"].values()
        for p in area["area_boundary"]
    ]
    for lane in archive["lane_segments"].values():
        for side in ("left_lane_boundary", "right_lane_boundary"):
            xy += [(p["x"], p["y"]) for p in lane[side]]
    return shapely.box(*shapely.MultiPoint(xy).bounds)


R = _drivable_grown()
EXTENT = _extent()


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    yield from client_with_map(analytic_model_path)


def body(t: float, state: dict[str, float], **extra: Any) -> dict[str, Any]:
    """An observation with a wide prediction: a set reaching well off the road."""
    pose = {k: state[k] for k in ("x", "y", "heading", "speed")}
    return {
        **observation(t, **pose),
        "prediction": prediction(var=(0.2, 1.0)),
        "config": {"gamma": 0.9, **extra.pop("config", {})},
        **extra,
    }


def observe(client: TestClient, agent_id: str, t: float, state: dict, **extra: Any) -> dict:
    r = client.post(
        f"/v1/agents/{agent_id}/observations?wait_frt_ms=10000", json=body(t, state, **extra)
    )
    assert r.status_code == 200, r.text
    assert r.json()["frt_ready"]
    return r.json()


def check(client: TestClient, agent_id: str, points: list[dict], **extra: Any) -> dict:
    request = {"trajectory": points, "deadline_ms": 10_000, **extra}
    r = client.post(f"/v1/agents/{agent_id}/collision-check", json=request)
    assert r.status_code == 200, r.text
    return r.json()


def tube_k(client: TestClient, agent_id: str) -> tuple[shapely.Geometry, dict]:
    answer = client.get(f"/v1/agents/{agent_id}/frt?slices=1.0,2.5").json()
    return shape(answer["tube"]["K"]), answer


def off_road_point(k: shapely.Geometry, clearance: float) -> Point:
    """A point inside ``k`` and the map's extent, more than ``clearance`` from R."""
    off = k.intersection(EXTENT.buffer(-1.0)).difference(R.buffer(clearance))
    assert off.area > 1.0
    return off.representative_point()


@pytest.fixture(scope="module")
def pair(client: TestClient) -> dict[str, Any]:
    """One car on the road named with the map and the same car without it."""
    observe(client, "road-car", 0.0, ON_ROAD, map_id="austin")
    observe(client, "plain-car", 0.0, ON_ROAD)
    k_plain, _ = tube_k(client, "plain-car")
    point = off_road_point(k_plain, RADIUS + 4.0)
    return {"k_plain": k_plain, "point": point}


def test_a_car_on_the_road_is_answered_under_its_assumptions(client, pair) -> None:
    agent = client.get("/v1/agents/road-car").json()
    assert agent["map_id"] == "austin" and agent["assumptions"] == BOTH
    assert agent["relaxed_assumptions"] == [] and agent["config"]["assumptions"] == CONFIGURED
    plain = client.get("/v1/agents/plain-car").json()
    assert (plain["map_id"], plain["assumptions"], plain["relaxed_assumptions"]) == (None, [], [])
    Agent.model_validate(agent)  # the SDK reads it


def test_a_check_colliding_only_off_the_road_is_clear_with_the_map(client, pair) -> None:
    point = pair["point"]  # inside the uncut K, more than R_col + 4 m off R by construction
    assert pair["k_plain"].contains(point) and R.distance(point) > RADIUS + 4.0
    trajectory = [{"t": 3.0, "x": point.x, "y": point.y}]  # the whole tube in either mode
    for mode in ("tube", "time_indexed"):
        plain = check(client, "plain-car", trajectory, mode=mode)
        cut = check(client, "road-car", trajectory, mode=mode)
        assert plain["collision"] and plain["assumptions"] == [], mode
        assert not cut["collision"] and cut["assumptions"] == BOTH, mode
        assert cut["verdict"] == "exact"
        # The cut K lies in R within the extent: the point is at least this far from C.
        assert cut["clearance"][0] >= R.distance(point) - RADIUS - 1e-6
        CollisionCheck.model_validate(cut)
    # The ego's box there (its discs all more than 4 m off R, far from the cut set too).
    boxed = [{**trajectory[0], "heading": 0.0}]
    footprint = {"length": 2.0, "width": 1.0}
    assert check(client, "plain-car", boxed, footprint=footprint)["collision"]
    assert not check(client, "road-car", boxed, footprint=footprint)["collision"]
    many = client.post(
        "/v1/collision-check",
        json={"trajectory": trajectory, "agent_ids": ["road-car", "plain-car"], "deadline_ms": 1e4},
    ).json()
    by_agent = {r["agent_id"]: r for r in many["results"]}
    assert not by_agent["road-car"]["collision"] and by_agent["plain-car"]["collision"]
    assert by_agent["road-car"]["assumptions"] == BOTH


def test_a_batch_is_answered_from_the_cut_set_as_single_checks_are(client, pair) -> None:
    """Each trajectory of a batch has the verdict and least clearance of its single check, with
    the map and without; entries or columns, points or footprints alike."""
    point = pair["point"]
    far = {"t": 1.0, "x": ON_ROAD["x"] + 150.0, "y": ON_ROAD["y"], "heading": 0.0}
    trajectories = [
        [{"t": 3.0, "x": point.x, "y": point.y, "heading": 0.0}],
        [far],
        [{"t": 2.0, "x": ON_ROAD["x"], "y": ON_ROAD["y"] + 3.0, "heading": 1.5}, {**far, "t": 2.5}],
    ]
    footprint = {"footprint": {"length": 2.0, "width": 1.0}}
    for mode in ("tube", "time_indexed"):
        for extra in ({}, {"answer_columns": True}, footprint):
            for agent, labels in (("road-car", BOTH), ("plain-car", [])):
                answer = _batch(client, agent, trajectories, mode=mode, **extra)
                assert answer["assumptions"] == labels, (mode, agent)
                rows = answer.get("trajectories") or [
                    dict(zip(answer["trajectory_columns"], values, strict=True))
                    for values in zip(*answer["trajectory_columns"].values(), strict=True)
                ]
                for trajectory, row in zip(trajectories, rows, strict=True):
                    single = check(client, agent, trajectory, mode=mode, **footprint_of(extra))
                    assert row["collision"] == single["collision"], (mode, agent, trajectory)
                    assert row["min_clearance"] == pytest.approx(min(single["clearance"]))
    plain = _batch(client, "plain-car", trajectories[:1])
    cut = _batch(client, "road-car", trajectories[:1])
    assert plain["trajectories"][0]["collision"] and not cut["trajectories"][0]["collision"]


def footprint_of(extra: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in extra.items() if k == "footprint"}


def _batch(client: TestClient, agent_id: str, trajectories: list, **extra: Any) -> dict:
    request = {"trajectories": trajectories, "deadline_ms": 10_000, **extra}
    r = client.post(f"/v1/agents/{agent_id}/collision-check", json=request)
    assert r.status_code == 200, r.text
    return r.json()


def test_a_clear_check_is_measured_on_the_uncut_set_and_labelled(client, pair) -> None:
    far = [{"t": 1.0, "x": ON_ROAD["x"] + 150.0, "y": ON_ROAD["y"]}]
    plain, cut = check(client, "plain-car", far), check(client, "road-car", far)
    assert not cut["collision"] and cut["assumptions"] == BOTH
    # Not near C: the uncut set's clearance, a lower bound of the cut set's.
    assert cut["clearance"] == plain["clearance"]


def test_contours_are_cut_to_the_road_and_labelled(client, pair) -> None:
    k_cut, answer = tube_k(client, "road-car")
    assert answer["assumptions"] == BOTH
    k_plain = pair["k_plain"]
    assert k_cut.area < 0.5 * k_plain.area
    assert k_cut.difference(k_plain.buffer(0.01)).area == 0.0
    assert k_cut.intersection(EXTENT).difference(R.buffer(0.01)).area == 0.0
    for whole, cut in zip(
        client.get("/v1/agents/plain-car/frt?slices=1.0,2.5").json()["slices"],
        answer["slices"],
        strict=True,
    ):
        assert shape(cut["K"]).difference(shape(whole["K"]).buffer(0.01)).area == 0.0


def _pieces(slice_: dict[str, Any]) -> shapely.Geometry:
    return shapely.union_all([Polygon(p["vertices"]) for p in slice_["pieces"]])


def test_constraints_hold_the_cut_set_and_list_its_assumptions(client, pair) -> None:
    """Each time's pieces contain the cut K ⊕ R_col the contours draw (shapely), list the cut's
    assumptions, and cover clearly less than the uncut set's pieces."""
    query = "slices=1.0,2.5&max_pieces=4"
    cut = client.get(f"/v1/agents/road-car/constraints?{query}").json()
    plain = client.get(f"/v1/agents/plain-car/constraints?{query}").json()
    contours = client.get("/v1/agents/road-car/frt?slices=1.0,2.5").json()
    assert cut["assumptions"] == BOTH and plain["assumptions"] == []
    assert cut["frt_version"] == contours["frt_version"]
    for mine, whole, drawn in zip(cut["slices"], plain["slices"], contours["slices"], strict=True):
        held = shape(drawn["K"]).buffer(RADIUS - 0.01)
        assert held.difference(_pieces(mine).buffer(0.01)).area == 0.0
        assert _pieces(mine).area < 0.8 * _pieces(whole).area


def test_the_assumptions_follow_the_config_and_the_class(client, pair) -> None:
    observe(client, "da-car", 0.0, ON_ROAD, map_id="austin", config={"assumptions": ["drivable_area"]})  # fmt: skip
    observe(client, "no-car", 0.0, ON_ROAD, map_id="austin", config={"assumptions": []})
    observe(client, "bike", 0.0, ON_ROAD, map_id="austin", agent_class="cyclist")
    observe(client, "walker", 0.0, {**ON_ROAD, "speed": 1.0}, map_id="austin", agent_class="pedestrian")  # fmt: skip
    got = {a: client.get(f"/v1/agents/{a}").json()["assumptions"] for a in ("da-car", "no-car", "bike", "walker")}  # fmt: skip
    assert got == {"da-car": ["drivable_area"], "no-car": [], "bike": ["drivable_area"], "walker": []}  # fmt: skip
    k_da, _ = tube_k(client, "da-car")
    k_both, _ = tube_k(client, "road-car")
    assert k_both.difference(k_da.buffer(0.01)).area == 0.0  # R ∩ L inside R
    trajectory = [{"t": 2.0, "x": pair["point"].x, "y": pair["point"].y}]
    assert not check(client, "da-car", trajectory)["collision"]
    # Without assumptions the map changes nothing: the answer of the car without a map.
    unlabelled, plain = check(client, "no-car", trajectory), check(client, "plain-car", trajectory)
    assert unlabelled == plain | {"agent_id": "no-car"}


def test_without_a_map_the_answers_are_those_of_an_agent_without_one(client, pair) -> None:
    """An agent that never named a map stores nothing of maps, and with the map registered its
    answers are those of a server without maps (same set, same clearance, every bit)."""
    trajectory = [{"t": t, "x": pair["point"].x + t, "y": pair["point"].y} for t in (0.5, 1.5, 2.5)]
    observe(client, "other-car", 0.0, ON_ROAD, map_id="austin", config={"assumptions": []})
    for mode in ("tube", "time_indexed"):
        plain = check(client, "plain-car", trajectory, mode=mode)
        assert plain["assumptions"] == [] and plain["collision"]
        other = check(client, "other-car", trajectory, mode=mode)
        assert other == plain | {"agent_id": "other-car"}
    assert "map_id" not in json.dumps(client.get("/v1/agents/plain-car").json()["config"])


def test_a_car_off_the_road_loses_the_assumption_for_the_relax_time(client, pair) -> None:
    before = _violations(client)
    observe(client, "wanderer", 10.0, OFF_ROAD, map_id="austin")
    agent = client.get("/v1/agents/wanderer").json()
    assert R.distance(Point(OFF_ROAD["x"], OFF_ROAD["y"])) > 0.0  # off R by the archive itself
    relaxed = {r["assumption"]: r["until"] for r in agent["relaxed_assumptions"]}
    assert relaxed["drivable_area"] == 15.0 and "drivable_area" not in agent["assumptions"]
    assert _violations(client) > before
    # Back on the road within the relax time: still answered without it, from the uncut set.
    observe(client, "wanderer", 12.0, ON_ROAD)
    agent = client.get("/v1/agents/wanderer").json()
    assert "drivable_area" not in agent["assumptions"] and agent["map_id"] == "austin"
    k_own, contours = tube_k(client, "wanderer")
    assert "drivable_area" not in contours["assumptions"]
    point = off_road_point(k_own, RADIUS + 4.0)
    trajectory = [{"t": 14.0, "x": point.x, "y": point.y}]
    answer = check(client, "wanderer", trajectory)
    assert answer["collision"] and "drivable_area" not in answer["assumptions"]
    # At the relax time's end, on the road, it holds again.
    observe(client, "wanderer", 15.0, ON_ROAD)
    agent = client.get("/v1/agents/wanderer").json()
    assert agent["assumptions"] == BOTH and agent["relaxed_assumptions"] == []
    assert not check(client, "wanderer", [{**trajectory[0], "t": 17.0}])["collision"]


def _violations(client: TestClient) -> float:
    prefix = 'frt_assumption_violations_total{agent_class="car",assumption="drivable_area"} '
    lines = [ln for ln in client.get("/metrics").text.splitlines() if ln.startswith(prefix)]
    return float(lines[0].split()[-1]) if lines else 0.0


def test_an_unknown_map_is_a_422_naming_map_id_that_stores_nothing(client, pair) -> None:
    r = client.post("/v1/agents/lost/observations", json=body(0.0, ON_ROAD, map_id="nowhere"))
    assert r.status_code == 422 and r.json()["field"] == "map_id"
    assert client.get("/v1/agents/lost").status_code == 404
    before = client.get("/v1/agents/road-car").json()
    r = client.post("/v1/agents/road-car/observations", json=body(99.0, ON_ROAD, map_id="x"))
    assert r.status_code == 422 and r.json()["field"] == "map_id"
    assert client.get("/v1/agents/road-car").json() == before


def test_a_frame_rejects_only_the_entry_with_an_unknown_map(client, pair) -> None:
    entries = []
    for agent_id, map_id in (("f-a", "austin"), ("f-b", "nowhere"), ("f-c", None)):
        entry = {"agent_id": agent_id, **body(0.0, ON_ROAD)}
        del entry["timestamp"]
        if map_id is not None:
            entry["map_id"] = map_id
        entries.append(entry)
    r = client.post("/v1/frames", json={"timestamp": 0.0, "agents": entries})
    assert r.status_code == 200, r.text
    answer = r.json()
    assert (answer["applied"], answer["rejected"]) == (2, 1)
    assert answer["results"][1]["error"]["field"] == "agents.1.map_id"
    assert client.get("/v1/agents/f-b").status_code == 404
    assert client.get("/v1/agents/f-a").json()["map_id"] == "austin"
    assert client.get("/v1/agents/f-c").json()["map_id"] is None


def test_the_stream_observes_with_a_map(client: TestClient, pair) -> None:
    with client.websocket_connect("/v1/stream") as ws:
        ws.send_json({"id": 1, "op": "observe", "agent_id": "ws-car", **body(0.0, ON_ROAD, map_id="nowhere")})  # fmt: skip
        refused = ws.receive_json()
        ws.send_json({"id": 2, "op": "observe", "agent_id": "ws-car", **body(0.0, ON_ROAD, map_id="austin")})  # fmt: skip
        accepted = ws.receive_json()
    assert not refused["ok"] and refused["error"]["field"] == "map_id"
    assert accepted["ok"], accepted
    assert client.get("/v1/agents/ws-car").json()["map_id"] == "austin"


def test_the_sdk_sends_map_id_and_assumptions() -> None:
    call = calls.observe(
        "a",
        timestamp=0.0,
        state=(0, 0, 0, 1),
        prediction=prediction(),
        map_id="austin",
        config={"assumptions": ["drivable_area"]},
    )
    assert call.json["map_id"] == "austin" and call.message["map_id"] == "austin"  # type: ignore[index]
    assert call.json["config"]["assumptions"] == ["drivable_area"]  # type: ignore[index]
    frame = calls.frame(
        timestamp=0.0,
        agents=[
            {"agent_id": "a", "state": (0, 0, 0, 1), "prediction": prediction(), "map_id": "m"}
        ],
    )
    assert frame.json["agents"][0]["map_id"] == "m"  # type: ignore[index]


def test_the_server_wide_setting_is_the_default_an_agent_overrides(
    analytic_model_path: Path,
) -> None:
    assert settings_for(analytic_model_path, assumptions="").assumptions == ()
    settings = settings_for(analytic_model_path, assumptions="drivable_area")
    assert settings.assumptions == ("drivable_area",)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        wait_ready(client)
        assert put(client, "austin", RAW).status_code == 200
        observe(client, "car", 0.0, ON_ROAD, map_id="austin")
        observe(client, "lanes", 0.0, ON_ROAD, map_id="austin", config={"assumptions": BOTH})
        assert client.get("/v1/agents/car").json()["assumptions"] == ["drivable_area"]
        assert client.get("/v1/agents/lanes").json()["assumptions"] == BOTH


@pytest.fixture(scope="module")
def shipped_engine() -> FRTEngine:
    return engine_for(ValueModel.load(MODEL, threads=1), network=False)


@pytest.mark.parametrize("index", range(3))
def test_a_cut_conservative_set_contains_the_cut_exact_one(shipped_engine, index) -> None:
    """A check's conservative answer under assumptions stays conservative: cutting keeps
    containment (exact ⊂ conservative, so their cuts by R, and by R ∩ L, are nested too)."""
    engine, road = shipped_engine, RoadMap.from_json(RAW)
    pose, v_start, bounds = scenario_settings()[index]
    exact, outer = engine.exact(pose, v_start, bounds), engine.conservative(pose, v_start, bounds)
    cuts = [(CutSet(exact, road, MARGIN), CutSet(outer, road, MARGIN))]
    lanes = lane_cut(exact, road, MARGIN), lane_cut(outer, road, MARGIN)
    assert lanes[0] is not None and lanes[1] is not None  # each car is in a lane of its heading
    cuts.append(lanes)  # type: ignore[arg-type]
    for inner, wider in cuts:
        for j in range(0, inner.n_slices, 5):
            assert inner.tube(j).difference(wider.tube(j).buffer(1e-6)).area < 1e-6, j
