"""Numbers that say whether the simulated data is what was asked for (reports/data.json)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

SEGMENT_GAP_S = 18.0  # the thesis's gap that ends a track segment; reported here for orientation

# The thesis's test data (30 + 30 scenarios), for comparison with our test split.
THESIS_TEST_TARGET_PLOTS = 24873
THESIS_TEST_FALSE_PLOTS = 242419


def _route_lengths_m(routes: pa.Table) -> np.ndarray:
    ids = routes.column("route_id").to_numpy()
    xyz = np.stack([routes.column(c).to_numpy() for c in ("x_ecef_m", "y_ecef_m", "z_ecef_m")], axis=1)
    steps = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    same_route = ids[1:] == ids[:-1]
    return np.bincount(ids[1:][same_route], weights=steps[same_route], minlength=ids.max() + 1)[np.unique(ids)]


def _flight_hours(routes: pa.Table) -> float:
    spans = routes.group_by("route_id").aggregate([("time_unix_s", "min"), ("time_unix_s", "max")])
    return float(pc.sum(pc.subtract(spans.column("time_unix_s_max"), spans.column("time_unix_s_min"))).as_py()
                 or 0.0) / 3600.0


def target_plot_errors_m(plots: pa.Table) -> np.ndarray:
    """Distance between each target plot (eqs 4.1-4.6) and the true position at its time."""
    target = plots.filter(plots.column("is_target"))
    measured = np.stack([target.column(c).to_numpy() for c in ("x_ecef_m", "y_ecef_m", "z_ecef_m")], axis=1)
    true = np.stack([target.column(c).to_numpy() for c in ("true_x_ecef_m", "true_y_ecef_m", "true_z_ecef_m")], axis=1)
    return np.linalg.norm(measured - true, axis=1)


def target_plot_intervals_s(plots: pa.Table) -> np.ndarray:
    """Time between consecutive plots of the same target."""
    target = plots.filter(plots.column("is_target"))
    ids = target.column("scenario_id").to_numpy()
    times = target.column("time_unix_s").to_numpy()
    same = ids[1:] == ids[:-1]
    return np.diff(times)[same]


def summarise_split(routes: pa.Table, plots: pa.Table, truth: pa.Table) -> dict:
    strategies = routes.group_by("strategy").aggregate([("route_id", "count_distinct")])
    types = routes.group_by("aircraft_type").aggregate([("route_id", "count_distinct")])
    lengths = _route_lengths_m(routes)
    targets = int(pc.sum(plots.column("is_target")).as_py() or 0)
    false = plots.num_rows - targets
    errors = target_plot_errors_m(plots)
    intervals = target_plot_intervals_s(plots)
    covered = truth.filter(truth.column("in_coverage"))
    detected = int(pc.sum(covered.column("detected")).as_py() or 0)
    return {
        "routes": dict(zip(strategies.column("strategy").to_pylist(),
                           strategies.column("route_id_count_distinct").to_pylist())),
        "aircraft": dict(zip(types.column("aircraft_type").to_pylist(),
                             types.column("route_id_count_distinct").to_pylist())),
        "route_length_km_mean": float(lengths.mean() / 1000.0) if len(lengths) else 0.0,
        "flight_hours": _flight_hours(routes),
        "target_plots": targets,
        "false_plots": false,
        "false_per_target_plot": false / targets if targets else None,
        "detection_rate_in_coverage": detected / covered.num_rows if covered.num_rows else None,
        "scans_in_coverage": covered.num_rows,
        "plot_error_m_mean": float(errors.mean()) if len(errors) else None,
        "plot_error_m_median": float(np.median(errors)) if len(errors) else None,
        "plot_interval_s_mean": float(intervals.mean()) if len(intervals) else None,
        "plot_gaps_over_18s": int((intervals > SEGMENT_GAP_S).sum()),
    }
