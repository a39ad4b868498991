"""Stage `simulate`: the rotating radar over each split's routes: plots, per-scan truth, radar description.

Each stage computes all its results before writing any file, so a failure leaves the
previous outputs (or none) rather than a mix of new and old.
"""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import io
from pipeline.params import Params
from pipeline.progress import progress_logger
from pipeline.simulation import routes, simulate

log = logging.getLogger("pipeline")


def run_simulate(params: Params, routes_dir: Path, out_dir: Path) -> None:
    """Stage `simulate`: plots, per-scan truth and the radar description per split."""
    results = {}
    for split in params.routes.splits:
        table = io.read_parquet(routes_dir / f"{split.name}.parquet", routes.ROUTE_SCHEMA)
        results[split.name] = simulate.simulate_split(params, split, table, progress_logger(f"simulate {split.name}"))
    description = simulate.radar_description(params)
    for name, (plots, truth) in results.items():
        simulate.write_split(plots, truth, description, out_dir / name)
        targets = sum(plots.column("is_target").to_pylist())
        log.info("simulate %s: %d target plots, %d false plots -> %s", name, targets, plots.num_rows - targets,
                 out_dir / name)
