"""An agent's state, and what a store of them must do (:class:`AgentStore`).

The one write path is :meth:`AgentStore.update`: an atomic read-modify-write of one agent under that
agent's lock, with the timestamp check of API.md ("timestamps must increase per agent", 409) done by
the store itself; :meth:`AgentStore.update_many` is that update of each of several agents in one
pass (one frame of observations). Agent state is a plain dataclass of JSON types (``to_dict``/``from_dict``) so any
store can serialise it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Protocol, runtime_checkable

from service.wire.errors import APIError

#: Builds the agent's next state from its current one (``None`` for a new agent), which it reads
#: and never modifies (the store may share it with readers of ``get_many(shared=True)``). It may
#: raise (an :class:`~service.wire.errors.APIError` such as a 422) to abort the update; nothing is
#: written then.
UpdateFn = Callable[["AgentState | None"], "AgentState"]
#: One agent's part of a batched update (:meth:`AgentStore.update_many`): its id, its
#: :data:`UpdateFn` and the timestamp its update must be later than the stored one's (None: none).
Update = tuple[str, UpdateFn, "float | None"]


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
    #: The last prediction's first step (the one the next observed action is scored against; a
    #: multi-modal agent's modes keep theirs in ``modes``): ``{"dt": float, "mean": [[u1, u2]],
    #: "cov": [[[..], [..]]]}``. States written with every step are read alike.
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

    def set_bounds(self) -> list[float]:
        """The bounds the state's FRT job is built from: one row of eight per mode in the set,
        flat (eight values for a single Gaussian or a set of one mode)."""
        if self.modes is None:
            return self.control_bounds
        rows = self.modes["bounds"]
        return rows[0] if len(rows) == 1 else [b for row in rows for b in row]

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
        propagate and leave the stored state unchanged. The new state returned is the caller's to
        read, not to modify: the store may share it with readers of ``get_many(shared=True)``.
        """
        ...

    async def update_many(self, updates: Sequence[Update]) -> list[AgentState | APIError]:
        """:meth:`update` of each agent of ``updates`` (distinct ids), in one pass over the store.

        Per agent it is :meth:`update` exactly: one atomic read-modify-write with the timestamp
        check, and the same refusals (:class:`StaleTimestampError`, :class:`StoreFullError`, an
        :class:`~service.wire.errors.APIError` raised by its function), each the agent's result in
        place of its new state and leaving that agent's stored state unchanged; the others are
        written. Any other exception from a function propagates, and nothing is written.
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
