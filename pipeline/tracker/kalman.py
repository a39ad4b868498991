"""Classical estimators and gates for the same tracker: tuned CV, CA or IMM filters with
chi-square gating on the Mahalanobis distance.

They plug into the tracking loop exactly where the networks do (same track management,
pre-filter and deletion), so the comparison with the neural tracker is on identical
plots, rules and metrics. Each track keeps its own filter in ECEF (see
`pipeline.classical_filters`), started at its first plot with the velocity unknown up to
the tuned spread. Measurements carry the converted-measurement covariance of the radar's
range, azimuth and altitude errors (`pipeline.baselines.measurement_covariance`).

A track's filter is NumPy arrays stepped with filterpy's equations (`KalmanFilter`,
`IMMEstimator`: Joseph-form update, Gaussian likelihoods, here in log space), which the tests
check against filterpy's objects step by step. filterpy's objects gave the same numbers but
cost about 1 ms per IMM step in Python; here a track keeps what its next prediction starts
from (for the IMM the mixed models and predicted mode probabilities, computed once per
update), the transition and process noise are made once per distinct time step (plot times
are quantised), and the gate predicts all candidate tracks of a plot in one batch.
`pipeline.batch_filters` holds the same equations laid out for tuning, many long sequences
stepped side by side.

Gating: d^2 = y' S^-1 y with S = H P H' + R, inside the gate when d^2 is below the chi-square
quantile of `kalman_gate_probability` (3 degrees of freedom); the normalised error is
d^2 / quantile.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from pipeline import baselines, geodesy, motion_models
from pipeline.classical_filters import FilterSettings
from pipeline.params import Radar
from pipeline.tracker.association import Scores
from pipeline.tracker.tracks import Track

LOG_NORMALISER = 3 * np.log(2 * np.pi)  # of a 3-dimensional Gaussian density


@dataclass
class TrackFilter:
    """One track's filter, as what its next prediction starts from: each of its M motion models'
    state x (M, n) and covariance P (M, n, n) and the predicted mode probabilities cbar (M,) (the
    IMM's mixed initial conditions; a single Kalman filter's posterior and [1]); the time it is
    at (s); and the covariance (3 x 3, m^2) of the track's position estimate, for the
    consistency metrics."""

    x: np.ndarray
    P: np.ndarray
    cbar: np.ndarray
    time: float
    position_covariance: np.ndarray


def mixed(settings: FilterSettings, x: np.ndarray, P: np.ndarray, mu: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IMM mixing of one track's posterior (x (M, n), P (M, n, n), mode probabilities mu (M,)):
    each model's starting state and covariance and the predicted mode probabilities, as
    `IMMEstimator` computes them after an update. A single filter starts from its posterior."""
    if settings.kind != "imm":
        return x, P, mu
    transition = settings.transition_probabilities()
    cbar = mu @ transition
    omega = transition * mu[:, None] / cbar[None, :]                  # omega[i, j]: model i in model j's start
    start = omega.T @ x                                               # (j, n)
    offset = x[None, :, :] - start[:, None, :]                        # (j, i, n)
    spread = np.einsum("ij,jinm->jnm", omega, P[None] + offset[..., :, None] * offset[..., None, :])
    return start, spread, cbar


def combined_positions(mu: np.ndarray, x: np.ndarray, P: np.ndarray, measured: list[int]
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The mode-weighted positions (..., 3) and their covariances (..., 3, 3) of models' states
    x (..., M, n) and covariances P (..., M, n, n) with probabilities mu (..., M)."""
    positions = x[..., measured]
    mean = np.einsum("...m,...mk->...k", mu, positions)
    offset = positions - mean[..., None, :]
    spread = P[..., measured, :][..., measured] + offset[..., :, None] * offset[..., None, :]
    return mean, np.einsum("...m,...mkl->...kl", mu, spread)


class KalmanEstimator:
    """A classical filter per track, with the network estimator's interface."""

    def __init__(self, radar: Radar, settings: FilterSettings) -> None:
        self.radar, self.settings = radar, settings
        self.site = geodesy.radar_site_ecef(radar)
        self.measured = settings.measured
        self.H = motion_models.measurement_matrix(settings.models[0])
        self._motions: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._last_covariance: tuple[bytes, np.ndarray] = (b"", np.empty((3, 3)))

    def measurement_covariance(self, position: np.ndarray) -> np.ndarray:
        """Converted-measurement covariance (3 x 3, ECEF, m^2) of a plot at `position` (ECEF, m).
        The last one is kept, since gating a plot and updating a track with it ask for the same."""
        key = position.tobytes()
        if key != self._last_covariance[0]:
            self._last_covariance = (key, baselines.measurement_covariance(position[None], self.radar)[0])
        return self._last_covariance[1]

    def motion(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Each model's transition F and process noise Q (M, n, n each) over dt seconds, made once."""
        found = self._motions.get(dt)
        if found is None:
            settings = self.settings
            found = self._motions[dt] = (
                np.stack([motion_models.transition(model, dt) for model in settings.models]),
                np.stack([motion_models.process_noise(model, dt, noise)
                          for model, noise in zip(settings.models, settings.noise_std)]))
        return found

    def _filter(self, track: Track) -> TrackFilter:
        """The track's filter, started at its first plot when first needed (clutter tracks never are)."""
        if track.estimate is None:
            first, settings = track.plots[0], self.settings
            covariance = self.measurement_covariance(first[1:4])
            pairs = [motion_models.initial_state(model, first[1:4], covariance, settings.velocity_std_mps,
                                                 settings.acceleration_std_mps2) for model in settings.models]
            probabilities = settings.initial_probabilities() if settings.kind == "imm" else np.ones(1)
            track.estimate = TrackFilter(*mixed(settings, np.stack([x for x, _ in pairs]),
                                                np.stack([P for _, P in pairs]), probabilities), first[0], covariance)
        return track.estimate

    def predicted_positions(self, tracks: list[Track], time: float) -> tuple[np.ndarray, np.ndarray]:
        """Predicted positions (N x 3, ECEF m) and their covariances (N x 3 x 3) at `time`, the
        filters unchanged: for the IMM its own predicted density, the models' predictions mixed
        with the predicted mode probabilities. All tracks in one batch."""
        filters = [self._filter(track) for track in tracks]
        x = np.stack([f.x for f in filters])                          # (N, M, n)
        P = np.stack([f.P for f in filters])
        motions = [self.motion(time - f.time) for f in filters]
        F = np.stack([F for F, _ in motions])                         # (N, M, n, n)
        Q = np.stack([Q for _, Q in motions])
        return combined_positions(np.stack([f.cbar for f in filters]), (F @ x[..., None])[..., 0],
                                  F @ P @ np.swapaxes(F, -1, -2) + Q, self.measured)

    def as_states(self, time: float, positions: np.ndarray) -> np.ndarray:
        """Rows [t, x, y, z, r] (N x 5) of ECEF positions (N x 3) at one time, r the range to the radar."""
        return np.column_stack([np.full(len(positions), time), positions,
                                np.linalg.norm(positions - self.site, axis=1)])

    def update(self, track: Track, plot: np.ndarray, predicted: np.ndarray | None) -> np.ndarray:
        """Predict the track's filter to the plot and update it with the plot; the new [t, x, y, z, r].
        (`predicted`, the gate's prediction, is not needed: the filter predicts itself.)"""
        current, settings, measured = self._filter(track), self.settings, self.measured
        F, Q = self.motion(plot[0] - current.time)
        x = (F @ current.x[..., None])[..., 0]                        # (M, n)
        P = F @ current.P @ np.swapaxes(F, -1, -2) + Q
        R = self.measurement_covariance(plot[1:4])
        innovation = plot[1:4] - x[:, measured]                       # (M, 3)
        S = P[:, measured][:, :, measured] + R
        gain = np.swapaxes(np.linalg.solve(S, P[:, measured]), -1, -2)  # P H' S^-1: (M, n, 3)
        x = x + (gain @ innovation[..., None])[..., 0]
        joseph = np.eye(x.shape[1]) - gain @ self.H
        P = joseph @ P @ np.swapaxes(joseph, -1, -2) + gain @ R @ np.swapaxes(gain, -1, -2)
        mu = current.cbar
        if settings.kind == "imm":
            distance = np.einsum("mk,mk->m", innovation, np.linalg.solve(S, innovation[..., None])[..., 0])
            log_weight = np.log(current.cbar) - 0.5 * (distance + np.linalg.slogdet(S)[1] + LOG_NORMALISER)
            weight = np.exp(log_weight - log_weight.max())
            mu = weight / weight.sum()
        position, covariance = combined_positions(mu, x, P, measured)
        track.estimate = TrackFilter(*mixed(settings, x, P, mu), plot[0], covariance)
        return self.as_states(plot[0], position[None])[0]

    def position_covariance(self, track: Track) -> np.ndarray:
        """The covariance (3 x 3, m^2) of the track's position estimate after its last update."""
        return track.estimate.position_covariance


class MahalanobisGate:
    """Chi-square gate on the Mahalanobis distance between the plot and each track's prediction."""

    def __init__(self, estimator: KalmanEstimator, gate_probability: float) -> None:
        self.estimator = estimator
        self.threshold = float(chi2.ppf(gate_probability, df=3))

    def __call__(self, tracks: list[Track], plot: np.ndarray) -> Scores:
        positions, covariances = self.estimator.predicted_positions(tracks, plot[0])
        innovation = plot[1:4] - positions
        residual_covariance = covariances + self.estimator.measurement_covariance(plot[1:4])
        distance = np.einsum("ni,ni->n", innovation,
                             np.linalg.solve(residual_covariance, innovation[:, :, None])[:, :, 0])
        return Scores(np.where(distance < self.threshold, distance / self.threshold, np.inf),
                      self.estimator.as_states(plot[0], positions))
