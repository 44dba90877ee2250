"""Which agents' exact sets change planners' answers: the exact sets to build first.

A check whose trajectory clears an agent's conservative set has the exact set's verdict without it
(the exact set lies inside); an exact set changes an answer only for an agent whose set a planner's
trajectory comes near. Checks note such agents here (``service.flows.checks``: a clearance from
either set below the margin) for ``hold_s`` seconds, and among them the agents a trajectory met
(a collision answered), whose next answers are conservative until their exact sets land: the
scheduler starts those agents' queued sets first, then the other demanded agents', then the rest
as the workers allow (``service.runtime.scheduler``): while any agent is demanded, the others'
sets keep off one worker, so that a demanded agent's new version starts as soon as it is
submitted.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable


class ExactDemand:
    """Agents a planner's recent trajectories came near, each until a time."""

    def __init__(self, hold_s: float, size: int) -> None:
        #: How long one check keeps an agent demanded.
        self.hold_s = hold_s
        self._size = size
        self._until: dict[str, float] = {}
        #: The agents a trajectory met, each until a time (a subset of :attr:`_until`'s).
        self._met_until: dict[str, float] = {}
        self._lock = threading.Lock()

    def note(self, agent_ids: Iterable[str], now: float | None = None, met: bool = False) -> None:
        """Demand ``agent_ids`` from ``now`` for :attr:`hold_s` seconds; ``met``: a trajectory
        met their sets (they go first, :meth:`met`)."""
        until = (time.perf_counter() if now is None else now) + self.hold_s
        with self._lock:
            for agent_id in agent_ids:
                self._until.pop(agent_id, None)  # re-inserted: the dict stays in expiry order
                self._until[agent_id] = until
                if met:
                    self._met_until.pop(agent_id, None)
                    self._met_until[agent_id] = until
            for noted in (self._until, self._met_until):
                while len(noted) > self._size:
                    noted.pop(next(iter(noted)))

    def wants(self, agent_id: str, now: float | None = None) -> bool:
        """Whether a check came near ``agent_id`` within the last :attr:`hold_s` seconds."""
        return self._noted(self._until, agent_id, now)

    def met(self, agent_id: str, now: float | None = None) -> bool:
        """Whether a check's trajectory met ``agent_id``'s set within the last :attr:`hold_s`
        seconds."""
        return self._noted(self._met_until, agent_id, now)

    def _noted(self, table: dict[str, float], agent_id: str, now: float | None) -> bool:
        with self._lock:
            until = table.get(agent_id)
        return until is not None and (time.perf_counter() if now is None else now) < until

    def rank(self, agent_id: str, now: float | None = None) -> int:
        """2 for an agent a trajectory met, 1 for one a trajectory only came near, else 0."""
        now = time.perf_counter() if now is None else now
        return 2 if self.met(agent_id, now) else int(self.wants(agent_id, now))

    def active(self, now: float | None = None) -> bool:
        """Whether any agent is demanded (the last to expire is the last in the dict)."""
        with self._lock:
            last = next(reversed(self._until.values()), None)
        return last is not None and (time.perf_counter() if now is None else now) < last

    def forget(self, agent_id: str) -> None:
        with self._lock:
            self._until.pop(agent_id, None)
            self._met_until.pop(agent_id, None)
