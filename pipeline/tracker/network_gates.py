"""The gates that run networks (thesis 4.5), `Gate`s of `pipeline.tracker.gate`:

- `MonteCarloGate` (`mia`): 100 samples around the track's last state, all predicted; the
  gate is centred on their mean with radius K * sigma, sigma the RMS distance of the samples'
  predictions from their mean, K = 20 - padded states (10 if none is padded). The mean is the
  prediction the update resumes from. A pair's samples are its own (`pipeline.tracker.draws`), so
  the gate is `pairwise`: a scan's pairs are predicted in one call.
- `AutoencoderGate` (`ae`): the track's last 4 plots and the candidate through the
  autoencoder; the error is the sum of absolute differences, within the calibrated threshold.

Both score every (track, plot) pair of a scan in one network call (`pairwise`). Neither uses the loop's shared prediction: MIA predicts its own samples, AE predicts nothing.
Each declares the latest plots of a track it reads (`latest_plots`, `pipeline.tracker.gate`):
MIA the latest one (its radar, through the estimator's state windows), AE its window.
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry import geodesy
from pipeline.learning.inference import BatchNetwork
from pipeline.learning.model_store import LoadedModel
from pipeline.params import MIA
from pipeline.tracker.estimator import Prediction
from pipeline.tracker.draws import PairDraws
from pipeline.tracker.gate import Scores, within
from pipeline.tracker.network_estimator import NetworkEstimator
from pipeline.tracker.tracks import LiveTracks


class MonteCarloGate:
    """MIA: a variable window from the spread of predictions of perturbed last states."""

    uses_prediction = False
    pairwise = True
    latest_plots = 1

    def __init__(self, estimator: NetworkEstimator, params: MIA, seed: int | list[int]) -> None:
        self.estimator, self.params, self.draws = estimator, params, PairDraws(seed)

    def _samples(self, position: np.ndarray, radar_ecef: np.ndarray, pairs: tuple[np.ndarray, np.ndarray],
                 count: int) -> np.ndarray:
        """`count` ECEF offsets of each state at `position` (K x 3), state by state (K * count x 3):
        normal with sigma = radius / 3, pulled back into the ball of that radius, each state's its own
        (`pairs`: the track ids and plot ids (K,) of the (track, plot) pairs). Drawn in the radial
        frame at each state (cross-range, down-range, up; `geodesy.radial_rotations`, one per state),
        so the same flight relative to the radar draws the same samples at any site."""
        offsets = self.draws.normals(*pairs, count) * (self.params.ball_radius_m / 3.0)
        norms = np.linalg.norm(offsets, axis=1, keepdims=True)
        local = offsets * np.minimum(1.0, self.params.ball_radius_m / np.maximum(norms, 1e-12))
        rotations = np.repeat(geodesy.radial_rotations(position, radar_ecef), count, axis=0)
        return np.einsum("nj,nji->ni", local, rotations)

    def __call__(self, tracks: LiveTracks, slots: np.ndarray, row: int | np.ndarray, prediction: Prediction | None
                 ) -> Scores:
        count = self.params.samples
        windows, padded, radar = self.estimator.state_windows(tracks, slots, tracks.plots.time[row])
        pairs = (np.array([tracks.tracks[slot].track_id for slot in slots], dtype=np.int64),
                 np.broadcast_to(tracks.plots.plot_id[row], slots.shape))
        perturbed = np.repeat(windows, count, axis=0)
        perturbed[:, -1, 2:5] += self._samples(windows[:, -1, 2:5], radar, pairs, count)
        predictions = self.estimator.predict_windows(perturbed, np.repeat(radar, count, axis=0)).reshape(
            len(slots), count, -1)
        mean = predictions.mean(axis=1)
        sigma = np.sqrt(((predictions[:, :, 1:4] - mean[:, None, 1:4]) ** 2).sum(axis=2).mean(axis=1))
        k = np.where(padded > 0, self.params.k_padded_base - padded, self.params.k_no_padding)
        radius = np.maximum(k * sigma, 1e-9)
        distance = np.linalg.norm(mean[:, 1:4] - tracks.plots.position[row], axis=1)
        return Scores(within(distance, radius), Prediction(mean[:, 1:4], None, mean))


class AutoencoderGate:
    """AE: accept a plot if the autoencoder reconstructs the track's last plots plus it well enough."""

    uses_prediction = False
    pairwise = True

    def __init__(self, autoencoder: LoadedModel, runnable: BatchNetwork) -> None:
        if "threshold" not in autoencoder.extras:
            raise ValueError("the autoencoder model has no calibrated threshold; retrain it with train_autoencoder")
        self.model, self.run, self.threshold = autoencoder, runnable, float(autoencoder.extras["threshold"])
        self.latest_plots = autoencoder.config.input_steps - 1  # the plots before the candidate

    def __call__(self, tracks: LiveTracks, slots: np.ndarray, row: int | np.ndarray, prediction: Prediction | None
                 ) -> Scores:
        features = tracks.plots.features
        rows = np.array([[*tracks.tracks[slot].rows[-self.latest_plots:], plot]
                         for slot, plot in zip(slots, np.broadcast_to(row, slots.shape))])
        windows = features[rows]
        origin = self.model.scaler.origin(windows, tracks.plots.radar_position[rows[:, 0]])
        scaled = self.model.scaler.transform(windows, origin)
        reconstructed = self.run(scaled)
        error = np.abs(reconstructed - scaled).sum(axis=(1, 2))
        return Scores(np.where(error <= self.threshold, error / self.threshold, np.inf), None)
