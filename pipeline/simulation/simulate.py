"""Run the radar over every route of a split: plots, per-scan truth and the radar description.

One scenario per route: one aircraft and the clutter of the scans it spans. Each
scenario draws from its own random stream (simulate seed, split seed, route id), so a
scenario's plots do not change when other routes are added or removed. The pieces, one
aircraft's plots (`aircraft_plots`) and the clutter of a time span (`false_plots`), also make
the multi-target scenes (`pipeline.simulation.scenes`).

Every floating-point function here is processor-independent (`pipeline.geometry.strict_math`, through
`geodesy` and `radar`), so the plots and truth have the same bytes on any machine (issue 27).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
import pyarrow as pa
from scipy.interpolate import CubicHermiteSpline

from pipeline import io
from pipeline.geometry import geodesy
from pipeline.geometry import strict_math as sm
from pipeline.params import Params, Radar, Split
from pipeline.recordings.plot_table import NO_TARGET
from pipeline.simulation import radar as radar_model

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


def aircraft_plots(params: Params, route: dict[str, np.ndarray], detection_rng: np.random.Generator,
                   noise_rng: np.random.Generator, scenario_id: int, target_id: int
                   ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """One aircraft's plots (unsorted, without plot ids) and its per-scan truth, labelled with
    `scenario_id` and `target_id`.

    Detections and measurement noise draw from their own streams, and every beam crossing gets its
    noise whether detected or not: a plot's noise never depends on which other plots were detected.
    So the same flight past a radar at another site, where the local earth curvature hides one
    more plot below the horizon, differs by that plot only.
    """
    radar = params.radar
    kind = params.aircraft[str(route["aircraft_type"][0])]
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
        "scenario_id": np.full(len(scan), scenario_id, np.int32), "target_id": np.full(len(scan), target_id, np.int32),
        "scan": scan, "time_unix_s": crossing,
        "x_ecef_m": true_ecef[:, 0], "y_ecef_m": true_ecef[:, 1], "z_ecef_m": true_ecef[:, 2],
        "range_m": true_range, "azimuth_deg": true_azimuth, "altitude_m": true_altitude, "in_coverage": covered,
        "snr_db": 10.0 * sm.log10(snr), "detection_probability": np.where(covered, radar_model.detection_probability(
            snr, radar), 0.0), "detected": detected,
    }
    noisy = [values[detected] for values in radar_model.add_measurement_noise(
        noise_rng, true_range, true_azimuth, true_altitude, radar)]
    measured = radar_model.measure(crossing[detected], *noisy, radar=radar,
                                   reference_unix_s=scan[detected] * radar.scan_period_s)
    # Truth at the recorded (quantised) plot time, so a plot pairs with the truth at its own time stamp.
    plot_truth = trajectory(np.clip(measured.time_unix_s, start, end))
    return _plot_columns(measured, scan[detected], scenario_id, target_id, plot_truth, radar), truth


def false_plots(params: Params, clutter_rng: np.random.Generator, start: float, end: float, scenario_id: int
                ) -> dict[str, np.ndarray]:
    """The clutter of the scans overlapping [start, end] (Unix s) that falls within it (unsorted,
    without plot ids): `radar.false_plots_per_scan` a scan on average, drawn from `clutter_rng`."""
    radar = params.radar
    false_scan, false_time, *false_measured = radar_model.false_plot_draws(
        clutter_rng, radar_model.scan_numbers(start, end, radar), radar)
    in_span = (false_time >= start) & (false_time <= end)
    measured = radar_model.measure(false_time[in_span], *(values[in_span] for values in false_measured), radar=radar,
                                   reference_unix_s=false_scan[in_span] * radar.scan_period_s)
    return _plot_columns(measured, false_scan[in_span], scenario_id, NO_TARGET,
                         np.full((int(in_span.sum()), 3), np.nan), radar)


def _plot_columns(measured: radar_model.Measurements, scan: np.ndarray, scenario_id: int, target_id: int,
                  plot_truth: np.ndarray, radar: Radar) -> dict[str, np.ndarray]:
    """PLOT_SCHEMA's columns but the plot id for N measured plots of one target (or of none:
    NO_TARGET) with their scans (N,) and true positions (N, 3) m ECEF (NaN for false plots)."""
    count = len(scan)
    return {
        "scenario_id": np.full(count, scenario_id, np.int32), "radar_id": np.full(count, radar.radar_id, np.int32),
        "scan": scan, "time_of_day_s": measured.time_of_day_s, "time_unix_s": measured.time_unix_s,
        "range_m": measured.range_m, "azimuth_deg": measured.azimuth_deg, "flight_level": measured.flight_level,
        "altitude_m": measured.altitude_m,
        "x_ecef_m": measured.ecef[:, 0], "y_ecef_m": measured.ecef[:, 1], "z_ecef_m": measured.ecef[:, 2],
        "is_target": np.full(count, target_id != NO_TARGET), "target_id": np.full(count, target_id, np.int32),
        "true_x_ecef_m": plot_truth[:, 0], "true_y_ecef_m": plot_truth[:, 1], "true_z_ecef_m": plot_truth[:, 2],
    }


def simulate_scenario(params: Params, split: Split, route: dict[str, np.ndarray]
                      ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Plots (target and false, unsorted, without plot ids) and per-scan truth of one route: its
    aircraft (`aircraft_plots`) and the clutter of the scans it spans (`false_plots`).

    Detections, measurement noise and clutter each draw from their own stream, seeded by
    (simulate seed, split seed, route id), and no draw depends on the site (see `aircraft_plots`).
    """
    route_id = int(route["route_id"][0])
    detection_rng, noise_rng, clutter_rng = (np.random.default_rng([params.simulate_seed, split.seed, route_id, stream])
                                             for stream in range(3))
    target, truth = aircraft_plots(params, route, detection_rng, noise_rng, route_id, route_id)
    clutter = false_plots(params, clutter_rng, float(route["time_unix_s"][0]), float(route["time_unix_s"][-1]),
                          route_id)
    return {name: np.concatenate([target[name], clutter[name]]) for name in target}, truth


def routes_by_id(routes: pa.Table) -> list[dict[str, np.ndarray]]:
    """Each route's ROUTE_COLUMNS (rows of one route id together), in table order."""
    columns = {name: routes.column(name).to_numpy(zero_copy_only=False) for name in ROUTE_COLUMNS}
    ids = columns["route_id"]
    boundaries = np.flatnonzero(np.diff(ids)) + 1
    starts, ends = np.concatenate([[0], boundaries]), np.concatenate([boundaries, [len(ids)]])
    return [{name: values[a:b] for name, values in columns.items()} for a, b in zip(starts, ends) if b > a]


def simulate_split(params: Params, split: Split, routes: pa.Table,
                   progress: Callable[[int, int], None] | None = None) -> tuple[pa.Table, pa.Table]:
    """Plots (time-ordered within each scenario, plot ids numbered in that order) and truth."""
    plot_parts, truth_parts = [], []
    scenarios = routes_by_id(routes)
    for done, route in enumerate(scenarios, start=1):
        plots, truth = simulate_scenario(params, split, route)
        plot_parts.append(plots)
        truth_parts.append(truth)
        if progress is not None:
            progress(done, len(scenarios))
    return tables(plot_parts, truth_parts)


def tables(plot_parts: list[dict[str, np.ndarray]], truth_parts: list[dict[str, np.ndarray]]
           ) -> tuple[pa.Table, pa.Table]:
    """The plots of scenarios (each part one scenario's, put in time order, target plots first at
    equal times; plot ids numbered in that order) and their truth, as PLOT_SCHEMA and TRUTH_SCHEMA tables."""
    ordered = []
    for plots in plot_parts:
        order = np.lexsort((~plots["is_target"], plots["time_unix_s"]))
        ordered.append({name: values[order] for name, values in plots.items()})
    plots = _concatenate(ordered, PLOT_SCHEMA, skip=("plot_id",))
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
