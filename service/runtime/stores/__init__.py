"""Per-agent state behind one interface (:class:`AgentStore`): in memory by default
(``memory``), in Redis shared by replicas (``redis``); :func:`make_store` picks one by URL."""

from __future__ import annotations

from service.runtime.stores.memory import InMemoryAgentStore
from service.runtime.stores.state import (
    AgentState,
    AgentStore,
    StoreFullError,
    Update,
    UpdateFn,
)

__all__ = [
    "AgentState",
    "AgentStore",
    "InMemoryAgentStore",
    "StoreFullError",
    "Update",
    "UpdateFn",
    "make_store",
]


def make_store(
    url: str | None, *, ttl_s: float, max_agents: int
) -> AgentStore:  # pragma: no cover - trivial
    """The store named by ``settings.store_url``: unset or ``memory://`` keeps agents in memory."""
    if url is None or url in ("", "memory://"):
        return InMemoryAgentStore(ttl_s=ttl_s, max_agents=max_agents)
    if url.startswith(("redis://", "rediss://", "unix://")):
        try:
            from service.runtime.stores.redis import RedisAgentStore
        except ImportError as exc:
            raise ValueError(f"store_url {url!r}: no Redis store in this build") from exc
        return RedisAgentStore(url, ttl_s=ttl_s, max_agents=max_agents)  # type: ignore[no-any-return]
    raise ValueError(f"store_url {url!r}: unknown scheme (use memory:// or redis://)")
