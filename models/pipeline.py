"""``python -m models.pipeline --config C [--out RUN]``: train the value network, then export it to
ONNX with its card (``models.train`` -> ``models.export``; neither imports the other)."""

from __future__ import annotations

import argparse
from pathlib import Path

from models.export import export_run
from models.train import TrainConfig, train


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--config", type=Path, required=True)
    parser.add_argument("--out", type=Path, default=None, help="run folder (default runs/<name>)")
    parser.add_argument("--max-minutes", type=float, default=None)
    args = parser.parse_args()
    config = TrainConfig.load(args.config)
    out = args.out or Path("runs") / config.name
    train(config, out, args.max_minutes)
    export_run(out, config)


if __name__ == "__main__":
    main()
