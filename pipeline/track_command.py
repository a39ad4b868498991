"""`python -m pipeline track`: the trained tracker on a user's recording.

Input is either Parquet plots in the schema `simulate` writes (truth columns optional) with
a radar description, or ASTERIX CAT048 plots with CAT034 north markers. Plots are placed
in ECEF from their own measurements (slant range, azimuth, altitude) and the radar's
position, so the tracker works for a radar anywhere on Earth. For a radar far from where
the networks were trained, train with `windows.frame: enu`: ECEF windows of the same
manoeuvre look different elsewhere, ENU windows do not.

Plots out of time order are sorted (stable) and the count is logged: a recording merged
from several files is often slightly out of order, and the tracker needs time order.
"""

from __future__ import annotations

import dataclasses
import logging
from datetime import date
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import asterix_io, geodesy, io
from pipeline.evaluate_stage import load_tracker_models
from pipeline.params import Params
from pipeline.tracker.run import track_plots
from pipeline.tracker.tracks import status

log = logging.getLogger("pipeline")

PLOT_INPUT_SCHEMA = io.schema(
    ("plot_id", pa.int64()),
    ("radar_id", pa.int32()),
    ("time_unix_s", pa.float64()),
    ("range_m", pa.float64()),
    ("azimuth_deg", pa.float64()),
    ("altitude_m", pa.float64()),
    ("scenario_id", pa.int32(), True),
)
RADAR_INPUT_SCHEMA = io.schema(
    ("radar_id", pa.int32()),
    ("latitude_deg", pa.float64()),
    ("longitude_deg", pa.float64()),
    ("height_m", pa.float64()),
)
TRACK_SCHEMA = io.schema(
    ("radar_id", pa.int32()),
    ("scenario_id", pa.int32(), True),
    ("track_id", pa.int64()),
    ("time_unix_s", pa.float64()),
    ("plot_id", pa.int64()),
    ("x_ecef_m", pa.float64()),
    ("y_ecef_m", pa.float64()),
    ("z_ecef_m", pa.float64()),
    ("latitude_deg", pa.float64()),
    ("longitude_deg", pa.float64()),
    ("altitude_m", pa.float64()),
    ("range_m", pa.float64()),
    ("weight", pa.float64()),
    ("status", pa.string()),
    ("association", pa.string()),
    ("association_error", pa.float64(), True),
)


def read_parquet_recording(plots_path: Path, radar_path: Path) -> tuple[pa.Table, pa.Table]:
    plots = io.read_parquet(plots_path, PLOT_INPUT_SCHEMA, optional=("scenario_id",))
    radars = io.read_parquet(radar_path, RADAR_INPUT_SCHEMA)
    return plots, radars


def read_asterix_recording(paths: list[Path], first_date: date) -> tuple[pa.Table, pa.Table]:
    """Plots and radars of a recording given as ASTERIX files in time order."""
    plots, radars = asterix_io.decode(paths, first_date)
    plots = plots.append_column("scenario_id", pa.nulls(plots.num_rows, pa.int32()))
    return plots.select(PLOT_INPUT_SCHEMA.names).cast(PLOT_INPUT_SCHEMA), \
        radars.select(RADAR_INPUT_SCHEMA.names).cast(RADAR_INPUT_SCHEMA)


def track_recording(plots: pa.Table, radars: pa.Table, method: str, window_m: float, params: Params,
                    models_dir: Path, source: str) -> pa.Table:
    """Track every (radar, scenario) group of a recording; one row per track update."""
    radar_rows = {row["radar_id"]: row for row in radars.to_pylist()}
    radar_ids = plots.column("radar_id").to_numpy()
    unknown = sorted(set(np.unique(radar_ids).tolist()) - set(radar_rows))
    if unknown:
        raise io.InputError(f"{source}: plots from radar id {unknown[0]} ({len(unknown)} unknown in all), which "
                            f"the radar description does not list (it has {sorted(radar_rows)})")
    models = load_tracker_models(models_dir, params, [method])
    scenario_ids = plots.column("scenario_id").fill_null(-1).to_numpy()
    parts = []
    for radar_id in np.unique(radar_ids):
        row = radar_rows[int(radar_id)]
        radar = dataclasses.replace(params.radar, latitude_deg=row["latitude_deg"],
                                    longitude_deg=row["longitude_deg"], height_m=row["height_m"])
        for scenario_id in np.unique(scenario_ids[radar_ids == radar_id]):
            rows = np.flatnonzero((radar_ids == radar_id) & (scenario_ids == scenario_id))
            parts.append(_track_group(plots.take(rows), radar, int(radar_id), int(scenario_id), method, window_m,
                                      params, models))
    return pa.concat_tables(parts) if parts else TRACK_SCHEMA.empty_table()


def _track_group(plots: pa.Table, radar: object, radar_id: int, scenario_id: int, method: str, window_m: float,
                 params: Params, models: object) -> pa.Table:
    times = plots.column("time_unix_s").to_numpy()
    out_of_order = int((np.diff(times) < 0).sum())
    if out_of_order:
        log.warning("radar %d: %d plots out of time order; sorted by time", radar_id, out_of_order)
    order = np.argsort(times, kind="stable")
    range_m = plots.column("range_m").to_numpy()[order]
    ecef = geodesy.plot_to_ecef(range_m, plots.column("azimuth_deg").to_numpy()[order],
                                plots.column("altitude_m").to_numpy()[order], radar)
    features = np.column_stack([times[order], ecef, range_m])
    seed = [params.tracker.seed, scenario_id] if scenario_id >= 0 else [params.tracker.seed]
    updates = track_plots(features, plots.column("plot_id").to_numpy()[order], method, window_m, models,
                          params.tracker, seed=seed, radar=radar)
    states = np.column_stack([updates["x_ecef_m"], updates["y_ecef_m"], updates["z_ecef_m"]])
    lat, lon, alt = geodesy.ecef_to_geodetic(states)
    count = len(updates["track_id"])
    return pa.Table.from_pydict({
        "radar_id": np.full(count, radar_id, np.int32),
        "scenario_id": pa.array(np.full(count, scenario_id, np.int32), mask=np.full(count, scenario_id < 0)),
        "track_id": updates["track_id"].astype(np.int64), "time_unix_s": updates["time_unix_s"],
        "plot_id": updates["plot_id"].astype(np.int64),
        "x_ecef_m": states[:, 0], "y_ecef_m": states[:, 1], "z_ecef_m": states[:, 2],
        "latitude_deg": lat, "longitude_deg": lon, "altitude_m": alt, "range_m": updates["range_m"],
        "weight": updates["weight"], "status": [status(w, params.tracker) for w in updates["weight"]],
        "association": updates["association"].astype(str), "association_error": updates["association_error"],
    }, schema=TRACK_SCHEMA)


def run_track(params: Params, plots_path: Path | None, radar_path: Path | None, asterix_paths: list[Path],
              first_date: date | None, method: str, window_m: float, models_dir: Path, out: Path) -> None:
    if asterix_paths:
        if first_date is None:
            raise io.InputError("ASTERIX input carries only the time of day: give --date (UTC date of the first record)")
        plots, radars = read_asterix_recording(asterix_paths, first_date)
        source = ", ".join(str(p) for p in asterix_paths)
    else:
        if plots_path is None or radar_path is None:
            raise io.InputError("give --plots and --radar (Parquet), or --asterix files")
        plots, radars = read_parquet_recording(plots_path, radar_path)
        source = str(plots_path)
    tracks = track_recording(plots, radars, method, window_m, params, models_dir, source)
    io.write_parquet(tracks, out)
    confirmed = np.unique(np.asarray(tracks.column("track_id"))[np.asarray(tracks.column("status")) == "confirmed"])
    log.info("track: %d plots, %d track updates, %d confirmed tracks -> %s", plots.num_rows, tracks.num_rows,
             len(confirmed), out)


def export_asterix(plots_path: Path, radar_path: Path, scenario_id: int, out: Path) -> None:
    """Write one simulated scenario as a CAT034 + CAT048 recording."""
    plots = io.read_parquet(plots_path, pq.read_schema(plots_path))
    plots = plots.filter(pa.compute.equal(plots.column("scenario_id"), scenario_id))
    if plots.num_rows == 0:
        raise io.InputError(f"{plots_path}: no plots of scenario {scenario_id}")
    radar = io.read_parquet(radar_path, pq.read_schema(radar_path)).to_pylist()[0]
    scans = np.unique(plots.column("scan").to_numpy()) * radar["scan_period_s"]
    data = asterix_io.encode(plots, radar, scans)
    with io.atomic_path(out) as temporary:
        temporary.write_bytes(data)
    log.info("asterix: scenario %d, %d plots, %d north markers -> %s", scenario_id, plots.num_rows, len(scans), out)
