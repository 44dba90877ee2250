"""Smoke-sized training run: losses finite, checkpoint/resume, ONNX export that follows the contract."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from models.export import export_run, parity  # noqa: E402
from models.network import ValueNetwork  # noqa: E402
from models.runtime import ValueModel  # noqa: E402
from models.train import TrainConfig, train  # noqa: E402
from reach.contract import COL, COLUMNS, N_INPUTS  # noqa: E402
from reach.dynamics import initial_set_value  # noqa: E402

SMOKE = Path(__file__).resolve().parent.parent / "models" / "configs" / "smoke.json"


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[TrainConfig, Path]:
    config = TrainConfig.load(SMOKE)
    out = tmp_path_factory.mktemp("smoke")
    train(config, out)
    return config, out


def test_losses_are_logged_and_finite(smoke_run: tuple[TrainConfig, Path]) -> None:
    config, out = smoke_run
    rows = list(csv.DictReader((out / "log.csv").open()))
    assert int(rows[-1]["step"]) == config.steps
    assert all(np.isfinite(float(r["total"])) for r in rows)
    assert json.loads((out / "train_meta.json").read_text())["steps_done"] == config.steps


def test_resume_continues_from_the_checkpoint(smoke_run, tmp_path: Path) -> None:
    config, _ = smoke_run
    short = dataclasses.replace(config, steps=20, checkpoint_every=10)
    train(short, tmp_path)
    longer = dataclasses.replace(config, steps=30, checkpoint_every=10)
    train(longer, tmp_path)
    state = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert state["step"] == 30
    steps = [int(r["step"]) for r in csv.DictReader((tmp_path / "log.csv").open())]
    assert steps == sorted(steps) and steps[-1] == 30


def test_the_corridor_hinge_raises_the_value_where_it_is_bounded(smoke_run, tmp_path: Path) -> None:
    """The hinge is relu(bound - V) on states with a proven lower bound on V; a step on it alone
    lifts V there. A run started from the smoke run's checkpoint with it configured logs it."""
    config, out = smoke_run
    from models.bounded_states import sample_bounded_states
    from models.loss import LossWeights, training_losses

    x, bound = sample_bounded_states(8, 32, np.random.default_rng(1))
    inputs, lower = torch.as_tensor(x, dtype=torch.float32), torch.as_tensor(bound).float()
    net = ValueNetwork(config.network_config())
    net.load_state_dict(torch.load(out / "checkpoint.pt", weights_only=True)["model"])
    weights = LossWeights(pde=0.0, upper=0.0, lower=0.0, corridor=1.0)
    losses = training_losses(net, inputs[:4], torch.zeros(1), weights, (inputs, lower))
    assert torch.isfinite(losses["total"])
    with torch.no_grad():
        before = net(inputs)[:, 0]
    assert losses["corridor"].item() == pytest.approx(float(torch.relu(lower - before).mean()))
    losses["total"].backward()
    with torch.no_grad():
        for p in net.parameters():
            p -= 1e-3 * p.grad
        after = net(inputs)[:, 0]
    violated = lower > before
    assert violated.any() and float((after - before)[violated].mean()) > 0

    data = tmp_path / "bounds.npz"
    np.savez(data, x=x.astype(np.float32), lower_bound=bound.astype(np.float32))
    tuned = dataclasses.replace(
        config,
        steps=config.steps + 10,
        init_checkpoint=str(out / "checkpoint.pt"),
        corridor_data=str(data),
        corridor_per_step=64,
        weights={**config.weights, "corridor": 1.0},
    )
    train(tuned, tmp_path / "tuned")
    rows = list(csv.DictReader((tmp_path / "tuned" / "log.csv").open()))
    assert int(rows[0]["step"]) > config.steps and float(rows[0]["corridor"]) > 0


def test_boundary_condition_is_exact_at_t0(smoke_run) -> None:
    config, out = smoke_run
    net = ValueNetwork(config.network_config())
    net.load_state_dict(torch.load(out / f"{config.name}.pt", weights_only=True))
    rng = np.random.default_rng(3)
    x = rng.uniform(-1, 1, (500, N_INPUTS)).astype(np.float32)
    x[:, COL["t"]] = 0.0
    x[:, COL["speed"]] = rng.uniform(0, 20, 500)
    x[:, COL["v_start"]] = rng.uniform(0, 20, 500)
    with torch.no_grad():
        v = net(torch.as_tensor(x)).numpy()[:, 0]
    expected = initial_set_value(
        x[:, COL["px"]],
        x[:, COL["py"]],
        x[:, COL["heading"]],
        x[:, COL["speed"]],
        x[:, COL["v_start"]],
    )
    np.testing.assert_allclose(v, expected, atol=1e-4)


def test_export_follows_the_model_contract(smoke_run) -> None:
    config, out = smoke_run
    onnx_path = export_run(out, config)
    card = json.loads(onnx_path.with_suffix(".json").read_text())
    assert card["semantics"] == "set"
    assert list(card["ranges"]) == list(COLUMNS)
    assert card["parity_max_abs_diff"] <= 1e-4
    model = ValueModel.load(onnx_path)
    x = np.zeros((7, N_INPUTS), dtype=np.float32)
    assert model.evaluate(x).shape == (7,)
    net = ValueNetwork(config.network_config())
    net.load_state_dict(torch.load(out / f"{config.name}.pt", weights_only=True))
    assert parity(net, onnx_path, n=2000) <= 1e-4
