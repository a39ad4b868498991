"""Where the time of one training step goes, and what a whole training costs, per network.

For each network with the params' batch size and the real windows, one step is taken apart
by timing growing pieces of it in bare PyTorch, then the same step inside Lightning's
Trainer, as the training stage runs it (in-memory tensor batches, MLflow off):

- data: cutting one shuffled batch out of the in-memory tensors;
- forward: the GRU layers and the dense head (forward pass and MSE loss);
- backward: autograd through them;
- optimiser: Adam's update;
- Lightning: the rest of a Trainer step (hooks, closure, loss bookkeeping, and the epoch's
  validation pass spread over its steps), the Trainer's time per step less the bare step.

It then prints the epochs the committed run trained (`reports/models/<network>.json`) and
what they cost at the measured speed. Needs `dvc repro windows` first.

    python benchmarks/bench_training.py [--steps 200] [--params params.yaml] [--windows data/windows]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import time
from pathlib import Path

import torch

from pipeline.learning.networks import build_network
from pipeline.learning.training import network_config, train, training_config, training_pairs
from pipeline.settings import load_params


def per_step(step: callable, steps: int) -> float:
    """Milliseconds per call of `step`, after a few warm-up calls."""
    for index in range(5):
        step(index)
    start = time.perf_counter()
    for index in range(steps):
        step(index)
    return 1000 * (time.perf_counter() - start) / steps


def bare_steps(kind: str, inputs: torch.Tensor, targets: torch.Tensor, batch: int, rate: float, steps: int,
               config) -> dict[str, float]:
    """Cumulative ms per step: data; + forward; + backward; + optimiser."""
    network = build_network(config)
    optimiser = torch.optim.Adam(network.parameters(), lr=rate)
    generator = torch.Generator().manual_seed(0)
    order = [torch.randperm(len(inputs), generator=generator)[:batch] for _ in range(steps + 5)]
    loss = torch.nn.MSELoss()

    def data(i: int) -> tuple:
        return inputs[order[i]], targets[order[i]]

    def forward(i: int) -> torch.Tensor:
        x, y = data(i)
        return loss(network(x), y)

    def backward(i: int) -> None:
        optimiser.zero_grad()
        forward(i).backward()

    def full(i: int) -> None:
        backward(i)
        optimiser.step()

    return {name: per_step(step, steps) for name, step in
            (("data", data), ("forward", forward), ("backward", backward), ("optimiser", full))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=200, help="steps timed per piece (default: %(default)s)")
    parser.add_argument("--params", default="params.yaml")
    parser.add_argument("--windows", default="data/windows")
    parser.add_argument("--reports", default="reports", help="where the committed run's metrics are")
    args = parser.parse_args()
    logging.getLogger("lightning").setLevel(logging.ERROR)
    logging.getLogger("lightning.pytorch").setLevel(logging.ERROR)
    params = load_params(args.params)
    print("ms per step | data | forward | backward | optimiser | Lightning and validation | whole step | per epoch | "
          "epochs trained | training")
    total = 0.0
    for kind in ("filter", "predictor", "autoencoder"):
        inputs, targets = training_pairs(kind, Path(args.windows) / f"{kind}.parquet", params)
        schedule = training_config(kind, params)
        torch.set_num_threads(schedule.threads)
        config = network_config(kind, params)
        bare = bare_steps(kind, torch.as_tensor(inputs, dtype=torch.float32),
                          torch.as_tensor(targets, dtype=torch.float32), schedule.batch_size,
                          schedule.learning_rate, args.steps, config)
        steps_per_epoch = -(-int(round(len(inputs) * (1 - schedule.validation_fraction))) // schedule.batch_size)
        epochs = max(2, -(-args.steps // steps_per_epoch))
        start = time.perf_counter()
        train(config, inputs, targets, dataclasses.replace(schedule, epochs=epochs, early_stopping_patience=0,
                                                           lr_decay_patience=0))
        per_epoch = (time.perf_counter() - start) / epochs
        whole = 1000 * per_epoch / steps_per_epoch
        metrics = Path(args.reports) / "models" / f"{kind}.json"
        trained = json.loads(metrics.read_text())["epochs_trained"] if metrics.is_file() else schedule.epochs
        total += trained * per_epoch
        print(f"{kind} (batch {schedule.batch_size}, {steps_per_epoch} steps/epoch) | {bare['data']:.2f} | "
              f"{bare['forward'] - bare['data']:.2f} | {bare['backward'] - bare['forward']:.2f} | "
              f"{bare['optimiser'] - bare['backward']:.2f} | {whole - bare['optimiser']:.2f} | {whole:.2f} | "
              f"{per_epoch:.2f} s | {trained} | {trained * per_epoch:.0f} s", flush=True)
    print(f"all three: {total / 60:.1f} min of training at these speeds (validation included)")


if __name__ == "__main__":
    main()
