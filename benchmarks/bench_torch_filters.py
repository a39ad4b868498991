"""Speed of the torch Kalman core (`pipeline.filters.torch_filters`) against the NumPy core (`pipeline.filters.batch_filters`).

Each filter runs over B synthetic tracks of T plots (straight flights, a plot about every 6 s with
the time quantised to 10 ms as a radar's are, 50/50/30 m noise), batched (B = 256) and single
(B = 1): the NumPy core's `filter_sequences`, the torch `filter_sequences` forward only (no graph),
and the torch forward and backward of a loss on the positions w.r.t. per-step Q and R scales, as
training runs it (truncated every --detach steps). Printed per filter and batch size: steps per
second (columns of the batch, each B tracks) and track-steps per second (B x steps), best of
--repeat. Singer has no NumPy twin in `filter_sequences` (n/a). Then the network-scaled filter
(`pipeline.learning.kalman_net`, Singer base, a GRU cell or an MLP of 16 units): forward, and forward and
backward of the mean position error w.r.t. its weights; against singer's rows, the network's cost.

    python benchmarks/bench_torch_filters.py [--steps 200] [--repeat 3] [--threads 1] [--detach 20]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import torch

from pipeline.filters import batch_filters, torch_filters
from pipeline.filters.classical_filters import FilterSettings
from pipeline.filters.torch_filters import FilterSpec, Scales, SequenceBatch
from pipeline.learning.kalman_net import CELLS, KalmanNet, KalmanNetConfig

KINDS = ("cv", "ca", "imm", "singer")
BATCHES = (256, 1)
NOISE_STD = np.array([50.0, 50.0, 30.0])  # plot noise, m


def classical(kind: str) -> FilterSettings:
    noise = {"cv": (5.0,), "ca": (2.0,), "imm": (1.0, 3.0)}[kind]
    return FilterSettings(kind, noise, 300.0, 20.0, switch_probability=0.05, initial_cv_probability=0.9)


def spec(kind: str) -> FilterSpec:
    if kind == "singer":
        return FilterSpec("singer", (4.0,), 300.0, 20.0, manoeuvre_time_s=20.0)
    return FilterSpec.from_settings(classical(kind))


def tracks(rows: int, steps: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    """times (B, T) s, positions (B, T, 3) m, covariances (B, T, 3, 3) m^2, valid and restart (B, T)."""
    rng = np.random.default_rng(seed)
    times = np.round(np.cumsum(rng.uniform(5.5, 6.5, (rows, steps)), axis=1), 2)
    velocity = rng.uniform(-250.0, 250.0, (rows, 1, 3)) * [1.0, 1.0, 0.05]
    positions = rng.uniform(-1e5, 1e5, (rows, 1, 3)) + velocity * times[..., None]
    positions += rng.normal(size=positions.shape) * NOISE_STD
    covariances = np.broadcast_to(np.diag(NOISE_STD ** 2), (rows, steps, 3, 3)).copy()
    restart = np.zeros((rows, steps), bool)
    restart[:, 0] = True
    return times, positions, covariances, np.ones((rows, steps), bool), restart


def best_seconds(run: Callable[[], object], repeat: int) -> float:
    run()  # warm-up
    seconds = []
    for _ in range(repeat):
        began = time.perf_counter()
        run()
        seconds.append(time.perf_counter() - began)
    return min(seconds)


def numpy_filter(kind: str, arrays: tuple[np.ndarray, ...]) -> Callable[[], object] | None:
    if kind == "singer":
        return None
    return lambda: batch_filters.filter_sequences(classical(kind), *arrays)


def torch_forward(kind: str, rows: tuple[torch.Tensor, ...]) -> Callable[[], object]:
    def run() -> None:
        with torch.no_grad():
            torch_filters.filter_sequences(spec(kind), *rows)
    return run


def torch_training_step(kind: str, rows: tuple[torch.Tensor, ...], detach_every: int) -> Callable[[], object]:
    """Forward and backward of the mean position error w.r.t. per-step Q and R scales."""
    def run() -> None:
        log_q = torch.zeros(rows[0].shape, dtype=torch.float64, requires_grad=True)
        log_r = torch.zeros(rows[0].shape, dtype=torch.float64, requires_grad=True)
        filtered = torch_filters.filter_sequences(spec(kind), *rows, scales=Scales(q=log_q.exp(), r=log_r.exp()),
                                                  detach_every=detach_every)
        filtered.position.nan_to_num().norm(dim=-1).mean().backward()
    return run


def network_scaled(kind: str) -> KalmanNet:
    """The network-scaled filter on the singer base (default params' sizes), untrained: its cost per step
    does not depend on the weights."""
    return KalmanNet(KalmanNetConfig("singer", kind, 16, 4.0, 20.0, 300.0, 20.0, 1.0, 100.0, 4.0, 10.0, 400.0, 10.0))


def network_forward(model: KalmanNet, batch: SequenceBatch) -> Callable[[], object]:
    def run() -> None:
        with torch.no_grad():
            model(batch)
    return run


def network_training_step(model: KalmanNet, batch: SequenceBatch, detach_every: int) -> Callable[[], object]:
    """Forward and backward of the mean position error w.r.t. the network's weights."""
    def run() -> None:
        model.zero_grad()
        batch.position_error(model(batch, detach_every)).backward()
    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    parser.add_argument("--detach", type=int, default=20, help="truncation length of the training step")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"{args.steps} steps, best of {args.repeat}, torch {torch.__version__} on {args.threads} thread(s), float64")
    print("filter  B    method                   steps/s   track-steps/s")
    for kind in KINDS:
        for batch in BATCHES:
            arrays = tracks(batch, args.steps)
            rows = tuple(torch.as_tensor(array) for array in arrays)
            runs = {"numpy filter_sequences": numpy_filter(kind, arrays),
                    "torch forward": torch_forward(kind, rows),
                    "torch forward+backward": torch_training_step(kind, rows, args.detach)}
            for method, run in runs.items():
                if run is None:
                    print(f"{kind:7s} {batch:<4d} {method:24s} {'n/a':>8s}")
                    continue
                rate = args.steps / best_seconds(run, args.repeat)
                print(f"{kind:7s} {batch:<4d} {method:24s} {rate:8.0f} {rate * batch:15.0f}")
    for cell in CELLS:
        for batch in BATCHES:
            times, positions, covariances, valid, restart = (torch.as_tensor(a) for a in tracks(batch, args.steps))
            rows = SequenceBatch(times, positions, covariances, positions, valid, restart, valid)
            model = network_scaled(cell)
            for method, run in (("torch forward", network_forward(model, rows)),
                                ("torch forward+backward", network_training_step(model, rows, args.detach))):
                rate = args.steps / best_seconds(run, args.repeat)
                print(f"{'net-' + cell:7s} {batch:<4d} {method:24s} {rate:8.0f} {rate * batch:15.0f}")


if __name__ == "__main__":
    main()
