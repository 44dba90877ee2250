"""Background computation of exact FRTs on a few workers, with an LRU cache of the results.

Workers are threads or, in the server, processes (:mod:`service.runtime.exact_worker`): an exact set is
milliseconds of numpy and onnxruntime that, on a thread, would hold the event loop's GIL.

An observation submits the exact set of the agent's new FRT version and returns at once; a collision
check waits for that set only until its deadline (:meth:`FRTScheduler.wait`) and otherwise answers
from the engine's conservative set. Results are keyed by agent, version *and* a digest of the inputs,
so a cached set can never answer for other inputs (e.g. an agent deleted and created again, whose
versions restart, or another replica's state).

A set may be *refined* after it is ready (:attr:`FRTScheduler.refinement`, the queue of
``service.runtime.refiner``): a tighter set of the same key, computed when no exact set is waiting
and on at most ``workers - 1`` workers, replaces the cached one. Readiness (and so observation ->
ready) is the first set's; both contain the true set.
"""

from __future__ import annotations

import asyncio
import functools
import hashlib
import heapq
import logging
import math
import struct
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import BrokenExecutor, CancelledError, Executor, Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from service.runtime.demand import ExactDemand
from service.runtime.metrics import Metrics
from service.runtime.refiner import Refinement, RefinementQueue, RefinementRule

log = logging.getLogger("frt.scheduler")


class FRTKey(NamedTuple):
    """An agent's version of a set and the digest of its inputs (a named tuple: hashed and
    compared in C, as the caches and queues do hundreds of times a check)."""

    agent_id: str  # "" for the stateless endpoint
    version: int
    digest: str

    @classmethod
    def of(cls, agent_id: str, version: int, inputs: Sequence[float]) -> FRTKey:
        """Key of the FRT for ``inputs`` = (x, y, heading, v_start, *eight bounds)."""
        packed = struct.pack(f"<{len(inputs)}d", *(float(v) for v in inputs))
        return cls(agent_id, version, hashlib.blake2b(packed, digest_size=12).hexdigest())


#: Sets kept per agent: its current version's and the one before (for a check that read the agent's
#: state just before an update). Older versions are never asked for again (checks, contours and
#: observations use the current state's), and a cache full of them only kept objects alive for the
#: garbage collector to walk (tens of polygons per exact set once its tubes are drawn).
VERSIONS_PER_AGENT = 2

#: Exact sets start newest first; the oldest queued goes next all the same once it has waited
#: this long, so that an agent observed rarely (whose queued version stays current) is not passed
#: over for ever by agents observed often, whose queued versions are replaced by newer ones.
EXACT_OLDEST_AFTER_S = 0.5


class LRUCache:
    """A small thread-safe least-recently-used map of FRT sets by :class:`FRTKey`, holding at most
    ``per_agent`` keys of each agent (the latest cached; the stateless endpoint's, agent "", are
    limited by ``size`` only)."""

    def __init__(self, size: int, per_agent: int = VERSIONS_PER_AGENT) -> None:
        self._size = size
        self._per_agent = per_agent
        self._items: OrderedDict[FRTKey, Any] = OrderedDict()
        self._by_agent: dict[str, list[FRTKey]] = {}  # cached keys per agent, oldest first
        self._lock = threading.Lock()

    def __len__(self) -> int:
        with self._lock:
            return len(self._items)

    def __contains__(self, key: object) -> bool:
        with self._lock:
            return key in self._items

    def get(self, key: FRTKey) -> Any | None:
        """The cached value for ``key`` (marked recently used), or None."""
        with self._lock:
            value = self._items.get(key)
            if value is not None:
                self._items.move_to_end(key)
            return value

    def get_or_compute(self, key: FRTKey, compute: Callable[[], Any]) -> tuple[Any, bool]:
        """The cached value for ``key`` or ``compute()`` (cached); and whether it was a hit."""
        value = self.get(key)
        if value is not None:
            return value, True
        value = compute()  # outside the lock: two racing misses both compute, harmlessly
        self.put(key, value)
        return value, False

    def put(self, key: FRTKey, value: Any) -> None:
        """Cache ``value`` for ``key``; the agent's oldest keys beyond ``per_agent`` and the least
        recently used beyond ``size`` go."""
        with self._lock:
            known = key in self._items
            self._items[key] = value
            self._items.move_to_end(key)
            if key.agent_id and not known:
                keys = self._by_agent.setdefault(key.agent_id, [])
                keys.append(key)
                while len(keys) > self._per_agent:
                    self._items.pop(keys.pop(0), None)
            while len(self._items) > self._size:
                self._untrack(self._items.popitem(last=False)[0])

    def replace(self, key: FRTKey, value: Any) -> bool:
        """Put ``value`` in place of ``key``'s cached one, if ``key`` is still cached (its place
        in the LRU order kept); whether it was."""
        with self._lock:
            if key not in self._items:
                return False
            self._items[key] = value
            return True

    def newer_cached(self, key: FRTKey) -> bool:
        """Whether a later version of ``key``'s agent is cached."""
        with self._lock:
            return any(k.version > key.version for k in self._by_agent.get(key.agent_id, ()))

    def forget(self, agent_id: str) -> None:
        """Drop every set of ``agent_id``."""
        with self._lock:
            for key in self._by_agent.pop(agent_id, []):
                self._items.pop(key, None)

    def _untrack(self, key: FRTKey) -> None:
        keys = self._by_agent.get(key.agent_id)
        if keys is not None and key in keys:
            keys.remove(key)
            if not keys:
                del self._by_agent[key.agent_id]


class FRTScheduler:
    """Exact sets computed on an executor (threads, or worker processes: :meth:`use_executor`),
    at most ``workers`` at a time.

    Sets wait in the scheduler's own queue, one per agent, until a worker is free: a newer version
    of an agent replaces its queued older one, and a version older than one queued or running for
    the same agent is not started at all. Only then does a set go to the executor, which therefore
    never holds a superseded one. The set submitted last goes first (``EXACT_OLDEST_AFTER_S``):
    when the workers fall behind, the version observed last has the most of its life left to be
    served, while one that waited is the likeliest to be superseded before it is ready.
    """

    def __init__(self, *, workers: int, cache_size: int, metrics: Metrics) -> None:
        self._workers = workers
        #: Sets handed to the executor at once: ``workers``, or more where the executor keeps
        #: each worker's next task at hand (:meth:`use_executor`).
        self._slots = workers
        self._metrics = metrics
        self._executor: Executor | None = None
        self._cache = LRUCache(cache_size)
        self._cache_size = cache_size
        self._pending: dict[FRTKey, _Job] = {}  # queued or running
        self._queue: OrderedDict[Hashable, FRTKey] = OrderedDict()  # one per agent, FIFO
        self._running: set[FRTKey] = set()
        #: The running sets started for agents not demanded while a :attr:`demand` is set.
        self._background: set[FRTKey] = set()
        #: When each running set was handed to a worker, and how long sets take from there
        #: (moving average), to tell whether a running set can finish within a check's wait.
        self._started: dict[FRTKey, float] = {}
        self._typical_s = 0.0
        self._discard: set[FRTKey] = set()  # running for a forgotten agent: do not cache
        self._refinements = RefinementQueue(metrics, remembered=cache_size)
        self._lock = threading.RLock()  # done-callbacks may run inline in submit()
        #: The agents whose queued sets start first (None: the newest first, whoever's).
        self.demand: ExactDemand | None = None

    @property
    def workers(self) -> int:
        return self._workers

    @property
    def refinement(self) -> RefinementRule | None:
        """Given a finished set's compute and result, the refinement of the same key (or None):
        asked again of each refinement that lands, so refinements may come in stages."""
        return self._refinements.rule

    @refinement.setter
    def refinement(self, rule: RefinementRule | None) -> None:
        self._refinements.rule = rule

    def start(self) -> None:
        with self._lock:
            if self._executor is None:
                self._executor = ThreadPoolExecutor(self._workers, thread_name_prefix="frt-exact")

    def use_executor(self, executor: Executor, depth: int = 1) -> None:
        """Compute on ``executor`` from now on (e.g. a process pool; its tasks must then pickle).
        Sets already started finish where they are; the scheduler shuts ``executor`` down.
        ``depth``: tasks each worker holds at once (``PipePool``'s), so up to ``workers * depth``
        sets are handed over together."""
        with self._lock:
            old = self._executor
            self._executor = executor
            self._slots = self._workers * depth
        if old is not None:
            old.shutdown(wait=False)
        self._dispatch()

    def shutdown(self) -> None:
        with self._lock:
            executor, self._executor = self._executor, None
            queued = [self._pending.pop(key) for key in self._queue.values()]
            self._queue.clear()
            self._refinements.clear()
        for job in queued:
            job.future.cancel()
        if executor is not None:
            # Worker processes are waited for (at most the sets they are computing) so that none
            # outlives the server; threads are not.
            wait = not isinstance(executor, ThreadPoolExecutor)
            executor.shutdown(wait=wait, cancel_futures=True)

    def lookup(self, key: FRTKey) -> Any | None:
        """The cached set for ``key`` (marking it recently used), or ``None``."""
        return self._cache.get(key)

    def is_ready(self, key: FRTKey) -> bool:
        return key in self._cache

    def submit(
        self, key: FRTKey, compute: Callable[[], Any], *, observed: bool = False
    ) -> Future[Any]:
        """Start computing ``key`` unless it is cached or under way. A queued older version of the
        same agent is cancelled and this one is queued in its stead, to start first (newest
        first); if a newer version is queued or running, this one is not computed (the returned
        future is cancelled). ``observed``: the version was stored here by an observation (its
        set is counted as such in ``frt_exact_sets``; else it was read from the store)."""
        return self.submit_many([(key, compute)], observed=observed)[0]

    def submit_many(
        self, jobs: Sequence[tuple[FRTKey, Callable[[], Any]]], *, observed: bool = False
    ) -> list[Future[Any]]:
        """:meth:`submit` of each (key, compute) in turn (a frame's agents), the workers fed once
        after all of them are queued."""
        with self._lock:
            if self._executor is None:
                raise RuntimeError("scheduler not started")
            futures = [self._enqueued(key, compute, observed) for key, compute in jobs]
        self._dispatch()
        return futures

    def _enqueued(self, key: FRTKey, compute: Callable[[], Any], observed: bool) -> Future[Any]:
        """:meth:`submit`'s queueing of one key (called with ``_lock`` held)."""
        cached = self._cache.get(key)
        if cached is not None:
            done: Future[Any] = Future()
            done.set_result(cached)
            return done
        pending = self._pending.get(key)
        if pending is not None:
            pending.observed |= observed
            return pending.future
        future: Future[Any] = Future()
        slot: Hashable = key.agent_id or key
        if key.agent_id:
            # The agent's queued set is in its slot (one per agent): no scan of the queue.
            older = self._queue.get(slot)
            if (older is not None and older.version > key.version) or any(
                k.agent_id == key.agent_id and k.version > key.version for k in self._running
            ):
                future.cancel()
                return future
            if older is not None:
                self._pending.pop(older).future.cancel()
        self._pending[key] = _Job(compute, future, observed=observed)
        self._queue[slot] = key
        self._queue.move_to_end(slot)  # the newest at the end, taken first
        if key.agent_id:
            self._refinements.note_version(key)
        return future

    async def wait(self, key: FRTKey, compute: Callable[[], Any], timeout_s: float) -> Any | None:
        """The exact set for ``key`` if it is (or becomes) ready within ``timeout_s``, else ``None``.

        Never cancels the computation: a late result still lands in the cache. (Collision checks
        use :meth:`waitable`, which skips sets that cannot make their deadline.)
        """
        cached = self.lookup(key)
        if cached is not None:
            self._metrics.frt_cache.labels("hit").inc()
            return cached
        with self._lock:
            under_way = key in self._pending
        self._metrics.frt_cache.labels("pending" if under_way else "miss").inc()
        submitted = self.submit(key, compute)
        if submitted.cancelled():
            return None
        future = asyncio.wrap_future(submitted)
        if timeout_s > 0:
            await asyncio.wait({future}, timeout=timeout_s)
        if future.done() and not future.cancelled() and future.exception() is None:
            return future.result()
        return None

    def waitable(
        self, key: FRTKey, compute: Callable[[], Any], timeout_s: float
    ) -> Future[Any] | None:
        """For a collision check, without awaiting: the future of ``key``'s set if it may be ready
        within ``timeout_s`` at the workers' recent pace (done; running and due; or queued and
        its turn due, :meth:`queued_finish_s`), else ``None``. Starts computing it if nobody has. A check of many
        agents then awaits the few futures together instead of one task per agent."""
        return self.waitable_many([(key, compute)], timeout_s)[0]

    def waitable_many(
        self, jobs: Sequence[tuple[FRTKey, Callable[[], Any]]], timeout_s: float
    ) -> list[Future[Any] | None]:
        """:meth:`waitable` of several sets, the cache metrics counted once per label (a
        planner's check of 50 agents whose sets are late: one update, not 50)."""
        with self._lock:
            under_way = sum(key in self._pending for key, _ in jobs)
        for label, count in (("pending", under_way), ("miss", len(jobs) - under_way)):
            if count:
                self._metrics.frt_cache.labels(label).inc(count)
        futures = self.submit_many(jobs)
        queued_finish = self.queued_finish_s() if any(not f.running() for f in futures) else {}
        out: list[Future[Any] | None] = []
        for (key, _), future in zip(jobs, futures, strict=True):
            if future.cancelled():
                out.append(None)
            elif future.done():
                out.append(future)
            elif future.running():
                out.append(future if self.expected_remaining_s(key) <= timeout_s else None)
            else:
                out.append(future if queued_finish.get(key, math.inf) <= timeout_s else None)
        return out

    def queued_finish_s(self) -> dict[FRTKey, float]:
        """About how long until each queued exact set is done, at the workers' recent pace: the
        queue taken newest first by the first worker free (a running exact set's worker when it is
        due; a worker refining is taken as busy beyond any wait). Empty while no set has been
        timed here."""
        with self._lock:
            typical = self._typical_s
            if typical <= 0.0 or self._executor is None:
                return {}
            now = time.perf_counter()
            free = [max(self._started.get(k, now) + typical - now, 0.0) for k in self._running]
            free = sorted(free)[: self._workers]  # handed-over sets beyond a worker each wait
            idle = self._workers - len(self._running) - len(self._refinements.running)
            free += [0.0] * max(idle, 0)
            queued = list(reversed(self._queue.values()))  # newest first, as dispatched
        heapq.heapify(free)
        finish: dict[FRTKey, float] = {}
        for key in queued:
            if not free:
                break
            done = heapq.heappop(free) + typical
            finish[key] = done
            heapq.heappush(free, done)
        return finish

    def expected_remaining_s(self, key: FRTKey) -> float:
        """About how long until the running set ``key`` is done (0 if unknown or not running)."""
        with self._lock:
            started = self._started.get(key)
            typical = self._typical_s
        if started is None:
            return 0.0
        return max(started + typical - time.perf_counter(), 0.0)

    def forget(self, agent_id: str) -> None:
        with self._lock:
            self._cache.forget(agent_id)
            queued = self._queue.pop(agent_id, None)
            job = self._pending.pop(queued) if queued is not None else None
            self._refinements.drop(agent_id)
            self._discard.update(
                k for k in self._running | self._refinements.running if k.agent_id == agent_id
            )
        if job is not None:
            job.future.cancel()

    def _dispatch(self) -> None:
        """Hand queued sets to the executor while fewer than ``workers`` are running; then, if no
        exact set waits, refinements (``_dispatch_refinements``)."""
        while True:
            with self._lock:
                if self._executor is None:
                    return
                if len(self._running) + len(self._refinements.running) >= self._slots:
                    return
                if not self._queue:
                    self._dispatch_refinements()
                    return
                key = self._next_queued()
                if key is None:  # only others' sets queued, and their workers busy
                    return
                job = self._pending[key]
                if not job.future.set_running_or_notify_cancel():
                    del self._pending[key]
                    self._background.discard(key)
                    continue
                self._running.add(key)
                job.dispatched = self._started[key] = time.perf_counter()
                self._metrics.exact_phase_seconds.labels("queued").observe(
                    job.dispatched - job.submitted
                )
                executor = self._executor
                try:
                    handle = executor.submit(timed, job.compute)
                except Exception as exc:  # e.g. a broken process pool; _finished says so
                    handle = Future()
                    handle.set_exception(exc)
            handle.add_done_callback(functools.partial(self._finished, key))

    def _next_queued(self) -> FRTKey | None:
        """Take the next queued set (lock held, queue not empty): of the demanded agents'
        (:attr:`demand`) if any is queued (of those a trajectory met, if any is), else of all;
        among them the newest, or the oldest once it has waited ``EXACT_OLDEST_AFTER_S``. None
        while agents are demanded, none of theirs is queued and the others' sets hold every
        worker but one (kept for the demanded ones)."""
        demand = self.demand
        slots = list(self._queue)
        if demand is not None:
            wanted = [s for s in slots if self._queue[s].agent_id and demand.wants(s)]
            if not wanted and len(self._background) >= self._background_cap(demand):
                return None
            met = [s for s in wanted if demand.met(s)]
            priority = "demanded" if wanted else "background"
            self._metrics.exact_set_starts.labels(priority).inc()
            slots = met or wanted or slots
        oldest = self._queue[slots[0]]
        waited = time.perf_counter() - self._pending[oldest].submitted
        key = self._queue.pop(slots[0] if waited >= EXACT_OLDEST_AFTER_S else slots[-1])
        if demand is not None and not wanted:
            self._background.add(key)
        if demand is not None and wanted:
            self._pending[key].priority = "met" if met else "demanded"
        return key

    def _background_cap(self, demand: ExactDemand) -> int:
        """How many sets of agents not demanded may be handed over at once: every slot while no
        agent is demanded, else one set per worker but one."""
        return self._workers - 1 if self._workers > 1 and demand.active() else self._slots

    def _dispatch_refinements(self) -> None:
        """Start queued refinements (``RefinementQueue.next``) on free workers, keeping one worker
        for exact sets (called with the lock held and no exact set queued)."""
        executor = self._executor
        assert executor is not None
        refinements = self._refinements
        while len(refinements.running) < max(self._workers - 1, 1):
            if len(self._running) + len(refinements.running) >= self._workers:
                return
            entry = refinements.next(lambda key: key in self._cache)
            if entry is None:
                return
            refinements.running.add(entry.key)
            try:
                handle = executor.submit(timed, entry.refinement.compute)
            except Exception as exc:
                handle = Future()
                handle.set_exception(exc)
            handle.add_done_callback(functools.partial(self._refined, entry.key, entry.refinement))

    def _superseded(self, key: FRTKey) -> bool:
        """Whether a later version of ``key``'s agent is queued, running or cached (called with the
        lock held): checks ask for that version's set from then on, not ``key``'s. The agent's
        queued set is in its slot, so only the few running sets are scanned."""
        if not key.agent_id:
            return False
        queued = self._queue.get(key.agent_id)
        later = (
            k for k in (queued, *self._running) if k is not None and k.agent_id == key.agent_id
        )
        return any(k.version > key.version for k in later) or self._cache.newer_cached(key)

    def refinement_failed(self, key: FRTKey) -> bool:
        """Whether the refinement of ``key``'s set raised (it then stays the set first made
        ready)."""
        with self._lock:
            return self._refinements.failed(key)

    def refinement_skipped(self, key: FRTKey) -> bool:
        """Whether a later stage of ``key``'s refinement was skipped
        (``RefinementQueue.lands_in_time``): its set stays as the stage before left it."""
        with self._lock:
            return self._refinements.skipped(key)

    def _queue_refinement(
        self, key: FRTKey, compute: Callable[[], Any], result: Any, later: bool = False
    ) -> None:
        """Queue the refinement of ``key``'s set ``result`` (made by ``compute``), if there is one:
        in the second queue if ``result`` is itself a refinement (``later``)."""
        rule = self._refinements.rule
        follow_up = rule(compute, result) if rule is not None else None
        if follow_up is None:
            return
        with self._lock:
            self._refinements.queue(key, follow_up, later)

    def _refined(self, key: FRTKey, refinement: Refinement, handle: Future[Any]) -> None:
        """A refinement is done: its set replaces the cached one of the same key (if still
        cached; a newer version or a forgotten agent drops it), and its own refinement, if any, is
        queued while the set is its agent's current one."""
        follow = False
        refinements = self._refinements
        stage = refinement.stage
        with self._lock:
            refinements.running.discard(key)
            discard = key in self._discard
            self._discard.discard(key)
            error = handle.exception() if not handle.cancelled() else CancelledError()
            if error is None:
                result, seconds = handle.result()
                landed = not discard and self._cache.replace(key, result)
                outcome = "wasted"
                if landed:
                    outcome = "stale" if self._superseded(key) else "landed"
                    self._metrics.frt_compute_seconds.labels("refined").observe(seconds)
                refinements.took(stage, seconds)
                refinements.count(outcome, stage)
                follow = outcome == "landed"
            elif not discard and not isinstance(error, CancelledError):
                refinements.count("failed", stage)
                refinements.remember_failed(key)
        if error is not None and not isinstance(error, CancelledError | BrokenExecutor):
            log.error(
                "FRT refinement failed",
                extra={"agent_id": key.agent_id, "frt_version": key.version, "error": repr(error)},
            )
        if follow:
            self._queue_refinement(key, refinement.compute, handle.result()[0], later=True)
        self._dispatch()

    def _finished(self, key: FRTKey, handle: Future[Any]) -> None:
        with self._lock:
            self._running.discard(key)
            self._background.discard(key)
            started = self._started.pop(key, None)
            if started is not None and not handle.cancelled() and handle.exception() is None:
                self._typical_s += 0.2 * (time.perf_counter() - started - self._typical_s)
            job = self._pending.pop(key, None)
            discard = key in self._discard
            self._discard.discard(key)
            error = handle.exception() if not handle.cancelled() else CancelledError()
            if error is None:
                result, seconds = handle.result()
                if not discard:
                    self._cache.put(key, result)
        if isinstance(error, BrokenExecutor) and job is not None and self._fall_back(key, job):
            return
        self._dispatch()
        if job is None:
            return
        if error is None:
            self._metrics.frt_compute_seconds.labels("exact").observe(seconds)
            self._metrics.exact_sets.labels(_origin(key, job)).inc()
            self._metrics.exact_ready_seconds.labels(job.priority).observe(
                time.perf_counter() - job.submitted
            )
            if job.dispatched is not None:
                transfer = time.perf_counter() - job.dispatched - seconds
                self._metrics.exact_phase_seconds.labels("transfer").observe(max(transfer, 0.0))
            if not discard:
                self._queue_refinement(key, job.compute, result)
                self._dispatch()
            job.future.set_result(result)
            return
        job.future.set_exception(error)
        self._metrics.frt_failures.inc()
        log.error(
            "exact FRT failed",
            extra={"agent_id": key.agent_id, "frt_version": key.version, "error": repr(error)},
            exc_info=error,
        )

    def _fall_back(self, key: FRTKey, job: _Job) -> bool:
        """The executor broke (a worker process died): log it, compute on threads from now on, and
        run ``job`` again there. False if the executor was already threads."""
        with self._lock:
            broken = self._executor
            if broken is None or isinstance(broken, ThreadPoolExecutor):
                return False
            log.error(
                "FRT worker processes failed: computing exact sets on threads from now on, "
                "without refinements"
            )
            self._executor = ThreadPoolExecutor(self._workers, thread_name_prefix="frt-exact")
            self._refinements.rule = None  # on threads they would hold the event loop's GIL
            self._refinements.clear()
            self._pending[key] = job
            self._running.add(key)
            job.dispatched = self._started[key] = time.perf_counter()
            handle = self._executor.submit(timed, job.compute)
        broken.shutdown(wait=False, cancel_futures=True)
        handle.add_done_callback(functools.partial(self._finished, key))
        self._dispatch()
        return True


@dataclass
class _Job:
    compute: Callable[[], Any]
    future: Future[Any]
    #: When it was submitted and when a worker got it (``time.perf_counter()``).
    submitted: float = field(default_factory=time.perf_counter)
    dispatched: float | None = None
    #: Submitted by the observation that stored its version on this replica.
    observed: bool = False
    #: Its priority when a worker took it (``frt_exact_ready_seconds``): met, demanded or
    #: background.
    priority: str = "background"


def _origin(key: FRTKey, job: _Job) -> str:
    """The ``origin`` label of ``frt_exact_sets`` for the set of ``key`` computed by ``job``."""
    if not key.agent_id:
        return "stateless"
    return "observed" if job.observed else "read"


def timed(compute: Callable[[], Any]) -> tuple[Any, float]:
    """``compute()`` and its duration in seconds (module level: it runs in worker processes too)."""
    start = time.perf_counter()
    result = compute()
    return result, time.perf_counter() - start
