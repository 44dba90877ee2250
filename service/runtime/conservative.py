"""The conservative sets of many jobs at once (a frame's new versions): each one cached per key as
``Services.conservative`` caches it, the missing ones built together (``reach.union``: every
outer bound of the frame propagated in one pass, each bit for bit the one built alone).

A frame's outer bounds are propagated on threads of their own, its rows split between them (the
compiled propagation holds no GIL, and rows are independent), while the event loop goes on with
the frame and awaits them (:func:`start_conservative`); a few settings are propagated in place,
where the hand-over would cost more than it saves.
"""

from __future__ import annotations

import asyncio
import itertools
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from reach.batch import KERNEL_THREADS
from reach.sets import FRTSet
from reach.union import SettingRows
from service.runtime.jobs import FRTJob

if TYPE_CHECKING:
    from service.runtime.services import Services

#: Rows of bounds (settings, a multi-modal one's modes each) from which the outer bounds are
#: propagated on the thread.
THREAD_ROWS = 16
#: Threads a frame's rows are split between: as many as a batch check's kernels use, two where
#: the process may use two CPUs (the exact-set workers yield them: they run below the server).
PROPAGATION_THREADS = KERNEL_THREADS
_PROPAGATION = ThreadPoolExecutor(
    max_workers=PROPAGATION_THREADS, thread_name_prefix="frt-conservative"
)


@dataclass(frozen=True)
class ConservativeBuild:
    """Conservative sets under way: ``finish()`` waits for the propagation (if it is on the
    threads), builds and caches the sets and answers every job's; :meth:`propagated` awaits the
    threads without holding the event loop, so that finishing then does not wait."""

    finish: Callable[[], list[FRTSet]]
    propagating: tuple[Future[tuple[np.ndarray, float]], ...] = ()

    async def propagated(self) -> None:
        pending = [asyncio.wrap_future(f) for f in self.propagating if not f.done()]
        if pending:
            await asyncio.wait(pending)


def cached_conservative(services: Services, jobs: Sequence[FRTJob]) -> list[FRTSet]:
    """Each job's conservative set (boxes only, on the caller's thread unless there are many):
    from the cache, or built with the other missing ones and cached, so that checks finding an
    exact set late look it up."""
    return start_conservative(services, jobs).finish()


def start_conservative(services: Services, jobs: Sequence[FRTJob]) -> ConservativeBuild:
    """Start building the conservative sets of ``jobs`` that are not cached (the propagation of
    many rows on the threads, split between them)."""
    cache = services.conservative_cache
    found: list[FRTSet | None] = [cache.get(job.key) for job in jobs]
    missing = [i for i, frt in enumerate(found) if frt is None]
    if not missing:
        return ConservativeBuild(lambda: found)  # type: ignore[arg-type, return-value]
    engine = services.require_engine()
    rows = SettingRows.of(
        [jobs[i].pose for i in missing],
        [jobs[i].v_start for i in missing],
        [jobs[i].bounds for i in missing],
    )

    def propagate(part: slice) -> tuple[np.ndarray, float]:
        start = time.perf_counter()
        return rows.sweeps(engine, part), time.perf_counter() - start

    propagating: tuple[Future[tuple[np.ndarray, float]], ...] = ()
    if len(rows.bounds) >= THREAD_ROWS:
        edges = np.linspace(0, len(rows.bounds), PROPAGATION_THREADS + 1).round().astype(int)
        parts = [slice(int(a), int(b)) for a, b in itertools.pairwise(edges)]
        propagating = tuple(_PROPAGATION.submit(propagate, part) for part in parts)

    def finish() -> list[FRTSet]:
        done = [f.result() for f in propagating] or [propagate(slice(None))]
        sweeps = np.concatenate([part for part, _ in done])
        seconds = sum(s for _, s in done)
        start = time.perf_counter()
        built = rows.sets(engine, sweeps)  # type: ignore[arg-type]
        each = (seconds + time.perf_counter() - start) / len(missing)
        observe = services.metrics.frt_compute_seconds.labels("conservative").observe
        for i, frt in zip(missing, built, strict=True):
            cache.put(jobs[i].key, frt)
            found[i] = frt
            observe(each)
        return found  # type: ignore[return-value]

    return ConservativeBuild(finish, propagating)  # type: ignore[arg-type]
