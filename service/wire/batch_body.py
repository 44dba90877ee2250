"""A batch check's body read in bulk: its trajectories' columns as flat numpy arrays.

A batch of 500 trajectories of 30 points is 45 000 numbers; validating each as a pydantic float
costs more than the check itself. :func:`parse_batch_check` reads the body with orjson, checks the
``trajectories`` columns in bulk (numbers only, finite, within the schema's magnitudes, one length
per trajectory, the schema's caps) and validates the rest of the body with the model; a body with
``packed_trajectories`` (its columns strings) the model validates as orjson parsed it. It returns
None for any body it does not take whole (the point form, a missing or malformed column, a wrong
type anywhere): the model's own parser then reads it and names what is wrong, so a rejected body
is answered exactly as without this path.

The columns it takes stay flat (:class:`ColumnBatch`): a check reads every trajectory's points
from them at once, and a trajectory as :class:`TrajectoryColumns` is made only where one is read
on its own.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from itertools import chain
from typing import Any, TypeVar, overload

import numpy as np
import orjson
from pydantic import BaseModel, ValidationError

from service.wire.schemas import (
    ANGLE_MAX,
    COORD_MAX,
    TIME_MAX,
    TRAJECTORIES_CAP,
    TRAJECTORY_POINTS_CAP,
    PackedTrajectories,
    TrajectoryColumns,
)

M = TypeVar("M", bound=BaseModel)

#: Each column's magnitude limit, as the schema's field types have it.
LIMITS = {"t": TIME_MAX, "x": COORD_MAX, "y": COORD_MAX, "heading": ANGLE_MAX}
#: What the model sees in place of the columns while it validates the rest of the body.
PLACEHOLDER = [{"t": [0.0], "x": [0.0], "y": [0.0]}]
#: JSON's booleans: a body without these tokens has no boolean among its numbers.
BOOLEANS = (b"true", b"false")


class ColumnBatch(Sequence[TrajectoryColumns]):
    """A batch's trajectories as flat columns: ``t``, ``x``, ``y`` ``[P]`` of every point in
    order, trajectory k being points ``starts[k]:starts[k] + lengths[k]``; ``heading`` ``[P]``
    where ``headed[k]`` (NaN in the trajectories without one). Item k is trajectory k as
    :class:`TrajectoryColumns` (the columns numpy views)."""

    def __init__(
        self,
        columns: dict[str, np.ndarray],
        lengths: np.ndarray,
        headed: np.ndarray,
    ) -> None:
        self.t, self.x, self.y, self.heading = (columns[k] for k in ("t", "x", "y", "heading"))
        self.lengths = lengths
        self.headed = headed
        self.starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.intp)

    def __len__(self) -> int:
        return len(self.lengths)

    @overload
    def __getitem__(self, k: int) -> TrajectoryColumns: ...

    @overload
    def __getitem__(self, k: slice) -> list[TrajectoryColumns]: ...

    def __getitem__(self, k: int | slice) -> TrajectoryColumns | list[TrajectoryColumns]:
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        k = range(len(self))[k]
        a = int(self.starts[k])
        b = a + int(self.lengths[k])
        return TrajectoryColumns.model_construct(
            t=self.t[a:b],
            x=self.x[a:b],
            y=self.y[a:b],
            heading=self.heading[a:b] if self.headed[k] else None,
        )

    def __iter__(self) -> Iterator[TrajectoryColumns]:
        return (self[k] for k in range(len(self)))


def packed_batch(packed: PackedTrajectories) -> ColumnBatch:
    """A batch sent as packed columns (already read and checked by its model) as a
    :class:`ColumnBatch`: every trajectory headed, or none."""
    lengths = np.asarray(packed.lengths, dtype=np.intp)
    headed = np.full(len(lengths), packed.heading is not None)
    heading = packed.heading if packed.heading is not None else np.full(len(packed.t), np.nan)
    columns = {"t": packed.t, "x": packed.x, "y": packed.y, "heading": heading}
    return ColumnBatch(columns, lengths, headed)


def parse_batch_check(raw: bytes, model: type[M]) -> M | None:
    """``raw`` as ``model`` (a check body) with its ``trajectories`` a :class:`ColumnBatch`, or
    None where the bulk path does not take the body (see the module docstring)."""
    try:
        data = orjson.loads(raw)
    except orjson.JSONDecodeError:
        return None
    if not isinstance(data, dict):
        return None
    if "packed_trajectories" in data:
        # Its columns are strings: the model reads the body as parsed here, without a second parse.
        try:
            return model.model_validate(data)
        except ValidationError:
            return None
    columns = _columns(data.get("trajectories"), strict=holds_booleans(raw))
    if columns is None:
        return None
    try:
        request = model.model_validate({**data, "trajectories": PLACEHOLDER})
    except ValidationError:
        return None
    return request.model_copy(update={"trajectories": columns})


def holds_booleans(raw: bytes) -> bool:
    """Whether ``raw`` holds one of :data:`BOOLEANS` anywhere: the places of each token's first
    byte, narrowed byte by byte (one vectorised pass, where ``bytes.find`` scans the body once
    per token at a fraction of the speed)."""
    buffer = np.frombuffer(raw, dtype=np.uint8)
    for token in BOOLEANS:
        at = np.flatnonzero(buffer[: max(len(buffer) - len(token) + 1, 0)] == token[0])
        for k in range(1, len(token)):
            at = at[buffer[at + k] == token[k]]
        if len(at):
            return True
    return False


def _columns(batch: Any, strict: bool) -> ColumnBatch | None:
    """The batch's columns, or None unless every trajectory is a dict of the columns t, x, y and
    perhaps heading, each a list of one length (1 to the cap) of numbers within its limit.
    ``strict``: the body may hold booleans, so each number's type is checked one by one."""
    if not isinstance(batch, list) or not 1 <= len(batch) <= TRAJECTORIES_CAP:
        return None
    if set(map(type, batch)) != {dict}:
        return None
    sizes = np.fromiter(map(len, batch), dtype=np.intp, count=len(batch))
    headed = sizes == 4
    try:
        lists = {key: [part[key] for part in batch] for key in ("t", "x", "y")}
        headings = [part["heading"] for part in batch if len(part) == 4]
    except KeyError:
        return None
    if not ((sizes == 3) | headed).all():
        return None
    lists["heading"] = headings
    if any(set(map(type, values)) - {list} for values in lists.values()):
        return None
    lengths = np.fromiter(map(len, lists["t"]), dtype=np.intp, count=len(batch))
    if not ((lengths >= 1) & (lengths <= TRAJECTORY_POINTS_CAP)).all():
        return None
    for key in ("x", "y"):
        if not np.array_equal(np.fromiter(map(len, lists[key]), dtype=np.intp), lengths):
            return None
    if not np.array_equal(np.fromiter(map(len, headings), dtype=np.intp), lengths[headed]):
        return None
    flat = {key: _flat(key, lists[key], strict) for key in lists}
    if any(v is None for v in flat.values()):
        return None
    heading = np.full(int(lengths.sum()), np.nan)
    heading[np.repeat(headed, lengths)] = flat["heading"]
    return ColumnBatch({**flat, "heading": heading}, lengths, headed)  # type: ignore[dict-item]


def _flat(key: str, lists: list[list[Any]], strict: bool) -> np.ndarray | None:
    """The numbers of ``lists`` in one array, or None unless each is a finite int or float within
    the column's limit. Lists of one length are read by one ``np.array`` call, which infers a
    float or int dtype only where every item is a number or a boolean (the caller rules booleans
    out, or asks for each type to be checked: ``strict``)."""
    if not lists:
        return np.zeros(0)
    values = None
    if not strict and len(set(map(len, lists))) == 1:
        try:
            array = np.array(lists)
        except (ValueError, TypeError, OverflowError):
            return None
        if array.ndim == 2 and array.dtype.kind in "fi":
            values = array.astype(np.float64).reshape(-1)
        elif array.dtype.kind not in "O":
            return None
    if values is None:
        if not set(map(type, chain.from_iterable(lists))) <= {float, int}:
            return None
        values = np.fromiter(chain.from_iterable(lists), dtype=np.float64)
    if not (np.isfinite(values).all() and (np.abs(values) <= LIMITS[key]).all()):
        return None
    return values
