"""Stage `routes`: the aircraft routes (truth) of every split, one Parquet file each.

Each stage computes all its results before writing any file, so a failure leaves the
previous outputs (or none) rather than a mix of new and old.
"""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import io
from pipeline.params import Params
from pipeline.progress import progress_logger
from pipeline.simulation import routes

log = logging.getLogger("pipeline")


def run_routes(params: Params, out_dir: Path) -> None:
    """Stage `routes`: one Parquet file of truth per split."""
    tables = {split.name: routes.generate_split(params, split, progress_logger(f"routes {split.name}"))
              for split in params.routes.splits}
    for name, table in tables.items():
        io.write_parquet(table, out_dir / f"{name}.parquet")
        log.info("routes %s: %d routes, %d truth rows -> %s", name, len(set(table.column("route_id").to_pylist())),
                 table.num_rows, out_dir / f"{name}.parquet")
