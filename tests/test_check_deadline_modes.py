"""Checks of agents with many modes within their deadline: the members of a union measured
together (``reach.batch.least_member_clearances``) give the values of the members measured one by
one, bit for bit; the witness search (``service.flows.witnessed``) searches no row of bounds once
the deadline's time is spent, but for the small searches it always makes; and a 32-mode agent
checked along 1000 points with a 1 ms deadline gets a valid conservative answer, the same as with
a long one but for the witness search it had no time for. No figure here is a time."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from reach.batch import box_clearances, least_member_clearances
from reach.engine import FRTEngine
from reach.frames import Pose
from reach.sets import BoxTubeSet
from reach.union import box_members, conservative_sets, exact_union
from reach.witness import Witnesses, first_witnessed, witnessed
from service.flows import witnessed as witnessed_flow
from service.flows.check_points import check_points
from service.flows.witnessed import UNTIMED_POINTS, witnessed_collisions
from service.runtime.jobs import FRTJob, job_for
from service.runtime.settings import Settings
from service.runtime.stores import AgentState
from service.wire.schemas import MAX_MODES, CollisionCheckRequest
from tests.test_api_errors import client_for

SHIPPED = Path(__file__).resolve().parents[1] / "models" / "frt_unicycle.onnx"
COV = [[[0.01, 0.0], [0.0, 0.25]]] * 6


def _rows(rng: np.random.Generator, modes: int, spread: float) -> np.ndarray:
    """Rows of control bounds [modes, 8] (contract order) around random mode means."""
    u1 = rng.uniform(-1.0, 1.0, modes) * spread
    u2 = rng.uniform(-3.0, 3.0, modes) * spread
    width1, width2 = rng.uniform(0.02, 0.3, modes), rng.uniform(0.1, 1.5, modes)
    lo1, hi1, lo2, hi2 = u1 - width1, u1 + width1, u2 - width2, u2 + width2
    return np.column_stack([lo1, lo2, lo1, lo2, hi1, hi2, hi1, hi2])


def _member_by_member(
    groups: list[list[BoxTubeSet]], xy: np.ndarray, t_rel: list[np.ndarray | None]
) -> list[np.ndarray]:
    """Each group's least clearance, its members measured one by one (``BoxTubeSet.clearance``
    by ``box_clearances``) and their values' least taken member after member."""
    flat = [(g, s) for g, members in enumerate(groups) for s in members]
    measured = box_clearances([s for _, s in flat], xy, [t_rel[g] for g, _ in flat])
    out: dict[int, np.ndarray] = {}
    for (g, _), found in zip(flat, measured, strict=True):
        out[g] = found if g not in out else np.minimum(out[g], found)
    return [out[g] for g in range(len(groups))]


@pytest.mark.parametrize("spread", [1.0, 0.3, 0.02])
@pytest.mark.parametrize("time_indexed", [False, True])
def test_unions_measured_together_give_their_members_values_bit_for_bit(
    spread: float, time_indexed: bool
) -> None:
    rng = np.random.default_rng(round(spread * 100) + time_indexed)
    engine = FRTEngine()
    poses = [Pose(*rng.uniform(-8.0, 8.0, 2), rng.uniform(-3.0, 3.0)) for _ in range(5)]
    modes = [MAX_MODES, MAX_MODES, 7, 1, 2]
    bounds = [_rows(rng, m, spread) for m in modes]
    bounds[3] = bounds[3][0]  # one mode given as a single row: a box set, not a union
    sets = conservative_sets(engine, poses, [float(v) for v in rng.uniform(0, 15, 5)], bounds)
    groups = [box_members(s) for s in sets]
    # A group whose members lie in different frames is measured member by member.
    groups.append([groups[0][0], groups[1][0]])
    xy = np.concatenate([rng.uniform(-60.0, 60.0, (600, 2)), rng.normal(0.0, 4.0, (400, 2))])
    times = rng.uniform(-0.5, 3.5, len(xy)) if time_indexed else None
    t_rel = [times] * len(groups)
    got = least_member_clearances(groups, xy, t_rel)
    want = _member_by_member(groups, xy, t_rel)
    for g, w in zip(got, want, strict=True):
        assert np.array_equal(g, w) and np.array_equal(np.signbit(g), np.signbit(w))
    inside = np.concatenate(got[:2]) <= 0.0
    assert 0 < inside.sum() < len(inside)  # points inside the unions and outside them


def test_the_first_witnessed_point_is_the_brute_force_searchs() -> None:
    rng = np.random.default_rng(5)
    found = Witnesses(np.linspace(0.0, 3.0, 101), rng.normal(0.0, 8.0, (9, 101, 2)))
    for trial in range(60):
        points = rng.normal(0.0, 10.0, (int(rng.integers(1, 300)), 2))
        until = rng.uniform(-0.5, 3.5, len(points)) if trial % 2 else None
        radius = float(rng.uniform(0.0, 2.0))
        want = witnessed(found, points, until, radius)
        first = first_witnessed(found, points, until, radius)
        assert first == (int(np.argmax(want)) if want.any() else -1)


class _Ticks:
    """A clock that reads 0, 1, 2, ... and counts its reads."""

    def __init__(self) -> None:
        self.reads = 0

    def __call__(self) -> float:
        self.reads += 1
        return float(self.reads - 1)


def _agent(rows: np.ndarray) -> tuple[AgentState, FRTJob]:
    """A state at the origin heading +x at 5 m/s and the job of ``rows`` of bounds."""
    state = AgentState("a", 1.0, 0.0, 0.0, 0.0, 5.0, {}, {}, rows[0].tolist())
    return state, FRTJob.make("a", 1, Pose(0.0, 0.0, 0.0), 5.0, rows.reshape(-1))


def _search(
    rows: np.ndarray, n_points: int, until: float, monkeypatch: pytest.MonkeyPatch
) -> tuple[set[int], int]:
    """Witnessed agents of one check along the x axis 10 to 15 m ahead of ``_agent(rows)``
    (every point answered inside C) with the fake clock :class:`_Ticks`, and the rows whose
    rollouts the search took."""
    taken = []
    rollouts = witnessed_flow.witnesses

    def counted(v_start: float, row: np.ndarray) -> Witnesses:
        taken.append(row)
        return rollouts(v_start, row)

    monkeypatch.setattr(witnessed_flow, "witnesses", counted)
    state, job = _agent(rows)
    points = [
        {"t": 1.0 + 3.0 * k / n_points, "x": 10.0 + 5.0 * k / n_points, "y": 0.0}
        for k in range(n_points)
    ]
    request = CollisionCheckRequest.model_validate({"trajectory": points})
    found = witnessed_collisions(
        FRTEngine(),
        [state],
        [job],
        request,
        check_points(request, Settings()),
        (np.array([1.5]), np.full((1, n_points), -1.0), [0]),
        until,
        _Ticks(),
    )
    return found, len(taken)


#: Bounds that turn the car hard left at once (its rollouts leave the x axis), and bounds that
#: keep it on the axis.
LEFT = [1.8, -1.0, 1.8, -1.0, 2.0, 1.0, 2.0, 1.0]
STRAIGHT = [-0.01, -1.0, -0.01, -1.0, 0.01, 1.0, 0.01, 1.0]


def test_rows_of_bounds_are_searched_only_while_the_deadline_leaves_time(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """32 modes, the last one alone reaching the points far ahead: the clock is read once per
    row, and the rows from the one that reads ``until`` on are not searched."""
    rows = np.array([LEFT] * (MAX_MODES - 1) + [STRAIGHT])
    far = 1000
    assert _search(rows, far, np.inf, monkeypatch) == ({0}, MAX_MODES)
    assert _search(rows, far, MAX_MODES, monkeypatch) == ({0}, MAX_MODES)
    assert _search(rows, far, MAX_MODES - 1, monkeypatch) == (set(), MAX_MODES - 1)
    assert _search(rows, far, 0, monkeypatch) == (set(), 0)
    # One row over many points is timed too; one row over few is searched whatever the time.
    assert _search(rows[-1:], far, 0, monkeypatch) == (set(), 0)
    assert _search(rows[-1:], UNTIMED_POINTS, -np.inf, monkeypatch) == ({0}, 1)


def _observation(t: float, rng: np.random.Generator) -> dict:
    modes = [
        {
            "weight": float(rng.uniform(0.5, 1.5)),
            "mean": [[float(rng.uniform(-1, 1)), float(rng.uniform(-3, 3))]] * 6,
            "cov": COV,
        }
        for _ in range(MAX_MODES)
    ]
    return {
        "timestamp": t,
        "state": {"x": 3.0, "y": -2.0, "heading": 0.4, "speed": 6.0},
        "prediction": {"dt": 0.5, "modes": modes},
    }


@pytest.fixture(scope="module")
def client() -> Iterator[TestClient]:
    # Checks never wait for exact sets: every answer below comes from the conservative set.
    settings = Settings(model_path=SHIPPED, log_requests=False, deadline_wait_fraction=0)
    yield from client_for(settings)


def test_a_32_mode_check_of_1000_points_past_its_budget_is_a_valid_conservative_answer(
    client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With no time left (1 ms less the 1 ms reserve) the witness search is skipped; the answer
    is otherwise the one a long deadline gets, and it holds the exact set's: every point in the
    exact C is in collision, and no clearance outside K exceeds the exact one."""
    services = client.app.state.services  # type: ignore[attr-defined]
    monkeypatch.setattr(services, "cached_exact", lambda jobs: [None] * len(jobs))
    monkeypatch.setattr(services, "exact_futures", lambda jobs, timeout_s: [None] * len(jobs))
    body = _observation(1.0, np.random.default_rng(11))
    assert client.post("/v1/agents/many/observations", json=body).status_code == 200
    s = np.linspace(0.0, 1.0, 1000)
    xy = np.column_stack([3.0 + 40.0 * s - 20.0 * s**2, -2.0 + 25.0 * s])
    trajectory = [{"t": 1.0 + 3.0 * k, "x": x, "y": y} for k, (x, y) in zip(s, xy, strict=True)]
    answers = {
        deadline: client.post(
            "/v1/agents/many/collision-check",
            json={"trajectory": trajectory, "deadline_ms": deadline},
        ).json()
        for deadline in (1.0, 60_000.0)
    }
    short, long = answers[1.0], answers[60_000.0]
    assert short["conservative"] and short["collision"] and not short["collision_witnessed"]
    assert long["conservative"] and long["collision_witnessed"]
    assert {k: v for k, v in short.items() if k != "collision_witnessed"} == {
        k: v for k, v in long.items() if k != "collision_witnessed"
    }
    state = client.portal.call(services.store.get, "many")  # type: ignore[union-attr]
    job = job_for(state)
    assert job.bounds.shape == (MAX_MODES, 8)
    exact = exact_union(services.require_engine(), job.pose, job.v_start, job.bounds)
    exact_clearance = exact.clearance(xy) - short["collision_radius"]
    clearance = np.array(short["clearance"])
    assert (clearance[exact_clearance < 0.0] < 0.0).all() and (exact_clearance < 0.0).any()
    outside = exact_clearance > -short["collision_radius"]
    # To a micrometre: the exact contour's vertices lie on the boxes up to their rounding.
    assert (clearance[outside] <= exact_clearance[outside] + 1e-6).all()


def test_one_mode_small_searches_are_made_whatever_the_time(
    client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An agent of one mode checked along 20 points past its budget still has its collision
    witnessed (as before any budget), every answer conservative."""
    services = client.app.state.services  # type: ignore[attr-defined]
    monkeypatch.setattr(services, "cached_exact", lambda jobs: [None] * len(jobs))
    monkeypatch.setattr(services, "exact_futures", lambda jobs, timeout_s: [None] * len(jobs))
    body = {
        "timestamp": 1.0,
        "state": {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 5.0},
        "prediction": {"dt": 0.5, "mean": [[0.0, 0.0]] * 6, "cov": COV},
    }
    assert client.post("/v1/agents/one/observations", json=body).status_code == 200
    trajectory = [{"t": 1.0 + 0.1 * k, "x": 0.5 * k, "y": 0.0} for k in range(20)]
    for deadline, mode in itertools.product((1.0, 60_000.0), ("tube", "time_indexed")):
        check = {"trajectory": trajectory, "deadline_ms": deadline, "mode": mode}
        answer = client.post("/v1/agents/one/collision-check", json=check).json()
        assert answer["conservative"] and answer["collision"] and answer["collision_witnessed"]
