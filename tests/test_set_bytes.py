"""Sets as bytes (``reach.set_bytes``) and the worker pool that sends them so.

A set read back from its bytes must answer as the set sent: the same clearances (whole tube and
time-indexed), tubes, intervals, slices and contours, from the same arrays; a buffer that is not
one the writer wrote (truncated, a byte changed, another version, a forged header) is refused
with ``SetBytesError`` and nothing else.
"""

from __future__ import annotations

import pickle
import struct
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import shapely

from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.engine import FRTEngine
from reach.field_tube import FieldTubeSet
from reach.frames import Pose
from reach.set_bytes import SetBytesError, set_from_bytes, set_to_bytes
from reach.sets import BoxTubeSet, FRTSet
from reach.union import UnionSet, exact_union
from service.runtime.exact_worker import decode_result, encode_result
from service.runtime.pipe_pool import PipePool

MODEL = Path(__file__).resolve().parent.parent / "models" / "frt_unicycle.onnx"
pytestmark = pytest.mark.skipif(not MODEL.exists(), reason="no shipped model yet")

MOVING = np.array([-0.15, -1.5, -0.15, -1.5, 0.15, 1.5, 0.15, 1.5])
WIDE = np.array([-1.2, -6.0, -1.2, -6.0, 1.2, 6.0, 1.2, 6.0])
POSE = Pose(3.0, -2.0, 0.7)


@pytest.fixture(scope="module")
def sets() -> dict[str, FRTSet]:
    """Each kind of set a worker sends: held by its polygons (no fields), with the tubes checks
    asked for, cut by the network (fields kept), cut by the notch, a union of modes, a box set."""
    model = ValueModel.load(MODEL)
    served, network = engine_for(model, network=False), engine_for(model, network=True)
    return {
        "held": served.exact(POSE, 8.0, MOVING),
        "held_with_tubes": served.exact(POSE, 8.0, MOVING, tubes_upto=21),
        "network": network.exact(POSE, 8.0, MOVING, tubes_upto=5),
        "notch": served.exact(POSE, 8.0, WIDE, notch_cut=True, notch_stage=1),
        "union": exact_union(served, POSE, 8.0, np.stack([MOVING, MOVING * 3.0])),
        "boxes": served.conservative(POSE, 8.0, MOVING),
    }


def _arrays(obj: Any, prefix: str = "") -> dict[str, np.ndarray]:
    """Every numpy array an object holds (attributes, dataclass fields, tuples), by path."""
    out: dict[str, np.ndarray] = {}
    if isinstance(obj, np.ndarray):
        out[prefix] = obj
    elif isinstance(obj, tuple | list):
        for i, item in enumerate(obj):
            out.update(_arrays(item, f"{prefix}[{i}]"))
    elif hasattr(obj, "__dict__") and not isinstance(obj, shapely.Geometry | type):
        for name, value in vars(obj).items():
            if not name.startswith("_") or name in ("_unions",):
                out.update(_arrays(value, f"{prefix}.{name}"))
    return out


def _same_answers(got: FRTSet, want: FRTSet) -> None:
    """Clearances, tubes, intervals, slices and contours of ``got`` equal ``want``'s."""
    rng = np.random.default_rng(0)
    points = rng.uniform(-30.0, 40.0, (300, 2)) + np.array([POSE.x, POSE.y])
    times = rng.uniform(0.0, 3.0, 300)
    np.testing.assert_array_equal(got.clearance(points), want.clearance(points))
    np.testing.assert_array_equal(got.clearance(points, times), want.clearance(points, times))
    for j in range(want.n_slices):
        for kind in ("tube", "interval", "slice"):
            mine, theirs = getattr(got, kind)(j), getattr(want, kind)(j)
            assert shapely.equals_exact(mine, theirs, 0.0), (kind, j)
    for t in (None, 0.45, 1.0, 2.5):
        kind = "tube" if t is None else "slice"
        assert got.geojson(kind, t, 1.5) == want.geojson(kind, t, 1.5)


@pytest.mark.parametrize("name", ["held", "held_with_tubes", "network", "notch", "union", "boxes"])
def test_a_set_read_back_answers_as_the_set_sent(sets: dict[str, FRTSet], name: str) -> None:
    frt = sets[name]
    data = set_to_bytes(frt)
    received = set_from_bytes(data)
    assert type(received) is type(frt)
    # The same arrays, bit for bit, where the set sent keeps them (its __getstate__).
    state = pickle.loads(pickle.dumps(frt, protocol=4))
    sent, got = _arrays(state), _arrays(received)
    assert sent.keys() == got.keys()
    for path, values in sent.items():
        assert got[path].dtype == values.dtype and got[path].shape == values.shape, path
        assert got[path].tobytes() == values.tobytes(), path
    if isinstance(frt, FieldTubeSet):
        assert isinstance(received, FieldTubeSet)
        for memo in ("_tubes", "_slices", "_intervals", "_hulls"):
            want = getattr(frt, memo).snapshot()
            mine = getattr(received, memo).snapshot()
            assert list(mine) == list(want)
            assert all(shapely.equals_exact(mine[k], want[k], 0.0) for k in want)
    # Answers as the pickled set does (both draw what was not sent the same way).
    _same_answers(received, state)
    _same_answers(set_from_bytes(set_to_bytes(received)), state)


def test_the_bytes_are_no_larger_than_the_pickle(sets: dict[str, FRTSet]) -> None:
    for name, frt in sets.items():
        assert len(set_to_bytes(frt)) <= 1.02 * len(pickle.dumps(frt, protocol=4)), name


def _with_crc(data: bytearray) -> bytes:
    """``data`` with its CRC-32 made right again (a forged buffer)."""
    struct.pack_into("<I", data, 8, zlib.crc32(memoryview(data)[12:]))
    return bytes(data)


def test_a_truncated_or_corrupt_buffer_is_refused(sets: dict[str, FRTSet]) -> None:
    data = set_to_bytes(sets["held_with_tubes"])
    rng = np.random.default_rng(4)
    cuts = [0, 1, 5, 12, 16, 20, 100, len(data) // 2, len(data) - 8, len(data) - 1]
    for cut in [*cuts, *rng.integers(0, len(data), 30)]:
        with pytest.raises(SetBytesError):
            set_from_bytes(data[:cut])
    for at in rng.integers(0, len(data), 60):
        changed = bytearray(data)
        changed[at] ^= 1 << int(rng.integers(0, 8))
        with pytest.raises(SetBytesError):
            set_from_bytes(bytes(changed))
    with pytest.raises(SetBytesError):
        set_from_bytes(data + b"\x00" * 8)
    with pytest.raises(SetBytesError):
        set_from_bytes(pickle.dumps(sets["held"], protocol=4))
    other_version = bytearray(data)
    struct.pack_into("<H", other_version, 6, 99)
    with pytest.raises(SetBytesError, match="version"):
        set_from_bytes(_with_crc(other_version))


def test_a_forged_buffer_with_a_right_crc_is_refused(sets: dict[str, FRTSet]) -> None:
    """Every int of the header changed in turn (and the CRC made right): refused, or read as a
    set (some ints are free values, a key or a count of evaluations); never another error."""
    data = set_to_bytes(sets["held_with_tubes"])
    n_ints = struct.unpack_from("<I", data, 12)[0]
    refused = 0
    for i in range(n_ints):
        for value in (-1, 10**6, 3):
            forged = bytearray(data)
            struct.pack_into("<q", forged, 20 + 8 * i, value)
            try:
                set_from_bytes(_with_crc(forged))
            except SetBytesError:
                refused += 1
    assert refused > n_ints


def test_a_set_with_an_attribute_the_layout_lacks_is_not_written(
    sets: dict[str, FRTSet],
) -> None:
    frt = pickle.loads(pickle.dumps(sets["held"], protocol=4))
    frt.something_new = np.zeros(3)
    with pytest.raises(TypeError, match="something_new"):
        set_to_bytes(frt)

    class Other(FRTSet):
        pass

    with pytest.raises(TypeError):
        set_to_bytes(Other(POSE, 0.1, 3.0, 31, conservative=False))


def _warm() -> None:
    pass


def _computed_set(v_start: float) -> tuple[FRTSet, float]:
    """A set as a worker returns it to the scheduler: (set, seconds)."""
    start = time.perf_counter()
    frt = FRTEngine().exact(POSE, v_start, MOVING, tubes_upto=4)
    return frt, time.perf_counter() - start


def _box_set() -> BoxTubeSet:
    return FRTEngine().conservative(POSE, 5.0, MOVING)


def _not_a_set() -> dict[str, int]:
    return {"a": 1}


class _OtherSet(BoxTubeSet):
    """A set type the layout does not hold."""


def _other_set() -> BoxTubeSet:
    frt = _box_set()
    other = _OtherSet.__new__(_OtherSet)
    other.__dict__.update(vars(frt))
    return other


def _garbled(value: Any) -> bytes:
    return b"S" + b"not a set"


def test_the_pool_sends_sets_as_bytes_and_the_rest_pickled() -> None:
    decoded: list[int] = []

    def counting_decode(data: memoryview) -> Any:
        decoded.append(len(data))
        return decode_result(data)

    pool = PipePool(1, _warm, (), timeout_s=60.0, encode=encode_result, decode=counting_decode)
    try:
        frt, seconds = pool.submit(_computed_set, 8.0).result(timeout=60)
        assert isinstance(frt, FieldTubeSet) and isinstance(seconds, float)
        reference = FRTEngine().exact(POSE, 8.0, MOVING, tubes_upto=4)
        _same_answers(frt, pickle.loads(pickle.dumps(reference, protocol=4)))
        assert isinstance(pool.submit(_box_set).result(timeout=60), BoxTubeSet)
        assert len(decoded) == 2
        assert pool.submit(_not_a_set).result(timeout=60) == {"a": 1}  # pickled
        assert isinstance(pool.submit(_other_set).result(timeout=60), _OtherSet)  # pickled
        assert len(decoded) == 2
    finally:
        pool.shutdown()


def test_a_result_that_does_not_decode_fails_its_future_only() -> None:
    pool = PipePool(1, _warm, (), timeout_s=60.0, encode=_garbled, decode=decode_result)
    try:
        with pytest.raises(SetBytesError):
            pool.submit(_box_set).result(timeout=60)
        with pytest.raises(SetBytesError):  # the pool still serves
            pool.submit(_box_set).result(timeout=60)
    finally:
        pool.shutdown()


def test_a_union_is_read_back_as_a_union_of_its_members(sets: dict[str, FRTSet]) -> None:
    union = set_from_bytes(set_to_bytes(sets["union"]))
    assert isinstance(union, UnionSet) and len(union.members) == 2
    assert all(isinstance(m, FieldTubeSet) for m in union.members)
