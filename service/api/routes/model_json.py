"""A response whose body is a pydantic model serialised by pydantic's own JSON encoder.

A route that returns a model has FastAPI validate it again against ``response_model`` and encode it
through ``jsonable_encoder`` and ``json.dumps``, on the event loop: for a 50-agent collision answer
ten times what ``model_dump_json`` costs (``make bench``, case ``serialise_50_agents``). The hot
routes return this instead and keep ``response_model`` for the OpenAPI schema; their models are
built by the engine, already valid.

A batch check's answers (``trajectories``: thousands of plain dicts per agent, or
``trajectory_columns``: a list per field) are written by orjson, the rest of each answer by the
model, into the same JSON.
"""

from __future__ import annotations

from typing import Any

import orjson
from pydantic import BaseModel
from starlette.responses import Response

from service.wire.schemas import CollisionCheckResponse, MultiCollisionCheckResponse


class ModelJSONResponse(Response):
    media_type = "application/json"

    def render(self, content: BaseModel) -> bytes:
        if isinstance(content, CollisionCheckResponse) and _is_batch(content):
            return orjson.dumps(_batch_answer(content))
        if isinstance(content, MultiCollisionCheckResponse) and any(
            _is_batch(r) for r in content.results
        ):
            # One dump of the whole answer but its batches' answers, added to each as they are.
            batches = {"results": {"__all__": set(BATCH_FIELDS)}}
            data = content.model_dump(mode="json", exclude=batches)
            for result, answer in zip(data["results"], content.results, strict=True):
                _add_batch(result, answer)
            return orjson.dumps(data)
        return content.model_dump_json().encode()


#: A batch's answers, as entries or as columns: plain dicts and lists, written by orjson.
BATCH_FIELDS = ("trajectories", "trajectory_columns")


def _is_batch(answer: CollisionCheckResponse) -> bool:
    return answer.trajectories is not None or answer.trajectory_columns is not None


def _batch_answer(answer: CollisionCheckResponse) -> dict[str, Any]:
    """The answer as the model dumps it, its batch's answers as they are."""
    return _add_batch(answer.model_dump(mode="json", exclude=set(BATCH_FIELDS)), answer)


def _add_batch(data: dict[str, Any], answer: CollisionCheckResponse) -> dict[str, Any]:
    """``data`` (``answer`` dumped without its batch's answers) with them."""
    for key in BATCH_FIELDS:
        if getattr(answer, key) is not None:
            data[key] = getattr(answer, key)
    return data
