"""Batch checks and the ego's footprint (API.md, "Batch checks, footprints, constraints").

Ground truth is independent of the clearance code: a footprint's box is a shapely polygon tested
against the agent's C as the contours route draws it (K buffered by R_col, a polygon inscribed in
the true C), and a batch's answers are those of the same trajectories checked one by one.
"""

from __future__ import annotations

import base64
import json
import math
import uuid

import httpx
import numpy as np
import pytest
from frt_client import FRTClient, ValidationError, inputs
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError as PydanticValidationError
from shapely.affinity import rotate, translate
from shapely.geometry import Point, box, shape

from reach.footprint import MAX_DISCS, disc_centres, disc_cover, footprint_distances
from service.api.recent_checks import RecentChecks
from service.flows.check_points import CheckPoints, check_points
from service.runtime.settings import Settings
from service.wire.batch_body import holds_booleans, packed_batch, parse_batch_check
from service.wire.binary64 import read_binary64
from service.wire.errors import FieldError
from service.wire.schemas import (
    CollisionCheckRequest,
    CollisionCheckResponse,
    MultiCollisionCheckRequest,
)
from tests.conftest import LiveServer

STEPS = 6
#: How far inside the true C the contours' polygon of C may lie (K buffered with 8 segments per
#: quarter circle: R_col (1 - cos(pi / 32)) for R_col up to 2 m).
POLYGON_SLACK = 2.0 * (1.0 - math.cos(math.pi / 32)) + 1e-6
#: GeoJSON coordinates are rounded to the millimetre: each vertex moves by up to this.
ROUNDING = 0.5e-3 * math.sqrt(2.0) + 1e-9


def observation(t: float = 0.0) -> dict:
    return {
        "timestamp": t,
        "state": {"x": 0.0, "y": 0.0, "heading": 0.3, "speed": 6.0},
        "prediction": {
            "dt": 0.5,
            "mean": [[0.05, 0.3]] * STEPS,
            "cov": [[[0.02, 0.0], [0.0, 0.4]]] * STEPS,
        },
    }


@pytest.fixture(scope="module")
def agent(live_server: LiveServer) -> str:
    agent_id = f"batch-{uuid.uuid4().hex[:8]}"
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        answer = http.post(
            f"/v1/agents/{agent_id}/observations",
            params={"wait_frt_ms": 10_000},
            json=observation(),
        )
        assert answer.status_code == 200, answer.text
        assert answer.json()["frt_ready"]
    return agent_id


def check(http: httpx.Client, agent_id: str, body: dict) -> dict:
    answer = http.post(f"/v1/agents/{agent_id}/collision-check", json={"deadline_ms": 5000, **body})
    assert answer.status_code == 200, answer.text
    return answer.json()


def random_trajectories(rng: np.random.Generator, count: int, points: int) -> list[list[dict]]:
    """Straight lines through the region the agent's set covers, 0.1 s apart, random headings."""
    out = []
    for _ in range(count):
        start = rng.uniform([-5.0, -12.0], [30.0, 16.0])
        heading = rng.uniform(-math.pi, math.pi)
        speed = rng.uniform(0.0, 12.0)
        out.append(
            [
                {
                    "t": 0.1 * k,
                    "x": float(start[0] + speed * 0.1 * k * math.cos(heading)),
                    "y": float(start[1] + speed * 0.1 * k * math.sin(heading)),
                    "heading": float(heading),
                }
                for k in range(points)
            ]
        )
    return out


# ------------------------------------------------------------------------------- the disc cover


@settings(max_examples=200, deadline=None)
@given(
    length=st.floats(0.2, 12.0),
    width=st.floats(0.2, 4.0),
    ahead=st.floats(-2.0, 2.0),
    heading=st.floats(-math.pi, math.pi),
)
def test_the_discs_contain_the_box_with_the_fewest_discs(
    length: float, width: float, ahead: float, heading: float
) -> None:
    cover = disc_cover(length, width, ahead)
    centres = disc_centres(np.array([[1.0, -2.0]]), np.array([heading]), cover)
    footprint = rotate(
        translate(box(-length / 2, -width / 2, length / 2, width / 2), ahead, 0.0),
        heading,
        origin=(0.0, 0.0),
        use_radians=True,
    )
    footprint = translate(footprint, 1.0, -2.0)
    rng = np.random.default_rng(0)
    corners = np.array(footprint.exterior.coords)
    inside = [
        p
        for p in rng.uniform(corners.min(axis=0), corners.max(axis=0), size=(400, 2))
        if footprint.contains(Point(p))
    ]
    for p in [*corners, *inside]:
        assert np.min(np.hypot(*(centres - p).T)) <= cover.radius + 1e-9
    if cover.count < MAX_DISCS:
        assert cover.side_reach <= 0.1 + 1e-9
    if cover.count > 1:  # one disc fewer would reach further past the long sides
        assert math.hypot(length / (2 * (cover.count - 1)), width / 2) - width / 2 > 0.1


def test_footprint_distance_is_the_nearest_disc_less_its_radius() -> None:
    cover = disc_cover(4.0, 2.0)
    distances = np.arange(2 * cover.count, dtype=float)[None, :]
    result = footprint_distances(distances, cover)
    assert result.shape == (1, 2)
    assert result[0].tolist() == pytest.approx(
        [0.0 - cover.radius, float(cover.count) - cover.radius]
    )


# ------------------------------------------------------------------------------------- batches


def test_a_batch_answers_each_trajectory_as_a_single_check_would(
    live_server: LiveServer, agent: str
) -> None:
    rng = np.random.default_rng(1)
    trajectories = random_trajectories(rng, 24, 20)
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        for mode in ("tube", "time_indexed"):
            batch = check(http, agent, {"trajectories": trajectories, "mode": mode})
            columns = [
                {key: [p[key] for p in points] for key in ("t", "x", "y")}
                for points in trajectories
            ]
            as_columns = check(
                http, agent, {"trajectories": columns, "mode": mode, "include_clearance": True}
            )
            assert batch["clearance"] == [] and batch["first_collision_index"] is None
            assert batch["collision"] == any(t["collision"] for t in batch["trajectories"])
            collided = 0
            for k, points in enumerate(trajectories):
                single = check(http, agent, {"trajectory": points, "mode": mode})
                entry, full = batch["trajectories"][k], as_columns["trajectories"][k]
                assert entry["collision"] == single["collision"]
                assert entry["first_collision_index"] == single["first_collision_index"]
                assert entry["first_collision_time"] == single["first_collision_time"]
                assert entry["min_clearance"] == pytest.approx(min(single["clearance"]))
                assert "clearance" not in entry
                assert full["clearance"] == pytest.approx(single["clearance"])
                collided += entry["collision"]
            assert 0 < collided < len(trajectories)  # the sample meets the set and misses it


def test_a_batch_against_several_agents(live_server: LiveServer, agent: str) -> None:
    other = f"batch-{uuid.uuid4().hex[:8]}"
    rng = np.random.default_rng(2)
    trajectories = random_trajectories(rng, 8, 10)
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        http.post(f"/v1/agents/{other}/observations", json=observation()).raise_for_status()
        answer = http.post(
            "/v1/collision-check",
            json={"trajectories": trajectories, "agent_ids": [agent, other, "nobody"]},
        )
        assert answer.status_code == 200, answer.text
        body = answer.json()
        assert [r["agent_id"] for r in body["results"]] == [agent, other]
        assert body["missing"] == ["nobody"]
        for result in body["results"]:
            assert len(result["trajectories"]) == len(trajectories)
        single = check(http, agent, {"trajectory": trajectories[3]})
        assert body["results"][0]["trajectories"][3]["collision"] == single["collision"]


# ----------------------------------------------------------------------------------- footprints


def test_a_footprint_meeting_c_is_never_reported_clear(live_server: LiveServer, agent: str) -> None:
    length, width, ahead, radius = 4.8, 1.9, 1.4, 1.0
    cover = disc_cover(length, width, ahead)
    rng = np.random.default_rng(3)
    points = [p for t in random_trajectories(rng, 30, 10) for p in t]
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        c_set = shape(
            http.get(
                f"/v1/agents/{agent}/frt",
                params={"include": "C", "collision_radius": radius},
            ).json()["tube"]["C"]
        )
        answer = check(
            http,
            agent,
            {
                "trajectory": points,
                "collision_radius": radius,
                "footprint": {"length": length, "width": width, "rear_axle_to_center": ahead},
            },
        )
    assert not answer["conservative"]
    met = 0
    for p, clearance in zip(points, answer["clearance"], strict=True):
        footprint = translate(
            rotate(
                box(ahead - length / 2, -width / 2, ahead + length / 2, width / 2),
                p["heading"],
                origin=(0.0, 0.0),
                use_radians=True,
            ),
            p["x"],
            p["y"],
        )
        distance = footprint.distance(c_set)
        if footprint.intersects(c_set):
            met += 1
            assert clearance < ROUNDING
        else:  # a lower bound of the box's distance, short by at most the cover's overreach
            assert clearance <= distance + ROUNDING
            assert clearance >= distance - POLYGON_SLACK - cover.overreach - ROUNDING
    assert 0 < met < len(points)


# ------------------------------------------------------------------------------------ bad input


def agent_version(http: httpx.Client, agent_id: str) -> int:
    return http.get(f"/v1/agents/{agent_id}").json()["frt_version"]


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"trajectories": [[{"t": 0.0, "x": 0.0, "y": 0.0}]] * 1025}, "trajectories"),
        (
            {
                "trajectory": [{"t": 0.0, "x": 1.0, "y": 1.0}],
                "footprint": {"length": 4, "width": 2},
            },
            "trajectory.0.heading",
        ),
        (
            {
                "trajectories": [{"t": [0.0], "x": [1.0], "y": [1.0]}],
                "footprint": {"length": 4, "width": 2},
            },
            "trajectories.0.heading",
        ),
        (
            {
                "trajectory": [{"t": 0.0, "x": 1.0, "y": 1.0, "heading": 0.0}],
                "footprint": {"length": -4, "width": 2},
            },
            "footprint.length",
        ),
        ({"trajectories": [{"t": [0.0, 0.1], "x": [1.0], "y": [1.0, 2.0]}]}, "trajectories.0"),
        ({"trajectories": []}, "trajectories"),
        ({}, "body"),
        (
            {
                "trajectory": [{"t": 0.0, "x": 0.0, "y": 0.0}],
                "trajectories": [[{"t": 0.0, "x": 0.0, "y": 0.0}]],
            },
            "body",
        ),
    ],
)
def test_bad_batch_input_is_a_422_naming_the_field_and_changes_nothing(
    live_server: LiveServer, agent: str, body: dict, field: str
) -> None:
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        before = agent_version(http, agent)
        answer = http.post(f"/v1/agents/{agent}/collision-check", json=body)
        assert answer.status_code == 422, answer.text
        assert answer.json()["field"].startswith(field), answer.json()
        assert agent_version(http, agent) == before


def test_a_nan_heading_is_a_422_naming_it(live_server: LiveServer, agent: str) -> None:
    body = '{"trajectory": [{"t": 0, "x": 0, "y": 0, "heading": NaN}], "footprint": {"length": 4, "width": 2}}'
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        answer = http.post(
            f"/v1/agents/{agent}/collision-check",
            content=body,
            headers={"content-type": "application/json"},
        )
    assert answer.status_code == 422
    assert answer.json()["field"] == "trajectory.0.heading"


def test_too_much_work_for_one_check_is_a_422(live_server: LiveServer, agent: str) -> None:
    points = [{"t": 0.01 * k, "x": 0.0, "y": 0.0, "heading": 0.0} for k in range(1000)]
    body = {"trajectories": [points] * 120, "footprint": {"length": 4.8, "width": 1.9}}
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        answer = http.post(f"/v1/agents/{agent}/collision-check", content=json.dumps(body))
    assert answer.status_code == 422
    assert answer.json()["field"] == "trajectories"


# ------------------------------------------------------------------------- packed trajectories


def packed(trajectories: list[list[dict]], keys: tuple[str, ...] = ("t", "x", "y")) -> dict:
    """The batch as packed columns: base64 of little-endian float64s, built here by numpy."""
    out: dict = {"lengths": [len(points) for points in trajectories]}
    for key in keys:
        numbers = np.array([p[key] for points in trajectories for p in points], dtype="<f8")
        out[key] = base64.b64encode(numbers.tobytes()).decode()
    return out


def as_entries(columns: dict) -> list[dict]:
    """A batch's answers as columns turned into its entries."""
    rows = zip(*columns.values(), strict=True)
    return [dict(zip(columns, row, strict=True)) for row in rows]


def test_packed_batches_and_answers_as_columns_are_the_entries_of_the_same_batch(
    live_server: LiveServer, agent: str
) -> None:
    """Random batches of random lengths, both modes, with and without a footprint and per-point
    clearances, against two agents: sent packed, and answered as columns, each agent's answers
    are the default form's (columns in, an entry per trajectory out), entry for entry."""
    rng = np.random.default_rng(8)
    footprint = {"length": 4.8, "width": 1.9, "rear_axle_to_center": 1.4}
    keys = ("t", "x", "y", "heading")
    other = f"batch-{uuid.uuid4().hex[:8]}"
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        http.post(
            f"/v1/agents/{other}/observations",
            params={"wait_frt_ms": 10_000},
            json={**observation(), "state": {"x": 10.0, "y": 3.0, "heading": 2.0, "speed": 4.0}},
        ).raise_for_status()
        for trial in range(8):
            trajectories = [
                random_trajectories(rng, 1, int(rng.integers(1, 25)))[0]
                for _ in range(int(rng.integers(1, 40)))
            ]
            options = {
                "agent_ids": [agent, other],
                "deadline_ms": 5000,
                "mode": ("tube", "time_indexed")[trial % 2],
                "include_clearance": trial % 3 == 0,
                **({"footprint": footprint} if trial >= 4 else {}),
            }
            columns = [{k: [p[k] for p in points] for k in keys} for points in trajectories]
            bodies = (
                {"trajectories": columns},
                {"packed_trajectories": packed(trajectories, keys)},
                {"packed_trajectories": packed(trajectories, keys), "answer_columns": True},
                {"trajectories": columns, "answer_columns": True},
            )
            answers = [http.post("/v1/collision-check", json={**options, **b}) for b in bodies]
            assert all(a.status_code == 200 for a in answers), [a.text for a in answers]
            default, *others = (a.json()["results"] for a in answers)
            assert any(t["collision"] for r in default for t in r["trajectories"])
            for results in others:
                for mine, theirs in zip(results, default, strict=True):
                    assert mine["verdict"] == theirs["verdict"] == "exact"
                    assert mine["collision"] == theirs["collision"]
                    if "trajectory_columns" in mine:
                        assert "trajectories" not in mine
                        assert as_entries(mine["trajectory_columns"]) == theirs["trajectories"]
                    else:
                        assert mine["trajectories"] == theirs["trajectories"]


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"x": "not base64!"}, "packed_trajectories.x"),
        ({"y": base64.b64encode(b"1234567").decode()}, "packed_trajectories.y"),
        (
            {"t": base64.b64encode(np.array([0.0, np.nan]).tobytes()).decode()},
            "packed_trajectories.t",
        ),
        (
            {"heading": base64.b64encode(np.array([0.0, np.nan]).tobytes()).decode()},
            "packed_trajectories.heading",
        ),
        ({"x": base64.b64encode(np.array([1e8, 0.0]).tobytes()).decode()}, "packed_trajectories.x"),
        ({"lengths": [1, 2]}, "packed_trajectories"),
        ({"lengths": [0, 2]}, "packed_trajectories.lengths.0"),
        ({"lengths": [2] * 1025}, "packed_trajectories"),
        ({"footprint": {"length": 4, "width": 2}}, "packed_trajectories.heading"),
        ({"trajectory": [{"t": 0.0, "x": 0.0, "y": 0.0}]}, "body"),
        ({"colour": "red"}, "packed_trajectories.colour"),
        ({"answer_columns": "yes"}, "answer_columns"),
    ],
)
def test_bad_packed_input_is_a_422_naming_the_field_and_changes_nothing(
    live_server: LiveServer, agent: str, change: dict, field: str
) -> None:
    body = packed([[{"t": 0.0, "x": 1.0, "y": 1.0}, {"t": 0.1, "x": 2.0, "y": 1.0}]])
    outside = {
        k: change.pop(k) for k in ("footprint", "trajectory", "answer_columns") if k in change
    }
    if change.get("lengths") == [2] * 1025:
        body = packed([[{"t": 0.0, "x": 1.0, "y": 1.0}] * 2] * 1025)
        change = {}
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        before = agent_version(http, agent)
        answer = http.post(
            f"/v1/agents/{agent}/collision-check",
            json={"packed_trajectories": {**body, **change}, **outside},
        )
        assert answer.status_code == 422, answer.text
        assert answer.json()["field"] == field, answer.json()
        assert agent_version(http, agent) == before


# ------------------------------------------------------------------------------------------ SDK


def test_the_sdk_sends_a_batch_with_a_footprint_over_http_and_the_stream(
    live_server: LiveServer, agent: str
) -> None:
    rng = np.random.default_rng(4)
    trajectories = random_trajectories(rng, 12, 15)
    # (M, N, 4) rows (t, x, y, heading): the array form a sampling planner holds.
    array = np.array([[[p["t"], p["x"], p["y"], p["heading"]] for p in t] for t in trajectories])
    footprint = {"length": 4.8, "width": 1.9, "rear_axle_to_center": 1.4}
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        raw = check(
            http,
            agent,
            {"trajectories": trajectories, "footprint": footprint, "include_clearance": True},
        )
    with FRTClient(live_server.url) as frt, frt.stream() as stream:
        answers = [
            call(
                agent,
                trajectories=array,
                footprint=(4.8, 1.9, 1.4),
                include_clearance=True,
                deadline_ms=5000,
            )
            for call in (frt.collision_check, stream.collision_check)
        ]
        many = frt.collision_check_many(
            agent_ids=[agent], trajectories=array, footprint=footprint, deadline_ms=5000
        )
        with pytest.raises(ValidationError):
            frt.collision_check(agent, array[0], trajectories=array)
    for answer in [*answers, many.results[0]]:
        assert answer.trajectories is not None
        assert [t.collision for t in answer.trajectories] == [
            t["collision"] for t in raw["trajectories"]
        ]
        assert [t.min_clearance for t in answer.trajectories] == pytest.approx(
            [t["min_clearance"] for t in raw["trajectories"]]
        )
    assert answers[0].trajectories[0].clearance == pytest.approx(
        raw["trajectories"][0]["clearance"]
    )
    assert many.results[0].trajectories[0].clearance is None
    assert any(t["collision"] for t in raw["trajectories"])


# ------------------------------------------------------------------------------ the bulk parser


def test_the_bulk_parser_reads_a_batch_as_the_model_does() -> None:
    body = {
        "trajectories": [
            {"t": [0, 0.1, 0.2], "x": [1.5, 2, -3e6], "y": [0.0, 1.0, 2.0]},
            {"t": [0.0], "x": [1.0], "y": [2.0], "heading": [0.5]},
        ],
        "mode": "time_indexed",
        "footprint": {"length": 4.0, "width": 2.0},
        "agent_ids": None,
    }
    raw = json.dumps(body).encode()
    bulk = parse_batch_check(raw, MultiCollisionCheckRequest)
    model = MultiCollisionCheckRequest.model_validate_json(raw)
    assert bulk is not None
    assert bulk.model_dump(exclude={"trajectories"}) == model.model_dump(exclude={"trajectories"})
    for ours, theirs in zip(bulk.trajectories, model.trajectories, strict=True):
        for key in ("t", "x", "y", "heading"):
            a, b = getattr(ours, key), getattr(theirs, key)
            assert (a is None) == (b is None)
            if a is not None:
                assert np.asarray(a).tolist() == b


@pytest.mark.parametrize(
    "rest",
    [
        {"mode": "time_indexed", "footprint": {"length": 4, "width": 2.0}, "agent_ids": None},
        {"include_clearance": True, "answer_columns": True, "deadline_ms": 20},
        {"collision_radius": True},  # a boolean where a number goes: both refuse it
        {"deadline_ms": "20"},
        {"trajectories": [{"t": [0.0], "x": [1.0], "y": [2.0]}]},
    ],
)
def test_the_bulk_parser_reads_a_packed_batch_as_the_model_does(rest: dict) -> None:
    trajectories = [[{"t": 0.1 * k, "x": 1.5 * k, "y": -2.0, "heading": 0.3} for k in range(3)]]
    body = {"packed_trajectories": packed(trajectories, ("t", "x", "y", "heading")), **rest}
    raw = json.dumps(body).encode()
    bulk = parse_batch_check(raw, MultiCollisionCheckRequest)
    try:
        model = MultiCollisionCheckRequest.model_validate_json(raw)
    except PydanticValidationError:
        assert bulk is None
        return
    assert bulk is not None
    assert bulk.model_dump_json() == model.model_dump_json()


@pytest.mark.parametrize(
    "trajectories",
    [
        [{"t": [0.0, True], "x": [1.0, 2.0], "y": [1.0, 2.0]}],  # a boolean
        [{"t": [0.0, "1"], "x": [1.0, 2.0], "y": [1.0, 2.0]}],  # a string
        [{"t": [0.0, None], "x": [1.0, 2.0], "y": [1.0, 2.0]}],
        [{"t": [0.0, 0.1], "x": [1.0], "y": [1.0, 2.0]}],  # lengths differ
        [{"t": [0.0], "x": [1e8], "y": [1.0]}],  # beyond the coordinates' limit
        [{"t": [0.0], "x": [1.0], "y": [1.0], "heading": [1e5]}],
        [{"t": [0.0], "x": [1.0], "y": [1.0], "speed": [1.0]}],  # an unknown column
        [{"t": [0.0], "x": [1.0]}],
        [{"t": [], "x": [], "y": []}],
        [[{"t": 0.0, "x": 1.0, "y": 1.0}]],  # the point form: the model's to read
        [],
    ],
)
def test_the_bulk_parser_leaves_what_it_does_not_take_to_the_model(trajectories: list) -> None:
    raw = json.dumps({"trajectories": trajectories}).encode()
    assert parse_batch_check(raw, CollisionCheckRequest) is None


def test_the_bulk_parser_leaves_a_bad_rest_of_the_body_to_the_model() -> None:
    good = [{"t": [0.0], "x": [1.0], "y": [1.0]}]
    for body in (
        {"trajectories": good, "mode": "sideways"},
        {"trajectories": good, "trajectory": [{"t": 0.0, "x": 0.0, "y": 0.0}]},
        {"trajectories": good, "deadline_ms": "5"},
    ):
        assert parse_batch_check(json.dumps(body).encode(), CollisionCheckRequest) is None
    assert parse_batch_check(b'{"trajectories": [{"t": [NaN]', CollisionCheckRequest) is None


def test_a_body_with_booleans_elsewhere_is_read_in_bulk_as_the_model_reads_it() -> None:
    body = {
        "trajectories": [
            {"t": [0.0, 0.1], "x": [1.0, 2.0], "y": [3, 4]},
            {"t": [0.0, 0.1], "x": [5.0, 6.0], "y": [7.0, 8.0]},
        ],
        "include_clearance": True,
        "agent_ids": ["true-car"],
    }
    raw = json.dumps(body).encode()
    bulk = parse_batch_check(raw, MultiCollisionCheckRequest)
    model = MultiCollisionCheckRequest.model_validate_json(raw)
    assert bulk is not None and bulk.include_clearance
    assert [np.asarray(p.y).tolist() for p in bulk.trajectories] == [
        p.y for p in model.trajectories
    ]


def _points_of(body: dict) -> tuple[CheckPoints | None, FieldError | None]:
    """check_points of ``body`` read in bulk and read by the model (the same or both raising)."""
    raw = json.dumps(body).encode()
    bulk = parse_batch_check(raw, MultiCollisionCheckRequest)
    assert bulk is not None
    limits = Settings(max_trajectory_points=3, max_trajectories=3)
    found = []
    for request in (bulk, MultiCollisionCheckRequest.model_validate_json(raw)):
        try:
            found.append((check_points(request, limits), None))
        except FieldError as error:
            found.append((None, error))
    (ours, our_error), (theirs, their_error) = found
    if our_error is not None or their_error is not None:
        assert our_error is not None and their_error is not None
        assert (our_error.field, str(our_error)) == (their_error.field, str(their_error))
        return None, our_error
    assert ours is not None and theirs is not None
    for key in ("xy", "times", "starts", "headings"):
        np.testing.assert_array_equal(getattr(ours, key), getattr(theirs, key))
    assert ours.cover == theirs.cover
    return ours, None


@pytest.mark.parametrize(
    "change",
    [
        {},
        {"footprint": {"length": 4.0, "width": 2.0}},  # a trajectory without headings
        {"trajectories": [{"t": [0.0, 0.1, 0.2, 0.3], "x": [0.0] * 4, "y": [0.0] * 4}]},
        {"trajectories": [{"t": [0.0], "x": [0.0], "y": [0.0]}] * 4},
    ],
)
def test_a_batch_read_in_bulk_has_the_models_points_and_errors(change: dict) -> None:
    body = {
        "trajectories": [
            {
                "t": [0.0, 0.1, 0.2],
                "x": [1.0, 2.0, 3.0],
                "y": [0.0, 0.5, 1.0],
                "heading": [0.1] * 3,
            },
            {"t": [0.5], "x": [-1.0], "y": [2.0]},
        ],
        **change,
    }
    points, error = _points_of(body)
    assert (error is None) == (change == {})
    if points is not None:
        assert points.starts.tolist() == [0, 3]


@pytest.mark.parametrize(
    ("raw", "found"),
    [
        (b'{"a": true}', True),
        (b'{"a": [1.0, false]}', True),
        (b"true", True),
        (b'{"a": "tru", "b": "alse"}', False),
        (b'{"trajectories": [{"t": [0.1]}]}', False),
        (b"", False),
        (b"fals", False),
    ],
)
def test_the_bulk_parser_finds_every_boolean_token(raw: bytes, found: bool) -> None:
    assert holds_booleans(raw) is found
    assert found is any(token in raw for token in (b"true", b"false"))


def test_recent_checks_keep_a_batchs_verdicts_without_its_entries() -> None:
    entries = [
        {
            "collision": k == 1,
            "first_collision_index": 0 if k == 1 else None,
            "first_collision_time": 0.1 if k == 1 else None,
            "min_clearance": -0.5 if k == 1 else 2.0,
        }
        for k in range(3)
    ]
    common = {
        "first_collision_index": None,
        "first_collision_time": None,
        "clearance": [],
        "mode": "tube",
        "collision_radius": 1.0,
        "beta": 1.0,
        "frt_version": 1,
        "conservative": False,
        "horizon_end": 3.0,
    }
    batch = CollisionCheckResponse.model_construct(
        collision=True, trajectories=entries, agent_id="a", **common
    )
    as_columns = CollisionCheckResponse.model_construct(
        collision=True,
        trajectory_columns={k: [e[k] for e in entries] for k in entries[0]},
        agent_id="c",
        **common,
    )
    single = CollisionCheckResponse.model_construct(
        collision=False, trajectories=None, agent_id="b", **common
    )
    recent = RecentChecks()
    recent.record(
        CollisionCheckRequest(trajectory=[{"t": 0.0, "x": 0.0, "y": 0.0}]),
        [batch, single, as_columns],
    )
    ((_, _, kept),) = recent._checks
    assert kept[2].trajectory_columns is None and as_columns.trajectory_columns is not None
    assert kept[1] is single
    assert kept[0].trajectories is None and batch.trajectories == entries
    assert kept[0].model_dump(exclude={"trajectories"}) == batch.model_dump(
        exclude={"trajectories"}
    )


def test_the_sdk_packs_a_batch_as_the_service_reads_it() -> None:
    """An array and a list of trajectories of several lengths, packed by the SDK and read by the
    request model, give the points as sent; a batch whose trajectories differ in carrying
    headings is left to the columns form."""
    rng = np.random.default_rng(12)
    array = rng.uniform(-50.0, 50.0, size=(7, 5, 4))
    ragged = [rng.uniform(-50.0, 50.0, size=(int(n), 3)).tolist() for n in (1, 4, 9)]
    for batch in (array, array[..., :3], ragged):
        body = {"packed_trajectories": inputs.packed_trajectories(batch)}
        read = packed_batch(
            CollisionCheckRequest.model_validate_json(json.dumps(body)).packed_trajectories
        )
        for k, sent in enumerate(batch):
            rows = np.asarray(sent)
            got = read[k]
            assert np.array_equal(got.t, rows[:, 0]) and np.array_equal(got.x, rows[:, 1])
            assert np.array_equal(got.y, rows[:, 2])
            assert (got.heading is None) == (rows.shape[1] == 3)
            if got.heading is not None:
                assert np.array_equal(got.heading, rows[:, 3])
    mixed = [array[0].tolist(), array[1, :, :3].tolist()]
    assert inputs.packed_trajectories(mixed) is None


@settings(max_examples=300, deadline=None)
@given(numbers=st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=40))
def test_binary64_columns_read_as_the_standard_library_decodes_them(numbers: list) -> None:
    raw = np.array(numbers, dtype="<f8").tobytes()
    read = read_binary64(base64.b64encode(raw).decode())
    assert read is not None and read.tobytes() == raw and read.flags.writeable


@pytest.mark.parametrize(
    "text",
    [
        "A===",
        "====",
        "AAAAAAAAAA=A",
        "AAAAAAAAAAA",  # not a multiple of four
        "AAAAAAAA AAA",
        "AAAAAAAAAAA=\n",
        "AAAAAAAAAAA==AAA",
        "éAAAAAAAAAA=",
        base64.b64encode(b"1234567").decode(),  # 7 bytes: no whole float
        base64.b64encode(b"123456789").decode(),
        "AAAAAAAAAA-=",  # the URL-safe alphabet's
    ],
)
def test_binary64_columns_refuse_what_is_not_padded_base64_of_float64s(text: str) -> None:
    assert read_binary64(text) is None


def test_recent_checks_draw_a_packed_batchs_first_trajectory() -> None:
    trajectories = [
        [{"t": 0.1 * k, "x": 2.0 * k, "y": 1.0} for k in range(4)],
        [{"t": 0.0, "x": 9.0, "y": 9.0}],
    ]
    request = CollisionCheckRequest.model_validate_json(
        json.dumps({"packed_trajectories": packed(trajectories)})
    )
    recent = RecentChecks()
    recent.record(request, [])
    (drawn,) = recent.recent()
    assert drawn["trajectory"] == [[p["t"], p["x"], p["y"]] for p in trajectories[0]]


def test_disc_centres_are_each_point_plus_its_offsets_along_its_heading() -> None:
    """Bit for bit the broadcast ``xy + offset * (cos, sin)``, for a few covers."""
    rng = np.random.default_rng(13)
    xy = rng.uniform(-1e4, 1e4, size=(500, 2))
    heading = rng.uniform(-30.0, 30.0, size=500)
    direction = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    for length, width, ahead in ((4.8, 1.9, 1.4), (1.0, 1.0, 0.0), (12.0, 2.5, -3.0)):
        cover = disc_cover(length, width, ahead)
        expected = xy[:, None, :] + cover.offsets[None, :, None] * direction[:, None, :]
        assert np.array_equal(disc_centres(xy, heading, cover), expected.reshape(-1, 2))
