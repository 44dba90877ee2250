"""The value network as a plug-in: the engine builds sets from the certified geometry alone or cut
by a value field, and the service evaluates the network only where its card says it cuts."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from models.runtime import ValueModel
from models.value_fields import (
    ProjectionField,
    card_says_network_cuts,
    engine_for,
    network_decision,
)
from reach.frames import Pose
from reach.value_field import ValueField
from service.api.app import create_app
from service.runtime.settings import Settings
from tests.conftest import READY_TIMEOUT_S

ROOT = Path(__file__).resolve().parent.parent
MODEL = ROOT / "models" / "frt_unicycle.onnx"

#: (v_start, bounds in contract order): straight, turning, and one that may turn round.
SETTINGS = [
    (5.0, [-0.1, -1.0, -0.1, -1.0, 0.1, 1.0, 0.1, 1.0]),
    (8.0, [0.2, -3.0, 0.1, -2.0, 0.6, 2.0, 0.5, 1.0]),
    (3.0, [-1.2, -2.0, -1.2, -2.0, 1.2, 2.0, 1.2, 2.0]),
]


@pytest.fixture(scope="module")
def shipped() -> ValueModel:
    return ValueModel.load(MODEL)


def test_the_onnx_fields_are_value_fields(shipped: ValueModel) -> None:
    assert isinstance(ProjectionField(shipped), ValueField)


def test_the_shipped_card_says_the_network_cuts_nothing(shipped: ValueModel) -> None:
    assert card_says_network_cuts(shipped.card) is False
    assert network_decision(shipped.card, "auto")[0] is False
    assert network_decision(shipped.card, "on")[0] is True
    assert network_decision(shipped.card, "off")[0] is False


@pytest.mark.parametrize(("v_start", "bounds"), SETTINGS)
def test_the_shipped_network_changes_no_tube(
    shipped: ValueModel, v_start: float, bounds: list[float]
) -> None:
    """What the card claims, on settings of its own: the tubes with and without the network have
    the same area and each holds the other (so skipping it serves the same sets)."""
    b = np.array(bounds)
    with_net = engine_for(shipped).exact(Pose(0.0, 0.0, 0.0), v_start, b)
    without = engine_for(shipped, network=False).exact(Pose(0.0, 0.0, 0.0), v_start, b)
    assert with_net.evaluations > 0 and without.evaluations == 0
    for j in (10, 20, without.n_slices - 1):
        a, c = with_net.tube(j), without.tube(j)
        assert a.symmetric_difference(c).area <= 1e-9 * max(c.area, 1.0), j


def test_a_field_that_cuts_makes_the_set_smaller(analytic_model_path: Path) -> None:
    """The analytic disc model cuts inside the outer bound; without it the set is the geometry."""
    model = ValueModel.load(analytic_model_path)
    assert card_says_network_cuts(model.card) is None
    assert network_decision(model.card, "auto")[0] is True
    b = np.array(SETTINGS[1][1])
    cut = engine_for(model).exact(Pose(0.0, 0.0, 0.0), 8.0, b).tube(30)
    bare = engine_for(model, network=False).exact(Pose(0.0, 0.0, 0.0), 8.0, b).tube(30)
    assert cut.area < 0.9 * bare.area
    assert cut.difference(bare).area <= 1e-6 * bare.area  # the cut stays inside the geometry


def _active(network: str) -> dict:
    settings = Settings(model_path=MODEL, frt_executor="thread", network=network)
    with TestClient(create_app(settings)) as client:
        deadline = time.monotonic() + READY_TIMEOUT_S
        while client.get("/readyz").status_code != 200:
            assert time.monotonic() < deadline, client.get("/readyz").json()
            time.sleep(0.05)
        ready = client.get("/readyz").json()["active"]
        card = client.get("/v1/model").json()["active"]
        assert ready == card
        return card


def test_the_service_says_which_parts_build_its_sets() -> None:
    auto = _active("auto")
    assert auto["value_network"]["loaded"] is True
    assert auto["value_network"]["active"] is False
    assert "cuts nothing" in auto["value_network"]["reason"]
    assert auto["geometry"][0] == "outer_bound"
    assert _active("on")["value_network"]["active"] is True


def test_default_model_path_is_the_shipped_model() -> None:
    """A server started without FRT_MODEL_PATH serves the model shipped in models/."""
    from service.runtime.settings import DEFAULT_MODEL

    shipped = Path(__file__).resolve().parents[1] / "models" / "frt_unicycle.onnx"
    assert shipped == DEFAULT_MODEL
    assert DEFAULT_MODEL.is_file()
