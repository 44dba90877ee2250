"""``POST /v1/frames`` (API.md, "Frames"): one request per frame of many agents, each entry
validated and applied on its own, and the ``verdict`` of per-agent check answers (in-process,
the analytic model)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.runtime.settings import Settings

COV = [[[0.01, 0.0], [0.0, 0.25]]] * 6
MEAN = [[0.0, 0.0]] * 6


@pytest.fixture(scope="module")
def client(analytic_model_path: Path) -> Iterator[TestClient]:
    settings = Settings(model_path=analytic_model_path, log_requests=False, max_agents_per_frame=8)
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        deadline = time.monotonic() + 30
        while c.get("/readyz").status_code != 200:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        yield c


def entry(agent_id: str, x: float = 0.0, **extra) -> dict:
    return {
        "agent_id": agent_id,
        "state": {"x": x, "y": 0.0, "heading": 0.0, "speed": 5.0},
        "prediction": {"dt": 0.5, "mean": MEAN, "cov": COV},
        **extra,
    }


def observation(t: float, x: float = 0.0, **extra) -> dict:
    body = entry("unused", x, **extra)
    body.pop("agent_id")
    return {"timestamp": t, **body}


def test_a_frame_answers_as_the_observations_one_by_one(client: TestClient) -> None:
    action = {"steering_rate": 0.3, "acceleration": -2.0}
    for t, act in ((1.0, None), (1.5, action)):
        extra = {} if act is None else {"observed_action": act}
        frame = client.post(
            "/v1/frames",
            json={"timestamp": t, "agents": [entry(f"f{i}", i, **extra) for i in range(3)]},
        )
        assert frame.status_code == 200, frame.text
        for i in range(3):
            one = client.post(f"/v1/agents/s{i}/observations", json=observation(t, i, **extra))
            assert one.status_code == 200
            got, want = frame.json()["results"][i], one.json()
            assert got["agent_id"] == f"f{i}"
            for key in ("beta", "belief", "control_bounds", "frt_version", "action_scored"):
                assert got[key] == want[key]
    assert frame.json()["applied"] == 3 and frame.json()["rejected"] == 0
    assert client.get("/v1/agents/f2").json()["frt_version"] == 2


def test_a_bad_agent_is_rejected_by_index_and_field_and_the_others_apply(
    client: TestClient,
) -> None:
    assert client.post("/v1/frames", json={"timestamp": 1.0, "agents": [entry("b1")]}).is_success
    before = client.get("/v1/agents/b1").json()
    bad_cov = entry("b1")
    bad_cov["prediction"]["cov"] = [[[1.0, 0.0], [0.0, -1.0]]] * 6  # not positive definite
    agents = [
        entry("b0"),
        bad_cov,
        {"state": entry("x")["state"]},  # no agent_id
        entry("b3", extra_field=1),
        entry("b0"),  # twice in one frame
        entry("bad id!"),
    ]
    r = client.post("/v1/frames", json={"timestamp": 2.0, "agents": agents})
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["applied"] == 1 and out["rejected"] == 5
    results = out["results"]
    assert results[0]["agent_id"] == "b0" and "beta" in results[0]
    fields = {res["index"]: res["error"]["field"] for res in results[1:]}
    assert fields[1].startswith("agents.1.prediction.cov")
    assert fields[2] == "agents.2.agent_id"
    assert fields[3] == "agents.3.extra_field"
    assert fields[4] == "agents.4.agent_id"
    assert fields[5] == "agents.5.agent_id"
    assert all(res["error"]["status"] == 422 for res in results[1:])
    assert client.get("/v1/agents/b1").json() == before  # nothing of the bad one changed
    assert client.get("/v1/agents/b3").status_code == 404


def test_an_agents_first_valid_entry_applies_after_an_invalid_one(client: TestClient) -> None:
    """An entry rejected as an observation does not count as the agent's entry: the agent's
    next valid entry applies, and a later one is its second."""
    bad = entry("d0", extra_field=1)
    agents = [bad, entry("d0", 1.0), entry("d0", 2.0), entry("d1")]
    out = client.post("/v1/frames", json={"timestamp": 1.0, "agents": agents}).json()
    assert [r.get("index") for r in out["results"]] == [0, None, 2, None]
    assert out["results"][0]["error"]["field"] == "agents.0.extra_field"
    assert out["results"][2]["error"]["detail"] == "agent appears twice in the frame"
    assert client.get("/v1/agents/d0").json()["state"]["x"] == 1.0


def test_a_stale_agent_is_a_409_entry(client: TestClient) -> None:
    client.post("/v1/frames", json={"timestamp": 5.0, "agents": [entry("st")]})
    r = client.post("/v1/frames", json={"timestamp": 4.0, "agents": [entry("st"), entry("st2")]})
    results = r.json()["results"]
    assert results[0]["error"]["status"] == 409 and results[0]["agent_id"] == "st"
    assert results[1]["agent_id"] == "st2" and "beta" in results[1]


def test_a_frame_beyond_the_limit_is_a_422_naming_agents(client: TestClient) -> None:
    agents = [entry(f"l{i}") for i in range(9)]
    r = client.post("/v1/frames", json={"timestamp": 1.0, "agents": agents})
    assert r.status_code == 422 and r.json()["field"] == "agents"
    assert client.get("/v1/agents/l0").status_code == 404
    assert client.post("/v1/frames", json={"agents": []}).status_code == 422  # no timestamp


def test_the_stream_applies_a_frame(client: TestClient) -> None:
    with client.websocket_connect("/v1/stream") as ws:
        ws.send_json({"id": 1, "op": "frame", "timestamp": 1.0, "agents": [entry("w0")]})
        answer = ws.receive_json()
    assert answer["ok"] and answer["result"]["results"][0]["agent_id"] == "w0"


def test_the_verdict_says_how_good_each_answer_is(client: TestClient) -> None:
    client.post("/v1/agents/v/observations?wait_frt_ms=5000", json=observation(1.0))
    far = [{"x": 500.0, "y": 500.0, "t": 1.0 + 0.1 * k} for k in range(5)]
    near = [{"x": 0.0, "y": 0.0, "t": 1.0 + 0.1 * k} for k in range(5)]
    for trajectory, collision in ((far, False), (near, True)):
        r = client.post("/v1/agents/v/collision-check", json={"trajectory": trajectory}).json()
        assert r["collision"] is collision
        assert r["verdict"] == ("exact" if not r["conservative"] else r["verdict"])
    from service.wire.schemas import answer_verdict

    assert answer_verdict(False, True) == "exact"
    assert answer_verdict(True, False) == "decision_exact"
    assert answer_verdict(True, True) == "conservative"


def test_the_sdk_builds_a_frame_and_reads_its_answer(client: TestClient) -> None:
    from frt_client import FrameRejection, FrameResult, ObservationResult
    from frt_client.calls import frame

    call = frame(
        timestamp=1.0,
        agents=[
            {"agent_id": "k0", "state": (0.0, 0.0, 0.0, 5.0), "prediction": entry("k0")["prediction"]},
            {"agent_id": "k1", "state": (0.0, 0.0, 0.0, 500.0), "prediction": entry("k1")["prediction"]},
        ],
    )  # fmt: skip
    assert (call.method, call.path, call.op, call.idempotent) == (
        "POST",
        "/v1/frames",
        "frame",
        False,
    )
    result = FrameResult.model_validate(client.post(call.path, json=call.json).json())
    assert isinstance(result.results[0], ObservationResult)
    assert isinstance(result.results[1], FrameRejection)
    assert result.rejections()[0].error.field.startswith("agents.1.state.speed")


# ------------------------------------------------ a frame gives each agent its one-by-one state

#: Per agent of the equivalence frames: (agent_class, config, modes per round, steps, dt).
KINDS: list[tuple[str | None, dict, list[int], int, float]] = [
    (None, {}, [1], 6, 0.5),
    (None, {}, [3], 6, 0.5),
    (None, {"mode_floor": 0.05}, [2, 1, 3, 3, 1], 6, 0.5),  # the belief restarts from beta's
    ("pedestrian", {}, [1], 6, 0.5),
    ("cyclist", {}, [2], 6, 0.5),
    (None, {"bounds_rule": "uniform_mixture", "beta_low": 0.1, "epsilon": 0.2}, [1], 6, 0.5),
    ("pedestrian", {"bounds_rule": "uniform_mixture", "rescue_onset": 0.2}, [2], 6, 0.5),
    (None, {"bounds_rule": "mass_ramp", "bounds_fit": "endpoints"}, [1], 6, 0.5),
    (None, {"coverage_target": 0.9, "coverage_step": 0.05}, [1], 6, 0.5),  # adaptive gamma
    ("cyclist", {"coverage_target": 0.95}, [3], 6, 0.5),
    (None, {"epsilon": 0.0, "gamma": 0.3}, [1], 12, 0.25),
    (None, {"beta_low": 0.3}, [2], 12, 0.25),
]


def _gaussian(rng: np.random.Generator, steps: int, shift: float) -> dict:
    mean = rng.normal([shift, 0.0], [0.2, 1.0], size=(steps, 2))
    a = rng.normal(0.0, 0.3, size=(steps, 2, 2))
    cov = a @ a.transpose(0, 2, 1) + np.diag([0.01, 0.05])
    return {"mean": mean.tolist(), "cov": cov.tolist()}


def _kind_entry(rng: np.random.Generator, kind: int, k: int, first: bool) -> dict:
    klass, config, modes, steps, dt = KINDS[kind]
    m = modes[k % len(modes)]
    if m == 1:
        prediction = {"dt": dt, **_gaussian(rng, steps, 0.0)}
    else:
        prediction = {
            "dt": dt,
            "modes": [
                {"weight": float(w), **_gaussian(rng, steps, 0.4 * j)}
                for j, w in enumerate(rng.uniform(0.1, 1.0, m))
            ],
        }
    speed = {"pedestrian": 1.2, "cyclist": 4.0}.get(klass or "car", 8.0)
    body: dict = {
        "state": {"x": 3.0 * kind + 0.5 * k, "y": 0.2 * k, "heading": 0.1 * k, "speed": speed},
        "prediction": prediction,
    }
    # Actions near and far (the betas move both ways); some rounds without one.
    if not first and (kind + k) % 4 != 0:
        far = 4.0 if (kind * 7 + k) % 3 == 0 else 0.3
        body["observed_action"] = {
            "steering_rate": float(rng.normal(0.0, far * 0.3)),
            "acceleration": float(rng.normal(0.0, far)),
        }
    if first:
        body["config"] = config
        if klass is not None:
            body["agent_class"] = klass
    return body


@pytest.fixture(scope="module")
def wide(analytic_model_path: Path) -> Iterator[TestClient]:
    """A service whose exact sets are not refined in the background (the refinement, landing
    when it may, decides which tubes the audit finds drawn: the audit's scores would differ)."""
    settings = Settings(
        model_path=analytic_model_path,
        log_requests=False,
        max_agents_per_frame=64,
        frt_notch_cut=False,
    )
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        deadline = time.monotonic() + 30
        while c.get("/readyz").status_code != 200:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        yield c


def _sets_equal(a: object, b: object) -> bool:
    """Two conservative sets made of the same boxes (a union: member by member)."""
    members_a = getattr(a, "members", (a,))
    members_b = getattr(b, "members", (b,))
    return len(members_a) == len(members_b) and all(
        np.array_equal(x.boxes, y.boxes)
        and np.array_equal(x.boxes_until, y.boxes_until)
        and x.pose == y.pose
        for x, y in zip(members_a, members_b, strict=True)
    )


def _same_but_the_id(got: dict, want: dict) -> None:
    for key in set(got) | set(want):
        if key not in ("agent_id", "frt_ready"):
            assert got.get(key) == want.get(key), key


def test_a_frame_gives_each_agent_the_state_its_observations_one_by_one_give(
    wide: TestClient,
) -> None:
    """States, betas, bounds, modes, versions, adaptive gamma and conservative sets bit for bit:
    single Gaussians and mixtures (their number of modes changing), cars, pedestrians and
    cyclists, with and without actions, the bounds rules and fits."""
    services = wide.app.state.services
    rng = np.random.default_rng(36)
    ids = range(len(KINDS))
    for k in range(6):
        t = 10.0 + 0.5 * k
        bodies = [_kind_entry(rng, kind, k, first=k == 0) for kind in ids]
        frame = wide.post(
            "/v1/frames",
            json={"timestamp": t, "agents": [{"agent_id": f"eq-f{i}", **b} for i, b in zip(ids, bodies, strict=True)]},
        )  # fmt: skip
        assert frame.status_code == 200, frame.text
        assert frame.json()["rejected"] == 0, frame.json()
        for i, body in zip(ids, bodies, strict=True):
            one = wide.post(f"/v1/agents/eq-s{i}/observations", json={"timestamp": t, **body})
            assert one.status_code == 200, one.text
            _same_but_the_id(frame.json()["results"][i], one.json())
        for i in ids:  # the exact sets ready before the next round: the audits score alike
            for who in ("f", "s"):
                assert wide.get(f"/v1/agents/eq-{who}{i}?wait_frt_ms=10000").json()["frt_ready"]
            got, want = asyncio.run(services.store.get_many([f"eq-f{i}", f"eq-s{i}"]))
            assert got.frt_version == k + 1
            got.agent_id = want.agent_id
            assert got == want, KINDS[i]
            sets = [services.conservative_cache.get(services.job_for(s).key) for s in (got, want)]
            assert sets[0] is not None and _sets_equal(*sets)
            views = [wide.get(f"/v1/agents/eq-{who}{i}").json() for who in ("f", "s")]
            _same_but_the_id(views[0], views[1])
    adaptive = asyncio.run(services.store.get("eq-f8"))
    assert adaptive.gamma_state is not None  # the audit moved it


def test_a_state_written_between_the_frames_read_and_its_update_is_built_from(
    wide: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The frame reads an agent's state, another writer stores a newer one before the frame's
    update: the agent's next state is built from the stored one, as one by one."""
    from service.flows import agents
    from service.wire.schemas import ObservationRequest

    services = wide.app.state.services
    store = services.store
    rng = np.random.default_rng(5)
    bodies = [_kind_entry(rng, 1, k, first=k == 0) for k in range(3)]
    for who in ("race-f", "race-s"):
        r = wide.post(f"/v1/agents/{who}/observations", json={"timestamp": 1.0, **bodies[0]})
        assert r.is_success, r.text
    real_get_many = store.get_many
    overtaken = []

    async def read_then_overtaken(agent_ids: list[str], **kwargs: object) -> list:
        read = await real_get_many(agent_ids, **kwargs)
        if agent_ids == ["race-f"] and not overtaken:  # another writer, after this read
            overtaken.append(True)
            request = ObservationRequest.model_validate({"timestamp": 2.0, **bodies[1]})
            await agents.observe(services, "race-f", request)
        return read

    monkeypatch.setattr(store, "get_many", read_then_overtaken)
    frame = wide.post(
        "/v1/frames", json={"timestamp": 3.0, "agents": [{"agent_id": "race-f", **bodies[2]}]}
    )
    monkeypatch.undo()
    assert overtaken and frame.status_code == 200, frame.text
    assert frame.json()["rejected"] == 0, frame.json()
    for t, body in ((2.0, bodies[1]), (3.0, bodies[2])):
        one = wide.post("/v1/agents/race-s/observations", json={"timestamp": t, **body})
        assert one.status_code == 200, one.text
    _same_but_the_id(frame.json()["results"][0], one.json())
    got, want = asyncio.run(store.get_many(["race-f", "race-s"]))
    assert got.frt_version == 3
    got.agent_id = want.agent_id
    assert got == want


def test_agents_refused_by_the_flow_are_answered_in_place_and_keep_their_state(
    wide: TestClient,
) -> None:
    """Within one frame, refused by the flow: a class change (409), a speed outside the class's
    range and one invalid mode of a mixture (422s naming the field), a stale timestamp (409);
    the others of the frame are applied as one by one."""
    rng = np.random.default_rng(8)
    first = [_kind_entry(rng, kind, 0, first=True) for kind in (0, 3, 0, 1, 0)]
    ids = ["rj-ok", "rj-class", "rj-speed", "rj-mode", "rj-stale"]
    agents = [{"agent_id": a, **b} for a, b in zip(ids, first, strict=True)]
    assert (
        wide.post("/v1/frames", json={"timestamp": 1.0, "agents": agents}).json()["rejected"] == 0
    )
    late = {"agent_id": "rj-stale", **_kind_entry(rng, 0, 1, first=False)}
    assert (
        wide.post("/v1/frames", json={"timestamp": 3.0, "agents": [late]}).json()["rejected"] == 0
    )
    view = "/v1/agents/{}?wait_frt_ms=10000"  # the version's exact set ready: one view of it
    before = {a: wide.get(view.format(a)).json() for a in ids}
    bodies = [_kind_entry(rng, kind, 1, first=False) for kind in (0, 3, 0, 1, 0)]
    bodies[1]["agent_class"] = "car"  # a pedestrian until now
    bodies[2]["state"]["speed"] = 500.0
    bodies[3]["prediction"]["modes"][1]["cov"][0] = [[1.0, 0.0], [0.0, -1.0]]
    frame = [{"agent_id": a, **b} for a, b in zip(ids, bodies, strict=True)]
    out = wide.post("/v1/frames", json={"timestamp": 2.0, "agents": frame}).json()
    assert out["applied"] == 1 and out["rejected"] == 4
    errors = {r["agent_id"]: r["error"] for r in out["results"][1:]}
    assert errors["rj-class"]["status"] == 409 and "pedestrian" in errors["rj-class"]["detail"]
    assert (errors["rj-speed"]["status"], errors["rj-speed"]["field"]) == (
        422,
        "agents.2.state.speed",
    )
    assert errors["rj-mode"]["status"] == 422
    assert errors["rj-mode"]["field"] == "agents.3.prediction.modes.1.cov.0"
    assert errors["rj-stale"]["status"] == 409
    for a in ids[1:]:
        assert wide.get(view.format(a)).json() == before[a]  # nothing of it changed
    wide.post("/v1/agents/rj-ok-alone/observations", json={"timestamp": 1.0, **first[0]})
    one = wide.post("/v1/agents/rj-ok-alone/observations", json={"timestamp": 2.0, **bodies[0]})
    _same_but_the_id(out["results"][0], one.json())


def _frame_and_a_planner(services, prefix: str, t: float, n: int, order: list[str]):  # type: ignore[no-untyped-def]
    """``n`` agents' observations at ``t`` (named ``prefix-i``), and a planner's check of every
    agent half a second later that appends "check" to ``order`` once answered."""
    from service.flows import checks
    from service.wire.schemas import MultiCollisionCheckRequest, ObservationRequest

    observations = [
        (f"{prefix}-{i}", ObservationRequest.model_validate(observation(t, x=4.0 * i)))
        for i in range(n)
    ]
    check = MultiCollisionCheckRequest.model_validate(
        {"trajectory": [{"t": t + 0.5, "x": 0.0, "y": 30.0}], "mode": "time_indexed"}
    )

    async def a_planner() -> None:
        await checks.check_agents_at_once(services, check, time.perf_counter())
        order.append("check")

    return observations, a_planner


def test_a_check_arriving_during_a_frame_is_answered_between_its_stages(
    wide: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A check that arrives while a frame builds its agents' next states is answered before the
    frame's next group of agents (``STATES_PER_TURN``), not after the whole frame."""
    from service.flows import agents

    services = wide.app.state.services
    order: list[str] = []
    observations, a_planner = _frame_and_a_planner(
        services, "turns", 20.0, 2 * agents.STATES_PER_TURN + 1, order
    )
    arriving: list[asyncio.Task] = []
    real_next_states = agents.next_states

    def next_states_as_a_check_arrives(priors, inputs, *args):  # type: ignore[no-untyped-def]
        if not arriving:
            arriving.append(asyncio.get_running_loop().create_task(a_planner()))
        order.append(f"states of {len(inputs)}")
        return real_next_states(priors, inputs, *args)

    async def frame_and_check() -> list:
        applied = await agents.observe_many(services, observations)
        order.append("frame")
        await arriving[0]
        return applied

    monkeypatch.setattr(agents, "next_states", next_states_as_a_check_arrives)
    applied = asyncio.run(frame_and_check())
    assert not any(isinstance(a, Exception) for a in applied)
    per_turn = agents.STATES_PER_TURN
    assert order == [
        f"states of {per_turn}",
        "check",
        f"states of {per_turn}",
        "states of 1",
        "frame",
    ]


def test_demanded_agents_are_built_first_and_their_sets_start_before_the_frame_is_stored(
    wide: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Agents a planner came near (``service.runtime.demand``) have their next states built in
    the frame's first group and their exact sets submitted then, before the whole frame is
    stored; the others' sets are submitted once it is."""
    from service.flows import agents
    from service.wire.schemas import ObservationRequest

    services = wide.app.state.services
    n = agents.STATES_PER_TURN + 3
    ids = [f"early-{i}" for i in range(n)]
    demanded = {ids[-1], ids[-2]}  # last in the frame: built first all the same
    observations = [
        (a, ObservationRequest.model_validate(observation(30.0, x=4.0 * i)))
        for i, a in enumerate(ids)
    ]
    events: list[tuple[str, list[str]]] = []
    real_submit, real_update = services.submit_many, services.store.update_many

    keys: list[list] = []

    def submit_many(jobs):  # type: ignore[no-untyped-def]
        events.append(("submit", sorted(job.key.agent_id for job in jobs)))
        keys.append([job.key for job in jobs])
        return real_submit(jobs)

    async def update_many(updates):  # type: ignore[no-untyped-def]
        events.append(("store", []))
        return await real_update(updates)

    monkeypatch.setattr(services, "submit_many", submit_many)
    monkeypatch.setattr(services.store, "update_many", update_many)
    services.demand.note(sorted(demanded))
    applied = asyncio.run(agents.observe_many(services, observations))
    assert not any(isinstance(a, Exception) for a in applied)
    assert events[0] == ("submit", sorted(demanded))
    assert events[1] == ("store", [])
    assert events[2] == ("submit", sorted(ids))
    stored = asyncio.run(services.store.get_many(sorted(demanded)))
    assert sorted(keys[0], key=str) == sorted((services.job_for(s).key for s in stored), key=str)


def test_a_check_arriving_while_a_frame_is_stored_goes_before_its_answers(
    wide: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A frame's last stretch is split too: a check that arrives while the frame's versions are
    stored and queued is answered before the answers of a frame of more than
    ``STATES_PER_TURN`` agents are built."""
    from service.flows import agents

    services = wide.app.state.services
    order: list[str] = []
    observations, a_planner = _frame_and_a_planner(
        services, "late", 40.0, agents.STATES_PER_TURN + 1, order
    )
    arriving: list[asyncio.Task] = []
    real_submitted = agents._submitted

    def submitted_as_a_check_arrives(*args):  # type: ignore[no-untyped-def]
        arriving.append(asyncio.get_running_loop().create_task(a_planner()))
        order.append("stored")
        return real_submitted(*args)

    async def frame_and_check() -> None:
        await agents.observe_many(services, observations)
        order.append("frame")
        await arriving[0]

    monkeypatch.setattr(agents, "_submitted", submitted_as_a_check_arrives)
    asyncio.run(frame_and_check())
    assert order == ["stored", "check", "frame"]


def test_agents_a_trajectory_met_are_stored_before_the_rest_of_a_frame_is_built(
    wide: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A large frame's agents whose sets a planner's trajectory met are applied on their own
    first (stored, their sets under way), then the others; the answers keep the entries' order
    and are those of the frame applied in one pass."""
    from service.flows import agents, frames
    from service.wire.schemas import FrameRequest

    services = wide.app.state.services
    n = agents.STATES_PER_TURN + 3

    def frame_of(prefix: str) -> FrameRequest:
        return FrameRequest.model_validate(
            {"timestamp": 40.0, "agents": [entry(f"{prefix}-{i}", 4.0 * i) for i in range(n)]}
        )

    plain = asyncio.run(frames.apply_frame(services, frame_of("one-pass")))
    met = {"met-first-5", "met-first-20"}
    services.demand.note(sorted(met), met=True)
    stored: list[list[str]] = []
    real_update = services.store.update_many

    async def update_many(updates):  # type: ignore[no-untyped-def]
        stored.append(sorted(u[0] for u in updates))
        return await real_update(updates)

    monkeypatch.setattr(services.store, "update_many", update_many)
    split = asyncio.run(frames.apply_frame(services, frame_of("met-first")))
    assert stored == [sorted(met), sorted(f"met-first-{i}" for i in range(n) if i not in (5, 20))]
    assert [r.agent_id for r in split.results] == [f"met-first-{i}" for i in range(n)]
    for got, want in zip(split.results, plain.results, strict=True):
        assert got.model_dump(exclude={"agent_id", "frt_ready"}) == want.model_dump(
            exclude={"agent_id", "frt_ready"}
        )
