"""The refinement queue: tighter sets of keys already served, run on workers' spare time.

A set may be *refined* after it is ready: a tighter set of the same key (the notch cut,
``reach.notch``), computed when no exact set is waiting and on at most ``workers - 1`` workers,
replaces the cached one (``service.runtime.scheduler.FRTScheduler``, which owns the workers and
the lock every method here is called under). Refinements come in stages: a set's first stage
waits in the first queue, later stages in the second, which runs only while the first is empty (a
quick first cut of every agent before any fine one). A later stage that would land after its
agent's next version is skipped: nobody would ask for that version's set by then.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Any

from service.runtime.metrics import Metrics

#: Refinements start newest first: the version observed last has the most of its life left to be
#: served (``scripts/refinement_landing.py`` measures it). One queued this long goes next all the
#: same, so that an agent observed rarely, whose version stays current, is not passed over for
#: ever by agents observed often.
REFINE_OLDEST_AFTER_S = 1.0


@dataclass(frozen=True)
class Refinement:
    """A tighter set's computation, and which stage of its refinement it is (1: the first)."""

    compute: Callable[[], Any]
    stage: int = 1


#: Given a finished set's compute and result, the refinement of the same key (or None).
RefinementRule = Callable[[Callable[[], Any], Any], Refinement | None]


@dataclass(frozen=True)
class Queued:
    """A refinement waiting for a worker: its key (``FRTKey``), what it runs, since when."""

    key: Any
    refinement: Refinement
    queued_at: float


class RefinementQueue:
    """Queued and running refinements, and what is known of how long each stage takes."""

    def __init__(self, metrics: Metrics, remembered: int) -> None:
        self._metrics = metrics
        self._remembered = remembered
        self.rule: RefinementRule | None = None
        self._first: OrderedDict[Hashable, Queued] = OrderedDict()  # by slot: agent, or key
        self._later: OrderedDict[Hashable, Queued] = OrderedDict()
        self.running: set[Any] = set()
        #: Per agent, its latest version and when its last two versions came.
        self._version_times: OrderedDict[str, tuple[int, float, float]] = OrderedDict()
        self._typical_s: dict[int, float] = {}
        self._failed: OrderedDict[Any, None] = OrderedDict()
        self._skipped: OrderedDict[Any, None] = OrderedDict()

    # ------------------------------------------------------------------ bookkeeping
    def note_version(self, key: Any) -> None:
        """Remember when ``key``'s agent's latest versions came."""
        now = time.perf_counter()
        known = self._version_times.get(key.agent_id)
        if known is None:
            self._version_times[key.agent_id] = (key.version, -math.inf, now)
        elif key.version > known[0]:
            self._version_times[key.agent_id] = (key.version, known[2], now)
        self._version_times.move_to_end(key.agent_id)
        while len(self._version_times) > self._remembered:
            self._version_times.popitem(last=False)

    def lands_in_time(self, key: Any, stage: int) -> bool:
        """Whether a refinement of ``key`` at ``stage`` is expected to land while ``key`` is its
        agent's current version: if the agent's next version comes as long after this one as this
        one came after the one before, and the stage takes as long as it has (moving average)."""
        known = self._version_times.get(key.agent_id) if key.agent_id else None
        typical = self._typical_s.get(stage)
        if known is not None and known[0] > key.version:
            return False  # superseded already
        if known is None or typical is None:
            return True
        _, previous, latest = known
        return time.perf_counter() - latest + typical < latest - previous

    def took(self, stage: int, seconds: float) -> None:
        """A refinement at ``stage`` took ``seconds`` (moving average per stage)."""
        typical = self._typical_s.get(stage, seconds)
        self._typical_s[stage] = typical + 0.2 * (seconds - typical)

    def count(self, outcome: str, stage: int) -> None:
        """``frt_refinements_total`` by outcome and stage."""
        self._metrics.refinements.labels(outcome, str(stage)).inc()

    def remember_failed(self, key: Any) -> None:
        self._remember(self._failed, key)

    def failed(self, key: Any) -> bool:
        return key in self._failed

    def skipped(self, key: Any) -> bool:
        return key in self._skipped

    def _remember(self, keys: OrderedDict[Any, None], key: Any) -> None:
        keys[key] = None
        while len(keys) > self._remembered:
            keys.popitem(last=False)

    # ------------------------------------------------------------------ the queues
    def queue(self, key: Any, refinement: Refinement, later: bool) -> None:
        """Queue ``refinement`` of ``key``'s set in its slot (the newer one goes to the back): in
        the second queue if it refines a refinement (``later``)."""
        slot: Hashable = key.agent_id or key
        self.drop(slot)
        (self._later if later else self._first)[slot] = Queued(key, refinement, time.perf_counter())

    def drop(self, slot: Hashable) -> None:
        """Drop the refinement queued in ``slot``, in either queue."""
        for queue in (self._first, self._later):
            entry = queue.pop(slot, None)
            if entry is not None:
                self.count("dropped", entry.refinement.stage)

    def clear(self) -> None:
        self._first.clear()
        self._later.clear()

    def next(self, still_cached: Callable[[Any], bool]) -> Queued | None:
        """The refinement to start next: first stages before later ones; in each queue the newest
        first, or the oldest once it has waited REFINE_OLDEST_AFTER_S. One whose set left the
        cache (``still_cached``) is dropped, a later stage that would land stale is skipped."""
        while True:
            queue = self._first or self._later
            if not queue:
                return None
            oldest = next(iter(queue.values()))
            waited = time.perf_counter() - oldest.queued_at
            _, entry = queue.popitem(last=waited < REFINE_OLDEST_AFTER_S)
            stage = entry.refinement.stage
            if not still_cached(entry.key):
                self.count("dropped", stage)
                continue
            if queue is self._later and not self.lands_in_time(entry.key, stage):
                self.count("skipped", stage)
                self._remember(self._skipped, entry.key)
                continue
            return entry
