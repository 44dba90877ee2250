"""Constraints for MPC (API.md, "Batch checks, footprints, constraints"): per requested time, convex
pieces ``A x <= b`` in the world frame whose union contains C = K ⊕ R_col.

Ground truth is independent of ``reach.constraints``:

* positions reached at exactly t by RK4 rollouts of the dynamics under the set's own control
  bounds (``models.rollout``, the evaluation's mix of extremal and switching schedules), each moved
  by R_col in 32 directions and along every side's normal: points of the true C. Against the
  service they run on a server whose sets are the certified geometry alone (``FRT_NETWORK=off``,
  so no value field cuts where the rollouts go), with each agent's served control bounds (every
  mode's in the set, for a mixture);
* the vertices of C as the contours route draws it (the served set's K buffered by R_col);
* random unions of boxes, discs and crescents (some far apart, some not convex): their vertices
  moved by r in 32 directions, and random points within r of them.

Tightness: the pieces' total area (each piece cut from a large box by its half-planes, not read
from its vertices) over the area of C's polygon, which lies inside the true C.
"""

from __future__ import annotations

import asyncio
import math
import uuid

import httpx
import numpy as np
import pytest
import shapely
from frt_client import AgentConstraints, AsyncFRTClient, FRTClient, NotFoundError, ValidationError
from shapely.affinity import rotate
from shapely.geometry import Point, Polygon, box, shape

from models.rollout import rk4_rollout, sample_initial_states, sample_reference_schedules
from reach.agent_classes import agent_class
from reach.constraints import ConvexPiece, outer_pieces, slice_pieces
from reach.contract import BOUND_COLUMNS, COL, HORIZON_S, N_INPUTS
from reach.engine import FRTEngine
from reach.frames import Pose
from reach.union import conservative_union, exact_union
from tests.conftest import LiveServer

#: GeoJSON coordinates are rounded to the millimetre: each vertex moves by up to this.
ROUNDING = 0.5e-3 * math.sqrt(2.0) + 1e-9
#: Times asked: on the 0.1 s grid, between its instants, and the ends of the horizon.
TIMES = (0.0, 0.05, 0.35, 1.0, 1.55, 2.0, 2.95, 3.0)
#: The pieces' total area over the area of C's polygon: at most this.
AREA_FACTOR = 1.10
DIRECTIONS = 32


# ------------------------------------------------------------------------------- ground truth


def positions_at(v_start: float, bounds: np.ndarray, t: float, n: int, seed: int) -> np.ndarray:
    """Positions [n, 2] reached at exactly t (human frame) by rollouts of the true dynamics."""
    rng = np.random.default_rng(seed)
    params = np.zeros((n, N_INPUTS))
    params[:, COL["v_start"]] = v_start
    params[:, 6:] = bounds
    start = sample_initial_states(params[:, COL["v_start"]], rng, on_boundary=0.5)
    if t == 0.0:
        return np.stack(start[:2], axis=1)
    a1, a2, switches = sample_reference_schedules(n, HORIZON_S, rng)
    steps = max(2, round(t / 0.01))
    end, _ = rk4_rollout(start, params, np.full(n, t), a1, a2, switches * (t / HORIZON_S), steps)
    return np.stack(end[:2], axis=1)


def to_world(xy: np.ndarray, pose: Pose) -> np.ndarray:
    c, s = math.cos(pose.heading), math.sin(pose.heading)
    return xy @ np.array([[c, s], [-s, c]]) + np.array([pose.x, pose.y])


def moved_by(xy: np.ndarray, radius: float, normals: np.ndarray) -> np.ndarray:
    """Each point, and each point moved by ``radius`` in 32 directions and along each normal."""
    angles = 2.0 * math.pi * np.arange(DIRECTIONS) / DIRECTIONS
    steps = np.concatenate([np.stack([np.cos(angles), np.sin(angles)], axis=1), normals])
    return np.concatenate([xy, (xy[:, None, :] + radius * steps[None, :, :]).reshape(-1, 2)])


def outside(pieces: list[ConvexPiece], xy: np.ndarray, tolerance: float = 0.0) -> np.ndarray:
    """The points of ``xy`` in no piece."""
    inside = np.zeros(len(xy), dtype=bool)
    for piece in pieces:
        inside |= piece.contains(xy, tolerance)
    return xy[~inside]


def half_plane_polygon(a: np.ndarray, b: np.ndarray) -> Polygon:
    """{x : a x <= b} cut from a 10 km box, one half-plane at a time."""
    polygon = box(-1e4, -1e4, 1e4, 1e4)
    for (ax, ay), offset in zip(a, b, strict=True):
        # The half-plane as a large rectangle on the inner side of its line.
        foot = np.array([ax, ay]) * offset
        along = np.array([-ay, ax])
        corners = [foot + 3e4 * along, foot - 3e4 * along]
        corners += [corners[1] - 3e4 * np.array([ax, ay]), corners[0] - 3e4 * np.array([ax, ay])]
        polygon = polygon.intersection(Polygon(corners))
    return polygon


# -------------------------------------------------------------------- reach.constraints alone


def random_shape(rng: np.random.Generator) -> shapely.Geometry:
    """A union of 1-5 boxes, discs and crescents, scattered so some overlap and some do not."""
    parts = []
    for _ in range(int(rng.integers(1, 6))):
        centre = rng.uniform(-25.0, 25.0, 2)
        kind = rng.integers(0, 3)
        if kind == 0:
            length, width = rng.uniform(0.3, 20.0), rng.uniform(0.2, 5.0)
            part = box(-length / 2, -width / 2, length / 2, width / 2)
            part = rotate(part, rng.uniform(0, 180))
        elif kind == 1:
            part = Point(0, 0).buffer(rng.uniform(0.3, 6.0), quad_segs=int(rng.integers(1, 12)))
        else:
            outer = rng.uniform(3.0, 12.0)
            crescent = (
                Point(0, 0).buffer(outer).difference(Point(outer * 0.4, 0).buffer(outer * 0.9))
            )
            part = rotate(crescent, rng.uniform(0, 360), origin=(0, 0))
        parts.append(shapely.affinity.translate(part, *centre))
    return shapely.union_all(parts)


@pytest.mark.parametrize("seed", range(40))
def test_the_pieces_contain_c_of_random_shapes(seed: int) -> None:
    rng = np.random.default_rng(seed)
    k_set = random_shape(rng)
    radius = float(rng.choice([0.0, rng.uniform(0.1, 3.0)]))
    max_sides, max_pieces = int(rng.integers(3, 65)), int(rng.integers(1, 17))
    pieces = outer_pieces(k_set, radius, max_sides, max_pieces)
    assert 1 <= len(pieces) <= max_pieces
    for piece in pieces:
        assert 3 <= len(piece.normals) <= max_sides
        assert np.allclose(np.hypot(*piece.normals.T), 1.0, atol=1e-12)
        assert piece.contains(piece.corners, 1e-6).all()
    vertices = shapely.get_coordinates(k_set)
    low, high = vertices.min(axis=0) - radius, vertices.max(axis=0) + radius
    random = rng.uniform(low, high, (4000, 2))
    random = random[shapely.distance(k_set, shapely.points(random)) <= radius]
    points = np.concatenate([moved_by(vertices, radius, np.zeros((0, 2))), random])
    assert len(outside(pieces, points)) == 0
    pose = Pose(*rng.uniform(-1e5, 1e5, 2), rng.uniform(-10.0, 10.0))
    world = [piece.in_world(pose) for piece in pieces]
    assert len(outside(world, to_world(points, pose))) == 0
    for piece in pieces + world:  # corner i on the lines of sides i and i + 1
        on_side = np.sum(piece.corners * piece.normals, axis=1) - piece.offsets
        following = np.roll(piece.normals, -1, axis=0)
        on_next = np.sum(piece.corners * following, axis=1) - np.roll(piece.offsets, -1)
        assert np.abs(on_side).max() < 1e-6 and np.abs(on_next).max() < 1e-6


def test_a_convex_set_is_one_tight_piece_and_a_triangle_still_holds_it() -> None:
    k_set = Point(0, 0).buffer(5.0, quad_segs=4)  # a 16-gon
    (piece,) = outer_pieces(k_set, 1.5, max_sides=16, max_pieces=16)
    assert piece.area() / k_set.buffer(1.5, quad_segs=64).area < 1.03
    (triangle,) = outer_pieces(k_set, 1.5, max_sides=3, max_pieces=1)
    assert len(triangle.normals) == 3
    ring = shapely.get_coordinates(k_set.buffer(1.5, quad_segs=64))
    assert len(outside([triangle], ring)) == 0


def test_parts_far_apart_get_a_piece_each_and_an_l_is_cut() -> None:
    two = shapely.union_all([Point(0, 0).buffer(2.0), Point(60, 0).buffer(2.0)])
    pieces = outer_pieces(two, 1.0, max_pieces=4)
    assert len(pieces) == 2
    assert sum(p.area() for p in pieces) < 1.05 * two.buffer(1.0).area
    (hull,) = outer_pieces(two, 1.0, max_pieces=1)
    assert hull.area() > 5 * two.buffer(1.0).area
    ell = shapely.union_all([box(0, 0, 30, 2), box(0, 0, 2, 30)])
    cut = outer_pieces(ell, 0.5, max_pieces=4)
    (whole,) = outer_pieces(ell, 0.5, max_pieces=1)
    c_area = ell.buffer(0.5).area
    assert len(cut) >= 2
    assert sum(p.area() for p in cut) < 1.2 * c_area < whole.area()


def test_out_of_range_counts_are_refused() -> None:
    for sides, pieces in ((2, 4), (65, 4), (16, 0), (16, 17)):
        with pytest.raises(ValueError):
            outer_pieces(Point(0, 0).buffer(1.0), 1.0, sides, pieces)


# ------------------------------------------------------------ the engine's sets, every kind


def full_bounds(name: str) -> np.ndarray:
    k = agent_class(name)
    return np.array([-k.u1_limit, -k.u2_limit] * 2 + [k.u1_limit, k.u2_limit] * 2)


SETS = [
    ("car", 8.0, np.array([-0.3, -2.0, -0.2, -1.0, 0.2, 1.5, 0.3, 2.0])),
    ("car", 15.0, np.array([-0.05, -4.0, -0.05, -4.0, 0.05, 0.5, 0.05, 0.5])),
    ("pedestrian", 1.4, full_bounds("pedestrian")),
    ("cyclist", 0.0, full_bounds("cyclist")),
]


@pytest.mark.parametrize(("name", "speed", "bounds"), SETS, ids=[f"{n}-{v}" for n, v, _ in SETS])
def test_exact_and_conservative_sets_pieces_hold_rollouts(
    name: str, speed: float, bounds: np.ndarray
) -> None:
    engine = FRTEngine(ranges=agent_class(name).ranges())
    pose = Pose(120.0, -40.0, 2.2)
    radius = agent_class(name).collision_radius_m
    for frt in (engine.exact(pose, speed, bounds), engine.conservative(pose, speed, bounds)):
        for t in TIMES:
            pieces = slice_pieces(frt, t, radius)
            normals = np.concatenate([p.normals for p in pieces])
            reached = to_world(positions_at(speed, bounds, t, 1500, seed=round(100 * t)), pose)
            missed = outside(pieces, moved_by(reached, radius, normals))
            assert len(missed) == 0, (name, speed, frt.conservative, t, missed[:3])


def test_a_union_of_modes_pieces_hold_every_modes_rollouts() -> None:
    engine = FRTEngine()
    modes = np.array(
        [
            [0.2, 0.0, 0.2, 0.0, 0.4, 1.0, 0.4, 1.0],  # left
            [-0.4, 0.0, -0.4, 0.0, -0.2, 1.0, -0.2, 1.0],  # right
            [-0.02, -6.0, -0.02, -6.0, 0.02, -4.0, 0.02, -4.0],  # braking hard
        ]
    )
    pose = Pose(-3.0, 7.0, -0.4)
    for frt in (
        exact_union(engine, pose, 10.0, modes),
        conservative_union(engine, pose, 10.0, modes),
    ):
        for t in (0.5, 1.55, 3.0):
            pieces = slice_pieces(frt, t, 1.5, max_pieces=4)
            normals = np.concatenate([p.normals for p in pieces])
            for m, bounds in enumerate(modes):
                reached = to_world(positions_at(10.0, bounds, t, 1000, seed=m), pose)
                assert len(outside(pieces, moved_by(reached, 1.5, normals))) == 0, (m, t)


# ------------------------------------------------------------------------------- the service

STEPS = 6


def prediction(mean: list[float], cov: list[float]) -> dict:
    return {"dt": 0.5, "mean": [mean] * STEPS, "cov": [[[cov[0], 0.0], [0.0, cov[1]]]] * STEPS}


def state(x: float, y: float, heading: float, speed: float) -> dict:
    return {"x": x, "y": y, "heading": heading, "speed": speed}


#: (name, observations): cars slow, urban and fast, a pedestrian, a cyclist, a car whose predictor
#: was wrong (low beta: wide bounds) and a car with three modes (left, straight and braking).
AGENTS = {
    "car-urban": [
        {"state": state(5.0, -3.0, 0.3, 8.0), "prediction": prediction([0.05, 0.3], [0.02, 0.4])}
    ],
    "car-fast": [
        {
            "state": state(-20.0, 40.0, -2.0, 15.0),
            "prediction": prediction([0.0, -0.5], [0.01, 0.25]),
        }
    ],
    "car-creeping": [
        {"state": state(0.0, 0.0, 3.0, 1.0), "prediction": prediction([0.3, 0.5], [0.05, 0.5])}
    ],
    "pedestrian": [
        {
            "agent_class": "pedestrian",
            "state": state(3.0, 3.0, 1.2, 1.4),
            "prediction": prediction([0.2, 0.0], [0.5, 0.3]),
        }
    ],
    "cyclist": [
        {
            "agent_class": "cyclist",
            "state": state(-5.0, 2.0, -0.7, 5.0),
            "prediction": prediction([0.0, 0.2], [0.1, 0.5]),
        }
    ],
    "car-low-beta": [
        {"state": state(10.0, 10.0, 1.0, 6.0), "prediction": prediction([0.0, 0.0], [0.01, 0.1])},
        {
            "state": state(11.5, 12.6, 1.1, 5.0),
            "observed_action": {"steering_rate": 0.5, "acceleration": -2.5},
            "prediction": prediction([0.0, 0.0], [0.01, 0.1]),
        },
    ],
    "car-modes": [
        {
            "state": state(0.0, -8.0, 0.5, 10.0),
            "prediction": {
                "dt": 0.5,
                "modes": [
                    {
                        "weight": w,
                        **{k: v for k, v in prediction(m, [0.005, 0.05]).items() if k != "dt"},
                    }
                    for w, m in ((0.4, [0.35, 0.0]), (0.4, [0.0, 0.5]), (0.2, [-0.05, -5.0]))
                ],
            },
        }
    ],
}


def observe(http: httpx.Client, agent_id: str, observations: list[dict]) -> dict:
    """The observations in turn, 0.5 s apart; the last answer, its exact set ready."""
    for k, body in enumerate(observations):
        answer = http.post(
            f"/v1/agents/{agent_id}/observations",
            params={"wait_frt_ms": 10_000},
            json={"timestamp": 100.0 + 0.5 * k, "observed_action": None, **body},
        )
        assert answer.status_code == 200, answer.text
    result = answer.json()
    assert result["frt_ready"]
    return result


def bounds_of(observation: dict) -> list[np.ndarray]:
    """The control bounds of every mode in the served set (or of the one Gaussian)."""
    modes = observation.get("modes") or [
        {"in_set": True, "control_bounds": observation["control_bounds"]}
    ]
    return [np.array([m["control_bounds"][c] for c in BOUND_COLUMNS]) for m in modes if m["in_set"]]


def constraints(http: httpx.Client, agent_id: str, **params: object) -> dict:
    answer = http.get(f"/v1/agents/{agent_id}/constraints", params=params)
    assert answer.status_code == 200, answer.text
    return answer.json()


def pieces_of(slice_: dict) -> list[ConvexPiece]:
    return [
        ConvexPiece(np.array(p["A"]), np.array(p["b"]), np.array(p["vertices"]))
        for p in slice_["pieces"]
    ]


@pytest.fixture(scope="module")
def geometry_server(start_server) -> LiveServer:
    """A server whose sets are the certified geometry alone: no value field cuts them. It waits
    1 ms for an exact set not ready yet, so a version just observed is answered conservatively."""
    return start_server(network="off", exact_timeout_s="0.001")


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(AGENTS))
def test_the_served_pieces_hold_rollouts_of_the_agents_bounds(
    geometry_server: LiveServer, name: str
) -> None:
    agent_id = f"{name}-{uuid.uuid4().hex[:6]}"
    with httpx.Client(base_url=geometry_server.url, timeout=30.0) as http:
        observation = observe(http, agent_id, AGENTS[name])
        answer = constraints(http, agent_id, slices=",".join(map(str, TIMES)))
        agent = http.get(f"/v1/agents/{agent_id}").json()
    assert not answer["conservative"]
    assert answer["frt_version"] == observation["frt_version"]
    assert observation["beta"] < 0.5 if name == "car-low-beta" else observation["beta"] > 0.5
    assert len(bounds_of(observation)) == (3 if name == "car-modes" else 1)
    assert [s["t"] for s in answer["slices"]] == list(TIMES)
    assert [s["time"] for s in answer["slices"]] == [agent["timestamp"] + t for t in TIMES]
    pose = Pose(agent["state"]["x"], agent["state"]["y"], agent["state"]["heading"])
    speed, radius = agent["state"]["speed"], answer["collision_radius"]
    assert radius == agent["config"]["collision_radius"]
    for t, slice_ in zip(TIMES, answer["slices"], strict=True):
        pieces = pieces_of(slice_)
        assert 1 <= len(pieces) <= 4 and all(len(p.normals) <= 16 for p in pieces)
        normals = np.concatenate([p.normals for p in pieces])
        for m, bounds in enumerate(bounds_of(observation)):
            reached = to_world(positions_at(speed, bounds, t, 1500, seed=m), pose)
            missed = outside(pieces, moved_by(reached, radius, normals))
            assert len(missed) == 0, (name, t, m, missed[:3])


@pytest.mark.slow
def test_a_conservative_answer_holds_the_rollouts_too(geometry_server: LiveServer) -> None:
    name = "car-modes"
    with httpx.Client(base_url=geometry_server.url, timeout=30.0) as http:
        for _ in range(20):
            agent_id = f"late-{uuid.uuid4().hex[:6]}"
            body = {"timestamp": 0.0, "observed_action": None, **AGENTS[name][0]}
            observation = http.post(f"/v1/agents/{agent_id}/observations", json=body).json()
            answer = constraints(http, agent_id, slices="0.35,1.0,3.0")
            if answer["conservative"]:
                break
        else:
            pytest.fail("every exact set was ready within 1 ms")
    pose = Pose(**{k: AGENTS[name][0]["state"][k] for k in ("x", "y", "heading")})
    for slice_ in answer["slices"]:
        pieces = pieces_of(slice_)
        normals = np.concatenate([p.normals for p in pieces])
        for m, bounds in enumerate(bounds_of(observation)):
            reached = positions_at(10.0, bounds, slice_["t"], 1500, seed=m)
            radius = answer["collision_radius"]
            missed = outside(pieces, moved_by(to_world(reached, pose), radius, normals))
            assert len(missed) == 0, (slice_["t"], m, missed[:3])


@pytest.fixture(scope="module", params=["analytic", "geometry"])
def served(request: pytest.FixtureRequest) -> tuple[LiveServer, dict[str, str]]:
    """A server, the shared one (the analytic model cuts its sets) or ``geometry_server``, and
    every agent of ``AGENTS`` on it, by name."""
    server = request.getfixturevalue(
        "live_server" if request.param == "analytic" else "geometry_server"
    )
    ids = {}
    with httpx.Client(base_url=server.url, timeout=30.0) as http:
        for name, observations in AGENTS.items():
            ids[name] = f"{name}-{uuid.uuid4().hex[:6]}"
            observe(http, ids[name], observations)
    return server, ids


@pytest.mark.slow
def test_the_pieces_hold_c_as_the_contours_draw_it_and_stay_tight(
    served: tuple[LiveServer, dict[str, str]],
) -> None:
    server, agents = served
    slices = ",".join(map(str, TIMES))
    ratios = []
    with httpx.Client(base_url=server.url, timeout=30.0) as http:
        for name, agent_id in agents.items():
            for radius in (None, 0.0, 3.0):
                extra = {} if radius is None else {"collision_radius": radius}
                answer = constraints(http, agent_id, slices=slices, **extra)
                drawn = http.get(
                    f"/v1/agents/{agent_id}/frt",
                    params={"slices": slices, "include": "C", "tube": "false", **extra},
                ).json()
                assert drawn["frt_version"] == answer["frt_version"]
                assert not answer["conservative"] and not drawn["conservative"]
                for ours, theirs in zip(answer["slices"], drawn["slices"], strict=True):
                    c_set = shape(theirs["C"])
                    pieces = pieces_of(ours)
                    if c_set.is_empty:  # the analytic model's disc may leave the outer bound
                        assert pieces == []
                        continue
                    missed = outside(pieces, shapely.get_coordinates(c_set), ROUNDING)
                    assert len(missed) == 0, (name, radius, ours["t"], missed[:3])
                    areas = [half_plane_polygon(p.normals, p.offsets).area for p in pieces]
                    for piece, area in zip(pieces, areas, strict=True):
                        assert Polygon(piece.corners).area == pytest.approx(area, rel=1e-6)
                    ratios.append((sum(areas) / c_set.area, name, radius, ours["t"]))
    worst = max(ratios)
    assert worst[0] <= AREA_FACTOR, worst


# ---------------------------------------------------------------------------- errors and twins


@pytest.fixture(scope="module")
def agent(live_server: LiveServer) -> str:
    agent_id = f"mpc-{uuid.uuid4().hex[:8]}"
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        observe(http, agent_id, AGENTS["car-urban"])
    return agent_id


BAD_QUERIES = [
    ({}, "slices"),
    ({"slices": ""}, "slices"),
    ({"slices": "nan"}, "slices.0"),
    ({"slices": "1.0,inf"}, "slices.1"),
    ({"slices": "1.0,abc"}, "slices.1"),
    ({"slices": "3.5"}, "slices.0"),
    ({"slices": "1.0,-0.1"}, "slices.1"),
    ({"slices": ",".join(["1.0"] * 17)}, "slices"),
    ({"slices": "1.0", "max_sides": 2}, "max_sides"),
    ({"slices": "1.0", "max_sides": 65}, "max_sides"),
    ({"slices": "1.0", "max_sides": "16.5"}, "max_sides"),
    ({"slices": "1.0", "max_pieces": 0}, "max_pieces"),
    ({"slices": "1.0", "max_pieces": 17}, "max_pieces"),
    ({"slices": "1.0", "collision_radius": -1.0}, "collision_radius"),
    ({"slices": "1.0", "collision_radius": "nan"}, "collision_radius"),
    ({"slices": "1.0", "include": "K"}, "include"),
]


def test_bad_input_is_a_422_naming_the_field_and_changes_nothing(
    live_server: LiveServer, agent: str
) -> None:
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        before = http.get(f"/v1/agents/{agent}").json()
        good = constraints(http, agent, slices="1.0,2.0")
        for params, field in BAD_QUERIES:
            answer = http.get(f"/v1/agents/{agent}/constraints", params=params)
            assert answer.status_code == 422, (params, answer.text)
            assert answer.json()["field"] == field, (params, answer.json())
        assert http.get("/v1/agents/nobody/constraints", params={"slices": "1"}).status_code == 404
        assert http.get("/v1/agents/bad id/constraints", params={"slices": "1"}).status_code == 422
        assert http.get(f"/v1/agents/{agent}").json() == before
        assert constraints(http, agent, slices="1.0,2.0") == good


def test_the_sdk_and_the_stream_answer_as_http_does(live_server: LiveServer, agent: str) -> None:
    params = {"slices": "0.5,1.25,3.0", "max_sides": 8, "max_pieces": 2, "collision_radius": 2.0}
    with httpx.Client(base_url=live_server.url, timeout=30.0) as http:
        expected = AgentConstraints.model_validate(constraints(http, agent, **params))
    assert expected.max_sides == 8 and expected.max_pieces == 2
    assert expected.collision_radius == 2.0
    assert all(len(p.A) <= 8 for s in expected.slices for p in s.pieces)
    kwargs = {"slices": [0.5, 1.25, 3.0], "max_sides": 8, "max_pieces": 2, "collision_radius": 2.0}
    with FRTClient(live_server.url) as client:
        assert client.constraints(agent, **kwargs) == expected
        with client.stream(timeout=10.0) as stream:
            assert stream.constraints(agent, **kwargs) == expected
            with pytest.raises(ValidationError) as bad:
                stream.constraints(agent, slices=[1.0], max_sides=2)
            assert bad.value.field == "max_sides"
            with pytest.raises(ValidationError) as bad:
                stream.constraints(agent, slices=[9.0])
            assert bad.value.field == "slices.0"
            with pytest.raises(NotFoundError):
                stream.constraints("nobody", slices=[1.0])
        with pytest.raises(ValidationError) as bad:
            client.constraints(agent, slices=[1.0], max_pieces=0)
        assert bad.value.field == "max_pieces"

    async def twins() -> list[AgentConstraints]:
        async with AsyncFRTClient(live_server.url) as client:
            over_http = await client.constraints(agent, **kwargs)
            async with client.stream(timeout=10.0) as stream:
                return [over_http, await stream.constraints(agent, **kwargs)]

    assert asyncio.run(twins()) == [expected, expected]
    slice_ = expected.slices[1]
    centre = np.mean(slice_.pieces[0].vertices, axis=0)
    assert slice_.contains(*centre) and not slice_.contains(1e6, 1e6)
