"""Association methods of the neural tracker (thesis 4.5), each a small gate over candidate tracks.

A gate scores the candidate tracks of one plot in a single batch and returns, per track,
a *normalised* association error: the distance (or reconstruction error) divided by the
gate's size, infinite outside the gate. Normalising makes the errors of young tracks
(gated by the constant radius, in metres) and mature tracks (gated by a prediction window,
a variable window or an autoencoder threshold) comparable, which the thesis's rule "lowest
association error wins" needs but does not spell out.

- `radius`: distance from the track's last plot, within a constant radius.
- `via`: distance from the predicted position at the plot's time, within a constant window.
- `mia`: 100 samples around the track's last state, all predicted; the gate is centred on
  their mean with radius K * sigma, sigma the RMS distance of the samples' predictions from
  their mean, K = 20 - padded states (10 if none is padded).
- `ae`: the track's last 4 plots and the candidate through the autoencoder; the error is the
  sum of absolute differences, within the calibrated threshold.

A gate that predicts returns its predictions so the state update can reuse them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.inference import BatchNetwork
from pipeline.model_store import LoadedModel
from pipeline.params import TrackerParams
from pipeline.tracker.estimators import NetworkEstimator
from pipeline.tracker.tracks import Track


@dataclass
class Scores:
    errors: np.ndarray                 # normalised; inf outside the gate
    predictions: np.ndarray | None     # [t, x, y, z, r] per track at the plot's time, if computed


def radius_scores(last_plots: np.ndarray, plot: np.ndarray, radius: float) -> Scores:
    distance = np.linalg.norm(last_plots - plot[1:4], axis=1)
    return Scores(np.where(distance < radius, distance / radius, np.inf), None)


class PredictionGate:
    """VIA: a constant window around each track's prediction."""

    def __init__(self, estimator: NetworkEstimator, window_m: float) -> None:
        self.estimator, self.window = estimator, window_m

    def __call__(self, tracks: list[Track], plot: np.ndarray) -> Scores:
        predictions, _ = self.estimator.predict(tracks, np.full(len(tracks), plot[0]))
        distance = np.linalg.norm(predictions[:, 1:4] - plot[1:4], axis=1)
        return Scores(np.where(distance < self.window, distance / self.window, np.inf), predictions)


class MonteCarloGate:
    """MIA: a variable window from the spread of predictions of perturbed last states."""

    def __init__(self, estimator: NetworkEstimator, params: TrackerParams, rng: np.random.Generator) -> None:
        self.estimator, self.params, self.rng = estimator, params, rng

    def _samples(self, count: int) -> np.ndarray:
        """Offsets normal with sigma = radius / 3, pulled back into the ball of that radius."""
        offsets = self.rng.normal(0.0, self.params.mia_ball_radius_m / 3.0, size=(count, 3))
        norms = np.linalg.norm(offsets, axis=1, keepdims=True)
        return offsets * np.minimum(1.0, self.params.mia_ball_radius_m / np.maximum(norms, 1e-12))

    def __call__(self, tracks: list[Track], plot: np.ndarray) -> Scores:
        count = self.params.mia_samples
        windows, padded = self.estimator.state_windows(tracks, np.full(len(tracks), plot[0]))
        perturbed = np.repeat(windows, count, axis=0)
        perturbed[:, -1, 2:5] += self._samples(len(perturbed))
        predictions = self.estimator.predict_windows(perturbed).reshape(len(tracks), count, -1)
        mean = predictions.mean(axis=1)
        sigma = np.sqrt(((predictions[:, :, 1:4] - mean[:, None, 1:4]) ** 2).sum(axis=2).mean(axis=1))
        k = np.where(padded > 0, self.params.mia_k_padded_base - padded, self.params.mia_k_no_padding)
        radius = np.maximum(k * sigma, 1e-9)
        distance = np.linalg.norm(mean[:, 1:4] - plot[1:4], axis=1)
        return Scores(np.where(distance < radius, distance / radius, np.inf), mean)


class AutoencoderGate:
    """AE: accept a plot if the autoencoder reconstructs the track's last plots plus it well enough."""

    def __init__(self, autoencoder: LoadedModel, runnable: BatchNetwork) -> None:
        if "threshold" not in autoencoder.extras:
            raise ValueError("the autoencoder model has no calibrated threshold; retrain it with train_autoencoder")
        self.model, self.run, self.threshold = autoencoder, runnable, float(autoencoder.extras["threshold"])
        self.history = autoencoder.config.input_steps - 1

    def __call__(self, tracks: list[Track], plot: np.ndarray) -> Scores:
        windows = np.stack([np.vstack([*track.plots[-self.history:], plot]) for track in tracks])
        origin = self.model.scaler.origin(windows)
        scaled = self.model.scaler.transform(windows, origin)
        reconstructed = self.run(scaled)
        error = np.abs(reconstructed - scaled).sum(axis=(1, 2))
        return Scores(np.where(error <= self.threshold, error / self.threshold, np.inf), None)
