"""Time of the `tune_kalman` stage with the default params, and of one cost evaluation of each filter.

One cost evaluation is what Nelder-Mead repeats: each filter run over all the training routes'
target plots (`tuning.assess`, best of --repeat). With --stage the whole stage also runs as the
pipeline runs it (`python -m pipeline tune-kalman`, a fresh process, its MLflow run in a
temporary store) with each number of worker processes given (best of --repeat each).

    python benchmarks/bench_tuning.py [--params params.yaml] [--repeat 3] [--stage 1 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from pipeline import io
from pipeline.filters import tuning
from pipeline.filters.classical_filters import KINDS
from pipeline.params import load_params_tree
from pipeline.settings import load_params
from pipeline.simulation import simulate
from pipeline.stages.tune_stage import start_settings


def evaluation_seconds(params_path: str, repeat: int) -> dict[str, float]:
    """Best wall seconds of one cost evaluation of each filter kind at its start values."""
    params = load_params(params_path)
    plots = io.read_parquet(Path("data/simulated") / params.kalman.split / "plots.parquet", simulate.PLOT_SCHEMA)
    gating = params.tracker.association
    material = tuning.target_sequences(plots, params.radar, params.kalman.restart_gap_s, params.kalman.burn_in_updates,
                                       gating.kalman_gate_probability, gating.young_track_plots)
    best = {}
    for kind in KINDS:
        times = []
        for _ in range(repeat):
            began = time.perf_counter()
            tuning.assess(start_settings(kind, params), material)
            times.append(time.perf_counter() - began)
        best[kind] = min(times)
    return best


def stage_seconds(params_path: str, workers: int, folder: Path) -> tuple[float, dict]:
    """Wall seconds of the stage in a fresh process with compute.workers = `workers`, and its report."""
    tree = load_params_tree(params_path)
    tree["compute"]["workers"] = workers
    params = folder / f"params-{workers}.yaml"
    params.write_text(yaml.safe_dump(tree))
    command = [sys.executable, "-m", "pipeline", "-q", "tune-kalman", "--params", str(params), "--simulated",
               "data/simulated", "--models", str(folder / "models"), "--reports", str(folder / "reports")]
    environment = {**os.environ, "MLFLOW_TRACKING_URI": f"sqlite:///{folder / 'mlflow.db'}"}
    began = time.perf_counter()
    subprocess.run(command, check=True, env=environment, stdout=subprocess.DEVNULL)
    return time.perf_counter() - began, json.loads((folder / "reports" / "kalman_tuning.json").read_text())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params", default="params.yaml")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--stage", type=int, nargs="*", default=[], metavar="WORKERS",
                        help="also time the whole stage with these numbers of worker processes")
    args = parser.parse_args()
    for kind, seconds in evaluation_seconds(args.params, args.repeat).items():
        print(f"{kind}: one cost evaluation, best of {args.repeat}: {seconds:.3f} s")
    with tempfile.TemporaryDirectory() as folder:
        for workers in args.stage:
            runs = [stage_seconds(args.params, workers, Path(folder)) for _ in range(args.repeat)]
            filters = runs[0][1]["filters"]
            per_filter = ", ".join(f"{kind} {filters[kind]['cost_evaluations']} evaluations "
                                   f"{filters[kind]['seconds']:.1f} s" for kind in KINDS)
            best = min(seconds for seconds, _ in runs)
            print(f"tune_kalman, {workers} worker(s), best of {args.repeat}: {best:.1f} s ({per_filter})")


if __name__ == "__main__":
    main()
