"""The trip's share of a round trip, from the service's ``Server-Timing`` header.

The service answers a collision check within ``deadline_ms`` of the request's *arrival*: it cannot
see the time spent before (the client sending, the network, the kernel) or after (the answer's way
back). A planner whose budget counts from its own call must keep that share out of the deadline it
sends; :meth:`TripTimes.deadline_for` does so from the trips the client has measured::

    frt.collision_check_many(trajectory, deadline_ms=frt.trips.deadline_for(20.0))

Every response carries ``Server-Timing: app;dur=<ms>`` (arrival to the response's start); the trip
of a request is its round trip less that.
"""

from __future__ import annotations

import math
import threading
from collections import deque

import httpx

#: Trips remembered (the most recent ones).
TRIP_WINDOW = 256


def server_ms(response: httpx.Response) -> float | None:
    """The service's own time for ``response`` in ms (``Server-Timing: app;dur=<ms>``), if given."""
    for entry in response.headers.get("server-timing", "").split(","):
        name, _, params = entry.strip().partition(";")
        if name.strip() != "app":
            continue
        for param in params.split(";"):
            key, _, value = param.strip().partition("=")
            if key == "dur":
                try:
                    duration = float(value)
                except ValueError:
                    return None
                return duration if math.isfinite(duration) and duration >= 0 else None
    return None


class TripTimes:
    """Round trip less the service's own time, over the last ``window`` responses (thread-safe)."""

    def __init__(self, window: int = TRIP_WINDOW) -> None:
        self._trips: deque[float] = deque(maxlen=window)
        self._lock = threading.Lock()

    def record(self, round_trip_s: float, response: httpx.Response) -> None:
        """Remember one response's trip (ignored without a usable ``Server-Timing``)."""
        server = server_ms(response)
        if server is not None:
            with self._lock:
                self._trips.append(max(round_trip_s * 1000.0 - server, 0.0))

    def __len__(self) -> int:
        return len(self._trips)

    def quantile_ms(self, q: float = 0.99) -> float | None:
        """The ``q`` quantile (nearest rank) of the remembered trips in ms; None before any."""
        with self._lock:
            trips = sorted(self._trips)
        if not trips:
            return None
        return trips[min(len(trips) - 1, max(0, math.ceil(q * len(trips)) - 1))]

    def deadline_for(self, budget_ms: float, q: float = 0.99, floor_ms: float = 1.0) -> float:
        """The ``deadline_ms`` to send for an answer within ``budget_ms`` of the call: the budget
        less the ``q`` quantile of the trips so far (the whole budget before any), ``floor_ms`` at
        least (a deadline the service can still answer conservatively within)."""
        trip = self.quantile_ms(q)
        return max(budget_ms - (trip or 0.0), floor_ms)
