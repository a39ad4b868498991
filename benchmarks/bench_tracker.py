"""Tracker speed: plots per second per association method on the default test data.

Runs the tracking loop (no metrics, no I/O) over the test scenarios for each method, on one
core, and prints plots per second of wall time and of this process's CPU time (on a machine
shared with other work, the CPU figure is the steadier one). Needs the trained models
(`dvc repro`) for the neural methods, the tuned filters for the classical ones.

    python benchmarks/bench_tracker.py [--scenarios 10] [--window 4000] [--methods via imm ...]
                                       [--models models]
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from pipeline.bench.evaluation import read_scenarios
from pipeline.settings import load_params
from pipeline.tracker import registry
from pipeline.tracker.loading import load_models
from pipeline.tracker.run import track


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params", default="params.yaml")
    parser.add_argument("--scenarios", type=int, default=10, help="test scenarios to track per method")
    parser.add_argument("--window", type=float, default=4000.0)
    parser.add_argument("--methods", nargs="+", default=list(registry.TRACKERS), help="default: every tracker")
    parser.add_argument("--models", default="models", help="folder of the trained networks and tuned filters")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    params = load_params(args.params)
    scenarios = read_scenarios(params, Path("data/simulated"), Path("data/routes"))[:args.scenarios]
    models = load_models(Path(args.models), params, list(args.methods))
    count = sum(len(s.plots) for s in scenarios)
    for method in args.methods:
        start, cpu = time.perf_counter(), time.process_time()
        for scenario in scenarios:
            track(scenario.plots, registry.compose(method, models, params.tracker, args.window,
                                                   [params.tracker.seed, scenario.scenario_id]))
        elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
        print(f"{method:9s} {count} plots in {elapsed:.1f} s: {count / elapsed:,.0f} plots/s "
              f"({count / cpu:,.0f} per CPU second)")


if __name__ == "__main__":
    main()
