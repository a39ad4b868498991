"""The four training materials and the hold-out, as long Parquet tables (one row per window step).

Every material table has `window_id`, `step`, `scenario_id`, `segment_id`, `plot_id` per
step, the window's `linearity` and centring origin (`origin_t`, `origin_x/y/z` in ECEF,
`origin_r`, and its radar's site `origin_radar_x/y/z` in ECEF) per window, and scaled feature columns:

- filter:      `in_*` plots [t, x, y, z, r], `out_*` truth at the same times, same scaling
- predictor:   `state_*` true states [t, dt, x, y, z, r] over 6 steps: inputs are steps
               0-4, targets steps 2-5 (see `pipeline.learning.windows`); dt of the last step is 0
- autoencoder: `in_*` plots
- autoencoder_calibration: `in_*` plots (4 of the target, then a candidate) and the
               window's `label` (the candidate is the target's plot) and `candidate_plot_id`

The hold-out is not windowed, scaled or balanced: the raw target plots of the held-out
segments in metres, so model evaluation can window them exactly as it likes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pyarrow as pa

from pipeline import io
from pipeline.learning.scaling import WindowScaler, plot_scaler, state_scaler
from pipeline.learning.windows import TargetPlots, balance, gather, linearity, long_table, state_features, window_starts
from pipeline.params import Windows

HOLDOUT_SCHEMA = io.schema(
    ("scenario_id", pa.int32()), ("segment_id", pa.int64()), ("plot_id", pa.int64()), ("time_unix_s", pa.float64()),
    ("x_ecef_m", pa.float64()), ("y_ecef_m", pa.float64()), ("z_ecef_m", pa.float64()), ("range_m", pa.float64()),
    ("true_x_ecef_m", pa.float64()), ("true_y_ecef_m", pa.float64()), ("true_z_ecef_m", pa.float64()),
    ("true_range_m", pa.float64()))

# The centring origin of each window, `WindowScaler.origin`'s columns: its first sample and its radar's site.
ORIGIN_COLUMNS = ("t", "x", "y", "z", "r", "radar_x", "radar_y", "radar_z")

# (before, after balancing) in the thesis, for the report.
THESIS_COUNTS = {"filter": (83309, 39682), "predictor": (93675, 50730), "autoencoder": (96751, 12464)}


@dataclass(frozen=True)
class Material:
    """A balanced material and what balancing did to it."""

    table: pa.Table
    linearity_before: np.ndarray
    linearity_after: np.ndarray


def scalers(cfg: Windows) -> dict[str, WindowScaler]:
    """The plot scaler (N_u = filter length) and state scaler (N_p = predictor inputs)."""
    return {
        "plots": plot_scaler(cfg.dt_max_s, cfg.position_max_diff_m, cfg.range_scale_m, cfg.filter_length,
                             cfg.frame, cfg.centre_range),
        "states": state_scaler(cfg.dt_max_s, cfg.position_max_diff_m, cfg.range_scale_m, cfg.predictor_inputs,
                               cfg.frame, cfg.centre_range),
    }


def _ids(plots: TargetPlots, starts: np.ndarray, length: int) -> dict[str, np.ndarray]:
    return {name: gather(getattr(plots, name), starts, length) for name in ("scenario_id", "segment_id", "plot_id")}


def _per_window(origin: np.ndarray, values: np.ndarray) -> dict[str, np.ndarray]:
    return {"linearity": values, **{f"origin_{name}": origin[:, i] for i, name in enumerate(ORIGIN_COLUMNS)}}


def _balanced(plots: TargetPlots, starts: np.ndarray, length: int, cfg: Windows, rng: np.random.Generator
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Balance window starts by the linearity of their true positions: (kept starts, before, after)."""
    values = linearity(gather(plots.true_position, starts, length))
    keep = balance(values, cfg.balance_bins, cfg.balance_high_bins, rng)
    return starts[keep], values, values[keep]


def _material(plots: TargetPlots, length: int, cfg: Windows, scaler: WindowScaler, rng: np.random.Generator,
              raw_windows: Callable[[np.ndarray], dict[str, np.ndarray]]) -> Material:
    """Balanced windows of `length` whose raw arrays (by column prefix) come from `raw_windows(starts)`;
    all are centred on the first array's first sample."""
    starts, before, after = _balanced(plots, window_starts(plots.segment_id, length), length, cfg, rng)
    raw = raw_windows(starts)
    origin = scaler.origin(next(iter(raw.values())), plots.radar_position[starts])
    table = long_table({prefix: scaler.transform(values, origin) for prefix, values in raw.items()},
                       _ids(plots, starts, length), _per_window(origin, after))
    return Material(table, before, after)


def filter_material(plots: TargetPlots, cfg: Windows, scaler: WindowScaler, rng: np.random.Generator) -> Material:
    length = cfg.filter_length
    return _material(plots, length, cfg, scaler, rng, lambda starts: {
        "in": gather(plots.plot_features(), starts, length), "out": gather(plots.true_features(), starts, length)})


def predictor_material(plots: TargetPlots, cfg: Windows, scaler: WindowScaler, rng: np.random.Generator
                       ) -> Material:
    length = cfg.predictor_inputs + 1
    return _material(plots, length, cfg, scaler, rng,
                     lambda starts: {"state": state_features(plots.true_features(), starts, length)})


def autoencoder_material(plots: TargetPlots, cfg: Windows, scaler: WindowScaler, rng: np.random.Generator
                         ) -> Material:
    length = cfg.autoencoder_length
    return _material(plots, length, cfg, scaler, rng,
                     lambda starts: {"in": gather(plots.plot_features(), starts, length)})


def calibration_material(targets: TargetPlots, all_plots: pa.Table, cfg: Windows, scaler: WindowScaler) -> pa.Table:
    """Autoencoder calibration windows: 4 target plots, then every plot (target or false) of the
    same scenario less than `calibration_max_delay_s` after the 4th and within
    `calibration_max_distance_m` of it, labelled by whether it is the target's."""
    head = cfg.autoencoder_length - 1
    starts = window_starts(targets.segment_id, head)
    candidates = _candidate_table(all_plots)
    window, candidate = _calibration_pairs(targets, starts + head - 1, candidates, cfg)
    raw = np.concatenate([gather(targets.plot_features(), starts[window], head),
                          candidates["features"][candidate][:, None, :]], axis=1)
    origin = scaler.origin(raw, targets.radar_position[starts[window]])
    ids = {name: np.column_stack([gather(getattr(targets, name), starts[window], head), candidates[name][candidate]])
           for name in ("scenario_id", "plot_id")}
    ids["segment_id"] = np.repeat(targets.segment_id[starts[window]][:, None], head + 1, axis=1)
    per_window = _per_window(origin, linearity(gather(targets.true_position, starts[window], head)))
    per_window["label"] = candidates["is_target"][candidate]
    per_window["candidate_plot_id"] = candidates["plot_id"][candidate]
    return long_table({"in": scaler.transform(raw, origin)}, ids, per_window)


def _calibration_pairs(targets: TargetPlots, last: np.ndarray, candidates: dict[str, np.ndarray], cfg: Windows
                       ) -> tuple[np.ndarray, np.ndarray]:
    """(window index, candidate row) pairs: candidates just after each window's last plot and near it."""
    windows, rows = [np.array([], dtype=np.int64)], [np.array([], dtype=np.int64)]
    for scenario in np.unique(targets.scenario_id[last]):
        window = np.flatnonzero(targets.scenario_id[last] == scenario)
        lo, hi = np.searchsorted(candidates["scenario_id"], [scenario, scenario + 1])
        end_time = targets.time[last[window]]
        first = lo + np.searchsorted(candidates["time"][lo:hi], end_time, side="right")
        stop = lo + np.searchsorted(candidates["time"][lo:hi], end_time + cfg.calibration_max_delay_s, side="left")
        pair_window = np.repeat(window, stop - first)
        pair_row = np.concatenate([np.arange(a, b) for a, b in zip(first, stop)] + [np.array([], dtype=np.int64)])
        near = np.linalg.norm(candidates["position"][pair_row] - targets.position[last[pair_window]], axis=1) \
            < cfg.calibration_max_distance_m
        windows.append(pair_window[near])
        rows.append(pair_row[near])
    return np.concatenate(windows), np.concatenate(rows)


def _candidate_table(plots: pa.Table) -> dict[str, np.ndarray]:
    """Every plot (target and false) in scenario and time order, as arrays."""
    scenario = plots.column("scenario_id").to_numpy()
    time = plots.column("time_unix_s").to_numpy()
    order = np.lexsort((time, scenario))
    position = np.column_stack([plots.column(c).to_numpy() for c in ("x_ecef_m", "y_ecef_m", "z_ecef_m")])[order]
    features = np.column_stack([time[order], position, plots.column("range_m").to_numpy()[order]])
    return {"scenario_id": scenario[order], "time": time[order], "position": position, "features": features,
            "plot_id": plots.column("plot_id").to_numpy()[order],
            "is_target": plots.column("is_target").to_numpy(zero_copy_only=False)[order]}


def holdout_table(plots: TargetPlots) -> pa.Table:
    """The held-out segments' target plots, unscaled, in metres and seconds."""
    return pa.Table.from_pydict({
        "scenario_id": plots.scenario_id, "segment_id": plots.segment_id, "plot_id": plots.plot_id,
        "time_unix_s": plots.time,
        "x_ecef_m": plots.position[:, 0], "y_ecef_m": plots.position[:, 1], "z_ecef_m": plots.position[:, 2],
        "range_m": plots.range_m,
        "true_x_ecef_m": plots.true_position[:, 0], "true_y_ecef_m": plots.true_position[:, 1],
        "true_z_ecef_m": plots.true_position[:, 2], "true_range_m": plots.true_range_m,
    }, schema=HOLDOUT_SCHEMA)
