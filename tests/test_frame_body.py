"""A frame read typed in one pass (``service.wire.frame_body``) against the same frame read
entry by entry (``service.flows.frames``): the same observations, and the bodies it does not
take left to the entry-by-entry path."""

from __future__ import annotations

import json

import numpy as np
import pytest

from service.flows.frames import _checked
from service.wire.frame_body import TypedFrame, parse_frame
from service.wire.schemas import FrameRequest, ObservationRequest
from tests.test_frames import KINDS, _kind_entry


def _frame(first: bool, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    agents = [
        {"agent_id": f"k{kind}-{k}", **_kind_entry(rng, kind, k, first)}
        for kind in range(len(KINDS))
        for k in range(4)
    ]
    agents[0]["map_id"] = None
    return {"timestamp": 7.5, "agents": agents}


@pytest.mark.parametrize("first", [True, False])
def test_a_valid_frame_read_typed_gives_the_observations_read_entry_by_entry(first: bool) -> None:
    body = _frame(first)
    typed = parse_frame(json.dumps(body).encode(), FrameRequest)
    assert isinstance(typed, TypedFrame)
    results: list = [None] * len(body["agents"])
    by_entry = _checked(FrameRequest.model_validate_json(json.dumps(body)), results)
    assert results == [None] * len(body["agents"])
    pairs = typed.observations()
    assert [a for a, _ in pairs] == [a for _, a, _ in by_entry]
    for (_, got), (_, _, want) in zip(pairs, by_entry, strict=True):
        assert isinstance(want, ObservationRequest) and type(got) is ObservationRequest
        assert got.model_dump() == want.model_dump()
        assert got.model_fields_set == want.model_fields_set


def _broken(edit) -> bytes:  # type: ignore[no-untyped-def]
    body = _frame(False, seed=1)
    edit(body["agents"])
    return json.dumps(body).encode()


@pytest.mark.parametrize(
    "edit",
    [
        lambda agents: agents[2].update(timestamp=1.0),  # an entry's own timestamp
        lambda agents: agents[3]["state"].update(speed="fast"),  # an invalid entry
        lambda agents: agents[1].update(extra_field=1),
        lambda agents: agents[4].pop("agent_id"),
        lambda agents: agents[0].update(agent_id="bad id!"),
    ],
)
def test_a_frame_with_an_entry_to_reject_is_left_to_the_entry_by_entry_path(edit) -> None:  # type: ignore[no-untyped-def]
    assert parse_frame(_broken(edit), FrameRequest) is None


def test_only_frames_and_json_are_read() -> None:
    assert parse_frame(b"{not json", FrameRequest) is None
    assert parse_frame(json.dumps(_frame(True)).encode(), TypedFrame) is None
