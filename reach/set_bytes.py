"""Sets as bytes: one buffer of numpy arrays behind a small header, sent between processes
instead of a pickle.

An exact set (``FieldTubeSet``, with its conservative ``BoxTubeSet``; a multi-modal
``UnionSet`` of them) is mostly arrays: the outer bound's supports and boxes, the slices' fields,
and the tubes drawn so far (shapely geometries, written as WKB). :func:`set_to_bytes` writes what
``FieldTubeSet.__getstate__`` keeps (and a box or union set's attributes), less the caches of
drawn GeoJSON and packed rings, which are rebuilt on demand. :func:`set_from_bytes` reads it back
with ``struct``, numpy views and shapely's WKB reader only, builds none but the types named here,
and refuses (:class:`SetBytesError`) a buffer that is truncated, corrupt (CRC-32), of another
version, or that does not describe these types.

Layout, little-endian::

    b"FRTSET" | u16 version | u32 CRC-32 of all that follows | u32 I | u32 F |
    I int64 | F float64 | the arrays, one after the other, each padded to a multiple of 8 bytes

The ints and floats say what the arrays are, in the order a set is written (:class:`_Writer`):
each array by its dtype code and shape (ints), each set by its type code and fields (numbers as
ints or floats, booleans as 0 or 1), each geometry by its index among the WKB records, which come
first (their count, then two arrays: the records' bytes one after the other and their ends).
"""

from __future__ import annotations

import dataclasses
import math
import struct
import zlib
from typing import Any

import numpy as np
import shapely
import shapely.errors
from shapely.geometry.base import BaseGeometry

from reach.field_tube import FieldTubeSet, Lattice, SliceFields
from reach.frames import Pose
from reach.memo import Memo
from reach.notch import NotchCut
from reach.outer_bound import OuterBound
from reach.sets import BoxTubeSet, FRTSet
from reach.union import UnionSet

MAGIC = b"FRTSET"
VERSION = 1
_PREFIX = struct.Struct("<6sHIII")  # magic, version, CRC-32, ints, floats
_CRC_FROM = 12  # the CRC covers the counts, the ints, the floats and the arrays
#: The dtypes an array may have, by code.
_DTYPES = (np.dtype("<f4"), np.dtype("<f8"), np.dtype("<i8"), np.dtype("|b1"), np.dtype("|u1"))
_CODES = {dtype: code for code, dtype in enumerate(_DTYPES)}
_BOOL_CODE = _CODES[np.dtype(bool)]
#: Set types by code.
_FIELD_TUBE, _BOX, _UNION = 1, 2, 3
#: The attributes of each set type that travel (the caches stay behind).
_CACHES = frozenset({"_world_cache", "_packed"})
_BASE = ("pose", "slice_dt", "horizon_s", "n_slices", "conservative", "evaluations")
_FIELD_TUBE_KEYS = frozenset(
    {
        *_BASE,
        *("notch", "notch_possible", "lattice", "instant", "sweep", "bound", "bound_rows"),
        *("outer", "coarse", "outer_held", "instants_uncut"),
    }
)
#: A FieldTubeSet's memos of geometries by int key that may travel (``__getstate__``), by code.
_GEOMETRY_MEMOS = ("_tubes", "_slices", "_intervals", "_hulls")
_BOX_ARRAYS = ("boxes", "boxes_until", "slice_boxes", "interval_boxes")
_BOX_KEYS = frozenset({*_BASE, *_BOX_ARRAYS, "_unions"})
_UNION_KEYS = frozenset({*_BASE, "members", "clearance_from_tubes", "_tubes"})
_NOTCH_ARRAYS = ("cut", "supports", "empty", "headings", "reach_m", "directions")
_BOUND_FIELDS = tuple(f.name for f in dataclasses.fields(OuterBound))


class SetBytesError(ValueError):
    """A buffer that is not a set this module wrote (truncated, corrupt, another version or
    layout)."""


def set_to_bytes(frt: FRTSet, prefix: bytes = b"") -> bytes:
    """``frt`` (a FieldTubeSet, BoxTubeSet or a UnionSet of them) as one buffer, after ``prefix``
    (a caller's own framing, written in the same copy); TypeError for another type, or a set with
    an attribute this layout does not hold."""
    writer = _Writer()
    writer.frt_set(frt)
    return writer.finish(prefix)


def set_from_bytes(data: bytes | bytearray | memoryview) -> FRTSet:
    """The set :func:`set_to_bytes` wrote into ``data``; :class:`SetBytesError` if ``data`` is not
    such a buffer. Its arrays are views of one copy of the data, owned by the set."""
    try:
        reader = _Reader(memoryview(data))
        frt = reader.frt_set()
        reader.done()
    except (SetBytesError, shapely.errors.ShapelyError) as exc:
        raise SetBytesError(str(exc)) from exc
    except (IndexError, ValueError) as exc:  # a count past the ints, floats or data
        raise SetBytesError(f"a set buffer that does not describe a set: {exc!r}") from exc
    return frt


class _Writer:
    """The ints, floats, arrays and geometries of the sets it writes, in order."""

    def __init__(self) -> None:
        self.ints: list[int] = []
        self.floats: list[float] = []
        self.arrays: list[np.ndarray] = []
        self.geometries: list[BaseGeometry] = []
        self._geometry_index: dict[int, int] = {}

    def array(self, values: np.ndarray) -> None:
        values = np.ascontiguousarray(values)
        code = _CODES.get(values.dtype)
        if code is None:
            raise TypeError(f"no binary layout for arrays of {values.dtype}")
        self.ints += [code, values.ndim, *values.shape]
        self.arrays.append(values)

    def geometries_by_key(self, values: dict[Any, BaseGeometry]) -> None:
        """Their count, the keys (ints), then each geometry's WKB record."""
        self.ints.append(len(values))
        self.ints += [int(k) for k in values]
        for geometry in values.values():
            if not isinstance(geometry, BaseGeometry):
                raise TypeError(f"not a geometry: {type(geometry).__name__}")
            index = self._geometry_index.get(id(geometry))
            if index is None:  # one record per object, however often it is held
                index = self._geometry_index[id(geometry)] = len(self.geometries)
                self.geometries.append(geometry)
            self.ints.append(index)

    def frt_set(self, frt: FRTSet) -> None:
        kind = type(frt)
        if kind is FieldTubeSet:
            self.field_tube(frt)  # type: ignore[arg-type]
            return
        state = {k: v for k, v in vars(frt).items() if k not in _CACHES}
        if kind is BoxTubeSet:
            _expect_keys(state, _BOX_KEYS, _BOX_KEYS, "BoxTubeSet")
            self.base(_BOX, state)
            self.array(state["boxes"])
            columns = [state[name] for name in ("boxes_until", "slice_boxes", "interval_boxes")]
            self.array(np.column_stack(columns).astype(np.int64))
            self.geometries_by_key(state["_unions"])
        elif kind is UnionSet:
            _expect_keys(state, _UNION_KEYS, _UNION_KEYS, "UnionSet")
            self.base(_UNION, state)
            self.ints += [len(state["members"]), int(bool(state["clearance_from_tubes"]))]
            for member in state["members"]:
                self.frt_set(member)
            self.geometries_by_key(state["_tubes"])
        else:
            raise TypeError(f"no binary layout for {kind.__name__}")

    def base(self, code: int, state: dict[str, Any]) -> None:
        pose = state["pose"]
        self.ints += [code, int(state["n_slices"]), int(bool(state["conservative"]))]
        self.ints.append(int(state["evaluations"]))
        self.floats += [pose.x, pose.y, pose.heading, state["slice_dt"], state["horizon_s"]]

    def field_tube(self, frt: FieldTubeSet) -> None:
        state = {k: v for k, v in frt.__getstate__().items() if k not in _CACHES}
        allowed = _FIELD_TUBE_KEYS | set(_GEOMETRY_MEMOS)
        _expect_keys(state, allowed, _FIELD_TUBE_KEYS, "FieldTubeSet")
        self.base(_FIELD_TUBE, state)
        lattice, notch, bound = state["lattice"], state["notch"], state["bound"]
        self.ints += [int(bool(state["notch_possible"])), int(bool(state["instants_uncut"]))]
        self.ints += [int(lattice.nx), int(lattice.ny), *map(int, state["bound_rows"])]
        self.floats += [lattice.x0, lattice.y0, lattice.step]
        self.ints += [len(bound.sweep), len(bound.directions)]
        shapes = _bound_shapes(len(bound.sweep), len(bound.directions))
        for name, shape in zip(_BOUND_FIELDS, shapes, strict=True):
            if getattr(bound, name).shape != shape:
                raise TypeError(
                    f"an outer bound whose {name} has shape {getattr(bound, name).shape}"
                )
        self.array(np.concatenate([np.ravel(getattr(bound, name)) for name in _BOUND_FIELDS]))
        self.array(np.stack([state["coarse"], state["outer_held"]]).astype(bool))
        self.slice_fields(state["instant"])
        self.slice_fields(state["sweep"])
        self.ints.append(int(notch is not None))
        if notch is not None:
            for name in _NOTCH_ARRAYS:
                self.array(getattr(notch, name))
            self.ints.append(int(notch.stage))
            self.floats.append(notch.turn_rad)
        self.frt_set(state["outer"])
        memos = [(code, state[name]) for code, name in enumerate(_GEOMETRY_MEMOS) if name in state]
        self.ints.append(len(memos))
        for code, memo in memos:
            self.ints += [code, -1 if memo.maxsize is None else int(memo.maxsize)]
            self.geometries_by_key(memo.snapshot())

    def slice_fields(self, fields: SliceFields) -> None:
        """The windows' offsets, the fields kept (their count, then slice, rows and columns of
        each; the others were dropped) and their values one after the other."""
        kept = [(j, v) for j, v in enumerate(fields.values) if v is not None]
        dtypes = {v.dtype for _, v in kept}
        if len(dtypes) > 1:
            raise TypeError(f"slice fields of several dtypes: {sorted(map(str, dtypes))}")
        self.array(np.stack([fields.k0, fields.i0]).astype(np.int64))
        self.ints.append(len(kept))
        for j, values in kept:
            self.ints += [j, *values.shape]
        dtype = dtypes.pop() if dtypes else np.dtype(np.float32)
        flat = [np.ravel(v) for _, v in kept]
        self.array(np.concatenate(flat).astype(dtype, copy=False) if flat else np.zeros(0, dtype))

    def finish(self, prefix: bytes = b"") -> bytes:
        """The buffer: the WKB records first, then the sets' ints, floats and arrays."""
        blobs = shapely.to_wkb(np.array(self.geometries, dtype=object))
        ends = np.cumsum([len(b) for b in blobs], dtype=np.int64)
        head = _Writer()
        head.ints.append(len(self.geometries))
        head.array(np.frombuffer(b"".join(blobs), dtype=np.uint8))
        head.array(ends)
        ints = np.array(head.ints + self.ints, dtype="<i8")
        floats = np.array(self.floats, dtype="<f8")
        parts: list[Any] = [struct.pack("<II", len(ints), len(floats)), ints, floats]
        for values in head.arrays + self.arrays:
            parts += [values, bytes(_aligned(values.nbytes) - values.nbytes)]
        crc = 0
        for part in parts:
            crc = zlib.crc32(part, crc)
        return b"".join([prefix, struct.pack("<6sHI", MAGIC, VERSION, crc), *parts])


class _Reader:
    """A buffer checked against its prefix and CRC, read in the order it was written."""

    def __init__(self, data: memoryview) -> None:
        if len(data) < _PREFIX.size:
            raise SetBytesError(f"{len(data)} bytes: shorter than the prefix")
        magic, version, crc, n_ints, n_floats = _PREFIX.unpack_from(data)
        if magic != MAGIC:
            raise SetBytesError("not a set buffer (no FRTSET magic)")
        if version != VERSION:
            raise SetBytesError(f"set buffer version {version}, this reader reads {VERSION}")
        if zlib.crc32(data[_CRC_FROM:]) != crc:
            raise SetBytesError("corrupt or truncated set buffer (CRC-32 mismatch)")
        start = _PREFIX.size + 8 * (n_ints + n_floats)
        if start > len(data):
            raise SetBytesError("truncated set buffer (numbers)")
        self.ints: list[int] = np.frombuffer(data, "<i8", n_ints, _PREFIX.size).tolist()
        self.floats: list[float] = np.frombuffer(
            data, "<f8", n_floats, _PREFIX.size + 8 * n_ints
        ).tolist()
        #: The arrays' bytes, copied once: the arrays read are views of it (owned by the set).
        self.owned = np.frombuffer(data, dtype=np.uint8, offset=start).copy()
        self.i = self.f = self.at = 0
        count = self.natural()
        blob, ends = self.array(np.uint8, 1).tobytes(), self.array(np.int64, 1).tolist()
        if (
            len(ends) != count
            or ends != sorted(ends)
            or ends[-1:] != ([len(blob)] if count else [])
        ):
            raise SetBytesError("WKB records that do not tile their bytes")
        starts = [0, *ends][: len(ends)]
        records = np.array([blob[a:b] for a, b in zip(starts, ends, strict=True)], dtype=object)
        self.geometries = shapely.from_wkb(records) if count else records

    def done(self) -> None:
        """SetBytesError unless every int, float and byte was read."""
        if (self.i, self.f, self.at) != (len(self.ints), len(self.floats), len(self.owned)):
            raise SetBytesError("a set buffer with more in it than its set")

    def take(self, n: int) -> list[int]:
        if n < 0 or self.i + n > len(self.ints):
            raise SetBytesError(f"{n} ints past the buffer's {len(self.ints)}")
        self.i += n
        return self.ints[self.i - n : self.i]

    def natural(self) -> int:
        (value,) = self.take(1)
        if value < 0:
            raise SetBytesError(f"a negative count or index: {value}")
        return value

    def flag(self) -> bool:
        (value,) = self.take(1)
        if value not in (0, 1):
            raise SetBytesError(f"a flag of {value}")
        return value == 1

    def numbers(self, n: int) -> list[float]:
        if self.f + n > len(self.floats):
            raise SetBytesError(f"{n} floats past the buffer's {len(self.floats)}")
        self.f += n
        return self.floats[self.f - n : self.f]

    def array(self, dtype: Any = None, ndim: int | None = None) -> np.ndarray:
        """The next array (a view of the data); its dtype and number of dimensions checked if
        given."""
        i = self.i
        code, n = self.ints[i : i + 2]
        dims = self.ints[i + 2 : i + 2 + n]
        self.i = i + 2 + n
        if n < 0 or len(dims) != n or not 0 <= code < len(_DTYPES) or min(dims, default=0) < 0:
            raise SetBytesError(f"an array of dtype code {code} and shape {dims}")
        kind = _DTYPES[code]
        if (dtype is not None and kind != dtype) or (ndim is not None and n != ndim):
            raise SetBytesError(f"an array of {kind} {dims}, expected {dtype} in {ndim} dimensions")
        start = self.at
        end = start + math.prod(dims) * kind.itemsize
        if end > len(self.owned):
            raise SetBytesError("an array past the end of the buffer")
        raw = self.owned[start:end]
        if code == _BOOL_CODE and bytes(raw).translate(None, b"\x00\x01"):
            raise SetBytesError("a boolean array holds other bytes than 0 and 1")
        self.at = end + (-end % 8)
        return raw.view(kind).reshape(dims)

    def geometries_by_key(self) -> dict[int, BaseGeometry]:
        count = self.natural()
        keys, indices = self.take(count), self.take(count)
        if min(indices, default=0) < 0:
            raise SetBytesError("a negative geometry index")
        return dict(zip(keys, self.geometries[indices].tolist(), strict=True))

    def frt_set(self) -> FRTSet:
        code, n_slices = self.take(2)
        state = self.base(n_slices)
        if code == _FIELD_TUBE:
            return self.field_tube(state)
        if code == _BOX:
            boxes, indices = self.array(np.float64, 2), self.array(np.int64, 2)
            if boxes.shape[1:] != (4,) or indices.shape != (n_slices, 4):
                raise SetBytesError(f"boxes {boxes.shape} and indices {indices.shape}")
            state.update(
                boxes=boxes,
                boxes_until=indices[:, 0],
                slice_boxes=indices[:, 1],
                interval_boxes=indices[:, 2:],
                _unions=self.geometries_by_key(),
            )
            return _built(BoxTubeSet, state)
        if code == _UNION:
            count, clearance_from_tubes = self.natural(), self.flag()
            members = tuple(self.frt_set() for _ in range(count))
            state.update(
                members=members,
                clearance_from_tubes=clearance_from_tubes,
                _tubes=self.geometries_by_key(),
            )
            _check_union(state)
            return _built(UnionSet, state)
        raise SetBytesError(f"no set type {code}")

    def base(self, n_slices: int) -> dict[str, Any]:
        x, y, heading, slice_dt, horizon_s = self.numbers(5)
        if n_slices < 1:
            raise SetBytesError(f"a set of {n_slices} slices")
        return {
            "pose": Pose(x, y, heading),
            "slice_dt": slice_dt,
            "horizon_s": horizon_s,
            "n_slices": n_slices,
            "conservative": self.flag(),
            "evaluations": self.take(1)[0],
            "_world_cache": {},
        }

    def field_tube(self, state: dict[str, Any]) -> FieldTubeSet:
        n = state["n_slices"]
        notch_possible, instants_uncut = self.flag(), self.flag()
        nx, ny = self.natural(), self.natural()
        rows = self.take(n)
        x0, y0, step = self.numbers(3)
        bound = self.outer_bound()
        flags = self.array(bool, 2)
        if flags.shape != (2, n) or min(rows) < 0 or max(rows) >= len(bound.times):
            raise SetBytesError("per-slice flags or rows that do not fit the slices")
        state.update(
            notch_possible=notch_possible,
            instants_uncut=instants_uncut,
            lattice=Lattice(x0, y0, step, nx, ny),
            bound_rows=rows,
            bound=bound,
            coarse=flags[0],
            outer_held=flags[1],
            instant=self.slice_fields(n),
            sweep=self.slice_fields(n),
            notch=self.notch() if self.flag() else None,
            outer=self.frt_set(),
        )
        if state["outer"].n_slices != n:
            raise SetBytesError("a conservative set of other slices")
        for _ in range(self.natural()):
            code, maxsize = self.take(2)
            if not 0 <= code < len(_GEOMETRY_MEMOS) or maxsize < -1 or maxsize == 0:
                raise SetBytesError(f"memo {code} of size {maxsize}")
            values = self.geometries_by_key()
            if 0 < maxsize < len(values):  # as putting them in turn would leave it
                values = dict(list(values.items())[-maxsize:])
            memo = state[_GEOMETRY_MEMOS[code]] = Memo.__new__(Memo)
            memo.__setstate__({"maxsize": None if maxsize < 0 else maxsize, "_values": values})
        frt = FieldTubeSet.__new__(FieldTubeSet)
        frt.__setstate__(state)
        return frt

    def outer_bound(self) -> OuterBound:
        """The outer bound's arrays, views of one float64 array in field order."""
        shapes = _bound_shapes(self.natural(), self.natural())
        flat = self.array(np.float64, 1)
        if len(flat) != sum(math.prod(shape) for shape in shapes):
            raise SetBytesError(f"an outer bound of {len(flat)} numbers")
        parts, at = {}, 0
        for name, shape in zip(_BOUND_FIELDS, shapes, strict=True):
            size = math.prod(shape)
            parts[name] = flat[at : at + size].reshape(shape)
            at += size
        return _built(OuterBound, parts)  # type: ignore[no-any-return]

    def notch(self) -> NotchCut:
        arrays = {name: self.array() for name in _NOTCH_ARRAYS}
        (turn_rad,) = self.numbers(1)
        return NotchCut(**arrays, turn_rad=turn_rad, stage=self.natural())

    def slice_fields(self, count: int) -> SliceFields:
        offsets = self.array(np.int64, 2)
        values: list[np.ndarray | None] = [None] * count
        shapes = [self.take(3) for _ in range(self.natural())]
        data, used = self.array(None, 1), 0
        for j, rows, cols in shapes:
            if not 0 <= j < count or values[j] is not None or rows < 0 or cols < 0:
                raise SetBytesError(f"slice field {j} of {count}, {rows} x {cols}")
            values[j] = data[used : used + rows * cols].reshape(rows, cols)
            used += rows * cols
        if used != len(data) or offsets.shape != (2, count):
            raise SetBytesError("slice fields that do not tile their data")
        return SliceFields(offsets[0], offsets[1], tuple(values))


def _bound_shapes(n: int, m: int) -> tuple[tuple[int, ...], ...]:
    """The shapes of an outer bound's arrays in ``OuterBound``'s field order (times, box_at,
    sweep, radius, heading, speed, directions, sweep_support, support_at, sweep_speed_max) for
    ``n`` sweeps and ``m`` support directions."""
    vectors = ((n + 1,), (n + 1, 4), (n, 4), (n + 1,), (n + 1, 2), (n + 1, 2), (m,))
    return (*vectors, (n, m), (n + 1, m), (n,))


def _check_union(state: dict[str, Any]) -> None:
    same = (state["pose"], state["slice_dt"], state["horizon_s"], state["n_slices"])
    members = state["members"]
    if not members or any((m.pose, m.slice_dt, m.horizon_s, m.n_slices) != same for m in members):
        raise SetBytesError("a union without members, or of unlike members")


def _built(kind: type, state: dict[str, Any]) -> Any:
    """An object of ``kind`` whose attributes are ``state``, as unpickling builds it."""
    obj = kind.__new__(kind)
    obj.__dict__.update(state)
    return obj


def _expect_keys(state: dict[str, Any], allowed: Any, required: Any, kind: str) -> None:
    """TypeError if ``state`` has an attribute not ``allowed`` or lacks a ``required`` one: a
    new attribute needs a place in this layout."""
    unknown, missing = set(state) - set(allowed), set(required) - set(state)
    if unknown or missing:
        raise TypeError(
            f"{kind} has no binary layout for {sorted(unknown)} (missing {sorted(missing)})"
        )


def _aligned(n: int) -> int:
    return (n + 7) // 8 * 8
