"""Train the value network: ``python -m models.train --config models/configs/full.json``.

Seeded, checkpointed every ``checkpoint_every`` steps (``<out>/checkpoint.pt``, resumed
automatically), logged to ``<out>/log.csv`` with a progress bar. At the end it writes
``<out>/<name>.pt`` (weights only); ``models.pipeline`` trains and exports in one command.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from models.loss import LossWeights, training_losses
from models.network import NetworkConfig, ValueNetwork
from models.sampling import sample_training_batch
from reach.contract import HORIZON_S


@dataclass
class TrainConfig:
    name: str = "frt_unicycle"
    seed: int = 0
    width: int = 256
    depth: int = 3
    steps: int = 24000
    params_per_batch: int = 256
    points_per_param: int = 16
    lr: float = 1e-3
    lr_final: float = 2e-5
    curriculum_fraction: float = 0.3
    checkpoint_every: int = 500
    weights: dict = field(default_factory=dict)
    #: A run's checkpoint to start from (weights, optimiser and step), when the run has none.
    init_checkpoint: str | None = None
    #: .npz of states with proven lower bounds on V (``python -m models.bounded_states``) for the
    #: corridor hinge (weight ``weights["corridor"]``), and how many of them per step.
    corridor_data: str | None = None
    corridor_per_step: int = 2048
    #: Share of training rollouts under the evaluation's Pontryagin-shaped schedules (0: the
    #: original switching/straight/random mix; see ``sample_training_batch``).
    extremal_share: float = 0.0
    #: Share of training parameter settings near the corners of the ranges (0: none; see
    #: ``sample_corner_parameters``).
    corner_share: float = 0.0
    #: Share of training parameter settings whose acceleration bound turns from braking to
    #: accelerating (0: none; see ``sample_restart_parameters``).
    restart_share: float = 0.0

    @classmethod
    def load(cls, path: Path) -> TrainConfig:
        return cls(**json.loads(Path(path).read_text()))

    def network_config(self) -> NetworkConfig:
        return NetworkConfig(width=self.width, depth=self.depth)

    def loss_weights(self) -> LossWeights:
        return LossWeights(**self.weights)


def horizon_at(step: int, config: TrainConfig) -> float:
    """Time curriculum: the sampled horizon grows from 0.2 T to T over the first fraction of steps."""
    if config.curriculum_fraction <= 0:
        return HORIZON_S
    progress = min(1.0, step / (config.curriculum_fraction * config.steps))
    return HORIZON_S * (0.2 + 0.8 * progress)


def learning_rate(step: int, config: TrainConfig) -> float:
    """Cosine decay from lr to lr_final."""
    progress = min(1.0, step / max(config.steps, 1))
    return config.lr_final + 0.5 * (config.lr - config.lr_final) * (
        1 + math.cos(math.pi * progress)
    )


def train(config: TrainConfig, out: Path, max_minutes: float | None = None) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(config.seed)
    net = ValueNetwork(config.network_config())
    optimiser = torch.optim.Adam(net.parameters(), lr=config.lr)
    rng = np.random.default_rng(config.seed)
    step, elapsed_before = 0, 0.0
    checkpoint = out / "checkpoint.pt"
    if not checkpoint.exists() and config.init_checkpoint:
        shutil.copyfile(config.init_checkpoint, checkpoint)
    if checkpoint.exists():
        state = torch.load(checkpoint, weights_only=True)
        net.load_state_dict(state["model"])
        optimiser.load_state_dict(state["optimiser"])
        step = int(state["step"])
        elapsed_before = float(state["elapsed_s"])
        rng = np.random.default_rng([config.seed, step])
        print(f"resumed from {checkpoint} at step {step}")
    weights = config.loss_weights()
    bounded_data = None
    if config.corridor_data and weights.corridor > 0:
        with np.load(config.corridor_data) as data:  # arrays only: no pickles
            bounded_data = (
                torch.as_tensor(data["x"], dtype=torch.float32),
                torch.as_tensor(data["lower_bound"], dtype=torch.float32),
            )
    log_path = out / "log.csv"
    new_log = not log_path.exists() or step == 0
    if not new_log:  # drop rows logged after the checkpoint we resume from
        lines = log_path.read_text().splitlines(keepends=True)
        kept = [ln for ln in lines[1:] if int(ln.split(",", 1)[0]) <= step]
        log_path.write_text(lines[0] + "".join(kept))
    log_file = log_path.open("w" if new_log else "a", newline="")
    log = csv.writer(log_file)
    if new_log:
        log.writerow(
            ["step", "elapsed_s", "lr", "t_max", "total", "pde", "upper", "lower", "corridor"]
        )

    def save() -> None:
        tmp = out / "checkpoint.tmp"
        torch.save(
            {
                "model": net.state_dict(),
                "optimiser": optimiser.state_dict(),
                "step": step,
                "elapsed_s": elapsed_before + time.monotonic() - started,
            },
            tmp,
        )
        tmp.replace(checkpoint)

    started = time.monotonic()
    bar = tqdm(total=config.steps, initial=step, desc="train", unit="step", mininterval=5)
    while step < config.steps:
        t_max = horizon_at(step, config)
        for group in optimiser.param_groups:
            group["lr"] = learning_rate(step, config)
        batch = sample_training_batch(
            config.params_per_batch,
            config.points_per_param,
            t_max,
            rng,
            extremal_share=config.extremal_share,
            corner_share=config.corner_share,
            restart_share=config.restart_share,
        )
        bounded = None
        if bounded_data is not None:
            pick = torch.as_tensor(rng.integers(0, len(bounded_data[1]), config.corridor_per_step))
            bounded = (bounded_data[0][pick], bounded_data[1][pick])
        losses = training_losses(
            net,
            torch.as_tensor(batch.pde_points, dtype=torch.float32),
            torch.as_tensor(batch.rollout_upper_bound, dtype=torch.float32),
            weights,
            bounded,
        )
        optimiser.zero_grad(set_to_none=True)
        losses["total"].backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        optimiser.step()
        step += 1
        bar.update(1)
        if step % 20 == 0 or step == config.steps:
            values = {k: float(v.detach()) for k, v in losses.items()}
            bar.set_postfix({k: f"{v:.3g}" for k, v in values.items()})
            elapsed = elapsed_before + time.monotonic() - started
            log.writerow(
                [step, f"{elapsed:.1f}", f"{learning_rate(step, config):.3g}", f"{t_max:.2f}"]
                + [f"{values[k]:.5g}" for k in ("total", "pde", "upper", "lower", "corridor")]
            )
            log_file.flush()
        if step % config.checkpoint_every == 0 or step == config.steps:
            save()
        if max_minutes is not None and time.monotonic() - started > 60 * max_minutes:
            save()
            print(f"stopped after {max_minutes} min at step {step}; run again to resume")
            break
    bar.close()
    log_file.close()
    weights_path = out / f"{config.name}.pt"
    torch.save(net.state_dict(), weights_path)
    meta = {
        "config": config.__dict__,
        "network": config.network_config().as_dict(),
        "steps_done": step,
        "train_time_s": elapsed_before + time.monotonic() - started,
    }
    (out / "train_meta.json").write_text(json.dumps(meta, indent=2))
    return weights_path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--config", type=Path, required=True)
    parser.add_argument("--out", type=Path, default=None, help="run folder (default runs/<name>)")
    parser.add_argument("--max-minutes", type=float, default=None)
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    config = TrainConfig.load(args.config)
    out = args.out or Path("runs") / config.name
    train(config, out, args.max_minutes)


if __name__ == "__main__":
    main()
