"""Training material: segments of a target's plots, sliding windows, linearity and balancing.

Follows thesis 4.2.3-4.2.4 (spec section 5). All windowing is index arithmetic on the
time-ordered target plots, so no window can cross a segment boundary: a window start is
valid only when its first and last index lie in the same segment.

Predictor windows span six consecutive true states s0..s5. The network reads s0..s4
(each with dT to the next state) and is trained to output s2..s5: the state after each
input from the second on (predicting from a single state is pointless, so the shifted
target sequence is one shorter). This reading reproduces the thesis's counts: with
2 688 segments, 96 751 windows of 5 and 83 309 windows of 10 imply 93 675 windows of 6.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from pipeline.geometry import geodesy
from pipeline.io import InputError
from pipeline.learning.scaling import PLOT_FEATURES, STATE_FEATURES
from pipeline.params import Radar


@dataclass(frozen=True)
class TargetPlots:
    """A split's target plots in scenario and time order, with their segment numbers."""

    scenario_id: np.ndarray
    plot_id: np.ndarray
    segment_id: np.ndarray
    time: np.ndarray
    position: np.ndarray       # measured, eqs 4.1-4.6 (N x 3)
    range_m: np.ndarray        # measured slant range
    true_position: np.ndarray  # truth at the plot time (N x 3)
    true_range_m: np.ndarray   # exact distance from the radar to the truth
    radar_position: np.ndarray  # ECEF of the radar that measured the plot (N x 3), for the radial window frame

    def take(self, mask: np.ndarray) -> "TargetPlots":
        return TargetPlots(*(getattr(self, name)[mask] for name in self.__dataclass_fields__))

    def plot_features(self) -> np.ndarray:
        """[T, x, y, z, R] of the measured plots (N x 5)."""
        return np.column_stack([self.time, self.position, self.range_m])

    def true_features(self) -> np.ndarray:
        """[T, x, y, z, R] of the truth at the plot times (N x 5)."""
        return np.column_stack([self.time, self.true_position, self.true_range_m])


def _columns(table: pa.Table, names: tuple[str, ...]) -> np.ndarray:
    return np.column_stack([table.column(name).to_numpy(zero_copy_only=False) for name in names])


def target_plots(plots: pa.Table, radar: Radar, gap_s: float, source: str) -> TargetPlots:
    """The target's plots of a split, cut into segments at gaps longer than `gap_s`."""
    target = plots.filter(plots.column("is_target"))
    true_position = _columns(target, ("true_x_ecef_m", "true_y_ecef_m", "true_z_ecef_m"))
    for axis, name in enumerate(("true_x_ecef_m", "true_y_ecef_m", "true_z_ecef_m")):
        missing = np.isnan(true_position[:, axis])
        if missing.any():
            raise InputError(f"{source}: column '{name}' is missing for {int(missing.sum())} target plots "
                             f"(first plot_id {int(target.column('plot_id')[int(np.argmax(missing))].as_py())})")
    site = geodesy.radar_site_ecef(radar)
    scenario = target.column("scenario_id").to_numpy()
    time = target.column("time_unix_s").to_numpy()
    order = np.lexsort((time, scenario))
    scenario, time, true_position = scenario[order], time[order], true_position[order]
    new_segment = np.ones(len(time), dtype=bool)
    new_segment[1:] = (scenario[1:] != scenario[:-1]) | (np.diff(time) > gap_s)
    return TargetPlots(
        scenario_id=scenario,
        plot_id=target.column("plot_id").to_numpy()[order],
        segment_id=np.cumsum(new_segment) - 1,
        time=time,
        position=_columns(target, ("x_ecef_m", "y_ecef_m", "z_ecef_m"))[order],
        range_m=target.column("range_m").to_numpy()[order],
        true_position=true_position,
        true_range_m=np.linalg.norm(true_position - site, axis=1),
        radar_position=np.tile(site, (len(time), 1)),
    )


def holdout_segments(segment_id: np.ndarray, fraction: float, seed: int) -> np.ndarray:
    """A seeded random choice of round(fraction * segments) segment ids."""
    segments = np.unique(segment_id)
    count = int(round(fraction * len(segments)))
    return np.sort(np.random.default_rng(seed).choice(segments, size=count, replace=False))


def window_starts(segment_id: np.ndarray, length: int) -> np.ndarray:
    """Indices where a window of `length` consecutive samples stays inside one segment."""
    if len(segment_id) < length:
        return np.array([], dtype=np.int64)
    starts = np.arange(len(segment_id) - length + 1)
    return starts[segment_id[starts] == segment_id[starts + length - 1]]


def gather(values: np.ndarray, starts: np.ndarray, length: int) -> np.ndarray:
    """Windows of `length` rows from each start (N x length x ...)."""
    return values[starts[:, None] + np.arange(length)]


def linearity(positions: np.ndarray) -> np.ndarray:
    """Eq. 4.7: straight-line distance over path length, per window (N x L x 3 -> N); 1 = straight."""
    path = np.linalg.norm(np.diff(positions, axis=1), axis=2).sum(axis=1)
    chord = np.linalg.norm(positions[:, -1] - positions[:, 0], axis=1)
    return np.divide(chord, path, out=np.ones_like(chord), where=path > 0.0)


def balance(values: np.ndarray, bins: int, high_bins: int, rng: np.random.Generator) -> np.ndarray:
    """Indices kept by the thesis's rule, in their original order.

    The observed range of `values` is cut into `bins` equal bins; every window in the
    first `bins - high_bins` is kept, and as many are drawn at random from the last
    `high_bins` (all of them if there are fewer).
    """
    if len(values) == 0 or values.min() == values.max():
        return np.arange(len(values))  # nothing to balance: one linearity for every window
    edges = np.linspace(values.min(), values.max(), bins + 1)
    which = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, bins - 1)
    high = which >= bins - high_bins
    low_index, high_index = np.flatnonzero(~high), np.flatnonzero(high)
    drawn = rng.choice(high_index, size=min(len(low_index), len(high_index)), replace=False)
    return np.sort(np.concatenate([low_index, drawn]))


def state_features(true: np.ndarray, starts: np.ndarray, length: int) -> np.ndarray:
    """Windows of true states [T, dT, x, y, z, R]; dT is the time to the next state, 0 for the last."""
    windows = gather(true, starts, length)
    dt = np.zeros(windows.shape[:2])
    dt[:, :-1] = np.diff(windows[:, :, 0], axis=1)
    return np.concatenate([windows[:, :, :1], dt[..., None], windows[:, :, 1:]], axis=2)


def long_table(windows: dict[str, np.ndarray], per_step: dict[str, np.ndarray], per_window: dict[str, np.ndarray]
               ) -> pa.Table:
    """One row per window step: window_id, step, per-step ids, per-window values, feature columns.

    `windows` maps a column prefix to an (N x L x F) array whose features are named by
    the prefix's layout; per-step values are (N x L), per-window values (N,).
    """
    first = next(iter(per_step.values()))
    count, length = first.shape
    columns: dict[str, np.ndarray] = {
        "window_id": np.repeat(np.arange(count, dtype=np.int64), length),
        "step": np.tile(np.arange(length, dtype=np.int8), count),
    }
    columns.update({name: values.reshape(-1) for name, values in per_step.items()})
    columns.update({name: np.repeat(values, length) for name, values in per_window.items()})
    for prefix, values in windows.items():
        names = STATE_FEATURES if values.shape[2] == len(STATE_FEATURES) else PLOT_FEATURES
        for index, name in enumerate(names):
            columns[f"{prefix}_{name}"] = values[:, :, index].reshape(-1)
    return pa.table(columns)


def window_arrays(table: pa.Table, prefix: str, features: tuple[str, ...]) -> np.ndarray:
    """The (N x L x F) array of a long table's `prefix_*` columns (inverse of `long_table`)."""
    length = int(np.max(table.column("step").to_numpy())) + 1
    values = np.column_stack([table.column(f"{prefix}_{name}").to_numpy() for name in features])
    return values.reshape(-1, length, len(features))

