"""The tracking loop: plots one at a time in time order (thesis 4.4-4.6).

For each plot: track management first (silent tracks lose weight, some are deleted), then
association against the tracks within the pre-filter distance (young tracks by the
constant radius, the others by the chosen method), lowest normalised error wins; the
winner's state is updated, otherwise the plot starts a new track.

The loop works in ECEF with the radar only entering through each plot's range, so it runs
for a radar anywhere on Earth.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from pipeline.params import Radar, TrackerParams
from pipeline.tracker.association import (AutoencoderGate, MonteCarloGate, PredictionGate, Scores,
                                           radius_scores)
from pipeline.tracker.estimators import NetworkEstimator
from pipeline.tracker.kalman import KalmanEstimator, MahalanobisGate
from pipeline.tracker.models import Models
from pipeline.tracker.tracks import LiveTracks, Track

UPDATE_COLUMNS = ("track_id", "time_unix_s", "plot_id", "x_ecef_m", "y_ecef_m", "z_ecef_m", "range_m", "weight",
                  "association", "association_error")


def make_estimator(method: str, models: Models, radar: Radar | None, params: TrackerParams
                   ) -> NetworkEstimator | KalmanEstimator:
    """The state estimator a method runs with: the networks, or a Kalman filter per track."""
    if method == "kalman_cv":
        if radar is None:
            raise ValueError("the kalman_cv method needs the radar (for the measurement covariance)")
        return KalmanEstimator(radar, params)
    return NetworkEstimator(models)


def make_gate(method: str, window_m: float, estimator: NetworkEstimator | KalmanEstimator, models: Models,
              params: TrackerParams, seed: int | list[int]
              ) -> tuple[Callable[[list[Track], np.ndarray], Scores] | None, int]:
    """The mature-track gate of a method and the plot count from which a track is mature."""
    if method == "kalman_cv":
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
    raise ValueError(f"association method {method!r}: must be radius, via, mia, ae or kalman_cv")


def track_plots(features: np.ndarray, plot_ids: np.ndarray, method: str, window_m: float, models: Models,
                params: TrackerParams, seed: int | list[int] | None = None, radar: Radar | None = None
                ) -> dict[str, np.ndarray]:
    """Track one radar's plots. `features` rows are [t, x, y, z, r] (ECEF), sorted by time.
    `seed` seeds the MIA sampling (default: the tracker seed); `radar` is needed by kalman_cv.

    Returns one row per track update (a track's start counts as its first update).
    """
    torch.set_num_threads(1)  # batches of a few windows: threads only add contention
    estimator = make_estimator(method, models, radar, params)
    gate, mature_from = make_gate(method, window_m, estimator, models, params,
                                  params.seed if seed is None else seed)
    live = LiveTracks()
    rows: dict[str, list] = {name: [] for name in UPDATE_COLUMNS}

    def record(index: int, plot_id: int, state: np.ndarray, association: str, error: float) -> None:
        rows["track_id"].append(live.tracks[index].track_id)
        rows["time_unix_s"].append(state[0])
        rows["plot_id"].append(plot_id)
        rows["x_ecef_m"].append(state[1])
        rows["y_ecef_m"].append(state[2])
        rows["z_ecef_m"].append(state[3])
        rows["range_m"].append(state[4])
        rows["weight"].append(live.weight[index])
        rows["association"].append(association)
        rows["association_error"].append(error)

    for plot, plot_id in zip(features, plot_ids):
        live.manage(plot[0], params)
        winner = _associate(live, plot, gate, mature_from, window_m, params) if len(live) else None
        if winner is None:
            index = live.start(plot, int(plot_id), params.weight_start, params.silence_s)
            record(index, int(plot_id), plot, "start", np.nan)
            continue
        index, error, predicted, by_method = winner
        track = live.tracks[index]
        if predicted is None:
            predicted = estimator.predict([track], np.array([plot[0]]))[0][0]
        state = estimator.update(track, plot, predicted)
        live.associate(index, plot, int(plot_id), state, params)
        record(index, int(plot_id), state, method if by_method else "radius", error)
    return {name: np.asarray(values) for name, values in rows.items()}


def _associate(live: LiveTracks, plot: np.ndarray, gate: Callable | None, mature_from: int, window_m: float,
               params: TrackerParams) -> tuple[int, float, np.ndarray | None, bool] | None:
    """The winning track (index, normalised error, its prediction if computed, whether the method's
    gate rather than the young-track radius won) or None."""
    offset = live.last_state - plot[1:4]
    near = np.flatnonzero(np.einsum("ij,ij->i", offset, offset) < params.prefilter_m ** 2)
    if not len(near):
        return None
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
    best = int(np.argmin(errors))
    if not np.isfinite(errors[best]):
        return None
    predicted = None if predictions is None or np.isnan(predictions[best, 0]) else predictions[best]
    return int(near[best]), float(errors[best]), predicted, bool(mature[best])
