"""Classical estimators and gates for the same tracker: tuned CV, CA or IMM filters (filterpy)
with chi-square gating on the Mahalanobis distance.

They plug into the tracking loop exactly where the networks do (same track management,
pre-filter and deletion), so the comparison with the neural tracker is on identical
plots, rules and metrics. Each track keeps its own filter in ECEF (see
`pipeline.classical_filters`), started at its first plot with the velocity unknown up to
the tuned spread. Measurements carry the converted-measurement covariance of the radar's
range, azimuth and altitude errors (`pipeline.baselines.measurement_covariance`).

Gating scores all candidate tracks of a plot in one NumPy batch: d^2 = y' S^-1 y with
S = H P H' + R, inside the gate when d^2 is below the chi-square quantile of
`kalman_gate_probability` (3 degrees of freedom); the normalised error is d^2 / quantile.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from pipeline import baselines, classical_filters, geodesy
from pipeline.classical_filters import FilterSettings
from pipeline.params import Radar
from pipeline.tracker.association import Scores
from pipeline.tracker.tracks import Track


class KalmanEstimator:
    """A classical filter per track, with the network estimator's interface."""

    def __init__(self, radar: Radar, settings: FilterSettings) -> None:
        self.radar, self.settings = radar, settings
        self.site = geodesy.radar_site_ecef(radar)
        self.measured = settings.measured

    def measurement_covariance(self, position: np.ndarray) -> np.ndarray:
        return baselines.measurement_covariance(position[None], self.radar)[0]

    def _filter(self, track: Track) -> object:
        """The track's filter, started at its first plot when first needed (clutter tracks never are)."""
        if track.estimate is None:
            first = track.plots[0]
            track.estimate = (classical_filters.start_filter(self.settings, first[1:4],
                                                             self.measurement_covariance(first[1:4])), first[0])
        return track.estimate[0]

    def predicted(self, tracks: list[Track], time: float) -> tuple[np.ndarray, np.ndarray]:
        """Predicted states (N x n) and covariances (N x n x n) at `time`, the filters unchanged."""
        pairs = [classical_filters.predicted_gaussian(self._filter(track), self.settings, time - track.estimate[1])
                 for track in tracks]
        return np.array([state for state, _ in pairs]), np.array([covariance for _, covariance in pairs])

    def as_state(self, time: float, position: np.ndarray) -> np.ndarray:
        return np.array([time, *position, np.linalg.norm(position - self.site)])

    def predict(self, tracks: list[Track], times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted [t, x, y, z, r] of each track at its time (and no padding, for the interface)."""
        out = np.array([self.as_state(time, self.predicted([track], time)[0][0][self.measured])
                        for track, time in zip(tracks, times)])
        return out, np.zeros(len(tracks), dtype=np.int64)

    def update(self, track: Track, plot: np.ndarray, predicted: np.ndarray) -> np.ndarray:
        """Predict the track's filter to the plot and update it with the plot."""
        estimator = self._filter(track)
        classical_filters.advance(estimator, self.settings, plot[0] - track.estimate[1])
        classical_filters.update(estimator, plot[1:4], self.measurement_covariance(plot[1:4]))
        track.estimate = (estimator, plot[0])
        return self.as_state(plot[0], estimator.x[self.measured])

    def position_covariance(self, track: Track) -> np.ndarray:
        """The covariance of the track's last position estimate (for consistency metrics)."""
        if track.estimate is None:
            return self.measurement_covariance(track.plots[-1][1:4])
        return track.estimate[0].P[np.ix_(self.measured, self.measured)]


class MahalanobisGate:
    """Chi-square gate on the Mahalanobis distance between the plot and each track's prediction."""

    def __init__(self, estimator: KalmanEstimator, gate_probability: float) -> None:
        self.estimator = estimator
        self.threshold = float(chi2.ppf(gate_probability, df=3))

    def __call__(self, tracks: list[Track], plot: np.ndarray) -> Scores:
        states, covariances = self.estimator.predicted(tracks, plot[0])
        measured = self.estimator.measured
        innovation = plot[1:4] - states[:, measured]
        residual_covariance = covariances[:, measured][:, :, measured] + \
            self.estimator.measurement_covariance(plot[1:4])
        distance = np.einsum("ni,ni->n", innovation,
                             np.linalg.solve(residual_covariance, innovation[:, :, None])[:, :, 0])
        predictions = np.array([self.estimator.as_state(plot[0], s[measured]) for s in states])
        return Scores(np.where(distance < self.threshold, distance / self.threshold, np.inf), predictions)
