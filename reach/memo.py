"""A thread-safe keyed memo: values computed once per key and shared by the threads that ask.

A value is computed outside the lock, so a slow computation never blocks the threads reading
other keys; two threads asking for one missing key at once may both compute it, and the value
put last is the one kept (the computations of one key give equal values). A memo pickles as its
values alone: the receiving process gets a fresh lock.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable
from typing import Any, Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class Memo(Generic[K, V]):
    """Values by key behind one lock. With ``maxsize`` it holds at most that many values and
    putting a new key past it drops the oldest put; without it, every value put is kept."""

    __slots__ = ("_lock", "_values", "maxsize")

    def __init__(self, maxsize: int | None = None) -> None:
        if maxsize is not None and maxsize < 1:
            raise ValueError("maxsize must be at least 1")
        self.maxsize = maxsize
        self._values: dict[K, V] = {}
        self._lock = threading.Lock()

    def get(self, key: K) -> V | None:
        """The value of ``key``, or None if none was put."""
        with self._lock:
            return self._values.get(key)

    def put(self, key: K, value: V) -> V:
        """Keep ``value`` for ``key`` (replacing any value it had) and return it."""
        with self._lock:
            self._values.pop(key, None)
            if self.maxsize is not None and len(self._values) >= self.maxsize:
                del self._values[next(iter(self._values))]
            self._values[key] = value
        return value

    def get_or_compute(self, key: K, compute: Callable[[], V]) -> V:
        """The value of ``key``, computed by ``compute()`` (outside the lock) and put if missing."""
        with self._lock:
            if key in self._values:
                return self._values[key]
        return self.put(key, compute())

    def snapshot(self) -> dict[K, V]:
        """A copy of every key and its value, taken at once."""
        with self._lock:
            return dict(self._values)

    def key_set(self) -> set[K]:
        """A copy of the keys that have a value, taken at once."""
        with self._lock:
            return set(self._values)

    def __contains__(self, key: object) -> bool:
        with self._lock:
            return key in self._values

    def __len__(self) -> int:
        with self._lock:
            return len(self._values)

    def clear(self) -> None:
        with self._lock:
            self._values.clear()

    def __getstate__(self) -> dict[str, Any]:
        return {"maxsize": self.maxsize, "_values": self.snapshot()}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.maxsize = state["maxsize"]
        self._values = state["_values"]
        self._lock = threading.Lock()
