"""A classical estimator and gate for the same tracker: constant-velocity Kalman filter (filterpy)
with chi-square gating on the Mahalanobis distance.

It plugs into the tracking loop exactly where the networks do (same track management,
pre-filter and deletion), so the comparison with the neural tracker is on identical
plots, rules and metrics. Each track keeps its own filterpy `KalmanFilter` in ECEF, state
[x, vx, y, vy, z, vz], started at its first plot with the velocity unknown up to
`max_speed`. Measurements carry the converted-measurement covariance of the radar's
range, azimuth and altitude errors (`pipeline.baselines.measurement_covariance`). The
process noise is white acceleration (`kalman_acceleration_std_mps2`), untuned here.

Gating scores all candidate tracks of a plot in one NumPy batch: d^2 = y' S^-1 y with
S = H P H' + R, inside the gate when d^2 is below the chi-square quantile of
`kalman_gate_probability` (3 degrees of freedom); the normalised error is d^2 / quantile.
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import KalmanFilter
from scipy.stats import chi2

from pipeline import baselines, geodesy
from pipeline.params import Radar, TrackerParams
from pipeline.tracker.association import Scores
from pipeline.tracker.tracks import Track

MEASURED = baselines.MEASURED


class KalmanEstimator:
    """Constant-velocity Kalman filters per track, with the network estimator's interface."""

    def __init__(self, radar: Radar, params: TrackerParams) -> None:
        self.radar, self.params = radar, params
        self.site = geodesy.radar_site_ecef(radar)

    def _filter(self, track: Track) -> KalmanFilter:
        if track.estimate is None:
            first = track.plots[0]
            covariance = baselines.measurement_covariance(first[None, 1:4], self.radar)[0]
            track.estimate = (baselines.constant_velocity_filter(first[1:4], covariance,
                                                                 self.params.kalman_max_speed_mps), first[0])
        return track.estimate[0]

    def predicted(self, tracks: list[Track], time: float) -> tuple[np.ndarray, np.ndarray]:
        """Predicted states (N x 6) and covariances (N x 6 x 6) at `time`, without changing the filters."""
        states, covariances = [], []
        for track in tracks:
            kf = self._filter(track)
            transition, noise = baselines.constant_velocity_model(time - track.estimate[1],
                                                                  self.params.kalman_acceleration_std_mps2)
            states.append(transition @ kf.x)
            covariances.append(transition @ kf.P @ transition.T + noise)
        return np.array(states), np.array(covariances)

    def as_state(self, time: float, position: np.ndarray) -> np.ndarray:
        return np.array([time, *position, np.linalg.norm(position - self.site)])

    def predict(self, tracks: list[Track], times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted [t, x, y, z, r] of each track at its time (and no padding, for the interface)."""
        out = np.array([self.as_state(time, self.predicted([track], time)[0][0][MEASURED])
                        for track, time in zip(tracks, times)])
        return out, np.zeros(len(tracks), dtype=np.int64)

    def update(self, track: Track, plot: np.ndarray, predicted: np.ndarray) -> np.ndarray:
        """Predict the track's filter to the plot and update it with the plot."""
        kf = self._filter(track)
        kf.F, kf.Q = baselines.constant_velocity_model(plot[0] - track.estimate[1],
                                                       self.params.kalman_acceleration_std_mps2)
        kf.predict()
        kf.update(plot[1:4], R=baselines.measurement_covariance(plot[None, 1:4], self.radar)[0])
        track.estimate = (kf, plot[0])
        return self.as_state(plot[0], kf.x[MEASURED])


class MahalanobisGate:
    """Chi-square gate on the Mahalanobis distance between the plot and each track's prediction."""

    def __init__(self, estimator: KalmanEstimator, gate_probability: float) -> None:
        self.estimator = estimator
        self.threshold = float(chi2.ppf(gate_probability, df=3))

    def __call__(self, tracks: list[Track], plot: np.ndarray) -> Scores:
        states, covariances = self.estimator.predicted(tracks, plot[0])
        innovation = plot[1:4] - states[:, MEASURED]
        measurement = baselines.measurement_covariance(plot[None, 1:4], self.estimator.radar)[0]
        residual_covariance = covariances[:, MEASURED][:, :, MEASURED] + measurement
        distance = np.einsum("ni,ni->n", innovation, np.linalg.solve(residual_covariance, innovation[:, :, None])[:, :, 0])
        predictions = np.array([self.estimator.as_state(plot[0], s[MEASURED]) for s in states])
        return Scores(np.where(distance < self.threshold, distance / self.threshold, np.inf), predictions)
