"""Refined sets (``FRTScheduler.refinement``, ``FRT_FRT_NOTCH_CUT``): once an exact set is ready, a
tighter set of the same key may replace it, computed only on a worker that exact sets do not need.
Readiness stays the first set's; a refinement of a set that left the cache is dropped."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from models.eval_settings import SETTINGS
from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.engine import FRTEngine
from reach.frames import Pose
from reach.notch import NOTCH_STAGES
from service.runtime.exact_worker import ExactTask
from service.runtime.metrics import Metrics
from service.runtime.model_loading import refine_by_notch_cut
from service.runtime.refiner import Refinement
from service.runtime.scheduler import FRTKey, FRTScheduler

MODEL = Path(__file__).resolve().parent.parent / "models" / "frt_unicycle.onnx"
NAMED = {s.name: s for s in SETTINGS}


class Refinable:
    """A compute whose result may be refined (``refinement`` returns the tighter compute)."""

    def __init__(self, value: str, refined: Callable[[], str] | None) -> None:
        self.value = value
        self.refined = refined

    def __call__(self) -> str:
        return self.value


def refine(compute: Callable[[], Any], result: Any) -> Refinement | None:
    if isinstance(compute, Refinable) and compute.refined is not None:
        return Refinement(compute.refined)
    return None


@pytest.fixture
def scheduler() -> Iterator[FRTScheduler]:
    s = FRTScheduler(workers=2, cache_size=16, metrics=Metrics())
    s.refinement = refine
    s.start()
    yield s
    s.shutdown()


def key(agent: str, version: int) -> FRTKey:
    return FRTKey.of(agent, version, [float(version), 1.0])


def until(condition: Callable[[], bool], timeout_s: float = 5.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.005)
    return condition()


def outcomes(scheduler: FRTScheduler, stage: int | None = None) -> dict[str, float]:
    """The scheduler's ``frt_refinements_total`` by outcome (0 where none), of one stage or all."""
    registry = scheduler._metrics.registry
    stages = [stage] if stage is not None else [1, 2, 3]
    return {
        outcome: sum(
            registry.get_sample_value(
                "frt_refinements_total", {"outcome": outcome, "stage": str(s)}
            )
            or 0.0
            for s in stages
        )
        for outcome in ("landed", "stale", "dropped", "wasted", "failed", "skipped")
    }


class Stage:
    """A refinement stage: logs its name when it starts, may wait for a gate, and has a next
    stage (``refinement`` finds it as ``refined``)."""

    def __init__(
        self,
        name: str,
        stage: int,
        log: list[str],
        refined: Callable[[], Any] | None = None,
        gate: threading.Event | None = None,
        seconds: float = 0.0,
    ) -> None:
        self.name, self.stage, self.log, self.refined, self.gate = name, stage, log, refined, gate
        self.seconds = seconds

    def __call__(self) -> str:
        self.log.append(self.name)
        if self.gate is not None:
            self.gate.wait(5)
        time.sleep(self.seconds)
        return self.name


def staged_refine(compute: Callable[[], Any], result: Any) -> Refinement | None:
    refined = compute.refined if isinstance(compute, Stage | Refinable) else None
    if refined is None:
        return None
    return Refinement(refined, stage=refined.stage if isinstance(refined, Stage) else 1)


def test_a_refined_set_replaces_the_ready_one(scheduler: FRTScheduler) -> None:
    gate = threading.Event()

    def tighter() -> str:
        gate.wait(5)
        return "refined"

    k = key("a", 1)
    first = asyncio.run(scheduler.wait(k, Refinable("exact", tighter), 5.0))
    assert first == "exact" and scheduler.lookup(k) == "exact"  # ready before the refinement
    gate.set()
    assert until(lambda: scheduler.lookup(k) == "refined")
    assert outcomes(scheduler) == {
        "landed": 1,
        "stale": 0,
        "dropped": 0,
        "wasted": 0,
        "failed": 0,
        "skipped": 0,
    }


def test_refinements_come_in_stages_each_landing_in_turn(scheduler: FRTScheduler) -> None:
    """A landed refinement is asked for its own (``refinement`` of the refined set): the second
    stage replaces the first, each counted under its stage."""
    scheduler.refinement = staged_refine
    log: list[str] = []
    gate = threading.Event()
    second = Stage("second cut", 2, log, gate=gate)
    first = Stage("first cut", 1, log, refined=second)
    k = key("a", 1)
    assert asyncio.run(scheduler.wait(k, Refinable("exact", first), 5.0)) == "exact"
    assert until(lambda: scheduler.lookup(k) == "first cut")  # served while the second runs
    gate.set()
    assert until(lambda: scheduler.lookup(k) == "second cut")
    assert log == ["first cut", "second cut"]
    assert until(lambda: outcomes(scheduler, stage=2)["landed"] == 1)
    assert outcomes(scheduler, stage=1)["landed"] == 1


def test_first_stages_run_before_later_ones(scheduler: FRTScheduler) -> None:
    """Agent z's first stage lands while agent a's first stage waits: a's goes before z's second,
    though z's second was queued last (newest first would run it first)."""
    scheduler.refinement = staged_refine
    log: list[str] = []
    gate = threading.Event()
    z_first = Stage("z1", 1, log, refined=Stage("z2", 2, log), gate=gate)
    asyncio.run(scheduler.wait(key("z", 1), Refinable("exact z", z_first), 5.0))
    assert until(lambda: log == ["z1"])  # holds the one refining worker
    a_first = Stage("a1", 1, log, refined=Stage("a2", 2, log))
    asyncio.run(scheduler.wait(key("a", 1), Refinable("exact a", a_first), 5.0))
    gate.set()
    assert until(lambda: len(log) == 4)
    assert log[:2] == ["z1", "a1"]
    assert until(lambda: scheduler.lookup(key("z", 1)) == "z2")
    assert until(lambda: scheduler.lookup(key("a", 1)) == "a2")


def test_a_later_stage_of_a_superseded_version_is_not_queued(scheduler: FRTScheduler) -> None:
    """A first stage that lands after its agent's next version came (stale) queues no second
    stage: nobody asks for that version's set any more."""
    scheduler.refinement = staged_refine
    log: list[str] = []
    gate = threading.Event()
    first = Stage("a1 first", 1, log, refined=Stage("a1 second", 2, log), gate=gate)
    asyncio.run(scheduler.wait(key("a", 1), Refinable("exact a1", first), 5.0))
    assert until(lambda: log == ["a1 first"])
    asyncio.run(scheduler.wait(key("a", 2), Refinable("exact a2", None), 5.0))
    gate.set()
    assert until(lambda: outcomes(scheduler, stage=1)["stale"] == 1)
    time.sleep(0.1)
    assert log == ["a1 first"]


def test_a_later_stage_that_would_land_after_the_next_version_is_skipped(
    scheduler: FRTScheduler,
) -> None:
    """Once a second stage is known to take ~0.2 s, an agent whose versions come 0.02 s apart
    does not start one (``skipped``): it would land stale and hold the refining worker from the
    next version's first stage. One whose versions come 0.6 s apart does."""
    scheduler.refinement = staged_refine
    log: list[str] = []

    def staged(name: str) -> Refinable:
        return Refinable(
            f"exact {name}",
            Stage(f"{name} first", 1, log, refined=Stage(f"{name} second", 2, log, seconds=0.2)),
        )

    asyncio.run(scheduler.wait(key("z", 1), staged("z1"), 5.0))  # learns the second's duration
    assert until(lambda: scheduler.lookup(key("z", 1)) == "z1 second")
    for agent, apart_s in (("often", 0.02), ("rarely", 0.6)):
        asyncio.run(scheduler.wait(key(agent, 1), Refinable(f"exact {agent}1", None), 5.0))
        time.sleep(apart_s)
        asyncio.run(scheduler.wait(key(agent, 2), staged(f"{agent}2"), 5.0))
    assert until(lambda: scheduler.lookup(key("rarely", 2)) == "rarely2 second")
    assert scheduler.lookup(key("often", 2)) == "often2 first"
    assert "often2 second" not in log
    # Said so (frt_refinement "done" at the first stage), and only of that key.
    assert scheduler.refinement_skipped(key("often", 2))
    assert not scheduler.refinement_skipped(key("rarely", 2))
    assert outcomes(scheduler, stage=2)["skipped"] == 1
    assert outcomes(scheduler, stage=2)["landed"] == 2  # z's and the rarely observed agent's


def test_refinements_leave_a_worker_to_exact_sets(scheduler: FRTScheduler) -> None:
    """With two workers, one busy refining, a new exact set starts at once on the other; a second
    refinement waits for the first."""
    gate = threading.Event()
    started: list[str] = []

    def tighter(name: str) -> Callable[[], str]:
        def compute() -> str:
            started.append(name)
            gate.wait(5)
            return f"refined {name}"

        return compute

    asyncio.run(scheduler.wait(key("a", 1), Refinable("exact a", tighter("a")), 5.0))
    assert until(lambda: started == ["a"])
    b = asyncio.run(scheduler.wait(key("b", 1), Refinable("exact b", tighter("b")), 1.0))
    assert b == "exact b"  # not queued behind the refinement
    time.sleep(0.1)
    assert started == ["a"]  # b's refinement waits: one worker stays free for exact sets
    gate.set()
    assert until(lambda: scheduler.lookup(key("b", 1)) == "refined b")
    assert scheduler.lookup(key("a", 1)) == "refined a"


@pytest.mark.parametrize("oldest_after_s, order", [(60.0, ["z", "b", "a"]), (0.0, ["z", "a", "b"])])
def test_refinements_start_newest_first_unless_the_oldest_has_waited(
    scheduler: FRTScheduler, monkeypatch, oldest_after_s: float, order: list[str]
) -> None:
    """The version observed last has the most life left to be served, so its refinement goes
    first; one that has waited REFINE_OLDEST_AFTER_S goes before it."""
    monkeypatch.setattr("service.runtime.refiner.REFINE_OLDEST_AFTER_S", oldest_after_s)
    gate = threading.Event()
    started: list[str] = []

    def tighter(name: str) -> Callable[[], str]:
        def compute() -> str:
            started.append(name)
            if name == "z":
                gate.wait(5)
            return f"refined {name}"

        return compute

    asyncio.run(scheduler.wait(key("z", 1), Refinable("exact z", tighter("z")), 5.0))
    assert until(lambda: started == ["z"])  # holds the refining worker; a's, then b's, queue
    for name in ("a", "b"):
        asyncio.run(scheduler.wait(key(name, 1), Refinable(f"exact {name}", tighter(name)), 5.0))
    gate.set()
    assert until(lambda: len(started) == 3)
    assert started == order


def test_a_refinement_of_a_forgotten_agent_is_dropped(scheduler: FRTScheduler) -> None:
    gate = threading.Event()
    done = threading.Event()

    def tighter() -> str:
        gate.wait(5)
        done.set()
        return "refined"

    k = key("a", 1)
    asyncio.run(scheduler.wait(k, Refinable("exact", tighter), 5.0))
    scheduler.forget("a")
    gate.set()
    assert done.wait(5)
    time.sleep(0.05)
    assert scheduler.lookup(k) is None
    assert until(lambda: outcomes(scheduler)["wasted"] == 1)  # it ran for nothing
    assert outcomes(scheduler)["landed"] == 0


def test_a_refinement_of_a_superseded_version_does_not_come_back(
    scheduler: FRTScheduler,
) -> None:
    """Refinements are queued one per agent: a newer version's replaces the older one's, and an
    older version's that finishes after its set left the cache is not put back."""
    gate = threading.Event()

    def tighter(value: str) -> Callable[[], str]:
        def compute() -> str:
            gate.wait(5)
            return value

        return compute

    # Agent z's refinement holds the refining worker; a's three versions queue theirs behind it.
    asyncio.run(scheduler.wait(key("z", 1), Refinable("exact z", tighter("refined z")), 5.0))
    for version in (1, 2, 3):
        computed = Refinable(f"exact a{version}", tighter(f"refined a{version}"))
        asyncio.run(scheduler.wait(key("a", version), computed, 5.0))
    assert scheduler.lookup(key("a", 1)) is None  # two versions per agent are kept
    gate.set()
    assert until(lambda: scheduler.lookup(key("a", 3)) == "refined a3")
    assert scheduler.lookup(key("a", 2)) == "exact a2"  # its refinement was replaced by a3's
    assert until(lambda: outcomes(scheduler)["landed"] == 2)  # z's and a3's
    assert outcomes(scheduler)["dropped"] == 2  # a1's and a2's, never run


def test_a_refinement_that_finishes_after_a_newer_version_counts_as_stale(
    scheduler: FRTScheduler,
) -> None:
    """Checks ask for the agent's current version's set: a refinement of the version before,
    finishing once the current one is cached, replaces a set nobody asks for (``stale``)."""
    gate = threading.Event()

    def tighter() -> str:
        gate.wait(5)
        return "refined a1"

    asyncio.run(scheduler.wait(key("a", 1), Refinable("exact a1", tighter), 5.0))
    asyncio.run(scheduler.wait(key("a", 2), Refinable("exact a2", None), 5.0))
    gate.set()
    assert until(lambda: scheduler.lookup(key("a", 1)) == "refined a1")
    assert until(lambda: outcomes(scheduler)["stale"] == 1)
    assert outcomes(scheduler)["landed"] == 0


def test_a_failed_refinement_keeps_the_ready_set(scheduler: FRTScheduler) -> None:
    def broken() -> str:
        raise RuntimeError("refinement failed")

    k = key("a", 1)
    asyncio.run(scheduler.wait(k, Refinable("exact", broken), 5.0))
    b = asyncio.run(scheduler.wait(key("b", 1), Refinable("exact b", None), 5.0))
    assert b == "exact b" and scheduler.lookup(k) == "exact"
    # Said so (GET /v1/agents/{id}: frt_refinement "failed"), and only of that key.
    assert until(lambda: scheduler.refinement_failed(k))
    assert outcomes(scheduler)["failed"] == 1
    assert not scheduler.refinement_failed(key("b", 1))
    assert not scheduler.refinement_failed(key("a", 2))


@pytest.fixture(scope="module")
def engine() -> FRTEngine:
    return engine_for(ValueModel.load(MODEL, threads=1))


def test_the_service_refines_sets_that_may_turn_round_by_the_notch_cut(
    engine: FRTEngine,
) -> None:
    """``refine_by_notch_cut``: an uncut set that could have a notch gets a cut refinement, whose
    set lies inside it and is smaller; a set that cannot turn round, or one already cut, gets
    none."""
    wide, narrow = NAMED["urban_wide"], NAMED["urban_narrow"]
    task = ExactTask(Pose(3.0, -2.0, 0.4), wide.v_start, wide.bounds(), engine)
    uncut = task()
    assert uncut.notch is None and uncut.notch_possible
    refinement = refine_by_notch_cut(task, uncut)
    assert refinement is not None and refinement.stage == 1
    follow_up = refinement.compute
    assert isinstance(follow_up, ExactTask) and follow_up.notch_cut and follow_up.stage == 1
    cut = follow_up()
    last = cut.n_slices - 1
    assert cut.notch is not None and cut.notch.stage == 1
    assert cut.tube(last).difference(uncut.tube(last)).area < 1e-6
    assert uncut.tube(last).area - cut.tube(last).area > 50.0  # m²
    # Then each finer stage in turn, inside the one before (up to the rounding of its outward
    # polygons) and smaller, until the last, which has none.
    task, coarser = follow_up, cut
    for stage in range(2, len(NOTCH_STAGES) + 1):
        refinement = refine_by_notch_cut(task, coarser)
        assert refinement is not None and refinement.stage == stage
        task = refinement.compute
        assert isinstance(task, ExactTask) and task.stage == stage
        finer = task()
        assert finer.notch is not None and finer.notch.stage == stage
        assert finer.tube(last).difference(coarser.tube(last)).area < 1e-3
        assert finer.tube(last).area < coarser.tube(last).area
        coarser = finer
    assert refine_by_notch_cut(task, coarser) is None
    plain = ExactTask(Pose(0.0, 0.0, 0.0), narrow.v_start, narrow.bounds(), engine)
    assert refine_by_notch_cut(plain, plain()) is None
    assert refine_by_notch_cut(lambda: None, uncut) is None  # not an exact set's task


def test_a_cut_set_comes_with_every_tube_drawn(engine: FRTEngine) -> None:
    """A set cut in a worker reaches the server with every tube drawn (a check there draws none
    on the event loop), each inside the uncut set's and growing with time."""
    wide = NAMED["shrinking_steering_only"]
    cut = engine.exact(Pose(0.0, 0.0, 0.0), wide.v_start, wide.bounds(), notch_cut=True)
    uncut = engine.exact(Pose(0.0, 0.0, 0.0), wide.v_start, wide.bounds())
    assert cut.missing_tubes(list(range(cut.n_slices))) == []
    assert len(uncut.missing_tubes(list(range(uncut.n_slices)))) == uncut.n_slices - 1
    for j in range(0, cut.n_slices, 5):
        assert cut.tube(j).difference(uncut.tube(j)).area < 1e-6
    areas = [cut.tube(j).area for j in range(cut.n_slices)]
    assert np.all(np.diff(areas) >= -1e-6)  # tubes grow with time


@pytest.mark.slow
def test_the_service_serves_the_cut_set_once_refined(start_server) -> None:
    """Through a real server on the shipped model: an agent whose predictor is unsure of the
    steering is ready with its uncut set, and soon after its tube shrinks to the cut one (inside
    the first), ``frt_refinement`` going from pending to done; ``FRT_FRT_NOTCH_CUT=false``, or
    exact sets on threads, keep the uncut set ("not_needed")."""
    import httpx
    import shapely.geometry

    from tests.fixtures.payloads import observation, prediction

    def tube_of(http: httpx.Client, agent: str) -> shapely.Geometry:
        body = http.get(f"/v1/agents/{agent}/frt", params={"include": "K"}).json()
        return shapely.geometry.shape(body["tube"]["K"])

    areas = {}
    for cut, executor in ((True, "process"), (False, "process"), (True, "thread")):
        server = start_server(
            model_path=str(MODEL), frt_notch_cut=str(cut).lower(), frt_executor=executor
        )
        refined = cut and executor == "process"  # never on threads (the event loop's GIL)
        with httpx.Client(base_url=server.url, timeout=30.0) as http:
            body = observation(0.0, speed=8.0, prediction=prediction(var=(50.0, 240.0)))
            ready = http.post("/v1/agents/w/observations?wait_frt_ms=10000", json=body).json()
            assert ready["frt_ready"] and ready["control_bounds"]["u1_max_start"] > 0.9
            first = tube_of(http, "w")
            agent = http.get("/v1/agents/w").json()
            assert agent["frt_refinement"] in (("pending", "done") if refined else ("not_needed",))
            assert agent["frt_refinement_stage"] in (
                range(len(NOTCH_STAGES) + 1) if refined else (0,)
            )
            smaller = first.area - 50.0
            assert until(lambda: tube_of(http, "w").area < smaller, 10.0) == refined  # noqa: B023
            if refined:  # the first stage has landed; "done" once the last has
                done = until(
                    lambda: http.get("/v1/agents/w").json()["frt_refinement"] == "done",
                    30.0,
                )
                assert done
            agent = http.get("/v1/agents/w").json()
            assert agent["frt_refinement"] == ("done" if refined else "not_needed")
            assert agent["frt_refinement_stage"] == (len(NOTCH_STAGES) if refined else 0)
            last = tube_of(http, "w")
            assert last.difference(first).area < 1.0  # m²: inside the first (up to rounding)
            areas[refined] = last.area
            counted = 'frt_compute_seconds_count{kind="refined"}'
            assert (counted in http.get("/metrics").text) == refined
    assert areas[True] < areas[False] - 50.0
