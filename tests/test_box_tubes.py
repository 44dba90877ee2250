"""The conservative sets of many settings at once (``reach.box_tubes``, ``reach.union``): each
setting's set bit for bit the one the engine builds for it alone."""

from __future__ import annotations

import numpy as np

from reach.box_tubes import box_tubes
from reach.engine import FRTEngine
from reach.frames import Pose
from reach.outer_bound import outer_bound, outer_boxes
from reach.sets import BoxTubeSet
from reach.union import UnionSet, conservative_sets


def _settings(n: int, seed: int) -> tuple[list[Pose], np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    lo = np.column_stack(
        [
            rng.uniform(-2, 0.3, n),
            rng.uniform(-10, 1, n),
            rng.uniform(-2, 0.3, n),
            rng.uniform(-10, 1, n),
        ]
    )
    hi = lo + rng.uniform(0, 1.5, (n, 4)) * np.array([1, 6, 1, 6])
    bounds = np.concatenate([lo, np.minimum(hi, [2, 10, 2, 10])], axis=1)
    bounds[::5] = 0.0  # held controls: zero-width bounds
    poses = [Pose(*rng.uniform(-50, 50, 2), rng.uniform(-3, 3)) for _ in range(n)]
    return poses, rng.uniform(0, 20, n), bounds


def _same(a: BoxTubeSet, b: BoxTubeSet) -> bool:
    return (
        a.pose == b.pose
        and (a.slice_dt, a.horizon_s, a.n_slices) == (b.slice_dt, b.horizon_s, b.n_slices)
        and all(
            np.array_equal(getattr(a, f), getattr(b, f))
            for f in ("boxes", "boxes_until", "slice_boxes", "interval_boxes")
        )
    )


def test_outer_boxes_are_each_settings_sweeps_bit_for_bit() -> None:
    _, v, bounds = _settings(40, 1)
    together = outer_boxes(v, bounds, 3.0, 120, 8)
    for i in range(len(v)):
        alone = outer_bound(v[i], bounds[i], 3.0, 120, 8, support_directions=0).sweep
        assert np.array_equal(together[i], alone)
        assert np.array_equal(outer_boxes(v[i : i + 1], bounds[i : i + 1], 3.0, 120, 8)[0], alone)


def test_box_tubes_are_each_outer_bounds_windows_bit_for_bit() -> None:
    """Each setting's box tube, built with the others, is its own outer bound's sweeps merged
    four at a time, tube j holding the boxes up to s_j + slice_dt / 2; the engine's conservative
    set is the same."""
    engine = FRTEngine()
    poses, v, bounds = _settings(30, 2)
    k, n = engine.outer_steps_per_slice, engine.outer_steps
    upto = [-(-min(j * k + (k + 1) // 2, n) // 4) for j in range(engine.n_slices)]
    for got, i in zip(box_tubes(engine, poses, v, bounds), range(len(v)), strict=True):
        sweep = outer_bound(v[i], bounds[i], engine.horizon, n, 8, support_directions=0).sweep
        windows = sweep.reshape(-1, 4, 4)  # 120 sweeps: 30 windows of 4
        boxes = np.stack(
            [
                windows[:, :, 0].min(axis=1),
                windows[:, :, 1].max(axis=1),
                windows[:, :, 2].min(axis=1),
                windows[:, :, 3].max(axis=1),
            ],
            axis=1,
        )
        assert np.array_equal(got.boxes, boxes) and got.pose == poses[i]
        assert got.boxes_until.tolist() == upto
        assert _same(got, engine.conservative(poses[i], v[i], bounds[i]))


def test_conservative_sets_of_single_and_multi_modal_settings() -> None:
    engine = FRTEngine()
    poses, v, bounds = _settings(12, 3)
    rows = [bounds[0], bounds[1:4], bounds[4], bounds[5:7], bounds[7]]  # one, three, one, two, one
    sets = conservative_sets(engine, poses[:5], v[:5], rows)
    for frt, pose, speed, b in zip(sets, poses[:5], v[:5], rows, strict=True):
        if b.ndim == 1:
            assert isinstance(frt, BoxTubeSet) and _same(frt, engine.conservative(pose, speed, b))
        else:
            assert isinstance(frt, UnionSet) and len(frt.members) == len(b)
            for member, row in zip(frt.members, b, strict=True):
                assert _same(member, engine.conservative(pose, speed, row))  # type: ignore[arg-type]


def test_the_compiled_sweeps_are_the_array_propagations_bit_for_bit() -> None:
    """``reach.sweep_boxes`` does step by step what ``_propagate`` does on arrays: each sweep's
    box is the fine points' boxes over its substeps and its end point."""
    from reach.contract import INITIAL_SET
    from reach.outer_bound import _propagate

    _, v, bounds = _settings(25, 4)
    v[3] = 0.0  # a parked car
    bounds[7] = [-2.0, -10.0, -2.0, -10.0, 2.0, 10.0, 2.0, 10.0]  # the widest
    steps, substeps = 120, 8
    p = _propagate(v, bounds, 3.0, steps * substeps, INITIAL_SET)
    idx = np.arange(1, steps + 1) * substeps

    def window(values: np.ndarray, reduce: np.ufunc) -> np.ndarray:
        inner = reduce.reduce(values[:, :-1].reshape(len(values), steps, substeps), axis=2)
        return reduce(inner, values[:, idx])

    sides = (p.x[0], np.minimum), (p.x[1], np.maximum), (p.y[0], np.minimum), (p.y[1], np.maximum)
    reference = np.stack([window(values, reduce) for values, reduce in sides], axis=2)
    assert np.array_equal(outer_boxes(v, bounds, 3.0, steps, substeps), reference)


def test_a_settings_rows_swept_in_parts_are_the_rows_swept_together() -> None:
    """``SettingRows.sweeps`` of slices of the rows (a frame's rows split between threads,
    ``service.runtime.conservative``) put together are the sweeps of all of them, bit for bit."""
    from reach.union import SettingRows

    engine = FRTEngine()
    poses, v, bounds = _settings(23, 5)
    rows = SettingRows.of(poses[:9], v[:9], [bounds[:3], *bounds[3:11]])
    whole = rows.sweeps(engine)
    parts = [rows.sweeps(engine, part) for part in (slice(0, 6), slice(6, 7), slice(7, None))]
    assert len(whole) == 11 and np.array_equal(np.concatenate(parts), whole)
