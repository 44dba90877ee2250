"""``reach.memo.Memo``: a value per key computed once, kept across threads and pickling."""

from __future__ import annotations

import pickle
import threading

import pytest

from reach.memo import Memo


def test_a_value_is_computed_once_per_key() -> None:
    memo: Memo[int, list[int]] = Memo()
    calls: list[int] = []

    def compute(k: int) -> list[int]:
        calls.append(k)
        return [k]

    first = memo.get_or_compute(3, lambda: compute(3))
    assert memo.get_or_compute(3, lambda: compute(3)) is first
    assert memo.get(4) is None and 4 not in memo
    assert calls == [3] and 3 in memo and len(memo) == 1


def test_put_replaces_and_snapshots_are_copies() -> None:
    memo: Memo[str, int] = Memo()
    assert memo.put("a", 1) == 1
    memo.put("a", 2)
    snapshot = memo.snapshot()
    memo.put("b", 3)
    assert snapshot == {"a": 2} and memo.key_set() == {"a", "b"}
    memo.clear()
    assert len(memo) == 0


def test_a_bounded_memo_drops_the_oldest_put() -> None:
    memo: Memo[int, int] = Memo(maxsize=2)
    memo.put(1, 1)
    memo.put(2, 2)
    memo.put(1, 10)  # put again: now the newest
    memo.put(3, 3)
    assert memo.snapshot() == {1: 10, 3: 3}
    with pytest.raises(ValueError):
        Memo(maxsize=0)


def test_a_memo_pickles_as_its_values_with_a_fresh_lock() -> None:
    memo: Memo[int, str] = Memo(maxsize=4)
    memo.put(1, "one")
    back = pickle.loads(pickle.dumps(memo))
    assert back.snapshot() == {1: "one"} and back.maxsize == 4
    back.put(2, "two")  # its lock works
    assert memo.key_set() == {1}


def test_threads_share_one_value_per_key() -> None:
    memo: Memo[int, int] = Memo()
    barrier = threading.Barrier(8)
    seen: list[int] = []

    def ask() -> None:
        barrier.wait()
        for k in range(200):
            seen.append(memo.get_or_compute(k % 20, lambda k=k: k % 20))

    threads = [threading.Thread(target=ask) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(seen) == 1600 and memo.snapshot() == {k: k for k in range(20)}
