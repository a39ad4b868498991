"""Hold-out metrics of the networks, in metres, against simple and classical references.

The hold-out segments are windowed here exactly as the training material was, but not
balanced, so errors are weighted as manoeuvres naturally occur (thesis 4.2.4). Network
outputs go back to metres through the same scaler's inverse.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import torch

from pipeline.filters import baselines
from pipeline.geometry import geodesy
from pipeline.learning import windows
from pipeline.learning.model_store import LoadedModel
from pipeline.learning.scaling import PLOT_FEATURES, STATE_FEATURES, WindowScaler
from pipeline.params import Radar

MAX_SPEED_MPS = 400.0  # the thesis's assumption; the Kalman filters' initial velocity spread
NETWORK_BATCH = 8192

# The thesis's hold-out results (spec section 6), for the report.
THESIS = {"raw_plot_error_m": 218.8, "filter_error_m": 225.1, "filter_range_error_m": 107.2,
          "linear_extrapolation_error_m": 478.8, "predictor_error_m": 182.0, "predictor_range_error_m": 317.1}


@dataclass(frozen=True)
class KalmanReference:
    acceleration_std_mps2: float
    truth_sigma_m: float  # measurement sigma when a Kalman filter is fed true states


def holdout_plots(table: pa.Table, radar: Radar) -> windows.TargetPlots:
    """The hold-out's target plots, all measured by `radar`."""
    column = lambda name: table.column(name).to_numpy()  # noqa: E731
    return windows.TargetPlots(
        scenario_id=column("scenario_id"), plot_id=column("plot_id"), segment_id=column("segment_id"),
        time=column("time_unix_s"), position=np.column_stack([column(f"{a}_ecef_m") for a in "xyz"]),
        range_m=column("range_m"), true_position=np.column_stack([column(f"true_{a}_ecef_m") for a in "xyz"]),
        true_range_m=column("true_range_m"),
        radar_position=np.tile(geodesy.radar_site_ecef(radar), (table.num_rows, 1)))


def run_network(model: LoadedModel, scaled: np.ndarray) -> np.ndarray:
    """Forward pass in large batches (no gradients)."""
    outputs = [model.predict(torch.as_tensor(scaled[i:i + NETWORK_BATCH], dtype=torch.float32)).numpy()
               for i in range(0, len(scaled), NETWORK_BATCH)]
    return np.concatenate(outputs) if outputs else np.empty((0,))


def output_scaler(scaler: WindowScaler) -> WindowScaler:
    """The scaler of the networks' outputs: [t, x, y, z, r] with the input scaler's scale values."""
    scale = dict(zip(scaler.features, scaler.scale))
    return WindowScaler(PLOT_FEATURES, tuple(scale[name] for name in PLOT_FEATURES), scaler.frame, scaler.centre_range)


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b, axis=-1).mean()) if len(a) else float("nan")


def evaluate_filter(model: LoadedModel, plots: windows.TargetPlots, radar: Radar, kalman: KalmanReference) -> dict:
    """Error of the filter's estimate of the last plot of each window, against the raw plot and a CV Kalman filter."""
    length = model.config.input_steps
    starts = windows.window_starts(plots.segment_id, length)
    raw = windows.gather(plots.plot_features(), starts, length)
    truth = windows.gather(plots.true_features(), starts, length)[:, -1]
    origin = model.scaler.origin(raw, plots.radar_position[starts])
    outputs = run_network(model, model.scaler.transform(raw, origin))
    estimate = output_scaler(model.scaler).inverse(outputs, origin)[:, -1]
    positions = raw[:, :, 1:4]
    covariances = geodesy.measurement_covariance(positions.reshape(-1, 3), radar).reshape(len(raw), length, 3, 3)
    kalman_last = baselines.kalman_filtered_last(raw[:, :, 0], positions, covariances,
                                                 kalman.acceleration_std_mps2, MAX_SPEED_MPS)
    return {
        "holdout_windows": int(len(raw)),
        "filter_error_m": _distance(estimate[:, 1:4], truth[:, 1:4]),
        "raw_plot_error_m": _distance(raw[:, -1, 1:4], truth[:, 1:4]),
        "kalman_cv_error_m": _distance(kalman_last, truth[:, 1:4]),
        "filter_range_error_m": float(np.abs(estimate[:, 4] - truth[:, 4]).mean()) if len(raw) else float("nan"),
    }


def evaluate_predictor(model: LoadedModel, plots: windows.TargetPlots, kalman: KalmanReference) -> dict:
    """Error of the predicted next state against linear extrapolation and a CV Kalman prediction."""
    inputs = model.config.input_steps
    starts = windows.window_starts(plots.segment_id, inputs + 1)
    states = windows.state_features(plots.true_features(), starts, inputs + 1)
    given, truth = states[:, :inputs], states[:, -1]
    origin = model.scaler.origin(given, plots.radar_position[starts])
    outputs = run_network(model, model.scaler.transform(given, origin))
    predicted = output_scaler(model.scaler).inverse(outputs, origin)[:, -1]
    position = [STATE_FEATURES.index(a) for a in "xyz"]
    times, target_times = given[:, :, 0], truth[:, 0]
    sigma = kalman.truth_sigma_m ** 2 * np.eye(3)
    covariances = np.broadcast_to(sigma, (*given.shape[:2], 3, 3))
    kalman_prediction = baselines.kalman_predicted(times, given[:, :, position], covariances, target_times,
                                                   kalman.acceleration_std_mps2, MAX_SPEED_MPS)
    return {
        "holdout_windows": int(len(given)),
        "predictor_error_m": _distance(predicted[:, 1:4], truth[:, position]),
        "linear_extrapolation_error_m": _distance(
            baselines.linear_extrapolation(times, given[:, :, position], target_times), truth[:, position]),
        "kalman_cv_prediction_error_m": _distance(kalman_prediction, truth[:, position]),
        "predictor_range_error_m": float(np.abs(predicted[:, 4] - truth[:, -1]).mean()) if len(given)
        else float("nan"),
    }


def reconstruction_errors(model: LoadedModel, scaled: np.ndarray) -> np.ndarray:
    """The autoencoder's association score: sum of absolute differences over the window."""
    return np.abs(run_network(model, scaled) - scaled).sum(axis=(1, 2)) if len(scaled) else np.empty(0)


def autoencoder_threshold(errors: np.ndarray, labels: np.ndarray) -> tuple[float, float]:
    """The thesis's rule: the smallest threshold that accepts every target window (accept if
    error <= threshold), and the share of false windows it rejects."""
    if not labels.any():
        raise ValueError("autoencoder calibration has no target windows: cannot choose a threshold")
    threshold = float(errors[labels].max())
    false = errors[~labels]
    return threshold, float((false > threshold).mean()) if len(false) else float("nan")


def evaluate_autoencoder(errors: np.ndarray, labels: np.ndarray, threshold: float, rejected: float) -> dict:
    return {
        "calibration_windows": int(len(labels)),
        "reconstruction_error_target": float(errors[labels].mean()) if labels.any() else float("nan"),
        "reconstruction_error_false": float(errors[~labels].mean()) if (~labels).any() else float("nan"),
        "threshold": threshold,
        "false_windows_rejected": rejected,
    }
