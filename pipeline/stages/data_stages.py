"""The DVC stages: read inputs, call the modules that do the work, write outputs atomically.

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
from pipeline.progress import progress_logger
from pipeline.reports import figures
from pipeline.simulation import routes, scenes, simulate
from pipeline.simulation.data_summary import summarise_split

log = logging.getLogger("pipeline")


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
        simulate.write_split(plots, truth, description, out_dir / name)
        targets = sum(plots.column("is_target").to_pylist())
        log.info("simulate %s: %d target plots, %d false plots -> %s", name, targets, plots.num_rows - targets,
                 out_dir / name)


def run_scenes(params: Params, out_dir: Path) -> None:
    """Stage `scenes`: the multi-target scenes' routes, plots, per-scan truth and radar description."""
    route_table, plots, truth = scenes.generate_scenes(params, progress_logger("scenes"))
    io.write_parquet(route_table, out_dir / "routes.parquet")
    simulate.write_split(plots, truth, simulate.radar_description(params), out_dir)
    targets = sum(plots.column("is_target").to_pylist())
    log.info("scenes: %d scenes of %d aircraft, %d target plots, %d false plots -> %s", params.scenes.count,
             params.scenes.aircraft, targets, plots.num_rows - targets, out_dir)


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
    picture = figures.linearity_histograms({name: (m.linearity_before, m.linearity_after) for name, m in built.items()},
                                           cfg.balance_bins)
    for name, material in built.items():
        io.write_parquet(material.table, out_dir / f"{name}.parquet")
    io.write_parquet(calibration, out_dir / "autoencoder_calibration.parquet")
    io.write_parquet(materials.holdout_table(holdout), out_dir / "holdout.parquet")
    io.write_json({name: scaler.to_dict() for name, scaler in scalers.items()}, out_dir / "scalers.json")
    io.write_json(summary, reports_dir / "windows.json")
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
