"""Parameters shared by several routes."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Path

from service.schemas import AGENT_ID_PATTERN
from service.services import Services, services_of

AgentIdPath = Annotated[
    str, Path(pattern=AGENT_ID_PATTERN, description="the caller's id of the human")
]
ServicesDep = Annotated[Services, Depends(services_of)]
