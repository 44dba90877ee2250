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
import contextlib
import hashlib
import json
import math
import random
import time
from collections.abc import Awaitable, Callable, Sequence
from typing import TypeVar

from redis import exceptions as redis_errors
from redis.asyncio import BlockingConnectionPool, Redis
from redis.asyncio.retry import Retry
from redis.backoff import NoBackoff

from service.runtime.stores import AgentState, StoreFullError, Update, UpdateFn
from service.wire.errors import APIError, ServiceUnavailableError, StaleTimestampError

T = TypeVar("T")

#: Errors that mean "Redis is not reachable right now" (restarting, loading its AOF, network).
_UNAVAILABLE = (
    redis_errors.ConnectionError,
    redis_errors.TimeoutError,
    redis_errors.BusyLoadingError,
    redis_errors.TryAgainError,
)

# One agent's compare-and-set: the stored value must be the one read (its SHA-1, '' = none), the new
# timestamp ('' = no check) later than the stored one's, a new agent must fit under max_agents;
# then the new value is written with its TTL and the index updated. Returns 'ok', 'conflict',
# 'stale' or 'full'.
_UPDATE_ONE_LUA = """
local function update_one(key, index, id, sha, value, ttl, max_agents, timestamp, now)
  local cur = redis.call('GET', key)
  if cur then
    if redis.sha1hex(cur) ~= sha then return 'conflict' end
    if timestamp ~= '' and tonumber(timestamp) <= tonumber(cjson.decode(cur)['timestamp']) then
      return 'stale'
    end
  else
    if sha ~= '' then return 'conflict' end
    redis.call('ZREMRANGEBYSCORE', index, '-inf', now)
    if redis.call('ZSCORE', index, id) == false and redis.call('ZCARD', index) >= max_agents then
      return 'full'
    end
  end
  redis.call('SET', key, value, 'PX', ttl)
  redis.call('ZADD', index, now + ttl, id)
  return 'ok'
end
local t = redis.call('TIME')
local now = tonumber(t[1]) * 1000 + math.floor(tonumber(t[2]) / 1000)
"""

# KEYS: agent key, index key. ARGV: agent id, SHA-1 of the value read ('' = none), new value,
# TTL in ms, max agents, new timestamp ('' = no check). Returns update_one's outcome.
_UPDATE_LUA = (
    _UPDATE_ONE_LUA
    + """
return update_one(KEYS[1], KEYS[2], ARGV[1], ARGV[2], ARGV[3], tonumber(ARGV[4]),
                  tonumber(ARGV[5]), ARGV[6], now)
"""
)

# KEYS: index key, then one agent key per agent. ARGV: TTL in ms, max agents, then per agent its
# id, SHA-1 read, new value and timestamp. Returns update_one's outcome per agent, in order.
_UPDATE_MANY_LUA = (
    _UPDATE_ONE_LUA
    + """
local ttl, max_agents, out = tonumber(ARGV[1]), tonumber(ARGV[2]), {}
for i = 2, #KEYS do
  local a = 3 + (i - 2) * 4
  out[i - 1] = update_one(KEYS[i], KEYS[1], ARGV[a], ARGV[a + 1], ARGV[a + 2], ttl, max_agents,
                          ARGV[a + 3], now)
end
return out
"""
)

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
        self._update_many_script = self._redis.register_script(_UPDATE_MANY_LUA)
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

    async def update_many(self, updates: Sequence[Update]) -> list[AgentState | APIError]:
        """One read of every agent (``MGET``) and one script writing them all, each agent's
        compare-and-set as :meth:`update`'s; an agent another writer got to first, or whose write
        Redis did not confirm, is then updated on its own as :meth:`update` does."""
        ids = [agent_id for agent_id, _, _ in updates]
        if len(set(ids)) != len(ids):
            raise ValueError("update_many: an agent appears twice")
        locks = [self._agent_locks.setdefault(agent_id, _CountedLock()) for agent_id in ids]
        for lock in locks:
            lock.users += 1
        try:
            async with contextlib.AsyncExitStack() as stack:
                for agent_id in sorted(ids):  # in id order: batches never wait on each other
                    await stack.enter_async_context(self._agent_locks[agent_id].lock)
                return await self._compare_and_set_many(updates)
        finally:
            for agent_id, lock in zip(ids, locks, strict=True):
                lock.users -= 1
                if lock.users == 0:
                    del self._agent_locks[agent_id]

    async def _compare_and_set_many(self, updates: Sequence[Update]) -> list[AgentState | APIError]:
        keys = [self.key(agent_id) for agent_id, _, _ in updates]
        raws = await self._call(lambda: self._redis.mget(keys))
        results: list[AgentState | APIError | None] = [None] * len(updates)
        sent: list[tuple[int, str | None, str]] = []  # (index, value read, value sent)
        for i, ((agent_id, fn, timestamp), raw) in enumerate(zip(updates, raws, strict=True)):
            current = None if raw is None else decode_state(raw)
            try:
                if timestamp is not None and current is not None and timestamp <= current.timestamp:
                    raise StaleTimestampError(agent_id, timestamp, current.timestamp)
                sent.append((i, raw, encode_state(fn(current))))
            except APIError as exc:
                results[i] = exc
        outcomes = await self._write_many(updates, sent)
        for (i, _, new_raw), outcome in zip(sent, outcomes, strict=True):
            if outcome == "ok":
                results[i] = decode_state(new_raw)
            elif outcome == "full":
                results[i] = StoreFullError(self._max_agents)
            else:  # another writer first, or no answer: this agent alone, as update does
                if outcome is not None:
                    self.conflicts += 1
                agent_id, fn, timestamp = updates[i]
                unconfirmed = new_raw if outcome is None else None
                try:
                    results[i] = await self._compare_and_set(agent_id, fn, timestamp, unconfirmed)
                except APIError as exc:
                    results[i] = exc
        return results  # type: ignore[return-value]

    async def _write_many(
        self, updates: Sequence[Update], sent: list[tuple[int, str | None, str]]
    ) -> list[str | None]:
        """The batch script's outcome per agent sent; None for each if Redis did not answer."""
        if not sent:
            return []
        args: list[object] = [self._ttl_ms, self._max_agents]
        for i, raw, new_raw in sent:
            agent_id, _, timestamp = updates[i]
            sha = "" if raw is None else _sha1(raw)
            args += [agent_id, sha, new_raw, "" if timestamp is None else repr(float(timestamp))]
        keys = [self._index, *(self.key(updates[i][0]) for i, _, _ in sent)]
        try:
            return list(await self._update_many_script(keys=keys, args=args))
        except _UNAVAILABLE:
            return [None] * len(sent)

    async def _compare_and_set(
        self,
        agent_id: str,
        fn: UpdateFn,
        timestamp: float | None,
        unconfirmed: str | None = None,
    ) -> AgentState:
        """``unconfirmed``: the value this update sent when the connection failed before Redis
        answered (a batch's, or this loop's own)."""
        key = self.key(agent_id)
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
