"""The classical estimator: a tuned CV, CA or IMM filter per track (`pipeline.classical_filters`),
stepped by the one Kalman core (`pipeline.batch_filters`), an `Estimator`.

Every live track's filter sits in arrays by slot: each motion model's state x (S, M, n) and
covariance P (S, M, n, n), the mode probabilities mu (S, M) and the time it is at (S,). What
is stored is what the next prediction starts from: after an update the IMM's mixed models and
predicted mode probabilities (`batch_filters.mixed`), a single filter's posterior. A track's
filter is started at its first plot, with the velocity unknown up to the tuned spread, when
the track is first predicted (clutter tracks, most of them, never are). The filters run in
ECEF: with the same noise on every axis this is the same as a local east-north-up frame
(`pipeline.motion_models`).

`predict` moves the candidate tracks' filters to the plot's time in one batch (F and Q made
once per distinct time step, plot times being quantised) and gives the combined position and
its covariance (the IMM's own predicted density, mixed with the predicted mode probabilities);
`update` resumes from that prediction's state with the plot's own measurement covariance (its
radar's) and stores the result.
"""

from __future__ import annotations

import functools

import numpy as np

from pipeline import batch_filters, motion_models
from pipeline.batch_filters import BatchState
from pipeline.classical_filters import FilterSettings
from pipeline.tracker.estimator import Prediction
from pipeline.tracker.tracks import LiveTracks

MOTION_CACHE = 4096  # F and Q kept for this many time steps: quantised plot times (1/128 s) repeat a few
                     # hundred steps; unquantised times would otherwise grow the cache with the recording


class KalmanEstimator:
    """One tuned classical filter per live track."""

    gives_covariance = True
    pairwise = True
    latest_plots = 0  # a track's first plot starts its filter; the filter keeps the rest

    def __init__(self, settings: FilterSettings, capacity: int = 64) -> None:
        self.settings = settings
        models, size = len(settings.models), motion_models.state_size(settings.models[0])
        self.x = np.zeros((capacity, models, size))
        self.P = np.zeros((capacity, models, size, size))
        self.mu = np.zeros((capacity, models))
        self.time = np.zeros(capacity)
        self.started = np.zeros(capacity, dtype=bool)
        self.motion = functools.lru_cache(maxsize=MOTION_CACHE)(self._motion)

    def _grow(self, capacity: int) -> None:
        extra = capacity - len(self.time)
        self.x = np.concatenate([self.x, np.zeros((extra, *self.x.shape[1:]))])
        self.P = np.concatenate([self.P, np.zeros((extra, *self.P.shape[1:]))])
        self.mu = np.concatenate([self.mu, np.zeros((extra, *self.mu.shape[1:]))])
        self.time = np.concatenate([self.time, np.zeros(extra)])
        self.started = np.concatenate([self.started, np.zeros(extra, dtype=bool)])

    def start(self, tracks: LiveTracks, slot: int) -> None:
        if slot >= len(self.time):
            self._grow(len(tracks.tracks))
        self.started[slot] = False

    def _store(self, slots: np.ndarray | slice, state: BatchState, time: np.ndarray | float) -> None:
        self.x[slots], self.P[slots], self.mu[slots], self.time[slots] = state.x, state.P, state.mu, time

    def _start_filters(self, tracks: LiveTracks, slots: np.ndarray) -> None:
        """Start the filters of the tracks at `slots` not started yet, at their first plots."""
        fresh = slots[~self.started[slots]]
        if len(fresh):
            fresh = np.unique(fresh)  # a scan's (track, plot) pairs hold a track once per plot
            rows = [tracks.tracks[slot].rows[0] for slot in fresh]
            plots = tracks.plots
            started = batch_filters.start(self.settings, plots.position[rows], plots.covariance[rows])
            self._store(fresh, batch_filters.mixed(self.settings, started), plots.time[rows])
            self.started[fresh] = True

    def _motion(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Each model's transition F and process noise Q (M, n, n each) over dt seconds; `motion`
        is this, remembering the MOTION_CACHE most recent steps."""
        table = batch_filters.motion(self.settings, np.array([dt]))[0]
        return table[0], table[1]

    def predict(self, tracks: LiveTracks, slots: np.ndarray, time: float | np.ndarray) -> Prediction:
        """The tracks' filters moved to `time` (one, or one per track: `pairwise`), unchanged:
        positions (K, 3), covariances (K, 3, 3), and the moved models as the state (a BatchState of
        K tracks)."""
        self._start_filters(tracks, slots)
        motions = [self.motion(dt) for dt in (time - self.time[slots]).tolist()]
        state = batch_filters.moved(BatchState(self.x[slots], self.P[slots], self.mu[slots]),
                                    np.array([F for F, _ in motions]), np.array([Q for _, Q in motions]))
        return Prediction(*batch_filters.position_estimates(state), state)

    def update(self, tracks: LiveTracks, slot: int, row: int, prediction: Prediction | None, index: int
               ) -> tuple[np.ndarray, np.ndarray]:
        """The track's filter updated with plot `row` (its position and measurement covariance):
        the new position (3,) and its covariance (3, 3)."""
        if prediction is None:
            prediction, index = self.predict(tracks, np.array([slot]), tracks.plots.time[row]), 0
        position, covariance = self._updated(tracks, slice(slot, slot + 1), slice(row, row + 1), prediction,
                                             slice(index, index + 1))
        return position[0], covariance[0]

    def update_pairs(self, tracks: LiveTracks, slots: np.ndarray, rows: np.ndarray, prediction: Prediction,
                     indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The filters of the tracks at `slots` (P,), each a different track, updated each with its
        plot of `rows` (P,) from row `indices` (P,) of `prediction`: the new positions (P, 3) and
        covariances (P, 3, 3)."""
        return self._updated(tracks, slots, rows, prediction, indices)

    def _updated(self, tracks: LiveTracks, slots: np.ndarray | slice, rows: np.ndarray | slice,
                 prediction: Prediction, indices: np.ndarray | slice) -> tuple[np.ndarray, np.ndarray]:
        """`update_pairs` for index arrays or, one track's update, slices (cheaper to index by)."""
        plots, moved = tracks.plots, prediction.state
        posterior = batch_filters.updated(self.settings, BatchState(moved.x[indices], moved.P[indices],
                                                                    moved.mu[indices]),
                                          plots.position[rows], plots.covariance[rows])
        self._store(slots, batch_filters.mixed(self.settings, posterior, each_alone=True), plots.time[rows])
        return batch_filters.position_estimates(posterior)
