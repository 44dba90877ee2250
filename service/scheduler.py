"""Background computation of exact FRTs on a small thread pool, with an LRU cache of the results.

An observation submits the exact set of the agent's new FRT version and returns at once; a collision
check waits for that set only until its deadline (:meth:`FRTScheduler.wait`) and otherwise answers
from the engine's conservative set. Results are keyed by agent, version *and* a digest of the inputs,
so a cached set can never answer for other inputs (e.g. an agent deleted and created again, whose
versions restart, or another replica's state).
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import struct
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from service.metrics import Metrics

log = logging.getLogger("frt.scheduler")


@dataclass(frozen=True)
class FRTKey:
    agent_id: str  # "" for the stateless endpoint
    version: int
    digest: str

    @classmethod
    def of(cls, agent_id: str, version: int, inputs: Sequence[float]) -> FRTKey:
        """Key of the FRT for ``inputs`` = (x, y, heading, v_start, *eight bounds)."""
        packed = struct.pack(f"<{len(inputs)}d", *(float(v) for v in inputs))
        return cls(agent_id, version, hashlib.blake2b(packed, digest_size=12).hexdigest())


class LRUCache:
    """A small thread-safe least-recently-used map (for the conservative sets)."""

    def __init__(self, size: int) -> None:
        self._size = size
        self._items: OrderedDict[FRTKey, Any] = OrderedDict()
        self._lock = threading.Lock()

    def get_or_compute(self, key: FRTKey, compute: Callable[[], Any]) -> tuple[Any, bool]:
        """The cached value for ``key`` or ``compute()`` (cached); and whether it was a hit."""
        with self._lock:
            value = self._items.get(key)
            if value is not None:
                self._items.move_to_end(key)
                return value, True
        value = compute()  # outside the lock: two racing misses both compute, harmlessly
        with self._lock:
            self._items[key] = value
            self._items.move_to_end(key)
            while len(self._items) > self._size:
                self._items.popitem(last=False)
        return value, False


class FRTScheduler:
    def __init__(self, *, workers: int, cache_size: int, metrics: Metrics) -> None:
        self._workers = workers
        self._cache_size = cache_size
        self._metrics = metrics
        self._executor: ThreadPoolExecutor | None = None
        self._cache: OrderedDict[FRTKey, Any] = OrderedDict()
        self._pending: dict[FRTKey, Future[Any]] = {}
        self._lock = threading.RLock()  # done-callbacks may run inline in submit()

    def start(self) -> None:
        if self._executor is None:
            self._executor = ThreadPoolExecutor(self._workers, thread_name_prefix="frt-exact")

    def shutdown(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    def lookup(self, key: FRTKey) -> Any | None:
        """The cached set for ``key`` (marking it recently used), or ``None``."""
        with self._lock:
            result = self._cache.get(key)
            if result is not None:
                self._cache.move_to_end(key)
            return result

    def is_ready(self, key: FRTKey) -> bool:
        with self._lock:
            return key in self._cache

    def submit(self, key: FRTKey, compute: Callable[[], Any]) -> Future[Any]:
        """Start computing ``key`` unless it is cached or under way; queued older versions of the same
        agent are cancelled, since no one will ask for them any more."""
        with self._lock:
            cached = self._cache.get(key)
            if cached is not None:
                done: Future[Any] = Future()
                done.set_result(cached)
                return done
            pending = self._pending.get(key)
            if pending is not None:
                return pending
            if key.agent_id:
                for other, fut in list(self._pending.items()):
                    if other.agent_id == key.agent_id and other.version < key.version:
                        fut.cancel()  # only succeeds while still queued
            if self._executor is None:
                raise RuntimeError("scheduler not started")
            fut = self._executor.submit(self._run, compute)
            self._pending[key] = fut
            fut.add_done_callback(lambda f: self._done(key, f))
            return fut

    async def wait(
        self,
        key: FRTKey,
        compute: Callable[[], Any],
        timeout_s: float,
        *,
        wait_if_queued: bool = True,
    ) -> Any | None:
        """The exact set for ``key`` if it is (or becomes) ready within ``timeout_s``, else ``None``.

        With ``wait_if_queued=False`` a set that is still queued behind others (submitted earlier,
        not yet started) is not waited for: it would rarely finish within a collision check's
        deadline. Never cancels the computation: a late result still lands in the cache.
        """
        cached = self.lookup(key)
        if cached is not None:
            self._metrics.frt_cache.labels("hit").inc()
            return cached
        with self._lock:
            under_way = key in self._pending
        self._metrics.frt_cache.labels("pending" if under_way else "miss").inc()
        submitted = self.submit(key, compute)
        if under_way and not wait_if_queued and not (submitted.running() or submitted.done()):
            return None
        future = asyncio.wrap_future(submitted)
        if timeout_s > 0:
            await asyncio.wait({future}, timeout=timeout_s)
        if future.done() and not future.cancelled() and future.exception() is None:
            return future.result()
        return None

    def forget(self, agent_id: str) -> None:
        with self._lock:
            for key in [k for k in self._cache if k.agent_id == agent_id]:
                del self._cache[key]
            for key, fut in list(self._pending.items()):
                if key.agent_id == agent_id:
                    fut.cancel()

    def _run(self, compute: Callable[[], Any]) -> Any:
        start = time.perf_counter()
        result = compute()
        self._metrics.frt_compute_seconds.labels("exact").observe(time.perf_counter() - start)
        return result

    def _done(self, key: FRTKey, fut: Future[Any]) -> None:
        with self._lock:
            self._pending.pop(key, None)
            if fut.cancelled():
                return
            error = fut.exception()
            if error is None:
                self._cache[key] = fut.result()
                self._cache.move_to_end(key)
                while len(self._cache) > self._cache_size:
                    self._cache.popitem(last=False)
                return
        self._metrics.frt_failures.inc()
        log.error(
            "exact FRT failed",
            extra={"agent_id": key.agent_id, "frt_version": key.version, "error": repr(error)},
            exc_info=error,
        )
