"""Which tubes of an agent's next exact sets time-indexed checks will ask for.

A time-indexed check compares each point at time t with the tube up to t (API.md); the worker that
computes an agent's exact set draws those tubes before sending it back
(``service.runtime.exact_worker.ExactTask.tubes_upto``), so the check finds them drawn and answers
from the exact set. The set is ready only once they are drawn, and drawing every tube costs about
as much as the set itself, so only the tubes this agent's checks have asked for are drawn: up to
the largest index asked so far (a planner's trajectory spans the same horizon check after check).
An agent no check has asked about yet, or one checked only against the whole tube, gets none
beyond the whole tube: its first time-indexed check draws what it needs on the event loop within
its budget (``service.runtime.tube_builder``) and names the tubes its next versions come with.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Sequence

#: ``upto`` of an agent no time-indexed check has named yet: no tube beyond the whole one.
NO_TUBES = -1


class TubeDemand:
    """Per agent, the largest tube index its checks have needed (at most ``size`` agents, the
    least recently checked forgotten first)."""

    def __init__(self, size: int) -> None:
        self._size = size
        self._largest: OrderedDict[str, int] = OrderedDict()
        self._lock = threading.Lock()

    def note(self, agent_id: str, largest_index: int) -> None:
        """A check of ``agent_id`` needed tubes up to ``largest_index`` (0: none but the first)."""
        self.note_many([(agent_id, largest_index)])

    def note_many(self, needed: Sequence[tuple[str, int]]) -> None:
        """:meth:`note` of each (agent, largest index) of one check."""
        with self._lock:
            for agent_id, largest_index in needed:
                known = self._largest.get(agent_id, -1)
                self._largest[agent_id] = max(known, int(largest_index))
                self._largest.move_to_end(agent_id)
            while len(self._largest) > self._size:
                self._largest.popitem(last=False)

    def upto(self, agent_id: str) -> int:
        """Draw the tubes 0..upto of the agent's next set (NO_TUBES if no check named it)."""
        with self._lock:
            return self._largest.get(agent_id, NO_TUBES)

    def forget(self, agent_id: str) -> None:
        with self._lock:
            self._largest.pop(agent_id, None)
