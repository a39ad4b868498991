"""The cost of the LSTM update's Monte-Carlo dropout (issue 18): plots per second against the copies.

Each track runs as 1 + `mc_samples` copies in one batch (`pipeline.learning.lstm_update`), so the copies
are what the covariance costs. For each number of copies the trained estimator (its weights and
calibration, only `lstm_update.mc_samples` changed) is timed two ways, on one core:
- tracker: the tracking loop (no metrics, no I/O) over the first test scenarios, every plot
  (clutter included) counted, beside the tuned IMM tracker on the same plots;
- estimator: the hold-out windows (`filter_holdout.window_batch`, every window in one batch),
  target plots filtered per second.
Wall time and this process's CPU time (on a machine shared with other work, the CPU figure is
the steadier one). Needs `dvc repro train_lstm_update` (and `tune_kalman` for the IMM).

    python benchmarks/bench_lstm_update.py [--samples 1 8 32] [--scenarios 10] [--window 4000]
"""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import replace
from pathlib import Path

import torch

from pipeline import io
from pipeline.bench.evaluation import read_scenarios
from pipeline.learning import filter_holdout, materials, model_eval
from pipeline.learning.lstm_update import LSTMUpdate
from pipeline.settings import load_params
from pipeline.tracker import registry
from pipeline.tracker.loading import load_models
from pipeline.tracker.run import track


def with_samples(model: LSTMUpdate, samples: int) -> LSTMUpdate:
    """The trained estimator with `samples` MC-dropout copies (weights and calibration kept)."""
    changed = LSTMUpdate(replace(model.config, mc_samples=samples))
    changed.load_state_dict(model.state_dict())
    return changed.eval()


def timed(work) -> tuple[float, float]:
    """Wall and CPU seconds of `work()`."""
    start, cpu = time.perf_counter(), time.process_time()
    work()
    return time.perf_counter() - start, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params", default="params.yaml")
    parser.add_argument("--samples", type=int, nargs="+", default=[1, 8, 32], help="MC-dropout copies per track")
    parser.add_argument("--scenarios", type=int, default=10, help="test scenarios to track")
    parser.add_argument("--window", type=float, default=4000.0)
    parser.add_argument("--models", default="models")
    parser.add_argument("--windows", default="data/windows", help="the windows stage's folder (the hold-out)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    params = load_params(args.params)
    scenarios = read_scenarios(params, Path("data/simulated"), Path("data/routes"))[:args.scenarios]
    models = load_models(Path(args.models), params, ["imm", "lstm_update"])
    torch.set_num_threads(1)
    plots = sum(len(s.plots) for s in scenarios)
    holdout = model_eval.holdout_plots(io.read_parquet(Path(args.windows) / "holdout.parquet",
                                                       materials.HOLDOUT_SCHEMA), params.radar)
    windows = filter_holdout.window_batch(holdout, params.radar, params.windows.filter_length)
    window_plots = int(windows.valid.sum())

    def tracked(method: str, chosen) -> tuple[float, float]:
        return timed(lambda: [track(s.plots, registry.compose(method, chosen, params.tracker, args.window,
                                                              [params.tracker.seed, s.scenario_id]))
                              for s in scenarios])

    elapsed, cpu = tracked("imm", models)
    print(f"tracker   imm              {plots} plots: {plots / elapsed:9,.0f} plots/s ({plots / cpu:,.0f} per CPU s)")
    for samples in args.samples:
        estimator = with_samples(models["lstm_update"], samples)
        elapsed, cpu = tracked("lstm_update", replace(models, lstm_update=estimator))
        print(f"tracker   lstm_update  N={samples:<3d} {plots} plots: {plots / elapsed:9,.0f} plots/s "
              f"({plots / cpu:,.0f} per CPU s)")
        with torch.no_grad():
            elapsed, cpu = timed(lambda: estimator(windows))
        print(f"estimator lstm_update  N={samples:<3d} {window_plots} plots: {window_plots / elapsed:9,.0f} plots/s "
              f"({window_plots / cpu:,.0f} per CPU s)")


if __name__ == "__main__":
    main()
