"""Collision checks before observations on the event loop.

A check has a deadline (API.md: it answers within ``deadline_ms`` of its arrival); an observation has
none. Both run on the one event loop, and an observation's numerical work (Bayes update, bounds fit,
conservative set: milliseconds) that starts while a check is in flight holds the loop when the check's
wait for an exact set ends: under the sustained load (100 observations per second) that put checks
past their deadline at the server. Here a check marks itself in flight (:meth:`ChecksFirst.check`),
and an observation waits before its numerical work until no check is
(:meth:`ChecksFirst.observation_turn`), for ``max_hold_s`` at most, so that a stream of checks
cannot starve observations.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from contextlib import contextmanager

#: Longest an observation waits for checks in flight (a planner checks at ~10 Hz, each check a few
#: milliseconds long: far more than one check needs, far less than the agent's next observation).
MAX_HOLD_S = 0.05


class ChecksFirst:
    """Counts the collision checks in flight and holds observations back while there are any."""

    def __init__(self, max_hold_s: float = MAX_HOLD_S) -> None:
        self.max_hold_s = max_hold_s
        self._in_flight = 0
        self._waiters: list[asyncio.Future[None]] = []

    @property
    def checks_in_flight(self) -> int:
        return self._in_flight

    @contextmanager
    def check(self) -> Iterator[None]:
        """Mark a check in flight for the duration of the block (on the event loop's thread)."""
        self._in_flight += 1
        try:
            yield
        finally:
            self._in_flight -= 1
            if self._in_flight == 0:
                waiters, self._waiters = self._waiters, []
                for waiter in waiters:
                    if not waiter.done():
                        waiter.set_result(None)

    async def observation_turn(self, hold_s: float | None = None) -> float:
        """Yield to requests already waiting on the loop, then wait while checks are in flight
        (``hold_s`` at most, default ``max_hold_s``; a frame's later turns pass what is left of
        it, so that its turns together hold it back that long at most). Returns the seconds held
        back."""
        await asyncio.sleep(0)
        hold = self.max_hold_s if hold_s is None else hold_s
        if self._in_flight == 0 or hold <= 0:
            return 0.0
        loop = asyncio.get_running_loop()
        start = loop.time()
        while self._in_flight:
            left = start + hold - loop.time()
            if left <= 0:
                break
            waiter = loop.create_future()
            self._waiters.append(waiter)
            await asyncio.wait({waiter}, timeout=left)
        return loop.time() - start
