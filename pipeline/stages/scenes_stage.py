"""Stage `scenes`: the multi-target scenes (crossings, formations, aircraft entering and leaving coverage).

Each stage computes all its results before writing any file, so a failure leaves the
previous outputs (or none) rather than a mix of new and old.
"""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import io
from pipeline.params import Params
from pipeline.progress import progress_logger
from pipeline.simulation import scenes, simulate

log = logging.getLogger("pipeline")


def run_scenes(params: Params, out_dir: Path) -> None:
    """Stage `scenes`: the multi-target scenes' routes, plots, per-scan truth and radar description."""
    route_table, plots, truth = scenes.generate_scenes(params, progress_logger("scenes"))
    io.write_parquet(route_table, out_dir / "routes.parquet")
    simulate.write_split(plots, truth, simulate.radar_description(params), out_dir)
    targets = sum(plots.column("is_target").to_pylist())
    log.info("scenes: %d scenes of %d aircraft, %d target plots, %d false plots -> %s", params.scenes.count,
             params.scenes.aircraft, targets, plots.num_rows - targets, out_dir)
