"""The conservative sets of many jobs at once (a frame's new versions): each one cached per key as
``Services.conservative`` caches it, the missing ones built together (``reach.union``:
every outer bound of the frame propagated in one pass, each bit for bit the one built alone)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

from reach.sets import FRTSet
from reach.union import conservative_sets
from service.runtime.jobs import FRTJob

if TYPE_CHECKING:
    from service.runtime.services import Services


def cached_conservative(services: Services, jobs: Sequence[FRTJob]) -> list[FRTSet]:
    """Each job's conservative set (boxes only, on the caller's thread): from the cache, or built
    with the other missing ones and cached, so that checks finding an exact set late look it up."""
    cache = services.conservative_cache
    found: list[FRTSet | None] = [cache.get(job.key) for job in jobs]
    missing = [i for i, frt in enumerate(found) if frt is None]
    if missing:
        engine = services.require_engine()
        start = time.perf_counter()
        built = conservative_sets(
            engine,
            [jobs[i].pose for i in missing],
            [jobs[i].v_start for i in missing],
            [jobs[i].bounds for i in missing],
        )
        each = (time.perf_counter() - start) / len(missing)
        observe = services.metrics.frt_compute_seconds.labels("conservative").observe
        for i, frt in zip(missing, built, strict=True):
            cache.put(jobs[i].key, frt)
            found[i] = frt
            observe(each)
    return found  # type: ignore[return-value]
