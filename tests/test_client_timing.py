"""The SDK's trip times: what a round trip cost beyond the service's own time (Server-Timing), and
the deadline to send for an answer within a budget counted from the call."""

from __future__ import annotations

import asyncio
import time

import httpx
import pytest
from frt_client import AsyncFRTClient, FRTClient, TripTimes
from frt_client.timing import server_ms

from tests.conftest import LiveServer


def response(server_timing: str | None) -> httpx.Response:
    headers = {} if server_timing is None else {"server-timing": server_timing}
    return httpx.Response(200, headers=headers)


def test_server_timing_is_read_and_anything_else_ignored() -> None:
    assert server_ms(response("app;dur=4.5")) == 4.5
    assert server_ms(response("db;dur=1, app;desc=x;dur=2.25")) == 2.25
    for unusable in (None, "", "app", "app;dur=", "app;dur=abc", "app;dur=-1", "app;dur=nan"):
        assert server_ms(response(unusable)) is None, unusable


def test_trips_give_the_deadline_for_a_budget() -> None:
    trips = TripTimes(window=4)
    assert trips.quantile_ms() is None and trips.deadline_for(20.0) == 20.0
    for round_trip_s, server in ((0.010, 4.0), (0.012, 4.0), (0.005, 4.0), (0.030, 4.0)):
        trips.record(round_trip_s, response(f"app;dur={server}"))
    trips.record(0.050, response(None))  # no header: not a trip
    assert len(trips) == 4
    assert trips.quantile_ms(0.5) == pytest.approx(6.0)  # trips 1, 6, 8, 26 ms
    assert trips.quantile_ms(0.99) == pytest.approx(26.0)
    assert trips.deadline_for(20.0, q=0.5) == pytest.approx(14.0)
    assert trips.deadline_for(20.0) == 1.0  # never below the floor
    trips.record(0.003, response("app;dur=2"))  # the window keeps the last four: 6, 8, 26, 1
    assert trips.quantile_ms(0.25) == pytest.approx(1.0)


def test_the_clients_measure_their_trips(live_server: LiveServer) -> None:
    with FRTClient(live_server.url) as frt:
        started = time.perf_counter()
        for _ in range(20):
            frt.health()
        elapsed_ms = (time.perf_counter() - started) * 1000.0
        assert len(frt.trips) == 20
        worst = frt.trips.quantile_ms(1.0)
        assert worst is not None and 0.0 <= worst < elapsed_ms
        assert 1.0 <= frt.trips.deadline_for(1000.0) < 1000.0

    async def run() -> TripTimes:
        async with AsyncFRTClient(live_server.url) as frt:
            for _ in range(5):
                await frt.health()
            return frt.trips

    trips = asyncio.run(run())
    assert len(trips) == 5 and trips.deadline_for(1000.0) < 1000.0
