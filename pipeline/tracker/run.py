"""The tracking loop: plots one at a time in time order (thesis 4.4-4.6).

For each plot: track management first (silent tracks lose weight, some are deleted), then
association against the tracks within the pre-filter distance (young tracks by the
constant radius, the others by the chosen method), lowest normalised error wins; the
winner's state is updated, otherwise the plot starts a new track.

Two variants for the classical methods: `<method>_gnn` associates a whole antenna scan at
once, the assignment of plots to tracks that minimises the summed normalised error
(global nearest neighbour, scipy's `linear_sum_assignment`); the scans are the radar's
rotation periods counted from the first plot, within which each target is seen once.
`oracle` is given the true association: only the target's plots, all to the one live track.

The loop works in ECEF with the radar only entering through each plot's range, so it runs
for a radar anywhere on Earth.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from pipeline import baselines
from pipeline.params import CLASSICAL_METHODS, GLOBAL_SUFFIX, Radar, TrackerParams
from pipeline.tracker.association import (AutoencoderGate, MonteCarloGate, PredictionGate, Scores,
                                           radius_scores)
from pipeline.tracker.estimators import NetworkEstimator
from pipeline.tracker.kalman import KalmanEstimator, MahalanobisGate
from pipeline.tracker.models import Models
from pipeline.tracker.tracks import LiveTracks, Track

UPDATE_COLUMNS = ("track_id", "time_unix_s", "plot_id", "x_ecef_m", "y_ecef_m", "z_ecef_m", "range_m", "weight",
                  "association", "association_error")


ORACLE = "oracle"  # true association, tuned IMM
ORACLE_FILTER = "imm"


def classical_kind(method: str) -> str | None:
    """The tuned filter a method runs (cv, ca, imm), or None for the networks."""
    if method == ORACLE:
        return ORACLE_FILTER
    return CLASSICAL_METHODS.get(method.removesuffix(GLOBAL_SUFFIX))


def make_estimator(method: str, models: Models, radar: Radar | None) -> NetworkEstimator | KalmanEstimator:
    """The state estimator a method runs with: the networks, or a classical filter per track."""
    kind = classical_kind(method)
    if kind is None:
        return NetworkEstimator(models)
    if radar is None:
        raise ValueError(f"the {method} method needs the radar (for the measurement covariance)")
    if kind not in models.filters:
        raise ValueError(f"the {method} method needs the tuned {kind} filter (models/kalman_tuned.json; "
                         f"run `dvc repro tune_kalman`)")
    return KalmanEstimator(radar, models.filters[kind])


def make_gate(method: str, window_m: float, estimator: NetworkEstimator | KalmanEstimator, models: Models,
              params: TrackerParams, seed: int | list[int]
              ) -> tuple[Callable[[list[Track], np.ndarray], Scores] | None, int]:
    """The mature-track gate of a method and the plot count from which a track is mature."""
    if classical_kind(method) is not None:
        return MahalanobisGate(estimator, params.kalman_gate_probability), params.young_track_plots
    if method == "radius":
        return None, np.iinfo(np.int64).max
    if method == "via":
        return PredictionGate(estimator, window_m), params.young_track_plots
    if method == "mia":
        return MonteCarloGate(estimator, params, np.random.default_rng(seed)), params.young_track_plots
    if method == "ae":
        if models.autoencoder is None:
            raise ValueError("the ae method needs the autoencoder model")
        return AutoencoderGate(models.autoencoder, models.runnable["autoencoder"]), params.young_track_plots_ae
    raise ValueError(f"association method {method!r}: must be radius, via, mia, ae, {ORACLE} or one of "
                     f"{list(CLASSICAL_METHODS)} (optionally with {GLOBAL_SUFFIX})")


def track_plots(features: np.ndarray, plot_ids: np.ndarray, method: str, window_m: float, models: Models,
                params: TrackerParams, seed: int | list[int] | None = None, radar: Radar | None = None
                ) -> dict[str, np.ndarray]:
    """Track one radar's plots. `features` rows are [t, x, y, z, r] (ECEF), sorted by time.
    `seed` seeds the MIA sampling (default: the tracker seed); `radar` is needed by the classical
    methods (and its rotation period by the `_gnn` ones). For `oracle`, pass only the target's plots.

    Returns one row per track update (a track's start counts as its first update), and the
    covariance of each updated position (NaN for the networks, which give none; for the classical
    methods a start's is its plot's measurement covariance, computed for all starts at once).
    """
    torch.set_num_threads(1)  # batches of a few windows: threads only add contention
    estimator = make_estimator(method, models, radar)
    gate, mature_from = make_gate(method, window_m, estimator, models, params, params.seed if seed is None else seed)
    live = LiveTracks()
    rows: dict[str, list] = {name: [] for name in (*UPDATE_COLUMNS, "position_covariance")}
    unknown = np.full((3, 3), np.nan)

    def record(index: int, plot_id: int, state: np.ndarray, association: str, error: float,
               covariance: np.ndarray = unknown) -> None:
        track = live.tracks[index]
        rows["track_id"].append(track.track_id)
        rows["time_unix_s"].append(state[0])
        rows["plot_id"].append(plot_id)
        rows["x_ecef_m"].append(state[1])
        rows["y_ecef_m"].append(state[2])
        rows["z_ecef_m"].append(state[3])
        rows["range_m"].append(state[4])
        rows["weight"].append(live.weight[index])
        rows["association"].append(association)
        rows["association_error"].append(error)
        rows["position_covariance"].append(covariance)

    def start(plot: np.ndarray, plot_id: int) -> None:
        index = live.start(plot, plot_id, params.weight_start, params.silence_s)
        record(index, plot_id, plot, "start", np.nan)

    def update(index: int, plot: np.ndarray, plot_id: int, error: float, predicted: np.ndarray | None,
               association: str) -> None:
        track = live.tracks[index]
        state = estimator.update(track, plot, predicted)
        live.associate(index, plot, plot_id, state, params)
        record(index, plot_id, state, association, error,
               estimator.position_covariance(track) if isinstance(estimator, KalmanEstimator) else unknown)

    if method.endswith(GLOBAL_SUFFIX):
        scans = np.floor((features[:, 0] - features[:1, 0]) / radar.scan_period_s).astype(np.int64)
        for members in np.split(np.arange(len(features)), np.flatnonzero(np.diff(scans)) + 1) if len(features) else []:
            _track_scan(live, features[members], plot_ids[members], gate, mature_from, window_m, params, start,
                        update, method)
    else:
        for plot, plot_id in zip(features, plot_ids):
            live.manage(plot[0], params)
            if method == ORACLE:
                winner = (int(np.flatnonzero(live.alive)[0]), 0.0, None, True) if len(live) else None
            else:
                winner = _associate(live, plot, gate, mature_from, window_m, params) if len(live) else None
            if winner is None:
                start(plot, int(plot_id))
                continue
            index, error, predicted, by_method = winner
            update(index, plot, int(plot_id), error, predicted, method if by_method else "radius")
    out = {name: np.asarray(values) for name, values in rows.items()}
    out["position_covariance"] = out["position_covariance"].reshape(-1, 3, 3)
    if isinstance(estimator, KalmanEstimator):
        starts = out["association"] == "start"
        positions = np.column_stack([out[f"{axis}_ecef_m"][starts] for axis in "xyz"])
        out["position_covariance"][starts] = baselines.measurement_covariance(positions, radar)
    return out


def _track_scan(live: LiveTracks, plots: np.ndarray, plot_ids: np.ndarray, gate: Callable, mature_from: int,
                window_m: float, params: TrackerParams, start: Callable, update: Callable, method: str) -> None:
    """Global nearest neighbour over one scan: score every plot against the tracks alive at the
    scan's start, assign by least summed normalised error, then update in time order (a track
    deleted by management before its plot's time leaves the plot to start a new track)."""
    live.manage(plots[0, 0], params)
    candidates = [_candidates(live, plot, gate, mature_from, window_m, params) for plot in plots]
    slots = np.unique(np.concatenate([near for near, *_ in candidates])) if candidates else np.empty(0, np.int64)
    assigned: dict[int, tuple[int, int, float, np.ndarray | None, bool]] = {}
    if len(slots):
        cost = np.full((len(plots), len(slots)), np.inf)
        for row, (near, errors, _, _) in enumerate(candidates):
            cost[row, np.searchsorted(slots, near)] = errors
        finite = np.isfinite(cost)
        rows, columns = linear_sum_assignment(np.where(finite, cost, UNASSIGNABLE))
        for row, column in zip(rows, columns):
            if finite[row, column]:
                near, errors, predictions, mature = candidates[row]
                at = int(np.searchsorted(near, slots[column]))
                predicted = None if predictions is None or np.isnan(predictions[at, 0]) else predictions[at]
                assigned[row] = (int(slots[column]), live.tracks[slots[column]].track_id, float(errors[at]),
                                 predicted, bool(mature[at]))
    for row, (plot, plot_id) in enumerate(zip(plots, plot_ids)):
        live.manage(plot[0], params)
        if row in assigned:
            index, track_id, error, predicted, by_method = assigned[row]
            track = live.tracks[index]
            if track is not None and track.track_id == track_id:
                update(index, plot, int(plot_id), error, predicted, method if by_method else "radius")
                continue
        start(plot, int(plot_id))


UNASSIGNABLE = 1e9  # stands for an infinite cost in the assignment; such pairs are dropped after it


def _candidates(live: LiveTracks, plot: np.ndarray, gate: Callable | None, mature_from: int, window_m: float,
                params: TrackerParams) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """The tracks within the pre-filter distance of a plot (sorted slots), their normalised errors
    (inf outside the gate), the method's predictions (NaN rows where none) and which are mature."""
    offset = live.last_state - plot[1:4]
    near = np.flatnonzero(np.einsum("ij,ij->i", offset, offset) < params.prefilter_m ** 2)
    if not len(near):  # most plots: clutter far from every track
        return near, np.empty(0), None, np.empty(0, dtype=bool)
    mature = live.plot_count[near] >= mature_from
    errors = np.full(len(near), np.inf)
    predictions: np.ndarray | None = None
    young = near[~mature]
    if len(young):
        errors[~mature] = radius_scores(live.last_plot[young], plot, window_m).errors
    if mature.any():
        scores = gate([live.tracks[j] for j in near[mature]], plot)
        errors[mature] = scores.errors
        if scores.predictions is not None:
            predictions = np.full((len(near), scores.predictions.shape[1]), np.nan)
            predictions[mature] = scores.predictions
    return near, errors, predictions, mature


def _associate(live: LiveTracks, plot: np.ndarray, gate: Callable | None, mature_from: int, window_m: float,
               params: TrackerParams) -> tuple[int, float, np.ndarray | None, bool] | None:
    """The winning track (index, normalised error, its prediction if computed, whether the method's
    gate rather than the young-track radius won) or None."""
    near, errors, predictions, mature = _candidates(live, plot, gate, mature_from, window_m, params)
    if not len(near):
        return None
    best = int(np.argmin(errors))
    if not np.isfinite(errors[best]):
        return None
    predicted = None if predictions is None or np.isnan(predictions[best, 0]) else predictions[best]
    return int(near[best]), float(errors[best]), predicted, bool(mature[best])
