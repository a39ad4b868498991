"""Stage `windows`: the networks' balanced, scaled training windows, their calibration material and the hold-out.

Each stage computes all its results before writing any file, so a failure leaves the
previous outputs (or none) rather than a mix of new and old.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute  # noqa: F401  (pa.compute)

from pipeline import io
from pipeline.learning import materials, windows
from pipeline.params import Params
from pipeline.reports import data_figures
from pipeline.simulation import simulate

log = logging.getLogger("pipeline")


def run_windows(params: Params, simulated_dir: Path, out_dir: Path, reports_dir: Path) -> None:
    """Stage `windows`: filter, predictor, autoencoder and calibration material, and the hold-out."""
    cfg = params.windows
    train_split, calibration_split = params.routes.split("train").name, params.routes.split("calibration").name
    train_path = simulated_dir / train_split / "plots.parquet"
    targets = windows.target_plots(io.read_parquet(train_path, simulate.PLOT_SCHEMA), params.radar,
                                   cfg.segment_gap_s, str(train_path))
    held = np.isin(targets.segment_id, windows.holdout_segments(targets.segment_id, cfg.holdout_fraction, cfg.seed))
    training, holdout = targets.take(~held), targets.take(held)
    scalers = materials.scalers(cfg)
    builders = {"filter": (materials.filter_material, "plots"), "predictor": (materials.predictor_material, "states"),
                "autoencoder": (materials.autoencoder_material, "plots")}
    built = {}
    for index, (name, (build, layout)) in enumerate(builders.items()):
        built[name] = build(training, cfg, scalers[layout], np.random.default_rng([cfg.seed, index]))
        log.info("windows %s: %d -> %d after balancing", name, len(built[name].linearity_before),
                 len(built[name].linearity_after))
    calibration_path = simulated_dir / calibration_split / "plots.parquet"
    calibration_plots = io.read_parquet(calibration_path, simulate.PLOT_SCHEMA)
    calibration = materials.calibration_material(
        windows.target_plots(calibration_plots, params.radar, cfg.segment_gap_s, str(calibration_path)),
        calibration_plots, cfg, scalers["plots"])
    summary = window_summary(built, calibration, targets, held)
    picture = data_figures.linearity_histograms({name: (m.linearity_before, m.linearity_after) for name, m in built.items()},
                                           cfg.balance_bins)
    for name, material in built.items():
        io.write_parquet(material.table, out_dir / f"{name}.parquet")
    io.write_parquet(calibration, out_dir / "autoencoder_calibration.parquet")
    io.write_parquet(materials.holdout_table(holdout), out_dir / "holdout.parquet")
    io.write_json({name: scaler.to_dict() for name, scaler in scalers.items()}, out_dir / "scalers.json")
    io.write_metrics(summary, reports_dir / "windows.json")
    io.write_bytes(picture, reports_dir / "windows_linearity.png")
    log.info("windows: %s", ", ".join(f"{k} {v}" for k, v in summary["segments"].items()))


def window_summary(built: dict[str, materials.Material], calibration: pa.Table, targets: windows.TargetPlots,
                   held: np.ndarray) -> dict:
    """Counts before and after balancing beside the thesis's, and the sizes of the other materials."""
    labels = calibration.filter(pa.compute.equal(calibration.column("step"), 0)).column("label").to_numpy(
        zero_copy_only=False)
    return {
        "materials": {name: {"before": len(m.linearity_before), "after": len(m.linearity_after),
                             "thesis_before": materials.THESIS_COUNTS[name][0],
                             "thesis_after": materials.THESIS_COUNTS[name][1]} for name, m in built.items()},
        "segments": {"total": int(len(np.unique(targets.segment_id))),
                     "holdout": int(len(np.unique(targets.segment_id[held]))),
                     "holdout_plots": int(held.sum())},
        "autoencoder_calibration": {"windows": int(len(labels)), "target": int(labels.sum()),
                                    "false": int(len(labels) - labels.sum())},
    }
