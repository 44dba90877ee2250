"""The analytic test model obeys the model contract and computes the value it documents."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from models.runtime import ModelCard, ValueModel
from reach.contract import COL, COLUMNS
from tests.fixtures.analytic_model import NAME, RANGES, disc, reference_value


def test_the_graph_computes_the_documented_value(analytic_model_path: Path) -> None:
    model = ValueModel.load(analytic_model_path)
    assert model.card.name == NAME and model.card.semantics == "set" and model.card.delta == 0.0
    rng = np.random.default_rng(0)
    lo = np.array([RANGES[c][0] for c in COLUMNS])
    hi = np.array([RANGES[c][1] for c in COLUMNS])
    x = rng.uniform(lo, hi, size=(512, len(COLUMNS)))
    assert np.allclose(model.evaluate(x), reference_value(x), atol=1e-3)


def test_the_zero_level_set_is_the_documented_disc(analytic_model_path: Path) -> None:
    model = ValueModel.load(analytic_model_path)
    bounds = {c: 0.0 for c in COLUMNS[6:]} | {"u1_max_start": 0.4, "u2_max_start": 1.0}
    cx, cy, radius = disc(2.0, 5.0, bounds)
    x = np.zeros((2, len(COLUMNS)))
    x[:, COL["t"]], x[:, COL["v_start"]] = 2.0, 5.0
    for name, value in bounds.items():
        x[:, COL[name]] = value
    x[0, COL["px"]], x[0, COL["py"]] = cx, cy  # centre: -radius
    x[1, COL["px"]], x[1, COL["py"]] = cx + radius, cy  # boundary: 0
    assert np.allclose(model.evaluate(x), [-radius, 0.0], atol=1e-5)


def test_the_card_is_complete(analytic_model_path: Path) -> None:
    raw = json.loads(analytic_model_path.with_suffix(".json").read_text())
    card = ModelCard.from_json(raw)
    assert set(card.ranges) == set(COLUMNS) and card.horizon_s == 3.0
    assert len(raw["sha256"]) == 64
