"""Stage `data_report`: metrics of the simulated data and pictures to check it by eye.

Each stage computes all its results before writing any file, so a failure leaves the
previous outputs (or none) rather than a mix of new and old.
"""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import io
from pipeline.params import Params
from pipeline.reports import data_figures
from pipeline.simulation import routes, simulate
from pipeline.simulation.data_summary import summarise_split

log = logging.getLogger("pipeline")


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
    routes_png = data_figures.route_examples(route_table, plots, params, params.example_routes)
    radar_png = data_figures.radar_statistics(plots, truth)
    io.write_metrics(summary, reports_dir / "data.json")
    io.write_bytes(routes_png, reports_dir / "data_routes.png")
    io.write_bytes(radar_png, reports_dir / "data_radar.png")
    log.info("data report: %s, %s, %s", reports_dir / "data.json", reports_dir / "data_routes.png",
             reports_dir / "data_radar.png")
