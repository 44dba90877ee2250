"""Per-agent state behind a small interface: in memory by default, Redis later.

The one write path is :meth:`AgentStore.update`: an atomic read-modify-write of one agent under that
agent's lock, with the timestamp check of API.md ("timestamps must increase per agent", 409) done by
the store itself, so a Redis implementation can do the same in a transaction (``WATCH``/``MULTI``, or
a Lua script for the check). Agent state is a plain dataclass of JSON types (``to_dict``/``from_dict``)
so any store can serialise it.
"""

from __future__ import annotations

import pickle
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any, Protocol, runtime_checkable

from service.api.errors import APIError, StaleTimestampError

#: Builds the agent's next state from its current one (``None`` for a new agent). It may raise
#: (an :class:`~service.api.errors.APIError` such as a 422) to abort the update; nothing is written then.
UpdateFn = Callable[["AgentState | None"], "AgentState"]


@dataclass
class AgentState:
    """Everything the service knows about one human, in JSON types only."""

    agent_id: str
    #: Time of the last observation, on the caller's clock (strictly increasing per agent).
    timestamp: float
    #: The human's world pose and speed at that observation: the FRT starts here.
    x: float
    y: float
    heading: float
    speed: float
    #: The Bayes filter over beta (``service.flows.confidence.Belief.to_dict()``).
    belief: dict[str, Any]
    #: The last prediction: ``{"dt": float, "mean": [[u1, u2], ...], "cov": [[[..], [..]], ...]}``.
    prediction: dict[str, Any]
    #: The eight control-bound columns in contract order (``reach.contract.BOUND_COLUMNS``).
    control_bounds: list[float]
    #: Per-agent overrides of server settings (beta_low, gamma, epsilon, collision_radius, bounds_fit).
    config: dict[str, Any] = field(default_factory=dict)
    #: Bumped by every observation; names the FRT the agent's collision checks are answered from.
    frt_version: int = 1
    #: A multi-modal agent's joint belief, modes and mode set (``service.flows.modes``); None for
    #: a single Gaussian.
    modes: dict[str, Any] | None = None
    #: Adaptive gamma's running state (``service.flows.adaptive_gamma``); None without a
    #: ``coverage_target``.
    gamma_state: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """A deep copy in JSON types (what the Redis store writes): faster than
        ``dataclasses.asdict``, which inspects every number of the prediction."""
        return {name: _json_copy(getattr(self, name)) for name in _STATE_FIELDS}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> AgentState:
        return cls(**data)


_STATE_FIELDS = tuple(f.name for f in fields(AgentState))


#: JSON leaves: immutable, shared by copies (checked inline, not by a call per number).
_LEAVES = (float, int, str, bool, type(None))


def _json_copy(value: Any) -> Any:
    if isinstance(value, list):
        return [v if isinstance(v, _LEAVES) else _json_copy(v) for v in value]
    if isinstance(value, dict):
        return {k: v if isinstance(v, _LEAVES) else _json_copy(v) for k, v in value.items()}
    return value  # str, number, bool, None: immutable


class StoreFullError(APIError):
    """A new agent does not fit: the store holds ``max_agents`` live agents."""

    def __init__(self, max_agents: int) -> None:
        super().__init__(
            503, f"agent store is full ({max_agents} agents); delete agents or wait for the TTL"
        )


@runtime_checkable
class AgentStore(Protocol):
    """What the routes need from a store. Every method is safe to call concurrently."""

    async def get(self, agent_id: str) -> AgentState | None:
        """The agent's state, or ``None`` if unknown or expired."""
        ...

    async def get_many(
        self, agent_ids: list[str], *, shared: bool = False
    ) -> list[AgentState | None]:
        """``get`` of each agent, in one round trip (a planner's check of many agents). With
        ``shared`` the caller promises not to modify the states, which may then be one object
        shared by such readers (a store may ignore it and copy anyway)."""
        ...

    async def update(
        self, agent_id: str, fn: UpdateFn, *, timestamp: float | None = None
    ) -> AgentState:
        """Atomically replace the agent's state by ``fn(current)`` and refresh its TTL.

        With ``timestamp`` the update is refused with :class:`StaleTimestampError` (409) unless it is
        strictly later than the stored state's timestamp; the check and the write are one atomic step.
        A new agent beyond the store's capacity raises :class:`StoreFullError`. Exceptions from ``fn``
        propagate and leave the stored state unchanged.
        """
        ...

    async def delete(self, agent_id: str) -> bool:
        """Forget the agent; ``False`` if it was unknown."""
        ...

    async def ids(self) -> list[str]:
        """Ids of the live agents."""
        ...

    async def count(self) -> int:
        """Number of live agents."""
        ...

    async def ping(self) -> bool:
        """Whether the store answers now (readiness); never raises."""
        ...

    async def close(self) -> None:
        """Release connections (nothing to do in memory)."""
        ...


@dataclass
class _Entry:
    #: The state, pickled: every read unpickles a fresh deep copy (faster than
    #: ``from_dict(to_dict())``, which a planner's check of 50 agents paid 50 times), and nothing a
    #: caller does to a state it was given can reach the stored one.
    data: bytes
    expires_at: float
    #: One unpickled copy for readers that promise not to modify it (``get_many(shared=True)``).
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
        lock = self._acquire(agent_id)
        try:
            with self._lock:
                self._purge_expired()
                entry = self._entries.get(agent_id)
            current = None if entry is None else entry.state()
            if timestamp is not None and current is not None and timestamp <= current.timestamp:
                raise StaleTimestampError(agent_id, timestamp, current.timestamp)
            # fn gets a copy: a half-applied change it raises on never leaks into the store.
            new = fn(current)
            data = _pickled(new)
            with self._lock:
                if agent_id not in self._entries:
                    self._purge_expired()
                    if len(self._entries) >= self._max_agents:
                        raise StoreFullError(self._max_agents)
                self._entries.pop(agent_id, None)
                self._entries[agent_id] = _Entry(data, self._clock() + self._ttl_s)
            return pickle.loads(data)  # type: ignore[no-any-return]
        finally:
            self._release(agent_id, lock)

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


def make_store(
    url: str | None, *, ttl_s: float, max_agents: int
) -> AgentStore:  # pragma: no cover - trivial
    """The store named by ``settings.store_url``: unset or ``memory://`` keeps agents in memory."""
    if url is None or url in ("", "memory://"):
        return InMemoryAgentStore(ttl_s=ttl_s, max_agents=max_agents)
    if url.startswith(("redis://", "rediss://", "unix://")):
        try:
            from service.runtime.redis_store import RedisAgentStore  # type: ignore[import-not-found]
        except ImportError as exc:
            raise ValueError(f"store_url {url!r}: no Redis store in this build") from exc
        return RedisAgentStore(url, ttl_s=ttl_s, max_agents=max_agents)  # type: ignore[no-any-return]
    raise ValueError(f"store_url {url!r}: unknown scheme (use memory:// or redis://)")
