"""Tubes drawn within a check's deadline (service.runtime.tube_builder), on a fake clock."""

from __future__ import annotations

import pytest

from service.runtime import tube_builder
from service.runtime.tube_builder import TubeBuilder

DRAW_S = 0.002


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class FakeSet:
    """Tubes that take DRAW_S of the fake clock to draw the first time, nothing after."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.drawn: list[int] = []

    def missing_tubes(self, indices: list[int]) -> list[int]:
        return sorted(set(indices).difference(self.drawn))

    def tube(self, j: int) -> None:
        if j not in self.drawn:
            self.clock.now += DRAW_S
            self.drawn.append(j)


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> Clock:
    fake = Clock()
    monkeypatch.setattr(tube_builder.time, "perf_counter", fake)
    return fake


def test_only_tubes_actually_drawn_are_timed(clock: Clock) -> None:
    builder, frt = TubeBuilder(), FakeSet(clock)
    assert builder.build(frt, [3, 1, 2, 1])  # type: ignore[arg-type]
    assert frt.drawn == [1, 2, 3]
    for _ in range(50):  # drawn already: costs nothing, teaches nothing
        assert builder.build(frt, [1, 2, 3])  # type: ignore[arg-type]
    assert builder.cost.mean_s == pytest.approx(DRAW_S)
    assert builder.spent_s == pytest.approx(3 * DRAW_S)


def test_a_check_draws_only_what_its_deadline_allows(clock: Clock) -> None:
    builder, warm = TubeBuilder(), FakeSet(clock)
    builder.build(warm, list(range(10)))  # type: ignore[arg-type]  # learn the cost
    frt = FakeSet(clock)
    start = clock.now
    assert not builder.build(frt, list(range(1, 21)), until=start + 0.011)  # type: ignore[arg-type]
    assert frt.drawn == [1, 2, 3, 4, 5]  # in order, the next one would end after `until`
    assert clock.now <= start + 0.011
    assert builder.build(frt, list(range(1, 21)))  # type: ignore[arg-type]  # no deadline: all
    assert frt.drawn == list(range(1, 21))


def test_nothing_is_drawn_past_the_deadline(clock: Clock) -> None:
    builder, frt = TubeBuilder(), FakeSet(clock)
    assert not builder.build(frt, [1, 2], until=clock.now - 0.001)  # type: ignore[arg-type]
    assert frt.drawn == []
