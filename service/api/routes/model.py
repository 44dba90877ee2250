"""``GET /v1/model``: the model card of the loaded value network."""

from __future__ import annotations

from fastapi import APIRouter

from service.api.routes.params import ServicesDep
from service.wire.schemas import ModelCardResponse

router = APIRouter(prefix="/v1", tags=["model"])


@router.get("/model", response_model=ModelCardResponse)
async def model_card(services: ServicesDep) -> ModelCardResponse:
    """The card: semantics, calibration margin, trained ranges, horizon, initial set, and the rest."""
    card = services.require_card()
    assert services.parts is not None
    return ModelCardResponse(
        name=card.name,
        semantics=card.semantics,
        delta=card.delta,
        horizon_s=card.horizon_s,
        ranges={k: [lo, hi] for k, (lo, hi) in card.ranges.items()},
        initial_set=dict(card.initial_set),
        card=card.raw,
        active=services.parts,
    )
