"""An agent's effective configuration: the server's settings overlaid with the agent's overrides.

One frozen value per agent and observation; the fields are the per-agent keys of API.md
(``config`` of an observation) that shape its sets. The agent's stored overrides (``AgentState.config``)
stay a plain dict of JSON types, since a store serialises them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from service.runtime.settings import Settings


@dataclass(frozen=True)
class AgentConfig:
    """What builds one agent's sets (paper: beta_low, gamma, epsilon; the service's others)."""

    beta_low: float
    gamma: float
    epsilon: float
    collision_radius: float
    bounds_fit: str
    bounds_rule: str
    rescue_onset: float
    coverage_target: float | None
    coverage_step: float
    #: The map assumptions the agent is answered under where it names a map and its class allows
    #: them (``service.flows.road``); the server's ``FRT_ASSUMPTIONS`` unless it names its own.
    assumptions: tuple[str, ...]

    @classmethod
    def of(cls, settings: Settings, overrides: dict[str, Any]) -> AgentConfig:
        """``settings`` overlaid with the non-null ``overrides`` of these fields."""
        values = {name: cls.value_of(settings, overrides, name) for name in CONFIG_KEYS}
        values["assumptions"] = tuple(values["assumptions"])
        return cls(**values)

    @staticmethod
    def value_of(settings: Settings, overrides: dict[str, Any], name: str) -> Any:
        """The field ``name``: the agent's override unless it is null, else the setting (a check
        of many agents reads only R_col)."""
        value = overrides.get(name)
        return getattr(settings, name) if value is None else value

    def with_gamma(self, gamma: float) -> AgentConfig:
        """The same configuration building its sets with ``gamma`` (adaptive gamma's)."""
        return replace(self, gamma=gamma)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


CONFIG_KEYS: tuple[str, ...] = tuple(f.name for f in fields(AgentConfig))
