"""Tubes of exact sets for time-indexed checks that the workers did not draw, within deadlines.

A time-indexed check compares each point at time t with the tube up to t (API.md). Worker processes
draw the tubes an agent's checks ask for before sending its set back
(``service.runtime.tube_demand``); a set computed on threads, or a check that asks for more tubes
than the agent's checks did before, finds some missing. The check then draws them here one by one
while its deadline allows (the clock read before each, against a cost estimate that is rarely
exceeded); for the points whose tubes are still missing, each is checked against the smallest tube
already drawn that ends no earlier than it does (the whole-horizon one at worst): tubes grow with
time, so that set contains the point's own tube and the answer says ``conservative: true`` (API.md:
"answer from a set that contains it"). The missing tubes are then drawn between requests, one per
event-loop turn, for the next check.

Only tubes actually drawn are timed: a tube drawn already returns at once and would drag the
estimate towards zero.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from reach.sets import FRTSet
from service.runtime.answer_cost import CostEstimate

#: Tubes waiting to be drawn between requests (the oldest are dropped beyond this).
MAX_PENDING = 512
#: First guess of the time to draw one tube, before any has been measured here.
INITIAL_COST_S = 0.002


class TubeBuilder:
    """Draws missing tubes now (while a check has the time) or between requests, and learns what
    one costs here."""

    def __init__(self, on_drawn: Callable[[], None] | None = None) -> None:
        #: Called once per tube drawn (the server counts them: ``frt_event_loop_tubes``).
        self.on_drawn = on_drawn
        self.cost = CostEstimate(mean_s=INITIAL_COST_S, deviation_s=INITIAL_COST_S / 2)
        #: Seconds spent drawing tubes so far (checks take their own share out of their timing).
        self.spent_s = 0.0
        self._pending: deque[tuple[FRTSet, int]] = deque(maxlen=MAX_PENDING)
        self._scheduled = False

    def build(self, frt: FRTSet, indices: list[int], until: float = math.inf) -> bool:
        """Draw the tubes ``indices`` of ``frt`` not drawn yet, in increasing order, each only if
        it should be done by ``until`` (``time.perf_counter()``) at the cost estimate; returns
        whether every one is drawn."""
        for j in frt.missing_tubes(indices):
            start = time.perf_counter()
            if start + self.cost.upper_s(1) > until:
                return False
            frt.tube(j)
            spent = time.perf_counter() - start
            self.spent_s += spent
            self.cost.record(spent, 1)
            if self.on_drawn is not None:
                self.on_drawn()
        return True

    def learn_cost(self, frt: FRTSet) -> None:
        """Time drawing every tube of ``frt`` (a warm-up set, before any request) and plan with
        that from now on instead of ``INITIAL_COST_S``: an agent's first time-indexed check then
        draws the tubes it needs if they fit its deadline at what they cost here."""
        measured = CostEstimate()
        for j in frt.missing_tubes(list(range(frt.n_slices))):
            start = time.perf_counter()
            frt.tube(j)
            measured.record(time.perf_counter() - start, 1)
        if measured.measured:
            self.cost = measured

    def later(self, frt: FRTSet, indices: list[int]) -> None:
        """Draw tubes ``indices`` of ``frt`` between requests, one per event-loop turn."""
        self._pending.extend((frt, j) for j in indices)
        if self._pending and not self._scheduled:
            self._scheduled = True
            asyncio.get_running_loop().call_soon(self._step)

    def _step(self) -> None:
        if self._pending:
            frt, j = self._pending.popleft()
            self.build(frt, [j])
        if self._pending:
            asyncio.get_running_loop().call_soon(self._step)
        else:
            self._scheduled = False


def within_built_tubes(frt: FRTSet, t_rel: np.ndarray) -> np.ndarray:
    """Times that put each point in the smallest tube already drawn that ends no earlier than its
    own (a superset of its own tube)."""
    tubes, rows = frt.tubes_present(frt.tube_indices(t_rel))
    built = np.array([frt.nearest_built_tube(j) for j in tubes.tolist()], dtype=np.float64)
    return built[rows] * frt.slice_dt
