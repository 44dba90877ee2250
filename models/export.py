"""Export a trained value network to ONNX and write its model card.

``python -m models.export --run runs/frt_unicycle --out models/`` (also called at the end of training).
The graph takes the 14 physical columns of the contract; all normalisation lives inside it.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import torch

from models.network import NetworkConfig, ValueNetwork, asinh_by_logs
from models.sampling import sample_parameters, set_state
from reach.contract import (
    COLUMNS,
    HORIZON_S,
    INITIAL_SET,
    INPUT_NAME,
    OUTPUT_NAME,
    U1_LIMIT,
    U2_LIMIT,
    V_START_MAX,
)

OPSET = 17
POSITION_LIMIT = INITIAL_SET.radius_m + (V_START_MAX + INITIAL_SET.speed_margin_mps) * HORIZON_S
POSITION_LIMIT += 0.5 * U2_LIMIT * HORIZON_S**2
SPEED_LIMIT = V_START_MAX + INITIAL_SET.speed_margin_mps + U2_LIMIT * HORIZON_S


def trained_ranges() -> dict[str, list[float]]:
    """Input ranges of the contract columns; the state domain contains every reachable state."""
    ranges: dict[str, list[float]] = {
        "t": [0.0, HORIZON_S],
        "px": [-math.ceil(POSITION_LIMIT), math.ceil(POSITION_LIMIT)],
        "py": [-math.ceil(POSITION_LIMIT), math.ceil(POSITION_LIMIT)],
        "heading": [-math.pi, math.pi],
        "speed": [0.0, math.ceil(SPEED_LIMIT)],
        "v_start": [0.0, V_START_MAX],
    }
    for name in COLUMNS[6:]:
        limit = U1_LIMIT if name.startswith("u1") else U2_LIMIT
        ranges[name] = [-limit, limit]
    return ranges


def random_inputs(n: int, seed: int) -> np.ndarray:
    """In-range inputs: random parameters, times and states inside the trained domain."""
    rng = np.random.default_rng(seed)
    params = sample_parameters(n, rng)
    state = (
        rng.uniform(-40, 80, n),
        rng.uniform(-60, 60, n),
        rng.uniform(-math.pi, math.pi, n),
        rng.uniform(0, 45, n),
    )
    return set_state(params, rng.uniform(0, HORIZON_S, n), state).astype(np.float32)


class Float64Graph(torch.nn.Module):
    """The exported function: float32 in and out, float64 inside.

    Values reach ~150 m far from the set, where float32 rounding alone differs between runtimes by
    ~1e-4; computing in float64 makes onnxruntime and torch agree to float32 output rounding.
    """

    def __init__(self, net: ValueNetwork) -> None:
        super().__init__()
        self.net = copy.deepcopy(net).double().eval()
        self.net.asinh = asinh_by_logs

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x.double()).float()


class Float32Graph(torch.nn.Module):
    """The same function in float32, which onnxruntime evaluates faster than the contract graph.

    The service evaluates this one on its grids (models/<name>.fast.onnx); the card records its
    measured difference from the contract graph, which calibration absorbs.
    """

    def __init__(self, net: ValueNetwork) -> None:
        super().__init__()
        self.net = copy.deepcopy(net).float().eval()
        self.net.asinh = asinh_by_logs

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


def export_onnx(net: ValueNetwork, path: Path, precision: str = "float64") -> None:
    graph = Float64Graph(net) if precision == "float64" else Float32Graph(net)
    example = torch.as_tensor(random_inputs(8, 0))
    torch.onnx.export(
        graph,
        (example,),
        str(path),
        input_names=[INPUT_NAME],
        output_names=[OUTPUT_NAME],
        dynamic_axes={INPUT_NAME: {0: "N"}, OUTPUT_NAME: {0: "N"}},
        opset_version=OPSET,
        dynamo=False,
    )
    model = onnx.load(str(path))
    onnx.checker.check_model(model, full_check=True)


def parity(net: ValueNetwork, path: Path, n: int = 20000, seed: int = 1) -> float:
    """max |V_onnxruntime - V_torch| on random in-range inputs."""
    import onnxruntime as ort

    x = random_inputs(n, seed)
    with torch.no_grad():
        expected = Float64Graph(net)(torch.as_tensor(x)).numpy()[:, 0]
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = session.run([OUTPUT_NAME], {INPUT_NAME: x})[0][:, 0]
    return float(np.max(np.abs(got - expected)))


def graph_difference(a: Path, b: Path, n: int = 20000, seed: int = 2) -> float:
    """max |V_a - V_b| between two ONNX graphs on random in-range inputs (onnxruntime)."""
    import onnxruntime as ort

    x = random_inputs(n, seed)
    values = [
        ort.InferenceSession(str(p), providers=["CPUExecutionProvider"]).run(
            [OUTPUT_NAME], {INPUT_NAME: x}
        )[0][:, 0]
        for p in (a, b)
    ]
    return float(np.max(np.abs(values[0] - values[1])))


def base_card(name: str, network: NetworkConfig, meta: dict[str, Any]) -> dict[str, Any]:
    return {
        "name": name,
        "semantics": "set",
        "calibration": {"delta": 0.0, "method": "none yet: run models.evaluate --write-card"},
        "horizon_s": HORIZON_S,
        "initial_set": INITIAL_SET.as_dict(),
        "hard_limits": {"u1": U1_LIMIT, "u2": U2_LIMIT},
        "ranges": trained_ranges(),
        "input": {"name": INPUT_NAME, "columns": list(COLUMNS), "dtype": "float32"},
        "output": {"name": OUTPUT_NAME, "units": "m", "meaning": "value <= delta: reachable"},
        "architecture": {
            "kind": "MLP on nominal-frame features, exact boundary condition",
            "formula": "V = l_nominal(t, x) + (t / T) * S(t) * MLP(features(x))",
            "activation": "SiLU",
            **network.as_dict(),
        },
        "training": meta,
        "opset": OPSET,
    }


def export_run(run: Path, config: Any, out_dir: Path | None = None) -> Path:
    """Export ``run/<name>.pt`` to ``out_dir/<name>.onnx`` and write the base card."""
    from models.export_card import file_sha256, write_card

    out_dir = Path(out_dir or run)
    out_dir.mkdir(parents=True, exist_ok=True)
    network = config.network_config()
    net = ValueNetwork(network)
    net.load_state_dict(torch.load(run / f"{config.name}.pt", weights_only=True))
    onnx_path = out_dir / f"{config.name}.onnx"
    export_onnx(net, onnx_path)
    err = parity(net, onnx_path)
    fast_path = out_dir / f"{config.name}.fast.onnx"
    export_onnx(net, fast_path, precision="float32")
    fast_err = graph_difference(onnx_path, fast_path)
    meta = json.loads((run / "train_meta.json").read_text())
    card = base_card(config.name, network, meta)
    card["parity_max_abs_diff"] = err
    card["runtime_graph"] = {
        "file": fast_path.name,
        "sha256": file_sha256(fast_path),
        "precision": "float32",
        "max_abs_diff_vs_contract_graph": fast_err,
    }
    existing = onnx_path.with_suffix(".json")
    if existing.exists():  # keep calibration and accuracy measured before, if any
        old = json.loads(existing.read_text())
        for key in ("calibration", "accuracy", "comparison"):
            if key in old:
                card[key] = old[key]
    write_card(card, onnx_path)
    print(f"exported {onnx_path} (parity max |dV| = {err:.2e})")
    return onnx_path


def main() -> None:
    from models.train import TrainConfig

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--run", type=Path, required=True)
    parser.add_argument("--config", type=Path, default=Path("models/configs/full.json"))
    parser.add_argument("--out", type=Path, default=Path("models"))
    args = parser.parse_args()
    export_run(args.run, TrainConfig.load(args.config), args.out)


if __name__ == "__main__":
    main()
