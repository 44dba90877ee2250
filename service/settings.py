"""Server settings, read from the environment (prefix ``FRT_``)."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from models.contract import HORIZON_S, U1_LIMIT, U2_LIMIT

DEFAULT_MODEL = Path(__file__).resolve().parent.parent / "models" / "frt_unicycle.onnx"


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="FRT_", extra="ignore")

    model_path: Path = DEFAULT_MODEL
    horizon_s: float = HORIZON_S
    beta_low: float = Field(0.03, gt=0.0, lt=1.0)
    beta_high: float = 1.0
    gamma: float = Field(0.075, gt=0.0, lt=1.0)
    #: Probability per observation that the belief resets to the prior (epsilon-static transition).
    epsilon: float = Field(0.05, ge=0.0, lt=1.0)
    collision_radius: float = Field(1.5, ge=0.0)
    u1_limit: float = U1_LIMIT
    u2_limit: float = U2_LIMIT
    bounds_fit: str = "envelope"
    max_agents: int = Field(10_000, ge=1)
    agent_ttl_s: float = Field(300.0, gt=0.0)
    max_body_bytes: int = Field(1_000_000, ge=1024)
    max_prediction_steps: int = Field(64, ge=1)
    max_trajectory_points: int = Field(1_000, ge=1)
    auth_token: str | None = None
    store_url: str | None = None


@lru_cache
def get_settings() -> Settings:
    return Settings()
