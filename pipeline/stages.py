"""The DVC stages: read inputs, call the modules that do the work, write outputs atomically.

Each stage computes all its results before writing any file, so a failure leaves the
previous outputs (or none) rather than a mix of new and old.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Callable

from pipeline import figures, io, routes, simulate
from pipeline.data_summary import summarise_split
from pipeline.params import Params

log = logging.getLogger("pipeline")


def progress_logger(label: str, every_s: float = 5.0) -> Callable[[int, int], None]:
    """A progress callback that logs a line at most every few seconds, and at the end."""
    last = [0.0]

    def report(done: int, total: int) -> None:
        now = time.monotonic()
        if done == total or now - last[0] >= every_s:
            last[0] = now
            log.info("%s: %d/%d (%.0f%%)", label, done, total, 100.0 * done / max(total, 1))

    return report


def run_routes(params: Params, out_dir: Path) -> None:
    """Stage `routes`: one Parquet file of truth per split."""
    tables = {split.name: routes.generate_split(params, split, progress_logger(f"routes {split.name}"))
              for split in params.routes.splits}
    for name, table in tables.items():
        io.write_parquet(table, out_dir / f"{name}.parquet")
        log.info("routes %s: %d routes, %d truth rows -> %s", name, len(set(table.column("route_id").to_pylist())),
                 table.num_rows, out_dir / f"{name}.parquet")


def run_simulate(params: Params, routes_dir: Path, out_dir: Path) -> None:
    """Stage `simulate`: plots, per-scan truth and the radar description per split."""
    results = {}
    for split in params.routes.splits:
        table = io.read_parquet(routes_dir / f"{split.name}.parquet", routes.ROUTE_SCHEMA)
        results[split.name] = simulate.simulate_split(params, split, table, progress_logger(f"simulate {split.name}"))
    description = simulate.radar_description(params)
    for name, (plots, truth) in results.items():
        io.write_parquet(plots, out_dir / name / "plots.parquet")
        io.write_parquet(truth, out_dir / name / "truth.parquet")
        io.write_parquet(description, out_dir / name / "radar.parquet")
        targets = sum(plots.column("is_target").to_pylist())
        log.info("simulate %s: %d target plots, %d false plots -> %s", name, targets, plots.num_rows - targets,
                 out_dir / name)


def run_data_report(params: Params, routes_dir: Path, simulated_dir: Path, reports_dir: Path) -> None:
    """Stage `data_report`: metrics of the simulated data and pictures to check it by eye."""
    summary, loaded = {}, {}
    for split in params.routes.splits:
        route_table = io.read_parquet(routes_dir / f"{split.name}.parquet", routes.ROUTE_SCHEMA)
        plots = io.read_parquet(simulated_dir / split.name / "plots.parquet", simulate.PLOT_SCHEMA)
        truth = io.read_parquet(simulated_dir / split.name / "truth.parquet", simulate.TRUTH_SCHEMA)
        summary[split.name] = summarise_split(route_table, plots, truth)
        loaded[split.name] = (route_table, plots, truth)
    first = params.routes.splits[0].name
    route_table, plots, truth = loaded[first]
    routes_png = figures.route_examples(route_table, plots, params, params.example_routes)
    radar_png = figures.radar_statistics(plots, truth)
    io.write_json(summary, reports_dir / "data.json")
    io.write_bytes(routes_png, reports_dir / "data_routes.png")
    io.write_bytes(radar_png, reports_dir / "data_radar.png")
    log.info("data report: %s, %s, %s", reports_dir / "data.json", reports_dir / "data_routes.png",
             reports_dir / "data_radar.png")
