"""The objects one app shares between its routes: settings, store, scheduler, metrics, engine.

The model is loaded in a background thread at start-up: ``/healthz`` answers at once, ``/readyz`` and
the model-dependent routes answer 503 until it is loaded (or for good, if it cannot be).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

from starlette.concurrency import run_in_threadpool
from starlette.requests import HTTPConnection

from models.runtime import ModelCard
from reach.engine import FRTEngine
from reach.notch import NOTCH_STAGES
from reach.sets import FRTSet
from reach.union import conservative_union
from service.runtime.answer_cost import AnswerCosts
from service.runtime.audit import AuditLedger, RollingCoverage, Scored, count_audited, score
from service.runtime.demand import ExactDemand
from service.runtime.exact_worker import ExactTask
from service.runtime.jobs import FRTJob, job_for
from service.runtime.maps import MapRegistry, registry_for
from service.runtime.memory import freeze_start_up_objects, keep_freed_memory
from service.runtime.metrics import Metrics
from service.runtime.model_loading import load_model
from service.runtime.priority import ChecksFirst
from service.runtime.scheduler import FRTKey, FRTScheduler, LRUCache
from service.runtime.settings import Settings
from service.runtime.stores import AgentState, AgentStore, make_store
from service.runtime.tube_builder import TubeBuilder
from service.runtime.tube_demand import TubeDemand
from service.wire.errors import ServiceUnavailableError
from service.wire.schemas import ActiveParts

log = logging.getLogger("frt.services")


@dataclass
class Services:
    settings: Settings
    metrics: Metrics
    store: AgentStore
    scheduler: FRTScheduler
    conservative_cache: LRUCache
    engine: FRTEngine | None = None
    #: The loaded model's card, and which parts build the served sets.
    card: ModelCard | None = None
    parts: ActiveParts | None = None
    model_name: str | None = None
    model_error: str | None = "model is loading"
    _loader: asyncio.Task[None] | None = field(default=None, repr=False)
    #: What answering a collision check costs per agent once its sets are known: a check of one
    #: trajectory, and a batch of trajectories (a planner sends batches of one size each cycle,
    #: each costing many single checks).
    answer_costs: AnswerCosts = field(default_factory=AnswerCosts, repr=False)
    batch_answer_costs: AnswerCosts = field(default_factory=AnswerCosts, repr=False)
    #: Draws the tubes time-indexed checks need, now or between requests.
    tubes: TubeBuilder = field(default_factory=TubeBuilder, repr=False)
    #: Holds observations' numerical work back while collision checks are in flight.
    priority: ChecksFirst = field(default_factory=ChecksFirst, repr=False)
    #: The agents whose exact sets change planners' answers: built first.
    demand: ExactDemand = field(default_factory=lambda: ExactDemand(1.0, 4096), repr=False)
    #: Which tubes each agent's checks ask for: the workers draw those (``frt_draw_tubes``).
    tube_demand: TubeDemand = field(default_factory=lambda: TubeDemand(4096), repr=False)
    #: Whether worker processes draw the tubes checks ask for before sending a set back
    #: (``Settings.frt_draw_tubes`` and worker processes running).
    _tubes_in_workers: bool = field(default=False, repr=False)
    #: The coverage audit: each agent's recent versions, and the fleet's rolling coverage.
    audit: AuditLedger = field(default_factory=lambda: AuditLedger(32, 10_000), repr=False)
    coverage: RollingCoverage = field(default_factory=lambda: RollingCoverage(1000), repr=False)
    #: The maps whose drivable area cuts sets (docs/maps.md).
    maps: MapRegistry = field(default_factory=lambda: MapRegistry(16, 1.0, 2_000_000), repr=False)

    @classmethod
    def build(cls, settings: Settings) -> Services:
        metrics = Metrics()
        store = make_store(
            settings.store_url, ttl_s=settings.agent_ttl_s, max_agents=settings.max_agents
        )
        scheduler = FRTScheduler(
            workers=settings.frt_workers, cache_size=settings.frt_cache_size, metrics=metrics
        )
        demand = ExactDemand(settings.exact_demand_s, settings.max_agents)
        if settings.exact_demand_s > 0:
            scheduler.demand = demand
        return cls(
            demand=demand,
            settings=settings,
            metrics=metrics,
            store=store,
            scheduler=scheduler,
            conservative_cache=LRUCache(settings.frt_cache_size),
            tubes=TubeBuilder(on_drawn=metrics.event_loop_tubes.inc),
            audit=AuditLedger(
                settings.audit_max_versions,
                settings.max_agents,
                ttl_s=settings.agent_ttl_s,
                spacing_s=settings.audit_spacing_s,
            ),
            coverage=RollingCoverage(settings.audit_window),
            maps=registry_for(settings),
        )

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        keep_freed_memory()  # a check of 50 agents stacks ~1 MB arrays: no page faults for them
        await run_in_threadpool(lambda: None)  # the request thread pool's first thread, up front
        self.scheduler.start()
        self._loader = asyncio.create_task(asyncio.to_thread(self.load_model))

    async def stop(self) -> None:
        if self._loader is not None and not self._loader.done():
            self._loader.cancel()
        self.scheduler.shutdown()
        await self.store.close()

    def load_model(self) -> None:
        """Load the ONNX model and its card and build the engine (blocking; runs in a thread);
        a model that cannot load leaves the service answering 503 and says why."""
        loaded = load_model(self.settings, self.scheduler, self.tubes)
        if isinstance(loaded, str):
            self.model_error = loaded
            return
        self._tubes_in_workers = loaded.tubes_in_workers
        self.engine = loaded.engine
        self.card = loaded.card
        self.parts = loaded.parts
        self.model_name = loaded.card.name
        self.model_error = None
        freeze_start_up_objects()
        self.metrics.model_ready.set(1)

    def require_card(self) -> ModelCard:
        if self.card is None:
            raise ServiceUnavailableError(self.model_error or "model not loaded")
        return self.card

    def answer_costs_for(self, batch: bool) -> AnswerCosts:
        """The answer costs of single checks, or of batch checks."""
        return self.batch_answer_costs if batch else self.answer_costs

    def require_engine(self) -> FRTEngine:
        if self.engine is None:
            raise ServiceUnavailableError(self.model_error or "model not loaded")
        return self.engine

    # ------------------------------------------------------------------ FRT sets
    @staticmethod
    def job_for(state: AgentState) -> FRTJob:
        return job_for(state)

    def forget(self, agent_id: str) -> None:
        """Drop every set of ``agent_id``, exact and conservative, and its queued exact set."""
        self.scheduler.forget(agent_id)
        self.conservative_cache.forget(agent_id)
        self.tube_demand.forget(agent_id)
        self.demand.forget(agent_id)
        self.audit.forget(agent_id)

    def score_position(self, agent_id: str, x: float, y: float, t: float) -> list[Scored]:
        """The position (x, y) observed at ``t`` scored against the agent's earlier versions whose
        horizon covers ``t`` (``service.runtime.audit``); none if there are none."""
        versions = self.audit.due(agent_id, t)
        return score(x, y, t, versions, self.scheduler.lookup) if versions else []

    def take_audit(self, agent_id: str, scored: Sequence[Scored], t: float) -> None:
        """Count audited positions into the agent's counts and the ``frt_audit_*`` metrics."""
        count_audited(self.metrics, self.audit, self.coverage, agent_id, scored, t)

    def submit_many(self, jobs: Sequence[FRTJob]) -> None:
        """Start computing the exact sets of ``jobs``, whose versions observations have just
        stored here, in the background (queued together)."""
        self.scheduler.submit_many([(job.key, self.exact_task(job)) for job in jobs], observed=True)

    def cached_exact(self, jobs: Sequence[FRTJob]) -> list[FRTSet | None]:
        """Each job's exact set if it is computed already, else None; the hits are counted at once
        (a planner's check of 50 agents: one counter update, not 50)."""
        found = [self.scheduler.lookup(job.key) for job in jobs]
        hits = sum(frt is not None for frt in found)
        if hits:
            self.metrics.frt_cache.labels("hit").inc(hits)
        return found

    def exact_futures(self, jobs: Sequence[FRTJob], timeout_s: float) -> list[Future[Any] | None]:
        """Per job, the future of its exact set if it may be ready within ``timeout_s``, else None
        (``FRTScheduler.waitable_many``; starts the sets nobody has)."""
        return self.scheduler.waitable_many(
            [(job.key, self.exact_task(job)) for job in jobs], timeout_s
        )

    async def exact_within(self, job: FRTJob, timeout_s: float) -> FRTSet | None:
        """The exact set if it is ready within ``timeout_s`` (starting it if nobody has), else None."""
        return await self.scheduler.wait(job.key, self.exact_task(job), timeout_s)

    def exact_task(self, job: FRTJob) -> ExactTask:
        """``engine.exact`` for ``job``: on this engine in a thread, on its own in a worker process."""
        return ExactTask(
            job.pose,
            job.v_start,
            job.bounds,
            self.require_engine(),
            tubes_upto=self.tube_demand.upto(job.key.agent_id) if self._tubes_in_workers else -1,
        )

    def refinement_state(self, exact: FRTSet | None, key: FRTKey) -> str | None:
        """Of the ready exact set of ``key``: "done" if it is cut by the notch cut's last stage, or
        by an earlier one whose next was skipped (it would have landed after the agent's next
        observation: ``frt_refinement_stage`` says which), "failed" if a refinement raised (the
        set stays the one before, which contains the cut one), "pending" if a stage is due
        (``FRT_FRT_NOTCH_CUT`` and a set that may turn round; the first stage may have landed
        already), else "not_needed"; None if no set."""
        if exact is None:
            return None
        stage = exact.notch_stage
        if stage >= len(NOTCH_STAGES) or (stage > 0 and self.scheduler.refinement_skipped(key)):
            return "done"
        if self.scheduler.refinement_failed(key):
            return "failed"
        due = self.scheduler.refinement is not None and exact.notch_possible
        return "pending" if due else "not_needed"

    @staticmethod
    def refinement_stage(exact: FRTSet | None) -> int | None:
        """Of the ready exact set: how many stages of the notch cut it has had (0: uncut); None if
        no set."""
        if exact is None:
            return None
        return exact.notch_stage

    def conservative(self, job: FRTJob) -> FRTSet:
        """The engine's fast set that contains the exact one (boxes only, built on the caller's
        thread: less than a round trip to a worker process would cost).

        Cached per key: each observation builds its version's set, so a planner's check of 50
        agents whose exact sets are late looks them up instead of building 50 within its deadline.
        """
        engine = self.require_engine()

        def compute() -> FRTSet:
            start = time.perf_counter()
            if job.bounds.ndim == 2:
                result = conservative_union(engine, job.pose, job.v_start, job.bounds)
            else:
                result = engine.conservative(job.pose, job.v_start, job.bounds)
            elapsed = time.perf_counter() - start
            self.metrics.frt_compute_seconds.labels("conservative").observe(elapsed)
            return result

        result, _ = self.conservative_cache.get_or_compute(job.key, compute)
        return result  # type: ignore[no-any-return]

    def horizon_s(self) -> float:
        engine = self.engine
        return float(engine.horizon) if engine is not None else self.settings.horizon_s


def services_of(conn: HTTPConnection) -> Services:
    """FastAPI dependency: the app's :class:`Services` (works for requests and WebSockets)."""
    return conn.app.state.services  # type: ignore[no-any-return]
