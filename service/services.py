"""The objects one app shares between its routes: settings, store, scheduler, metrics, engine.

The model is loaded in a background thread at start-up: ``/healthz`` answers at once, ``/readyz`` and
the model-dependent routes answer 503 until it is loaded (or for good, if it cannot be).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Sequence
from concurrent.futures import BrokenExecutor, Executor, Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from starlette.concurrency import run_in_threadpool
from starlette.requests import HTTPConnection

from service.engine import FRTEngine, FRTSet, Pose
from service.errors import ServiceUnavailableError
from service.exact_worker import ConservativeTask, ExactTask, start_pool, warm_up_task
from service.memory import freeze_start_up_objects, keep_freed_memory
from service.metrics import Metrics
from service.model_runtime import ValueModel
from service.scheduler import FRTKey, FRTScheduler, LRUCache, timed
from service.settings import Settings
from service.store import AgentState, AgentStore, make_store
from service.tube_builder import TubeBuilder

log = logging.getLogger("frt.services")


@dataclass(frozen=True)
class FRTJob:
    """What one FRT depends on, and its cache key."""

    key: FRTKey
    pose: Pose
    v_start: float
    bounds: np.ndarray

    @classmethod
    def make(cls, agent_id: str, version: int, pose: Pose, v_start: float, bounds: Any) -> FRTJob:
        bounds = np.asarray(bounds, dtype=np.float64)
        inputs = (pose.x, pose.y, pose.heading, v_start, *bounds.tolist())
        return cls(FRTKey.of(agent_id, version, inputs), pose, float(v_start), bounds)


@dataclass
class Services:
    settings: Settings
    metrics: Metrics
    store: AgentStore
    scheduler: FRTScheduler
    conservative_cache: LRUCache
    engine: FRTEngine | None = None
    model_name: str | None = None
    model_error: str | None = "model is loading"
    _loader: asyncio.Task[None] | None = field(default=None, repr=False)
    #: A worker process for conservative sets (None: they are built on threads of this process).
    _conservative_pool: Executor | None = field(default=None, repr=False)
    #: Conservative sets on their way back from that worker.
    _conservative_pending: dict[FRTKey, Future[Any]] = field(default_factory=dict, repr=False)
    #: Recent seconds per agent to answer a collision check once its sets are known (moving average).
    _answer_s_per_agent: float = field(default=0.0, repr=False)
    #: Draws the tubes time-indexed checks need, now or between requests.
    tubes: TubeBuilder = field(default_factory=TubeBuilder, repr=False)

    @classmethod
    def build(cls, settings: Settings) -> Services:
        metrics = Metrics()
        store = make_store(
            settings.store_url, ttl_s=settings.agent_ttl_s, max_agents=settings.max_agents
        )
        scheduler = FRTScheduler(
            workers=settings.frt_workers, cache_size=settings.frt_cache_size, metrics=metrics
        )
        return cls(
            settings=settings,
            metrics=metrics,
            store=store,
            scheduler=scheduler,
            conservative_cache=LRUCache(settings.frt_cache_size),
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
        pool, self._conservative_pool = self._conservative_pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        await self.store.close()

    def load_model(self) -> None:
        """Load the ONNX model and its card and build the engine (blocking; runs in a thread)."""
        path = self.settings.model_path
        start = time.perf_counter()
        try:
            model = ValueModel.load(path)
            engine = FRTEngine(model)
        except Exception as exc:  # a missing or broken model must not stop the service
            self.model_error = f"model not loaded: {exc}"
            log.error("model not loaded", extra={"model_path": str(path), "error": str(exc)})
            return
        if self.settings.frt_executor == "process":
            self._start_worker_processes(path, engine)
        self.engine = engine
        self.model_name = model.card.name
        self.model_error = None
        freeze_start_up_objects()
        self.metrics.model_ready.set(1)
        log.info(
            "model loaded",
            extra={
                "model": model.card.name,
                "model_path": str(path),
                "seconds": round(time.perf_counter() - start, 3),
            },
        )

    def _start_worker_processes(self, path: Path, engine: FRTEngine) -> None:
        """Compute exact sets in worker processes (their engines loaded and warmed before the
        server reports ready); if they cannot start, stay on threads and say why."""
        start = time.perf_counter()
        workers = self.scheduler.workers
        try:
            pool = start_pool(path, workers, self.settings.frt_worker_nice)
        except Exception as exc:
            log.warning(
                "FRT worker processes not started: computing exact sets on threads",
                extra={"error": repr(exc)},
            )
            return
        # A worker's first result costs ~20-50 ms more than the next ones (the first pickling there
        # and unpickling here): one per worker before any request.
        with contextlib.suppress(Exception):
            for warm in [pool.submit(timed, warm_up_task(engine)) for _ in range(workers)]:
                frt, _ = warm.result(60.0)
            for kind, t in (("tube", None), ("slice", 1.0)):  # and the first contours drawn here
                frt.geojson(kind, t, self.settings.collision_radius)
        self.scheduler.use_executor(pool)
        try:  # at the server's priority: checks that find the exact set late need these at once
            self._conservative_pool = start_pool(path, 1, 0)
        except Exception as exc:
            log.warning(
                "conservative-set worker not started: building them on threads",
                extra={"error": repr(exc)},
            )
        log.info(
            "FRT worker processes started",
            extra={"workers": workers, "seconds": round(time.perf_counter() - start, 3)},
        )

    def require_engine(self) -> FRTEngine:
        if self.engine is None:
            raise ServiceUnavailableError(self.model_error or "model not loaded")
        return self.engine

    # ------------------------------------------------------------------ FRT sets
    def job_for(self, state: AgentState) -> FRTJob:
        pose = Pose(state.x, state.y, state.heading)
        return FRTJob.make(
            state.agent_id, state.frt_version, pose, state.speed, state.control_bounds
        )

    def submit(self, job: FRTJob) -> None:
        """Start computing the exact set of ``job`` in the background."""
        self.scheduler.submit(job.key, self.exact_task(job))

    def cached_exact(self, jobs: Sequence[FRTJob]) -> list[FRTSet | None]:
        """Each job's exact set if it is computed already, else None; the hits are counted at once
        (a planner's check of 50 agents: one counter update, not 50)."""
        found = [self.scheduler.lookup(job.key) for job in jobs]
        hits = sum(frt is not None for frt in found)
        if hits:
            self.metrics.frt_cache.labels("hit").inc(hits)
        return found

    def exact_future(self, job: FRTJob, timeout_s: float) -> Future[Any] | None:
        """The future of ``job``'s exact set if it may be ready within ``timeout_s``, else None
        (``FRTScheduler.waitable``; starts the set if nobody has)."""
        return self.scheduler.waitable(job.key, self.exact_task(job), timeout_s)

    async def exact_within(self, job: FRTJob, timeout_s: float) -> FRTSet | None:
        """The exact set if it is ready within ``timeout_s`` (starting it if nobody has), else None."""
        return await self.scheduler.wait(job.key, self.exact_task(job), timeout_s)

    def exact_task(self, job: FRTJob) -> ExactTask:
        """``engine.exact`` for ``job``: on this engine in a thread, on its own in a worker process."""
        return ExactTask(job.pose, job.v_start, job.bounds, self.require_engine())

    def prepare_conservative(self, job: FRTJob) -> None:
        """Build the conservative set of ``job`` now, in the conservative-set worker process (or a
        thread), so that a collision check that finds the exact set late looks it up instead of
        building it (~1 ms each: 50 agents in one check would otherwise miss a 20 ms deadline on
        this alone)."""
        pool = self._conservative_pool
        if pool is None:
            asyncio.get_running_loop().run_in_executor(None, self.conservative, job)
            return
        try:
            handle = pool.submit(timed, ConservativeTask(job.pose, job.v_start, job.bounds))
        except Exception as exc:  # a broken pool: threads from now on
            self._conservative_failed(exc)
            asyncio.get_running_loop().run_in_executor(None, self.conservative, job)
            return
        self._conservative_pending[job.key] = handle
        handle.add_done_callback(lambda done: self._conservative_done(job, done))

    def conservative_on_its_way(self, job: FRTJob) -> Future[Any] | None:
        """The worker's future of ``job``'s conservative set if it is not cached yet, else None:
        a check can wait for it briefly rather than build it a second time."""
        if self.conservative_cache.peek(job.key) is not None:
            return None
        return self._conservative_pending.get(job.key)

    def _conservative_done(self, job: FRTJob, done: Future[Any]) -> None:
        self._conservative_pending.pop(job.key, None)
        if done.cancelled():
            return
        error = done.exception()
        if isinstance(error, BrokenExecutor):
            self._conservative_failed(error)
        if error is not None:
            return  # a check that needs the set builds it (and answers for a failure there)
        result, seconds = done.result()
        self.metrics.frt_compute_seconds.labels("conservative").observe(seconds)
        self.conservative_cache.put(job.key, result)

    def _conservative_failed(self, error: BaseException) -> None:
        pool, self._conservative_pool = self._conservative_pool, None
        if pool is not None:
            log.error(
                "conservative-set worker failed: building them on threads from now on",
                extra={"error": repr(error)},
            )
            pool.shutdown(wait=False, cancel_futures=True)

    def conservative(self, job: FRTJob) -> FRTSet:
        """The engine's fast set that contains the exact one (blocking: call from a thread).

        Cached per key too: a planner checking an agent at 10 Hz while its exact set is late
        (e.g. 50 agents in one multi-agent check) builds each conservative set once.
        """
        engine = self.require_engine()

        def compute() -> FRTSet:
            start = time.perf_counter()
            result = engine.conservative(job.pose, job.v_start, job.bounds)
            elapsed = time.perf_counter() - start
            self.metrics.frt_compute_seconds.labels("conservative").observe(elapsed)
            return result

        result, _ = self.conservative_cache.get_or_compute(job.key, compute)
        return result  # type: ignore[no-any-return]

    def record_answer_time(self, seconds: float, agents: int) -> None:
        if agents > 0:
            self._answer_s_per_agent += 0.2 * (seconds / agents - self._answer_s_per_agent)

    def answer_time_s(self, agents: int) -> float:
        """About how long answering ``agents`` agents of one collision check takes here."""
        return self._answer_s_per_agent * agents

    def horizon_s(self) -> float:
        engine = self.engine
        return float(engine.horizon) if engine is not None else self.settings.horizon_s


def services_of(conn: HTTPConnection) -> Services:
    """FastAPI dependency: the app's :class:`Services` (works for requests and WebSockets)."""
    return conn.app.state.services  # type: ignore[no-any-return]
