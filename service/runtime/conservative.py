"""The conservative sets of many jobs at once (a frame's new versions): each one cached per key as
``Services.conservative`` caches it, the missing ones built together (``reach.union``: every
outer bound of the frame propagated in one pass, each bit for bit the one built alone).

A frame's outer bounds are propagated on a thread of their own (the compiled propagation holds
no GIL) while the event loop goes on with the frame (:func:`start_conservative`); a few settings
are propagated in place, where the hand-over would cost more than it saves.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

from reach.sets import FRTSet
from reach.union import SettingRows
from service.runtime.jobs import FRTJob

if TYPE_CHECKING:
    from service.runtime.services import Services

#: Rows of bounds (settings, a multi-modal one's modes each) from which the outer bounds are
#: propagated on the thread.
THREAD_ROWS = 16
_PROPAGATION = ThreadPoolExecutor(max_workers=1, thread_name_prefix="frt-conservative")


def cached_conservative(services: Services, jobs: Sequence[FRTJob]) -> list[FRTSet]:
    """Each job's conservative set (boxes only, on the caller's thread unless there are many):
    from the cache, or built with the other missing ones and cached, so that checks finding an
    exact set late look it up."""
    return start_conservative(services, jobs)()


def start_conservative(services: Services, jobs: Sequence[FRTJob]) -> Callable[[], list[FRTSet]]:
    """Start building the conservative sets of ``jobs`` that are not cached; the call returned
    finishes them (waiting for the propagation), caches them and answers every job's set."""
    cache = services.conservative_cache
    found: list[FRTSet | None] = [cache.get(job.key) for job in jobs]
    missing = [i for i, frt in enumerate(found) if frt is None]
    if not missing:
        return lambda: found  # type: ignore[return-value]
    engine = services.require_engine()
    rows = SettingRows.of(
        [jobs[i].pose for i in missing],
        [jobs[i].v_start for i in missing],
        [jobs[i].bounds for i in missing],
    )

    def propagate() -> tuple[object, float]:
        start = time.perf_counter()
        return rows.sweeps(engine), time.perf_counter() - start

    propagating = _PROPAGATION.submit(propagate) if len(rows.bounds) >= THREAD_ROWS else None

    def finish() -> list[FRTSet]:
        sweeps, seconds = propagate() if propagating is None else propagating.result()
        start = time.perf_counter()
        built = rows.sets(engine, sweeps)  # type: ignore[arg-type]
        each = (seconds + time.perf_counter() - start) / len(missing)
        observe = services.metrics.frt_compute_seconds.labels("conservative").observe
        for i, frt in zip(missing, built, strict=True):
            cache.put(jobs[i].key, frt)
            found[i] = frt
            observe(each)
        return found  # type: ignore[return-value]

    return finish
