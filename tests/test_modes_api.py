"""Multi-modal predictions and agent classes through the API (in-process, the analytic model)."""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import shapely
from fastapi.testclient import TestClient
from shapely.geometry import shape

from service.api.app import create_app
from service.runtime.settings import Settings

COV = [[[0.01, 0.0], [0.0, 0.25]]] * 6
STRAIGHT = [[0.0, 0.0]] * 6
UTURN = [[0.5, -1.0]] * 6


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    settings = Settings(model_path=analytic_model_path, log_requests=False)
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        deadline = time.monotonic() + 30
        while c.get("/readyz").status_code != 200:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        yield c


def body(t: float, prediction: dict, action=None, **extra) -> dict:
    out = {
        "timestamp": t,
        "state": {"x": 2.0, "y": -1.0, "heading": 0.3, "speed": 5.0},
        "prediction": {"dt": 0.5, **prediction},
        **extra,
    }
    if action is not None:
        out["observed_action"] = {"steering_rate": action[0], "acceleration": action[1]}
    return out


def bimodal(w_straight: float = 0.9, w_uturn: float = 0.1) -> dict:
    return {
        "modes": [
            {"weight": w_straight, "mean": STRAIGHT, "cov": COV},
            {"weight": w_uturn, "mean": UTURN, "cov": COV},
        ]
    }


def observe(client: TestClient, agent: str, payload: dict) -> dict:
    r = client.post(f"/v1/agents/{agent}/observations?wait_frt_ms=5000", json=payload)
    assert r.status_code == 200, r.text
    return r.json()


def field_of(r) -> str:
    assert r.status_code == 422, r.text
    return r.json()["field"]


def without_id(d: dict) -> dict:
    return {k: v for k, v in d.items() if k not in ("agent_id", "server_ms")}


def test_a_one_mode_mixture_answers_exactly_as_the_single_gaussian(client: TestClient) -> None:
    plain = {"mean": [[0.1, -0.2]] * 6, "cov": COV}
    one = {"modes": [{"weight": 0.3, "mean": [[0.1, -0.2]] * 6, "cov": COV}]}
    trajectory = [{"t": 1.5 + 0.1 * k, "x": 2.0 + 2.0 * k, "y": -1.0 + 0.3 * k} for k in range(20)]
    for k, action in enumerate([None, (0.1, -0.2), (0.6, -1.0), (0.0, 0.0)]):
        a = observe(client, "one-plain", body(1.0 + k, plain, action))
        b = observe(client, "one-mode", body(1.0 + k, one, action))
        assert "modes" not in a and without_id(a) == without_id(b)
    ga, gb = client.get("/v1/agents/one-plain").json(), client.get("/v1/agents/one-mode").json()
    assert without_id(ga) == without_id(gb) and "modes" not in ga
    for mode in ("tube", "time_indexed"):
        check = {"trajectory": trajectory, "mode": mode, "deadline_ms": 5000}
        ca = client.post("/v1/agents/one-plain/collision-check", json=check).json()
        cb = client.post("/v1/agents/one-mode/collision-check", json=check).json()
        assert without_id(ca) == without_id(cb)
    fa = client.get("/v1/agents/one-plain/frt?slices=1.0,2.5").json()
    fb = client.get("/v1/agents/one-mode/frt?slices=1.0,2.5").json()
    assert without_id(fa) == without_id(fb)


def test_actions_following_the_minor_mode_raise_it_and_its_region_is_in_c(
    client: TestClient,
) -> None:
    first = observe(client, "uturn", body(1.0, bimodal()))
    assert [m["in_set"] for m in first["modes"]] == [True, True]
    assert [m["posterior"] for m in first["modes"]] == pytest.approx([0.9, 0.1])
    posteriors = [first["modes"][1]["posterior"]]
    answer = first
    for k in range(1, 6):
        answer = observe(client, "uturn", body(1.0 + k, bimodal(), (0.5, -1.0)))
        posteriors.append(answer["modes"][1]["posterior"])
    assert all(b > a for a, b in itertools.pairwise(posteriors))
    assert posteriors[-1] > 0.99
    view = client.get("/v1/agents/uturn").json()
    assert view["modes"] == answer["modes"] and view["mode_mass"] == 0.99
    assert view["modes"][1]["in_set"] and view["modes"][1]["beta"] > 0.9
    assert view["control_bounds"] == view["modes"][1]["control_bounds"]  # the most probable
    # The U-turn mode's own set (the stateless FRT of its bounds) lies inside the agent's C.
    c_set = shape(client.get("/v1/agents/uturn/frt").json()["tube"]["C"])
    alone = client.post(
        "/v1/frt",
        json={
            "state": body(0.0, {})["state"],
            "control_bounds": view["modes"][1]["control_bounds"],
            "contours": {"slices": [], "include": ["K"]},
        },
    )
    assert alone.status_code == 200, alone.text
    k_mode = shape(alone.json()["contours"]["tube"]["K"])
    assert k_mode.difference(c_set).area < 1e-3


def test_the_served_set_is_the_union_of_both_modes(client: TestClient) -> None:
    answer = observe(client, "union", body(1.0, bimodal()))
    k_union = shape(client.get("/v1/agents/union/frt?include=K").json()["tube"]["K"])
    alone = []
    for mode in answer["modes"]:
        r = client.post(
            "/v1/frt",
            json={
                "state": body(0.0, {})["state"],
                "control_bounds": mode["control_bounds"],
                "contours": {"slices": [], "include": ["K"]},
            },
        )
        alone.append(shape(r.json()["contours"]["tube"]["K"]))
    expected = shapely.union_all(alone)
    assert k_union.symmetric_difference(expected).area < 0.01 * expected.area
    # Every member's positions collide, whole-horizon and time-indexed.
    for member in alone:
        p = member.representative_point()
        for mode in ("tube", "time_indexed"):
            check = {"trajectory": [{"t": 4.0, "x": p.x, "y": p.y}], "mode": mode}
            r = client.post("/v1/agents/union/collision-check", json={**check, "deadline_ms": 5000})
            assert r.json()["collision"], r.text


def test_mixture_validation_names_the_field(client: TestClient) -> None:
    mode = {"weight": 1.0, "mean": STRAIGHT, "cov": COV}
    r = client.post("/v1/agents/v/observations", json=body(1.0, {"modes": [mode] * 33}))
    assert field_of(r) == "prediction.modes.32"
    assert observe(client, "v32", body(1.0, {"modes": [mode] * 32}))["frt_version"] == 1
    bad = {"modes": [mode, {**mode, "weight": 0.0}]}
    assert field_of(client.post("/v1/agents/v/observations", json=body(1.0, bad))).startswith(
        "prediction.modes.1.weight"
    )
    both = {"mean": STRAIGHT, "cov": COV, "modes": [mode]}
    assert field_of(client.post("/v1/agents/v/observations", json=body(1.0, both))) == "prediction"
    short = {"modes": [mode, {**mode, "mean": STRAIGHT[:3], "cov": COV[:3]}]}
    r = client.post("/v1/agents/v/observations", json=body(1.0, short))
    assert field_of(r) == "prediction.modes.1.mean"
    not_pd = {"modes": [mode, {**mode, "cov": [[[0.01, 0.0], [0.0, -1.0]]] * 6}]}
    r = client.post("/v1/agents/v/observations", json=body(1.0, not_pd))
    assert field_of(r) == "prediction.modes.1.cov.0"
    assert client.get("/v1/agents/v").status_code == 404


def test_agent_classes_are_fixed_once_set_and_checked(client: TestClient) -> None:
    plain = {"mean": STRAIGHT, "cov": COV}
    walker = body(1.0, plain, agent_class="pedestrian")
    walker["state"]["speed"] = 1.4
    observe(client, "walker", walker)
    view = client.get("/v1/agents/walker").json()
    assert view["agent_class"] == "pedestrian" and view["config"]["collision_radius"] == 0.75
    again = {**walker, "timestamp": 2.0}
    assert observe(client, "walker", again)["frt_version"] == 2  # omitted: the agent's class
    r = client.post(
        "/v1/agents/walker/observations", json={**walker, "timestamp": 3.0, "agent_class": "car"}
    )
    assert r.status_code == 409 and "pedestrian" in r.json()["detail"]
    observe(client, "a-car", body(1.0, plain))
    assert client.get("/v1/agents/a-car").json()["agent_class"] == "car"
    r = client.post("/v1/agents/a-car/observations", json=body(2.0, plain, agent_class="cyclist"))
    assert r.status_code == 409
    runner = body(1.0, plain, agent_class="pedestrian")
    runner["state"]["speed"] = 6.0
    assert field_of(client.post("/v1/agents/runner/observations", json=runner)) == "state.speed"
    rider = body(1.0, bimodal(), agent_class="cyclist")
    answer = observe(client, "rider", rider)
    for mode in answer["modes"]:  # the cyclist's limits: |u1| <= 1.5, |u2| <= 5
        bounds = mode["control_bounds"].values()
        assert all(abs(b) <= 5.0 for b in bounds)
