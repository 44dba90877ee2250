"""The agent store in Redis, shared by every replica of the service.

Layout (``prefix`` defaults to ``frt:``):

- ``{prefix}agent:{agent_id}``: the agent's :class:`~service.runtime.stores.AgentState` as JSON (never pickle),
  with a Redis expiry of the agent TTL, refreshed by every update;
- ``{prefix}agents``: a sorted set of live agent ids scored by their expiry (ms, Redis clock), so the
  ``max_agents`` check and :meth:`RedisAgentStore.count` need no ``SCAN``.

Within one replica, updates of one agent queue behind an asyncio lock. Across replicas, an update
is an optimistic compare-and-set: read the agent, run ``fn`` on it here, then one Lua script, atomic
on the Redis server, checks that the stored value is still the one that was read (by SHA-1), that
the new timestamp is strictly later than the stored one (409 otherwise), and that a new agent fits
under ``max_agents``, and only then writes the value, its expiry and the index. If another replica
wrote in between, the script refuses and the update is retried on the fresh value, so concurrent
updates of one agent from any number of replicas are serialised and none is lost. ``fn`` may
therefore run more than once per update: it must be pure (no side effects beyond its result).

Redis being down or restarting is retried for ``unavailable_wait_s`` and then answered as a 503
(:class:`~service.wire.errors.ServiceUnavailableError`, with ``Retry-After``: nothing was written), never
as a 500. A write whose reply was lost with the connection is recognised on the next read (the
stored value is the one this update wrote) and reported as done, not applied twice; if Redis stays
away past the wait, its fate is unknown and the answer is a 504 (:class:`StoreOutcomeUnknownError`).

The two keys an update touches are not in one hash slot: this is for a single Redis (with replicas
or Sentinel), not Redis Cluster.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import math
import random
import time
from collections.abc import Awaitable, Callable
from typing import TypeVar

from redis import exceptions as redis_errors
from redis.asyncio import BlockingConnectionPool, Redis
from redis.asyncio.retry import Retry
from redis.backoff import NoBackoff

from service.runtime.stores import AgentState, StoreFullError, UpdateFn
from service.wire.errors import APIError, ServiceUnavailableError, StaleTimestampError

T = TypeVar("T")

#: Errors that mean "Redis is not reachable right now" (restarting, loading its AOF, network).
_UNAVAILABLE = (
    redis_errors.ConnectionError,
    redis_errors.TimeoutError,
    redis_errors.BusyLoadingError,
    redis_errors.TryAgainError,
)

# KEYS: agent key, index key. ARGV: agent id, SHA-1 of the value read ('' = none), new value,
# TTL in ms, max agents, new timestamp ('' = no check). Returns 'ok', 'conflict', 'stale' or 'full'.
_UPDATE_LUA = """
local t = redis.call('TIME')
local now = tonumber(t[1]) * 1000 + math.floor(tonumber(t[2]) / 1000)
local cur = redis.call('GET', KEYS[1])
if cur then
  if redis.sha1hex(cur) ~= ARGV[2] then return 'conflict' end
  if ARGV[6] ~= '' and tonumber(ARGV[6]) <= tonumber(cjson.decode(cur)['timestamp']) then
    return 'stale'
  end
else
  if ARGV[2] ~= '' then return 'conflict' end
  redis.call('ZREMRANGEBYSCORE', KEYS[2], '-inf', now)
  if redis.call('ZSCORE', KEYS[2], ARGV[1]) == false
     and redis.call('ZCARD', KEYS[2]) >= tonumber(ARGV[5]) then
    return 'full'
  end
end
local ttl = tonumber(ARGV[4])
redis.call('SET', KEYS[1], ARGV[3], 'PX', ttl)
redis.call('ZADD', KEYS[2], now + ttl, ARGV[1])
return 'ok'
"""

# KEYS: agent key, index key. ARGV: agent id. Returns the number of agent keys deleted (0 or 1).
_DELETE_LUA = """
redis.call('ZREM', KEYS[2], ARGV[1])
return redis.call('DEL', KEYS[1])
"""

# KEYS: index key. ARGV: 'ids' or 'count'. Drops expired ids, then returns the live ones (oldest
# expiry first) or their number.
_LIVE_LUA = """
local t = redis.call('TIME')
local now = tonumber(t[1]) * 1000 + math.floor(tonumber(t[2]) / 1000)
redis.call('ZREMRANGEBYSCORE', KEYS[1], '-inf', now)
if ARGV[1] == 'count' then return redis.call('ZCARD', KEYS[1]) end
return redis.call('ZRANGE', KEYS[1], 0, -1)
"""


class StoreOutcomeUnknownError(APIError):
    """504: Redis went away after an update was sent and before it answered, and did not come back
    within the wait. The update may or may not be stored: resending it is safe (a 409 then says it
    was). Not a 503, which tells clients that nothing happened."""

    def __init__(self, agent_id: str, exc: Exception) -> None:
        super().__init__(
            504,
            f"agent store did not confirm the update of agent {agent_id!r} ({exc}); it may or "
            "may not be stored: resend it (409 means it was)",
        )


def encode_state(state: AgentState) -> str:
    """The agent's stored form: compact JSON, finite numbers only."""
    try:
        return json.dumps(state.to_dict(), separators=(",", ":"), allow_nan=False)
    except ValueError as exc:
        raise ValueError(f"agent {state.agent_id!r}: state is not finite JSON: {exc}") from exc


def decode_state(raw: str) -> AgentState:
    """Inverse of :func:`encode_state`."""
    return AgentState.from_dict(json.loads(raw))


def _sha1(raw: str) -> str:
    return hashlib.sha1(raw.encode("utf-8"), usedforsecurity=False).hexdigest()


class _CountedLock:
    """An asyncio lock with the number of its holders and waiters (dropped at zero)."""

    def __init__(self) -> None:
        self.lock = asyncio.Lock()
        self.users = 0


class RedisAgentStore:
    """:class:`~service.runtime.stores.AgentStore` on Redis, through redis-py's asyncio client.

    ``url`` is a redis-py URL (``redis://host:6379/0``, ``rediss://``, ``unix://``). The client is
    created here but connects on first use, so the store can be built outside an event loop.
    """

    def __init__(
        self,
        url: str,
        *,
        ttl_s: float,
        max_agents: int,
        prefix: str = "frt:",
        max_attempts: int = 64,
        unavailable_wait_s: float = 2.0,
        socket_timeout_s: float = 2.0,
        max_connections: int = 64,
    ) -> None:
        if not (math.isfinite(ttl_s) and ttl_s > 0):
            raise ValueError(f"ttl_s must be positive, got {ttl_s!r}")
        if max_agents < 1:
            raise ValueError(f"max_agents must be >= 1, got {max_agents!r}")
        self._ttl_ms = max(1, round(ttl_s * 1000))
        self._max_agents = max_agents
        self._prefix = prefix
        self._index = f"{prefix}agents"
        self._max_attempts = max_attempts
        self._unavailable_wait_s = unavailable_wait_s
        # redis-py's own retries are off: a blind resend of a write could not tell "applied, reply
        # lost" from "not applied"; this class retries itself and checks what was stored.
        # A blocking pool: a burst of requests waits for a free connection instead of failing.
        pool = BlockingConnectionPool.from_url(
            url,
            max_connections=max_connections,
            timeout=socket_timeout_s,
            decode_responses=True,
            socket_timeout=socket_timeout_s,
            socket_connect_timeout=socket_timeout_s,
            retry=Retry(NoBackoff(), 0),
            health_check_interval=30,
        )
        self._redis: Redis = Redis.from_pool(pool)
        self._update_script = self._redis.register_script(_UPDATE_LUA)
        self._delete_script = self._redis.register_script(_DELETE_LUA)
        self._live_script = self._redis.register_script(_LIVE_LUA)
        #: Compare-and-set attempts refused because another writer got there first (for tests
        #: and metrics): proof that concurrent updates really raced.
        self.conflicts = 0
        self._agent_locks: dict[str, _CountedLock] = {}

    def key(self, agent_id: str) -> str:
        """The Redis key holding ``agent_id``'s state."""
        return f"{self._prefix}agent:{agent_id}"

    async def get(self, agent_id: str) -> AgentState | None:
        raw = await self._call(lambda: self._redis.get(self.key(agent_id)))
        return None if raw is None else decode_state(raw)

    async def get_many(
        self, agent_ids: list[str], *, shared: bool = False
    ) -> list[AgentState | None]:
        if not agent_ids:
            return []
        keys = [self.key(agent_id) for agent_id in agent_ids]
        raws = await self._call(lambda: self._redis.mget(keys))
        return [None if raw is None else decode_state(raw) for raw in raws]

    async def update(
        self, agent_id: str, fn: UpdateFn, *, timestamp: float | None = None
    ) -> AgentState:
        # Updates of one agent within this replica queue here, so only replicas race in Redis.
        lock = self._agent_locks.setdefault(agent_id, _CountedLock())
        lock.users += 1
        try:
            async with lock.lock:
                return await self._compare_and_set(agent_id, fn, timestamp)
        finally:
            lock.users -= 1
            if lock.users == 0:
                del self._agent_locks[agent_id]

    async def _compare_and_set(
        self, agent_id: str, fn: UpdateFn, timestamp: float | None
    ) -> AgentState:
        key = self.key(agent_id)
        #: The value this update sent when the connection failed before Redis answered.
        unconfirmed: str | None = None
        deadline = time.monotonic() + self._unavailable_wait_s
        attempt = 0
        while True:
            try:
                raw = await self._redis.get(key)
                if unconfirmed is not None and raw == unconfirmed:
                    return decode_state(raw)  # the lost reply was an 'ok'
                unconfirmed = None
                current = None if raw is None else decode_state(raw)
                if timestamp is not None and current is not None and timestamp <= current.timestamp:
                    raise StaleTimestampError(agent_id, timestamp, current.timestamp)
                new_raw = encode_state(fn(current))  # fn's exceptions propagate: nothing written
                unconfirmed = new_raw
                outcome = await self._update_script(
                    keys=[key, self._index],
                    args=[
                        agent_id,
                        "" if raw is None else _sha1(raw),
                        new_raw,
                        self._ttl_ms,
                        self._max_agents,
                        "" if timestamp is None else repr(float(timestamp)),
                    ],
                )
                unconfirmed = None
            except _UNAVAILABLE as exc:
                if unconfirmed is not None and time.monotonic() >= deadline:
                    raise StoreOutcomeUnknownError(agent_id, exc) from exc
                deadline = await self._wait_or_raise(exc, deadline)
                continue
            if outcome == "ok":
                return decode_state(new_raw)
            if outcome == "full":
                raise StoreFullError(self._max_agents)
            # 'conflict' (another replica wrote since our read), or 'stale' (it wrote a later
            # timestamp: the next read raises the 409 with the stored timestamp): read again.
            self.conflicts += 1
            attempt += 1
            if attempt >= self._max_attempts:
                raise ServiceUnavailableError(
                    f"agent {agent_id!r}: too many concurrent updates, try again"
                )
            await asyncio.sleep(random.uniform(0, 0.001 * min(2**attempt, 32)))

    async def delete(self, agent_id: str) -> bool:
        deleted = await self._call(
            lambda: self._delete_script(keys=[self.key(agent_id), self._index], args=[agent_id])
        )
        return bool(deleted)

    async def ids(self) -> list[str]:
        return list(await self._call(lambda: self._live_script(keys=[self._index], args=["ids"])))

    async def count(self) -> int:
        return int(await self._call(lambda: self._live_script(keys=[self._index], args=["count"])))

    async def close(self) -> None:
        await self._redis.aclose()

    async def ping(self) -> bool:
        """Whether Redis answers now (for readiness checks); never raises."""
        try:
            return bool(await self._redis.ping())
        except (redis_errors.RedisError, OSError):
            return False

    async def _call(self, op: Callable[[], Awaitable[T]]) -> T:
        """Run an idempotent operation, retrying while Redis is unreachable (within the budget)."""
        deadline = time.monotonic() + self._unavailable_wait_s
        while True:
            try:
                return await op()
            except _UNAVAILABLE as exc:
                deadline = await self._wait_or_raise(exc, deadline)

    async def _wait_or_raise(self, exc: Exception, deadline: float) -> float:
        """Back off briefly before the next try, or raise the 503 once the budget is spent."""
        if time.monotonic() >= deadline:
            raise ServiceUnavailableError(f"agent store unavailable: {exc}") from exc
        await asyncio.sleep(0.05)
        return deadline
