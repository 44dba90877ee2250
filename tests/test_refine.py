"""Coarse-to-fine evaluation of the projection: the set it gives contains the full evaluation's,
and equals it when the network cuts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from models.eval_settings import SETTINGS
from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.frames import Pose
from reach.refine import coarse_nodes, coarse_to_fine, dilate

MODEL = Path(__file__).resolve().parent.parent / "models" / "frt_unicycle.onnx"


def _field_evaluator(field: np.ndarray, calls: list[int]):
    def evaluate(mask: np.ndarray) -> np.ndarray:
        calls.append(int(mask.sum()))
        return field[mask]

    return evaluate


def test_nodes_far_below_the_level_are_skipped_and_the_rest_are_exact() -> None:
    """W a cone whose level set crosses the window: every node it cuts and every node near the
    crossing is evaluated, only nodes below the level are skipped, and every evaluated value is
    the function's own."""
    ys, xs = np.mgrid[0:40, 0:50].astype(float)
    cone = np.hypot(xs - 25, ys - 20) * 0.5  # W rises 0.5 per metre (step 1 m)
    field = np.stack([cone, cone + 3.0])
    levels = np.array([8.0, 8.0])  # crossing at radius 16 m (instant 0) and 10 m (instant 1)
    inside = np.ones_like(field, dtype=bool)
    calls: list[int] = []
    out = coarse_to_fine(
        inside, np.array([0, 1]), np.array([0, 0]), 1.0, levels, _field_evaluator(field, calls)
    )
    values = out.values.reshape(field.shape)
    evaluated = np.isfinite(values)
    assert np.array_equal(values[evaluated], field[evaluated])
    cut = field > levels[:, None, None]
    assert evaluated[cut].all(), "a node the network cuts was skipped"
    near = np.abs(field - levels[:, None, None]) < 0.5
    assert evaluated[near].all()
    skipped = ~evaluated
    assert skipped.any()
    assert (field < levels[:, None, None])[skipped].all()
    assert out.evaluated == sum(calls)


def test_an_unevaluated_rim_is_evaluated() -> None:
    """Nodes with no evaluated coarse neighbour (here: odd rows and columns only) are evaluated."""
    field = np.full((1, 6, 6), -50.0)
    inside = np.zeros_like(field, dtype=bool)
    inside[0, 1, 1] = True  # odd row and column: not a coarse node
    out = coarse_to_fine(
        inside, np.array([0]), np.array([0]), 1.0, np.array([0.0]), _field_evaluator(field, [])
    )
    assert out.values.tolist() == [-50.0]


def test_coarse_nodes_follow_the_absolute_lattice_parity() -> None:
    inside = np.ones((2, 3, 3), dtype=bool)
    coarse = coarse_nodes(inside, np.array([0, 1]), np.array([0, 1]))
    assert coarse[0].tolist() == [[True, False, True], [False, False, False], [True, False, True]]
    assert coarse[1].tolist() == [
        [False, False, False],
        [False, True, False],
        [False, False, False],
    ]


def test_dilate_grows_by_a_square() -> None:
    mask = np.zeros((1, 5, 5), dtype=bool)
    mask[0, 2, 2] = True
    assert dilate(mask, 1)[0].sum() == 9
    assert dilate(mask, 2)[0].all()
    rng = np.random.default_rng(0)
    scattered = rng.uniform(size=(3, 20, 17)) < 0.05
    for radius in (1, 2, 3):
        padded = np.pad(scattered, ((0, 0), (radius, radius), (radius, radius)))
        square = np.zeros_like(scattered)
        for dk in range(2 * radius + 1):
            for di in range(2 * radius + 1):
                square |= padded[:, dk : dk + 20, di : di + 17]
        np.testing.assert_array_equal(dilate(scattered, radius), square)


@pytest.mark.skipif(not MODEL.exists(), reason="no shipped model yet")
@pytest.mark.parametrize("level_per_scale", [None, -0.05])
def test_refined_tubes_equal_the_full_evaluation(level_per_scale: float | None) -> None:
    """The shipped network at its calibrated level (where it cuts nothing inside the outer
    polygons), and at a negative level where it cuts large parts of them: the coarse-to-fine
    tubes equal the full evaluation's on several settings, never with more network evaluations (at the
    calibrated level, fewer than half)."""
    model = ValueModel.load(MODEL)
    full, refined = engine_for(model, refine=False), engine_for(model, refine=True)
    if level_per_scale is not None:
        for engine in (full, refined):
            engine.value_field.level_per_scale = level_per_scale
    pose = Pose(3.0, -2.0, 0.7)
    cut_somewhere = False
    for setting in (SETTINGS[3], SETTINGS[5], SETTINGS[12], SETTINGS[15], SETTINGS[18]):
        a = full.exact(pose, setting.v_start, setting.bounds())
        b = refined.exact(pose, setting.v_start, setting.bounds())
        assert b.evaluations <= a.evaluations
        if level_per_scale is None:
            assert b.evaluations < 0.5 * a.evaluations
        for j in (5, 15, 30):
            tube_a, tube_b = a.tube(j), b.tube(j)
            assert tube_a.difference(tube_b).area < 1e-6, (setting.name, j)
            assert tube_b.difference(tube_a).area < 1e-6, (setting.name, j)
            cut_somewhere |= tube_a.area < a.outer_tube(j).area - 1.0
    assert cut_somewhere or level_per_scale is None
