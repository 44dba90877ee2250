"""A batch check's body read in bulk: its trajectories' columns as numpy arrays.

A batch of 500 trajectories of 30 points is 45 000 numbers; validating each as a pydantic float
costs more than the check itself. :func:`parse_batch_check` reads the body with orjson, checks the
``trajectories`` columns in bulk (numbers only, finite, within the schema's magnitudes, one length
per trajectory, the schema's caps) and validates the rest of the body with the model. It returns
None for any body it does not take whole (the point form, a missing or malformed column, a wrong
type anywhere): the model's own parser then reads it and names what is wrong, so a rejected body
is answered exactly as without this path.
"""

from __future__ import annotations

from itertools import chain
from typing import Any, TypeVar

import numpy as np
import orjson
from pydantic import BaseModel, ValidationError

from service.wire.schemas import (
    ANGLE_MAX,
    COORD_MAX,
    TIME_MAX,
    TRAJECTORIES_CAP,
    TRAJECTORY_POINTS_CAP,
    TrajectoryColumns,
)

M = TypeVar("M", bound=BaseModel)

#: Each column's magnitude limit, as the schema's field types have it.
LIMITS = {"t": TIME_MAX, "x": COORD_MAX, "y": COORD_MAX, "heading": ANGLE_MAX}
#: What the model sees in place of the columns while it validates the rest of the body.
PLACEHOLDER = [{"t": [0.0], "x": [0.0], "y": [0.0]}]


def parse_batch_check(raw: bytes, model: type[M]) -> M | None:
    """``raw`` as ``model`` (a check body) with its ``trajectories`` as columns of numpy arrays,
    or None where the bulk path does not take the body (see the module docstring)."""
    try:
        data = orjson.loads(raw)
    except orjson.JSONDecodeError:
        return None
    if not isinstance(data, dict):
        return None
    columns = _columns(data.get("trajectories"))
    if columns is None:
        return None
    try:
        request = model.model_validate({**data, "trajectories": PLACEHOLDER})
    except ValidationError:
        return None
    return request.model_copy(update={"trajectories": columns})


def _columns(batch: Any) -> list[TrajectoryColumns] | None:
    if not isinstance(batch, list) or not 1 <= len(batch) <= TRAJECTORIES_CAP:
        return None
    if not all(type(part) is dict for part in batch):
        return None
    keys = ("t", "x", "y")
    with_heading = ["heading" in part for part in batch]
    for part, headed in zip(batch, with_heading, strict=True):
        if len(part) != 3 + headed or not all(key in part for key in keys):
            return None
    flat = {key: _flat(key, [part[key] for part in batch]) for key in keys}
    headed = [part["heading"] for part in batch if "heading" in part]
    heading = _flat("heading", headed) if headed else np.zeros(0)
    lengths = [len(part["t"]) for part in batch]
    if any(v is None for v in flat.values()) or heading is None:
        return None
    for part, n in zip(batch, lengths, strict=True):
        if not 1 <= n <= TRAJECTORY_POINTS_CAP or any(len(part[key]) != n for key in part):
            return None
    return _split(flat, heading, lengths, with_heading)


def _flat(key: str, lists: list[Any]) -> np.ndarray | None:
    """The numbers of ``lists`` in one array, or None unless each is a list of finite ints and
    floats within the column's limit."""
    if not all(type(values) is list for values in lists):
        return None
    if not set(map(type, chain.from_iterable(lists))) <= {float, int}:
        return None
    values = np.fromiter(chain.from_iterable(lists), dtype=np.float64)
    if not (np.isfinite(values).all() and (np.abs(values) <= LIMITS[key]).all()):
        return None
    return values


def _split(
    flat: dict[str, np.ndarray],
    heading: np.ndarray,
    lengths: list[int],
    with_heading: list[bool],
) -> list[TrajectoryColumns]:
    out, start, heading_start = [], 0, 0
    for n, headed in zip(lengths, with_heading, strict=True):
        end = start + n
        out.append(
            TrajectoryColumns.model_construct(
                t=flat["t"][start:end],
                x=flat["x"][start:end],
                y=flat["y"][start:end],
                heading=heading[heading_start : heading_start + n] if headed else None,
            )
        )
        start, heading_start = end, heading_start + (n if headed else 0)
    return out
