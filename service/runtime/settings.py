"""Server settings, read from the environment (prefix ``FRT_``)."""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator
from pydantic.fields import FieldInfo
from pydantic_settings import (
    BaseSettings,
    NoDecode,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
)

from reach.contract import HORIZON_S, U1_LIMIT, U2_LIMIT
from reach.notch import NOTCH_CUT_BY_DEFAULT
from service.runtime.profiles import PROFILE_ENV, load_profile

#: The map assumptions the service knows (docs/maps.md).
AssumptionName = Literal["drivable_area", "reachable_lanes", "speed_limit"]

DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "models" / "frt_unicycle.onnx"


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="FRT_", extra="ignore")

    model_path: Path = DEFAULT_MODEL
    horizon_s: float = HORIZON_S
    beta_low: float = Field(0.03, gt=0.0, lt=1.0)
    #: The top hypothesis is the predictor taken as it is (covariance inflated by 1/beta = 1, paper
    #: "Confidence estimation and update"); the filter's grid ends there, so no other value is
    #: accepted (a value that would be ignored must not be settable).
    beta_high: float = Field(1.0, ge=1.0, le=1.0)
    gamma: float = Field(0.075, gt=0.0, lt=1.0)
    #: Probability per observation that the belief resets to the prior (epsilon-static transition).
    epsilon: float = Field(0.05, ge=0.0, lt=1.0)
    collision_radius: float = Field(1.5, ge=0.0)
    u1_limit: float = U1_LIMIT
    u2_limit: float = U2_LIMIT
    bounds_fit: str = "envelope"
    #: How confidence widens the bounds (``service.flows.bounds_rule``): "paper" is the paper's
    #: covariance / beta with a fixed gamma; "uniform_mixture" mixes in a uniform over the class's
    #: limits weighted by the distrust 1 - beta; "mass_ramp" raises the trimmed mass instead.
    bounds_rule: Literal["paper", "uniform_mixture", "mass_ramp"] = "paper"
    #: The rule is the paper's wherever 1 - beta is at most this (a dead zone near full confidence).
    rescue_onset: float = Field(0.0, ge=0.0, lt=1.0)
    max_agents: int = Field(10_000, ge=1)
    agent_ttl_s: float = Field(300.0, gt=0.0)
    max_body_bytes: int = Field(1_000_000, ge=1024)
    #: The body limit of collision checks, which may carry a batch of trajectories.
    max_check_body_bytes: int = Field(8_000_000, ge=1024)
    max_prediction_steps: int = Field(64, ge=1)
    max_trajectory_points: int = Field(1_000, ge=1)
    auth_token: str | None = None
    store_url: str | None = None
    #: This replica's name, sent back on every HTTP response as ``X-FRT-Replica`` (none if unset):
    #: behind nginx it tells which replica answered (docs/deploy.md, "Scenes").
    replica_id: str | None = Field(None, min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.:-]+$")

    # Scheduling of the exact FRT and the latency budget of collision checks.
    #: Workers computing exact FRTs in the background (CPU-bound: keep at or below the core count).
    frt_workers: int = Field(2, ge=1, le=64)
    #: "process": workers are processes, each with its own engine (the event loop keeps its GIL);
    #: "thread": threads of the server process (also the fallback if processes cannot start).
    frt_executor: Literal["process", "thread"] = "process"
    #: How exact-set worker processes run below the server (``service.runtime.exact_worker.lower_priority``):
    #: "idle" (SCHED_IDLE) only on CPUs with nothing else to run, which the server's wake-ups treat
    #: as idle; "batch" (SCHED_BATCH plus ``frt_worker_nice``). On a busy machine the server's
    #: requests run first and exact sets take what is left; checks answer from conservative sets
    #: meanwhile.
    frt_worker_policy: Literal["idle", "batch"] = "idle"
    #: Niceness added to "batch" workers (19 kept the sustained bench's checks faster than 5 did).
    frt_worker_nice: int = Field(19, ge=0, le=19)
    #: Refine exact sets whose heading interval passes +-pi/2 (the car may turn round): once the
    #: uncut set is ready (observation -> ready unchanged), a worker with nothing else to do cuts
    #: it to the speed-coupled partition (``reach.engine.NotchCut``) and the cut set replaces it,
    #: in two stages (``NOTCH_STAGES``: quick, then fine if the version should still be current).
    #: Tighter, still sound sets behind such cars for a worker's spare time. Only with worker
    #: processes (``frt_executor``): on threads it would hold the event loop's GIL.
    frt_notch_cut: bool = NOTCH_CUT_BY_DEFAULT
    #: Worker processes draw the tubes an agent's time-indexed checks ask for
    #: (``service.runtime.tube_demand``) before sending its exact set back, so a check finds the
    #: tube of each of its points drawn and answers from the exact set; off, the event loop draws
    #: them within checks' deadlines and between requests.
    frt_draw_tubes: bool = True
    #: Exact FRTs kept in memory, keyed by (agent, FRT version, inputs): at most the two latest
    #: versions of each agent (``service.runtime.scheduler.VERSIONS_PER_AGENT``); least recently used go first.
    frt_cache_size: int = Field(1024, ge=1)
    #: Default deadline of a collision check, measured from the request's arrival.
    deadline_ms: float = Field(20.0, gt=0.0, le=60_000.0)
    #: A check waits for a late exact set for at most this fraction of its deadline ...
    deadline_wait_fraction: float = Field(0.6, ge=0.0, le=1.0)
    #: ... and never into the deadline's last milliseconds, kept to answer conservatively.
    deadline_reserve_ms: float = Field(1.0, ge=0.0)
    #: Exact sets start first for agents a check came near within this many seconds
    #: (``service.runtime.demand``; 0: newest first, whoever's) ...
    exact_demand_s: float = Field(1.0, ge=0.0)
    #: ... near: a conservative verdict, or a clearance below this (metres) from the exact set
    #: or from the conservative one (a lower bound of the exact set's).
    exact_demand_margin_m: float = Field(2.0, ge=0.0)
    #: How long contours and the stateless endpoint wait for an exact set before going conservative.
    exact_timeout_s: float = Field(5.0, gt=0.0)
    #: Agents one multi-agent collision check may name (or find, when it asks for all of them).
    max_agents_per_check: int = Field(256, ge=1)
    #: Trajectories one batch check may carry.
    max_trajectories: int = Field(1024, ge=1)
    #: Points one check measures against each agent (every trajectory's, times the footprint's
    #: discs) ...
    max_check_points: int = Field(131_072, ge=1)
    #: ... and against all its agents together (points x agents).
    max_check_work: int = Field(2_000_000, ge=1)
    #: Agents one frame (``POST /v1/frames``) may carry.
    max_agents_per_frame: int = Field(256, ge=1)
    #: Time slices one contour request may ask for.
    max_slices: int = Field(16, ge=1)

    # Maps (docs/maps.md): Argoverse 2 archives or Lanelet2 OSM files whose road cuts the sets.
    #: A map loaded at start-up (``FRT_MAP=path``; ``*.osm``: Lanelet2), registered as ``map_id``.
    map: Path | None = None
    map_id: str = Field("default", pattern=r"^[A-Za-z0-9_.:\-]{1,128}$")
    #: The drivable area is grown by this (metres) before it cuts a set: R = D ⊕ margin.
    map_margin_m: float = Field(1.0, ge=0.0, le=50.0)
    #: Maps held at once (``PUT /v1/maps/{map_id}`` of a new id past it: 409).
    max_maps: int = Field(16, ge=1)
    #: The body limit of ``PUT /v1/maps/{map_id}`` (413 past it) ...
    max_map_bytes: int = Field(16_000_000, ge=1024)
    #: ... and the points one archive may hold (422 past it).
    max_map_points: int = Field(2_000_000, ge=1)
    #: The map assumptions an agent that names a map is answered under, unless its ``config``
    #: names its own (``FRT_ASSUMPTIONS=drivable_area,reachable_lanes,speed_limit``; empty:
    #: none); each class keeps those that apply to it (``service.flows.road.CLASS_ASSUMPTIONS``).
    assumptions: Annotated[tuple[AssumptionName, ...], NoDecode] = (
        "drivable_area",
        "reachable_lanes",
        "speed_limit",
    )
    #: ``speed_limit``: a car's speed stays at most this × the highest limit of the lanes it can
    #: reach (``reach.speed_limit``): 1.2 leaves 20 % over the limit before the assumption is
    #: broken.
    speed_limit_factor: float = Field(1.2, ge=1.0, le=3.0)
    #: An assumption an agent is observed breaking is dropped for it for this many seconds of
    #: its own clock (SPOT's self-relaxation; docs/maps.md).
    assumption_relax_s: float = Field(5.0, ge=0.0, le=3600.0)

    #: Whether sets are cut by the value network: "auto" evaluates it unless its model card's
    #: evaluation found that it cuts nothing inside the certified geometry; "on", "off" force it.
    network: Literal["auto", "on", "off"] = "auto"
    #: Serve the operator's live page at ``GET /viewer`` (docs/viewer.md); off: 404.
    viewer: bool = True

    # The coverage audit (docs/coverage.md): each observation's position scored against the sets
    # served earlier for its agent.
    #: Off (``FRT_AUDIT=0``): no audit, no adaptive gamma.
    audit: bool = True
    #: Earlier versions of one agent kept for the audit (the latest; each holds its conservative
    #: set, a few kB): 32 covers a 3 s horizon at 10 Hz.
    audit_max_versions: int = Field(32, ge=1, le=256)
    #: A version is scored against its agent's positions at least this many seconds apart (the
    #: first after it, then every later one this long after the last scored; 0: every position).
    audit_spacing_s: float = Field(0.4, ge=0.0, le=10.0)
    #: Audited positions the rolling coverage gauges (``frt_audit_coverage``) average over.
    audit_window: int = Field(1000, ge=1, le=1_000_000)
    #: Adaptive gamma (``service.flows.adaptive_gamma``): the share of audited positions inside C
    #: to hold in the long run; None (the default) keeps gamma fixed. Per agent in ``config``.
    coverage_target: float | None = Field(None, gt=0.0, lt=1.0)
    #: The adaptive rule's step (eta of Gibbs & Candes 2021).
    coverage_step: float = Field(0.02, gt=0.0, le=1.0)

    # Logging: one JSON object per line on stderr.
    log_level: str = "INFO"
    log_json: bool = True
    #: Log one line per HTTP request (method, route, status, duration).
    log_requests: bool = True

    @field_validator("assumptions", mode="before")
    @classmethod
    def _comma_separated(cls, value: Any) -> Any:
        """``FRT_ASSUMPTIONS`` as comma-separated names (repeats dropped)."""
        if isinstance(value, str):
            value = [part.strip() for part in value.split(",") if part.strip()]
        if isinstance(value, list | tuple):
            value = tuple(dict.fromkeys(value))
        return value

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        """Explicit arguments, then the environment, then the profile ``FRT_PROFILE`` names
        (``service.runtime.profiles``), then the defaults."""
        profile = _ProfileSource(settings_cls)
        return init_settings, env_settings, dotenv_settings, profile, file_secret_settings


class _ProfileSource(PydanticBaseSettingsSource):
    """The settings of the profile ``FRT_PROFILE`` names (none if unset)."""

    def get_field_value(self, field: FieldInfo, field_name: str) -> tuple[Any, str, bool]:
        return None, field_name, False  # __call__ reads the whole profile at once

    def __call__(self) -> dict[str, Any]:
        name = os.environ.get(PROFILE_ENV)
        if not name:
            return {}
        return load_profile(name, known=set(self.settings_cls.model_fields))


@lru_cache
def get_settings() -> Settings:
    return Settings()
