"""Training speed of the three networks with the default params and the real windows.

Times a few epochs of each network exactly as the training stage runs them (Lightning
Trainer, in-memory tensor batches, MLflow off) and projects the time of the full
training from the epochs in params.yaml. Needs `dvc repro windows` first.

    python benchmarks/bench_training.py [--epochs 3] [--params params.yaml] [--windows data/windows]
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import time
from pathlib import Path

from pipeline.params import load_params
from pipeline.train_stage import network_config, training_config, training_pairs
from pipeline.training import train


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--epochs", type=int, default=3, help="epochs to time per network")
    parser.add_argument("--params", default="params.yaml")
    parser.add_argument("--windows", default="data/windows")
    args = parser.parse_args()
    logging.getLogger("lightning").setLevel(logging.ERROR)
    logging.getLogger("lightning.pytorch").setLevel(logging.ERROR)
    params = load_params(args.params)
    total = 0.0
    for kind in ("filter", "predictor", "autoencoder"):
        inputs, targets = training_pairs(kind, Path(args.windows) / f"{kind}.parquet", params)
        config = training_config(kind, params)
        start = time.perf_counter()
        train(network_config(kind, params), inputs, targets, dataclasses.replace(config, epochs=args.epochs))
        per_epoch = (time.perf_counter() - start) / args.epochs
        projected = per_epoch * config.epochs
        total += projected
        steps = -(-int(len(inputs) * (1 - config.validation_fraction)) // config.batch_size)
        print(f"{kind:12s} {len(inputs):6d} windows, batch {config.batch_size}: {per_epoch:.2f} s/epoch "
              f"({1000 * per_epoch / steps:.2f} ms/step), {config.epochs} epochs -> {projected / 60:.1f} min")
    print(f"all three: {total / 60:.1f} min projected (goal: under 12 min on 2 cores)")


if __name__ == "__main__":
    main()
