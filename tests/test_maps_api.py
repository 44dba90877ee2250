"""``/v1/maps/{map_id}`` in-process: register the shipped Argoverse 2 map archive (data/av2/,
© Argo AI, LLC, CC BY-NC-SA 4.0, https://creativecommons.org/licenses/by-nc-sa/4.0/), read it,
replace it, forget it; bad input is a 4xx naming what is wrong and registers nothing; FRT_MAP
loads one at start-up; ``POST /v1/frt`` with ``map_id`` answers from the set cut by its drivable
area and says so."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from shapely.geometry import shape

from reach.road_map import RoadMap
from service.api.app import create_app
from service.runtime.settings import Settings
from tests.conftest import READY_TIMEOUT_S
from tests.fixtures.payloads import NARROW_BOUNDS

ARCHIVE = (
    Path(__file__).resolve().parent.parent
    / "data"
    / "av2"
    / "log_map_archive_0a1e6f0a-1817-4a98-b02e-db8c9327d151.json"
)
RAW = ARCHIVE.read_bytes()


def settings_for(model: Path, **extra: object) -> Settings:
    """In-process settings: exact sets on one thread, the certified geometry alone."""
    fixed = {"frt_executor": "thread", "frt_workers": 1, "network": "off", "max_maps": 2}
    return Settings(model_path=model, log_requests=False, **{**fixed, **extra})


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    app = create_app(settings_for(analytic_model_path))
    with TestClient(app, raise_server_exceptions=False) as test_client:
        yield test_client


def put(client: TestClient, map_id: str, content: bytes):
    return client.put(
        f"/v1/maps/{map_id}", content=content, headers={"content-type": "application/json"}
    )


def field_of(response) -> str:
    assert response.status_code == 422, response.text
    return response.json()["field"]


def test_a_map_is_registered_read_replaced_and_forgotten(client: TestClient) -> None:
    assert client.get("/v1/maps/austin").status_code == 404
    first = put(client, "austin", RAW)
    assert first.status_code == 200, first.text
    body = first.json()
    assert body["map_id"] == "austin" and body["source"] == "api" and body["replaced"] is False
    assert (body["drivable_areas"], body["lane_segments"], body["pedestrian_crossings"]) == (
        2,
        71,
        6,
    )
    assert body["size_bytes"] == len(RAW) and body["margin_m"] == 1.0
    assert body["drivable_area_m2"] == pytest.approx(3815.75, abs=0.01)
    assert put(client, "austin", RAW).json()["replaced"] is True
    read = client.get("/v1/maps/austin").json()
    assert read["replaced"] is None and read["extent"] == body["extent"]
    assert client.delete("/v1/maps/austin").json() == {"map_id": "austin", "deleted": True}
    assert client.get("/v1/maps/austin").status_code == 404
    assert client.delete("/v1/maps/austin").status_code == 404


def test_a_malformed_archive_is_a_422_naming_the_field_and_registers_nothing(
    client: TestClient,
) -> None:
    archive = json.loads(RAW)
    archive["drivable_areas"]["11055391"]["area_boundary"][3]["x"] = "east"
    r = put(client, "bad", json.dumps(archive).encode())
    assert field_of(r) == "drivable_areas.11055391.area_boundary.3.x"
    assert "must be a number" in r.json()["detail"][0]["msg"]
    assert field_of(put(client, "bad", b'{"drivable_areas": {}, "roads": {}}')) == "roads"
    assert field_of(put(client, "bad", b'{"lane_segments": {}}')) == "drivable_areas"
    for content in (b"{", b"", b"[]", b'{"drivable_areas": NaN}'):
        assert field_of(put(client, "bad", content)) in ("body", "drivable_areas"), content
    assert client.get("/v1/maps/bad").status_code == 404


def test_a_bad_map_id_is_a_422_naming_it(client: TestClient) -> None:
    assert field_of(put(client, "a%20b", RAW)) == "map_id"
    assert field_of(client.get(f"/v1/maps/{'x' * 129}")) == "map_id"


def test_the_server_holds_at_most_max_maps(client: TestClient) -> None:
    assert put(client, "one", RAW).status_code == 200
    assert put(client, "two", RAW).status_code == 200
    full = put(client, "three", RAW)
    assert full.status_code == 409 and "FRT_MAX_MAPS" in full.json()["detail"]
    assert put(client, "two", RAW).status_code == 200  # replacing is always allowed
    for map_id in ("one", "two"):
        client.delete(f"/v1/maps/{map_id}")


def test_an_oversized_archive_is_a_413(analytic_model_path: Path) -> None:
    app = create_app(settings_for(analytic_model_path, max_map_bytes=50_000))
    with TestClient(app, raise_server_exceptions=False) as client:
        r = put(client, "austin", RAW)
        assert r.status_code == 413 and "50000 bytes" in r.json()["detail"]

        def chunks() -> Iterator[bytes]:  # no Content-Length: counted as it streams in
            for i in range(0, len(RAW), 8192):
                yield RAW[i : i + 8192]

        r = client.put("/v1/maps/austin", content=chunks())
        assert r.status_code == 413
        assert client.get("/v1/maps/austin").status_code == 404
        # The map limit is the maps' own: other bodies keep FRT_MAX_BODY_BYTES.
        assert put(client, "small", RAW[:40_000]).status_code == 422


def test_frt_map_is_loaded_at_start_up(analytic_model_path: Path, tmp_path: Path) -> None:
    app = create_app(settings_for(analytic_model_path, map=ARCHIVE, map_id="austin"))
    with TestClient(app, raise_server_exceptions=False) as client:
        body = client.get("/v1/maps/austin").json()
        assert body["source"] == "file" and body["lane_segments"] == 71
    broken = tmp_path / "broken.json"
    broken.write_text('{"drivable_areas": {"1": {"area_boundary": [{"x": 0}]}}}')
    with pytest.raises(ValueError, match=r"drivable_areas\.1\.area_boundary"):
        create_app(settings_for(analytic_model_path, map=broken))


def wait_ready(client: TestClient) -> None:
    deadline = time.monotonic() + READY_TIMEOUT_S
    while client.get("/readyz").status_code != 200:
        assert time.monotonic() < deadline, client.get("/readyz").json()
        time.sleep(0.02)


def client_with_map(model: Path, map_id: str = "austin") -> Iterator[TestClient]:
    """A ready in-process service with the scenario's archive registered as ``map_id``."""
    app = create_app(settings_for(model))
    with TestClient(app, raise_server_exceptions=False) as test_client:
        wait_ready(test_client)
        assert put(test_client, map_id, RAW).status_code == 200
        yield test_client


#: A car of the recorded scenario on the road, heading north at 10 m/s, with wide steering.
ON_ROAD = {"x": -424.74, "y": 1417.45, "heading": 1.495, "speed": 10.0}
#: A parked car's spot off the drivable area.
OFF_ROAD = {"x": -419.9, "y": 1377.8, "heading": 1.5, "speed": 1.0}
WIDE = {**NARROW_BOUNDS, "u1_min_start": -0.5, "u1_min_end": -0.5, "u1_max_start": 0.5,
        "u1_max_end": 0.5, "u2_min_start": -4.0, "u2_min_end": -4.0}  # fmt: skip


def frt(client: TestClient, state: dict, **extra: object) -> dict:
    body = {"state": state, "control_bounds": WIDE,
            "contours": {"slices": [1.0, 2.5], "include": ["K", "C"]}, **extra}  # fmt: skip
    r = client.post("/v1/frt", json=body)
    assert r.status_code == 200, r.text
    return r.json()


def test_the_stateless_frt_is_cut_by_a_named_map(client: TestClient) -> None:
    wait_ready(client)
    assert put(client, "austin", RAW).status_code == 200
    plain = frt(client, ON_ROAD)
    k_plain = shape(plain["contours"]["tube"]["K"])
    road = RoadMap.from_json(RAW)
    off = k_plain.difference(road.region(1.0).grown.buffer(4.0))
    point = off.representative_point()  # inside the uncut K, 4 m off the road
    trajectory = [{"t": 2.0, "x": point.x, "y": point.y}]
    plain = frt(client, ON_ROAD, trajectory=trajectory)
    cut = frt(client, ON_ROAD, trajectory=trajectory, map_id="austin")
    assert plain["assumptions"] == [] and cut["assumptions"] == ["drivable_area", "reachable_lanes"]
    assert plain["collision"]["collision"] and not cut["collision"]["collision"]
    road_only = frt(client, ON_ROAD, map_id="austin", assumptions=["drivable_area"])
    assert road_only["assumptions"] == ["drivable_area"]
    k_road_only = shape(road_only["contours"]["tube"]["K"])
    k_both = shape(cut["contours"]["tube"]["K"])
    assert k_both.difference(k_road_only.buffer(0.01)).area == 0.0  # R ∩ L inside R
    assert k_both.area < k_road_only.area
    assert cut["collision"]["clearance"][0] > 2.0
    for part in ("K", "C"):
        k_cut, k_whole = (
            shape(cut["contours"]["tube"][part]),
            shape(plain["contours"]["tube"][part]),
        )
        assert k_cut.area < 0.6 * k_whole.area
        assert k_cut.difference(k_whole.buffer(0.01)).area == 0.0
    for whole, sliced in zip(plain["contours"]["slices"], cut["contours"]["slices"], strict=True):
        assert shape(sliced["K"]).difference(shape(whole["K"]).buffer(0.01)).area == 0.0
    assert shape(cut["contours"]["tube"]["K"]).difference(road.region(1.0).grown).area < 0.01


def test_a_state_off_the_road_is_answered_uncut_and_counted(client: TestClient) -> None:
    wait_ready(client)
    assert put(client, "austin", RAW).status_code == 200
    plain, off = frt(client, OFF_ROAD), frt(client, OFF_ROAD, map_id="austin")
    assert off["assumptions"] == [] and off["contours"] == plain["contours"]
    metrics = client.get("/metrics").text
    assert (
        'frt_assumption_violations_total{agent_class="car",assumption="drivable_area"}' in metrics
    )
    assert 'frt_road_cuts_total{outcome="off_road"}' in metrics


def test_an_unknown_map_is_a_422_naming_map_id(client: TestClient) -> None:
    wait_ready(client)
    body = {"state": ON_ROAD, "control_bounds": WIDE, "map_id": "nowhere"}
    r = client.post("/v1/frt", json=body)
    assert field_of(r) == "map_id" and "unknown map 'nowhere'" in r.json()["detail"][0]["msg"]
    assert field_of(client.post("/v1/frt", json={**body, "map_id": "a b"})) == "map_id"
