"""Run the radar over every route of a split: plots, per-scan truth and the radar description.

One scenario per route: one aircraft and the clutter of the scans it spans. Each
scenario draws from its own random stream (simulate seed, split seed, route id), so a
scenario's plots do not change when other routes are added or removed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
import pyarrow as pa
from scipy.interpolate import CubicHermiteSpline

from pipeline import geodesy, io, radar as radar_model
from pipeline.params import Params, Split

PLOT_SCHEMA = io.schema(
    ("scenario_id", pa.int32()),
    ("plot_id", pa.int64()),
    ("radar_id", pa.int32()),
    ("scan", pa.int64()),
    ("time_of_day_s", pa.float64()),
    ("time_unix_s", pa.float64()),
    ("range_m", pa.float64()),
    ("azimuth_deg", pa.float64()),
    ("flight_level", pa.float64()),
    ("altitude_m", pa.float64()),
    ("x_ecef_m", pa.float64()),
    ("y_ecef_m", pa.float64()),
    ("z_ecef_m", pa.float64()),
    ("is_target", pa.bool_()),
    ("target_id", pa.int32()),
    ("true_x_ecef_m", pa.float64(), True),
    ("true_y_ecef_m", pa.float64(), True),
    ("true_z_ecef_m", pa.float64(), True),
)

TRUTH_SCHEMA = io.schema(
    ("scenario_id", pa.int32()),
    ("target_id", pa.int32()),
    ("scan", pa.int64()),
    ("time_unix_s", pa.float64()),
    ("x_ecef_m", pa.float64()),
    ("y_ecef_m", pa.float64()),
    ("z_ecef_m", pa.float64()),
    ("range_m", pa.float64()),
    ("azimuth_deg", pa.float64()),
    ("altitude_m", pa.float64()),
    ("in_coverage", pa.bool_()),
    ("snr_db", pa.float64()),
    ("detection_probability", pa.float64()),
    ("detected", pa.bool_()),
)

RADAR_SCHEMA = io.schema(
    ("radar_id", pa.int32()),
    ("sac", pa.int32()),
    ("sic", pa.int32()),
    ("latitude_deg", pa.float64()),
    ("longitude_deg", pa.float64()),
    ("height_m", pa.float64()),
    ("x_ecef_m", pa.float64()),
    ("y_ecef_m", pa.float64()),
    ("z_ecef_m", pa.float64()),
    ("scan_period_s", pa.float64()),
    ("range_max_m", pa.float64()),
)

ROUTE_COLUMNS = ("route_id", "aircraft_type", "time_unix_s", "x_ecef_m", "y_ecef_m", "z_ecef_m",
                 "vx_ecef_mps", "vy_ecef_mps", "vz_ecef_mps")


def radar_description(params: Params) -> pa.Table:
    """What a CAT034 north marker tells a receiver: identity, position and scan period."""
    radar = params.radar
    site = geodesy.radar_site_ecef(radar)
    return pa.Table.from_pylist([{
        "radar_id": radar.radar_id, "sac": radar.sac, "sic": radar.sic, "latitude_deg": radar.latitude_deg,
        "longitude_deg": radar.longitude_deg, "height_m": radar.height_m, "x_ecef_m": site[0], "y_ecef_m": site[1],
        "z_ecef_m": site[2], "scan_period_s": radar.scan_period_s, "range_max_m": radar.range_max_m,
    }], schema=RADAR_SCHEMA)


def trajectory_of(route: dict[str, np.ndarray]) -> CubicHermiteSpline:
    position = np.stack([route["x_ecef_m"], route["y_ecef_m"], route["z_ecef_m"]], axis=1)
    velocity = np.stack([route["vx_ecef_mps"], route["vy_ecef_mps"], route["vz_ecef_mps"]], axis=1)
    return CubicHermiteSpline(route["time_unix_s"], position, velocity)


def simulate_scenario(params: Params, split: Split, route: dict[str, np.ndarray]
                      ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Plots (target and false, unsorted, without plot ids) and per-scan truth of one route.

    Detections, measurement noise and clutter each draw from their own stream, and every beam
    crossing gets its noise whether detected or not: a plot's noise and the clutter never depend
    on which other plots were detected. So the same flight past a radar at another site, where
    the local earth curvature hides one more plot below the horizon, differs by that plot only.
    """
    radar = params.radar
    route_id = int(route["route_id"][0])
    kind = params.aircraft[str(route["aircraft_type"][0])]
    detection_rng, noise_rng, clutter_rng = (np.random.default_rng([params.simulate_seed, split.seed, route_id, stream])
                                             for stream in range(3))
    trajectory = trajectory_of(route)
    start, end = float(route["time_unix_s"][0]), float(route["time_unix_s"][-1])

    crossing, scan = radar_model.beam_crossings(trajectory, radar)
    true_ecef = trajectory(crossing)
    true_range, true_azimuth, true_altitude = geodesy.true_measurement(true_ecef, radar)
    line_of_sight = true_ecef - geodesy.radar_site_ecef(radar)
    snr = radar_model.mean_snr(true_range, radar_model.mean_rcs(trajectory(crossing, 1), line_of_sight, kind), radar)
    covered = radar_model.in_coverage(true_range, true_altitude, geodesy.elevation_deg(true_ecef, radar), radar)
    detected = radar_model.detect(detection_rng, snr, radar) & covered
    truth = {
        "scenario_id": np.full(len(scan), route_id, np.int32), "target_id": np.full(len(scan), route_id, np.int32),
        "scan": scan, "time_unix_s": crossing,
        "x_ecef_m": true_ecef[:, 0], "y_ecef_m": true_ecef[:, 1], "z_ecef_m": true_ecef[:, 2],
        "range_m": true_range, "azimuth_deg": true_azimuth, "altitude_m": true_altitude, "in_coverage": covered,
        "snr_db": 10.0 * np.log10(snr), "detection_probability": np.where(covered, radar_model.detection_probability(
            snr, radar), 0.0), "detected": detected,
    }

    noisy = [values[detected] for values in radar_model.add_measurement_noise(
        noise_rng, true_range, true_azimuth, true_altitude, radar)]
    false_scan, false_time, *false_measured = radar_model.false_plot_draws(
        clutter_rng, radar_model.scan_numbers(start, end, radar), radar)
    in_span = (false_time >= start) & (false_time <= end)
    n_target, n_false = int(detected.sum()), int(in_span.sum())
    all_scan = np.concatenate([scan[detected], false_scan[in_span]])
    measured = radar_model.measure(
        np.concatenate([crossing[detected], false_time[in_span]]),
        *(np.concatenate([target_part, false_part[in_span]]) for target_part, false_part in zip(noisy, false_measured)),
        radar=radar, reference_unix_s=all_scan * radar.scan_period_s)
    is_target = np.concatenate([np.ones(n_target, bool), np.zeros(n_false, bool)])
    # Truth at the recorded (quantised) plot time, so a plot pairs with the truth at its own time stamp.
    plot_truth = np.full((n_target + n_false, 3), np.nan)
    plot_truth[is_target] = trajectory(np.clip(measured.time_unix_s[is_target], start, end))
    plots = {
        "scenario_id": np.full(n_target + n_false, route_id, np.int32),
        "radar_id": np.full(n_target + n_false, radar.radar_id, np.int32),
        "scan": all_scan, "time_of_day_s": measured.time_of_day_s, "time_unix_s": measured.time_unix_s,
        "range_m": measured.range_m, "azimuth_deg": measured.azimuth_deg, "flight_level": measured.flight_level,
        "altitude_m": measured.altitude_m,
        "x_ecef_m": measured.ecef[:, 0], "y_ecef_m": measured.ecef[:, 1], "z_ecef_m": measured.ecef[:, 2],
        "is_target": is_target, "target_id": np.where(is_target, route_id, -1).astype(np.int32),
        "true_x_ecef_m": plot_truth[:, 0], "true_y_ecef_m": plot_truth[:, 1], "true_z_ecef_m": plot_truth[:, 2],
    }
    return plots, truth


def _routes_by_id(routes: pa.Table) -> list[dict[str, np.ndarray]]:
    columns = {name: routes.column(name).to_numpy(zero_copy_only=False) for name in ROUTE_COLUMNS}
    ids = columns["route_id"]
    boundaries = np.flatnonzero(np.diff(ids)) + 1
    starts, ends = np.concatenate([[0], boundaries]), np.concatenate([boundaries, [len(ids)]])
    return [{name: values[a:b] for name, values in columns.items()} for a, b in zip(starts, ends) if b > a]


def simulate_split(params: Params, split: Split, routes: pa.Table,
                   progress: Callable[[int, int], None] | None = None) -> tuple[pa.Table, pa.Table]:
    """Plots (time-ordered within each scenario, plot ids numbered in that order) and truth."""
    plot_parts, truth_parts = [], []
    scenarios = _routes_by_id(routes)
    for done, route in enumerate(scenarios, start=1):
        plots, truth = simulate_scenario(params, split, route)
        order = np.lexsort((~plots["is_target"], plots["time_unix_s"]))
        plot_parts.append({name: values[order] for name, values in plots.items()})
        truth_parts.append(truth)
        if progress is not None:
            progress(done, len(scenarios))
    plots = _concatenate(plot_parts, PLOT_SCHEMA, skip=("plot_id",))
    plots["plot_id"] = np.arange(len(plots["scenario_id"]), dtype=np.int64)
    return (pa.Table.from_pydict(plots, schema=PLOT_SCHEMA),
            pa.Table.from_pydict(_concatenate(truth_parts, TRUTH_SCHEMA), schema=TRUTH_SCHEMA))


def _concatenate(parts: list[dict[str, np.ndarray]], schema: pa.Schema, skip: tuple[str, ...] = ()
                 ) -> dict[str, np.ndarray]:
    names = [name for name in schema.names if name not in skip]
    if not parts:
        return {name: np.array([], dtype=schema.field(name).type.to_pandas_dtype()) for name in names}
    return {name: np.concatenate([part[name] for part in parts]) for name in names}


def write_split(plots: pa.Table, truth: pa.Table, description: pa.Table, folder: Path) -> None:
    """A split's simulated files as the stages read them: `<folder>/{plots,truth,radar}.parquet`."""
    io.write_parquet(plots, folder / "plots.parquet")
    io.write_parquet(truth, folder / "truth.parquet")
    io.write_parquet(description, folder / "radar.parquet")
