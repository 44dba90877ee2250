"""The agent store in memory (one process): TTL, capacity and per-agent locks."""

from __future__ import annotations

import pickle
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from service.runtime.stores.state import AgentState, StoreFullError, Update, UpdateFn
from service.wire.errors import APIError, StaleTimestampError


@dataclass
class _Entry:
    #: The state, pickled: every read unpickles a fresh deep copy (faster than
    #: ``from_dict(to_dict())``, which a planner's check of 50 agents paid 50 times), and nothing a
    #: caller does to a state it was given can reach the stored one.
    data: bytes
    expires_at: float
    #: One copy for readers that promise not to modify it (``get_many(shared=True)``): the state
    #: written (its writer only reads it, ``AgentStore.update``), else unpickled on first read.
    view: AgentState | None = None

    def state(self) -> AgentState:
        return pickle.loads(self.data)  # type: ignore[no-any-return]

    def shared_state(self) -> AgentState:
        if self.view is None:
            self.view = self.state()  # racing readers may both unpickle: equal copies
        return self.view


def _pickled(state: AgentState) -> bytes:
    return pickle.dumps(state, pickle.HIGHEST_PROTOCOL)


class InMemoryAgentStore:
    """A dict of agents with a TTL (refreshed by every update) and a maximum number of agents.

    Each agent has its own lock, so concurrent updates of one agent are serialised while different
    agents proceed in parallel; ``fn`` runs under the lock and must be quick (no I/O). The locks are
    threading locks and nothing awaits while one is held, so the store works from the event loop and
    from worker threads alike.
    """

    def __init__(
        self,
        *,
        ttl_s: float,
        max_agents: int,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._ttl_s = ttl_s
        self._max_agents = max_agents
        self._clock = clock
        self._entries: OrderedDict[str, _Entry] = OrderedDict()  # oldest expiry first
        self._lock = threading.Lock()  # guards _entries and _agent_locks
        self._agent_locks: dict[str, tuple[threading.Lock, int]] = {}  # lock, holders + waiters

    async def get(self, agent_id: str) -> AgentState | None:
        with self._lock:
            self._purge_expired()
            entry = self._entries.get(agent_id)
        return None if entry is None else entry.state()

    async def get_many(
        self, agent_ids: list[str], *, shared: bool = False
    ) -> list[AgentState | None]:
        with self._lock:
            self._purge_expired()
            entries = [self._entries.get(agent_id) for agent_id in agent_ids]
        if shared:  # a planner's check of 50 agents at 10 Hz: unpickled once per version
            return [None if e is None else e.shared_state() for e in entries]
        return [None if e is None else e.state() for e in entries]

    async def update(
        self, agent_id: str, fn: UpdateFn, *, timestamp: float | None = None
    ) -> AgentState:
        (result,) = await self.update_many([(agent_id, fn, timestamp)])
        if isinstance(result, APIError):
            raise result
        return result

    async def update_many(self, updates: Sequence[Update]) -> list[AgentState | APIError]:
        """Every agent's lock is held (taken in id order) while its state is read, its function
        run and its new state written: per agent one atomic step."""
        ids = [agent_id for agent_id, _, _ in updates]
        if len(set(ids)) != len(ids):
            raise ValueError("update_many: an agent appears twice")
        locks = [(agent_id, self._acquire(agent_id)) for agent_id in sorted(ids)]
        try:
            with self._lock:
                self._purge_expired()
                entries = [self._entries.get(agent_id) for agent_id in ids]
            built = [
                self._next(update, entry) for update, entry in zip(updates, entries, strict=True)
            ]
            with self._lock:
                return [
                    self._write(agent_id, *next_) if isinstance(next_, tuple) else next_
                    for agent_id, next_ in zip(ids, built, strict=True)
                ]
        finally:
            for agent_id, lock in reversed(locks):
                self._release(agent_id, lock)

    @staticmethod
    def _next(update: Update, entry: _Entry | None) -> tuple[AgentState, bytes] | APIError:
        """The agent's next state and its pickle, or why it is refused (called under its
        lock). The state is the caller's (``fn``'s result): the store keeps only the pickle."""
        agent_id, fn, timestamp = update
        # The readers' shared copy (fn only reads it): an observation that has just read the
        # agent's state shared is not unpickled again.
        current = None if entry is None else entry.shared_state()
        try:
            if timestamp is not None and current is not None and timestamp <= current.timestamp:
                raise StaleTimestampError(agent_id, timestamp, current.timestamp)
            new = fn(current)
            return new, _pickled(new)
        except APIError as exc:
            return exc

    def _write(self, agent_id: str, new: AgentState, data: bytes) -> AgentState | APIError:
        """Store ``data`` as the agent's state with a fresh TTL, unless a new agent does not fit
        (called with ``_lock`` held)."""
        if agent_id not in self._entries:
            self._purge_expired()
            if len(self._entries) >= self._max_agents:
                return StoreFullError(self._max_agents)
        self._entries.pop(agent_id, None)
        self._entries[agent_id] = _Entry(data, self._clock() + self._ttl_s, new)
        return new

    async def delete(self, agent_id: str) -> bool:
        lock = self._acquire(agent_id)
        try:
            with self._lock:
                self._purge_expired()
                return self._entries.pop(agent_id, None) is not None
        finally:
            self._release(agent_id, lock)

    async def ids(self) -> list[str]:
        with self._lock:
            self._purge_expired()
            return list(self._entries)

    async def count(self) -> int:
        with self._lock:
            self._purge_expired()
            return len(self._entries)

    async def ping(self) -> bool:
        return True

    async def close(self) -> None:
        return None

    def _purge_expired(self) -> None:
        """Drop expired agents; entries are ordered by expiry, so this stops at the first live one."""
        now = self._clock()
        while self._entries:
            agent_id, entry = next(iter(self._entries.items()))
            if entry.expires_at > now:
                break
            del self._entries[agent_id]

    def _acquire(self, agent_id: str) -> threading.Lock:
        with self._lock:
            lock, users = self._agent_locks.get(agent_id, (None, 0))
            if lock is None:
                lock = threading.Lock()
            self._agent_locks[agent_id] = (lock, users + 1)
        lock.acquire()
        return lock

    def _release(self, agent_id: str, lock: threading.Lock) -> None:
        lock.release()
        with self._lock:
            _, users = self._agent_locks[agent_id]
            if users <= 1:
                del self._agent_locks[agent_id]  # no one else holds or waits: don't keep it around
            else:
                self._agent_locks[agent_id] = (lock, users - 1)
