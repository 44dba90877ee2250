"""Plot the training losses of a run: ``python scripts/plot_training.py runs/frt_unicycle/log.csv``."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("log", type=Path)
    parser.add_argument("--out", type=Path, default=Path("docs/training_loss.png"))
    args = parser.parse_args()
    rows = list(csv.DictReader(args.log.open()))
    step = [int(r["step"]) for r in rows]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for ax, key, title in zip(
        axes,
        ("pde", "upper", "lower"),
        (
            "HJB PDE residual (mean square)",
            "rollout upper-bound hinge",
            "heading lower-bound hinge",
        ),
        strict=True,
    ):
        ax.semilogy(step, [max(float(r[key]), 1e-8) for r in rows], lw=0.6)
        ax.set_title(title)
        ax.set_xlabel("step")
        ax.grid(alpha=0.3)
    ax2 = axes[0].twinx()
    ax2.plot(step, [float(r["t_max"]) for r in rows], color="grey", ls="--", lw=0.8)
    ax2.set_ylabel("curriculum horizon [s]")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
