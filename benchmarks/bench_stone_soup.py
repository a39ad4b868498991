"""Stone Soup's trackers against ours on the same plots: plots a second, tracking alone, one core.

On one scenario of a finished pipeline run's test split (its plots, its tuned filters): Stone Soup's GNN and
JPDA as `pipeline.peers.stone_soup` sets them up (our tuned CV model), and this project's `imm_gnn` and
`kalman_cv` trackers (`pipeline.tracker`), each timed over the same plots (the first `--plots` of the
scenario). Prints a table. Stone Soup takes minutes for a scenario: start with a few thousand plots.

    python benchmarks/bench_stone_soup.py --run . --scenario 0 --plots 3000
    python benchmarks/bench_stone_soup.py --run /tmp/tiny --plots 500

Run it on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPOSITORY = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPOSITORY))

from pipeline.filters import classical_filters  # noqa: E402
from pipeline.peers import stone_soup  # noqa: E402
from pipeline.recordings import plot_table  # noqa: E402
from pipeline.settings import load_params  # noqa: E402
from pipeline.tracker import registry  # noqa: E402
from pipeline.tracker.loading import load_models  # noqa: E402
from pipeline.tracker.run import track  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, default=REPOSITORY, help="a folder where `dvc repro` ran (default: here)")
    parser.add_argument("--scenario", type=int, default=0, help="test scenario id (default: %(default)s)")
    parser.add_argument("--plots", type=int, default=3000, help="its first plots, at most (default: %(default)s)")
    args = parser.parse_args()
    params = load_params(args.run / "params.yaml")
    split = args.run / "data" / "simulated" / params.evaluate.split
    plots = dict(plot_table.read_parquet_plots(split / "plots.parquet", split / "radar.parquet",
                                               params.radar).scenarios())[args.scenario]
    plots = plots.take(np.arange(min(args.plots, len(plots))))
    cv = classical_filters.load_settings(args.run / "models" / "kalman_tuned.json")["cv"]
    models = load_models(args.run / "models", params, ["imm_gnn", "kalman_cv"])
    gate = params.tracker.association.kalman_gate_probability
    runs = {
        "stone_soup_gnn": lambda: stone_soup.track_with_stone_soup(
            plots, stone_soup.StoneSoupSettings.from_params("gnn", params.peers.stone_soup, cv, gate)),
        "stone_soup_jpda": lambda: stone_soup.track_with_stone_soup(
            plots, stone_soup.StoneSoupSettings.from_params("jpda", params.peers.stone_soup, cv, gate)),
        "imm_gnn": lambda: track(plots, registry.compose("imm_gnn", models, params.tracker, 4000.0, [0])),
        "kalman_cv": lambda: track(plots, registry.compose("kalman_cv", models, params.tracker, 4000.0, [0])),
    }
    print(f"scenario {args.scenario}, {len(plots)} plots ({args.run})")
    print(f"{'tracker':18s} {'seconds':>9s} {'plots/s':>9s}")
    for name, run in runs.items():
        start = time.perf_counter()
        run()
        seconds = time.perf_counter() - start
        print(f"{name:18s} {seconds:9.2f} {len(plots) / seconds:9.0f}", flush=True)


if __name__ == "__main__":
    main()
