"""A frame's body read typed in one pass: every entry validated as an observation straight from
the JSON bytes.

:class:`~service.wire.schemas.FrameRequest` keeps each entry as a dict, validated on its own
afterwards (``service.flows.frames``), so that one bad agent is rejected by index and field
while the others apply; read that way a frame's predictions are built as Python lists twice.
:func:`parse_frame` reads a frame whose every entry is a valid observation in one pass
(:class:`TypedFrame`) and returns None for any other body: a frame with an invalid entry, an
entry with its own ``timestamp`` or too many entries is read as a :class:`FrameRequest`, entry by
entry, and answered exactly as without this path.
"""

from __future__ import annotations

from pydantic import Field, ValidationError

from service.wire.schemas import (
    AGENTS_PER_FRAME_CAP,
    AgentId,
    FrameRequest,
    ObservationRequest,
    Time,
)


class FrameEntry(ObservationRequest):
    """An entry of a frame: an observation without its own timestamp (the frame's applies)."""

    agent_id: AgentId
    timestamp: Time | None = None  # type: ignore[assignment]


class TypedFrame(FrameRequest):
    """A frame whose every entry is a valid observation (:class:`FrameEntry`)."""

    agents: list[FrameEntry] = Field(max_length=AGENTS_PER_FRAME_CAP)  # type: ignore[assignment]

    def observations(self) -> list[tuple[str, ObservationRequest]]:
        """Each entry's agent id and observation at the frame's timestamp, in order (their
        values as validated, not validated again)."""
        fields = [name for name in ObservationRequest.model_fields if name != "timestamp"]
        out = []
        for entry in self.agents:
            given = (entry.model_fields_set - {"agent_id"}) | {"timestamp"}
            values = {name: getattr(entry, name) for name in fields}
            observation = ObservationRequest.model_construct(
                given, timestamp=self.timestamp, **values
            )
            out.append((entry.agent_id, observation))
        return out


def parse_frame(raw: bytes, model: type[FrameRequest]) -> FrameRequest | None:
    """``raw`` as a :class:`TypedFrame` if every entry is a valid observation without a
    timestamp of its own, else None (``service.api.routes.json_body``'s bulk parser)."""
    if model is not FrameRequest:
        return None
    try:
        frame = TypedFrame.model_validate_json(raw)
    except ValidationError:
        return None
    if any(entry.timestamp is not None for entry in frame.agents):
        return None
    return frame
