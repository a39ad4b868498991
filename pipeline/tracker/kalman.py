"""The classical estimator: a tuned CV, CA or IMM filter per track (`pipeline.filters.classical_filters`),
stepped by the one Kalman core (`pipeline.filters.batch_filters`), an `Estimator`.

Every live track's filter sits in arrays by slot: each motion model's state x (S, M, n) and
covariance P (S, M, n, n), the mode probabilities mu (S, M) and the time it is at (S,). What
is stored is what the next prediction starts from: after an update the IMM's mixed models and
predicted mode probabilities (`batch_filters.mixed`), a single filter's posterior. A track's
filter is started at its first plot, with the velocity unknown up to the tuned spread, when
the track is first predicted (clutter tracks, most of them, never are). The filters run in
ECEF: with the same noise on every axis this is the same as a local east-north-up frame
(`pipeline.filters.motion_models`), and a turning model turns about each track's own vertical.

`predict` moves the candidate tracks' filters to the plot's time in one batch (F and Q made
once per distinct time step, plot times being quantised; a turning model's per track, about
the vertical at its last update) and gives the combined position and its covariance (the IMM's
own predicted density, mixed with the predicted mode probabilities); `update` resumes from that
prediction's state with the plot's own measurement covariance (its radar's) and stores the result.
"""

from __future__ import annotations

import numpy as np

from pipeline.filters import batch_filters, motion_models
from pipeline.filters.batch_filters import BatchState
from pipeline.filters.classical_filters import FilterSettings
from pipeline.tracker.assigner import Hypotheses
from pipeline.tracker.estimator import Prediction
from pipeline.tracker.tracks import LiveTracks

MOTION_CACHE = 4096  # F and Q kept for this many time steps: quantised plot times (1/128 s) repeat a few
                     # hundred steps; unquantised times would otherwise grow the cache with the recording


class KalmanEstimator:
    """One tuned classical filter per live track."""

    gives_covariance = True
    gives_velocity = True
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
        self.up = np.zeros((capacity, 3))  # the vertical a turning model turns about next (`batch_filters.verticals`)
        self._motions = np.empty((0, 2, models, size, size))  # F and Q of the time steps in `_motion_code`, in order
        self._motion_code: dict[float, int] = {}

    def _grow(self, capacity: int) -> None:
        extra = capacity - len(self.time)
        self.x = np.concatenate([self.x, np.zeros((extra, *self.x.shape[1:]))])
        self.P = np.concatenate([self.P, np.zeros((extra, *self.P.shape[1:]))])
        self.mu = np.concatenate([self.mu, np.zeros((extra, *self.mu.shape[1:]))])
        self.time = np.concatenate([self.time, np.zeros(extra)])
        self.started = np.concatenate([self.started, np.zeros(extra, dtype=bool)])
        self.up = np.concatenate([self.up, np.zeros((extra, 3))])

    def start(self, tracks: LiveTracks, slot: int) -> None:
        if slot >= len(self.time):
            self._grow(len(tracks.tracks))
        self.started[slot] = False

    def _store(self, slots: np.ndarray | slice, posterior: BatchState, time: np.ndarray | float,
               each_alone: bool = True) -> None:
        """The posterior's mixed models (what the next prediction starts from; `each_alone` as in
        `batch_filters.mixed`) and, for a turning model, the vertical at the posterior
        (`batch_filters.verticals`)."""
        state = batch_filters.mixed(self.settings, posterior, each_alone=each_alone)
        self.x[slots], self.P[slots], self.mu[slots], self.time[slots] = state.x, state.P, state.mu, time
        up = batch_filters.verticals(self.settings, posterior)
        if up is not None:
            self.up[slots] = up

    def _start_filters(self, tracks: LiveTracks, slots: np.ndarray) -> None:
        """Start the filters of the tracks at `slots`, not started yet, at their first plots."""
        fresh = np.unique(slots)  # a scan's (track, plot) pairs hold a track once per plot
        rows = [tracks.tracks[slot].rows[0] for slot in fresh]
        plots = tracks.plots
        first = batch_filters.start(self.settings, plots.position[rows], plots.covariance[rows])
        self._store(fresh, first, plots.time[rows], each_alone=False)
        self.started[fresh] = True

    def _motion(self, steps: list[float]) -> np.ndarray:
        """Each model's transition F and process noise Q over each of `steps` (K,) seconds:
        (K, 2, M, n, n), F then Q. Gathered in one call from a table of the steps seen so far (plot
        times are quantised, so steps repeat), which starts afresh rather than hold more than
        MOTION_CACHE steps; the steps not in it are tabulated together in one call (F and Q are
        elementwise in dt, so each step's are the same as tabulated alone)."""
        codes = self._motion_code
        try:
            return self._motions.take([codes[dt] for dt in steps], axis=0)
        except KeyError:
            pass
        if len(codes) + len(steps) > MOTION_CACHE:
            codes.clear()
        missing = list(dict.fromkeys(dt for dt in steps if dt not in codes))
        known = len(codes)
        if known + len(missing) > len(self._motions):
            extra = np.empty((max(known + len(missing), 2 * len(self._motions), 16) - len(self._motions),
                              *self._motions.shape[1:]))
            self._motions = np.concatenate([self._motions, extra])
        self._motions[known:known + len(missing)] = batch_filters.motion(self.settings, np.array(missing))
        codes.update((dt, known + k) for k, dt in enumerate(missing))
        return self._motions.take([codes[dt] for dt in steps], axis=0)

    def predict(self, tracks: LiveTracks, slots: np.ndarray, time: float | np.ndarray) -> Prediction:
        """The tracks' filters moved to `time` (one, or one per track: `pairwise`), unchanged:
        positions (K, 3), covariances (K, 3, 3), and the moved models as the state (a BatchState of
        K tracks)."""
        started = self.started.take(slots)
        if np.count_nonzero(started) < len(slots):
            self._start_filters(tracks, slots[~started])
        dt = time - self.time.take(slots)
        motion = self._motion(dt.tolist())
        F = batch_filters.turned(self.settings, motion[:, 0], dt, self.up.take(slots, axis=0))
        state = batch_filters.moved(BatchState(self.x.take(slots, axis=0), self.P.take(slots, axis=0),
                                               self.mu.take(slots, axis=0)), F, motion[:, 1])
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

    def velocities(self, tracks: LiveTracks, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The velocities (K, 3) m/s and their covariances (K, 3, 3) of the tracks at `slots` after their
        latest update (`batch_filters.velocity_estimates` of the stored filters)."""
        return batch_filters.velocity_estimates(BatchState(self.x[slots], self.P[slots], self.mu[slots]))

    def update_pairs(self, tracks: LiveTracks, slots: np.ndarray, rows: np.ndarray, prediction: Prediction | None,
                     indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The filters of the tracks at `slots` (P,), each a different track, updated each with its
        plot of `rows` (P,) from row `indices` (P,) of `prediction` (None: predicted here, each to its
        plot's time): the new positions (P, 3) and covariances (P, 3, 3)."""
        if prediction is None:
            prediction, indices = self.predict(tracks, slots, tracks.plots.time[rows]), np.arange(len(slots))
        return self._updated(tracks, slots, rows, prediction, indices)

    def update_mixtures(self, tracks: LiveTracks, hypotheses: Hypotheses) -> tuple[np.ndarray, np.ndarray]:
        """The filters of the T tracks of `hypotheses` updated with all their plots at once, each weighted by
        its probability (a soft assigner's: `pipeline.tracker.jpda`): every hypothesis's update from the
        prediction at the track's reference plot, merged per model (`batch_filters.collapsed`), stored at
        the reference plot's time. Returns the new positions (T, 3) and covariances (T, 3, 3)."""
        plots, moved = tracks.plots, hypotheses.prediction.state
        index = hypotheses.reference_index
        prior = BatchState(moved.x[index], moved.P[index], moved.mu[index])
        each = index[hypotheses.track]
        posteriors = batch_filters.updated(self.settings, BatchState(moved.x[each], moved.P[each], moved.mu[each]),
                                           plots.position[hypotheses.rows], plots.covariance[hypotheses.rows])
        merged = batch_filters.collapsed(prior, posteriors, hypotheses.track, hypotheses.weights, hypotheses.missed)
        self._store(hypotheses.slots, merged, plots.time[hypotheses.reference])
        return batch_filters.position_estimates(merged)

    def _updated(self, tracks: LiveTracks, slots: np.ndarray | slice, rows: np.ndarray | slice,
                 prediction: Prediction, indices: np.ndarray | slice) -> tuple[np.ndarray, np.ndarray]:
        """`update_pairs` for index arrays or, one track's update, slices (cheaper to index by). A
        single filter's innovation covariance is the prediction's (its models combined), so the
        gate's inverse of it serves (`Prediction.innovation_inverse`)."""
        plots, moved, inverse = tracks.plots, prediction.state, prediction.innovation_inverse
        single = inverse is not None and moved.mu.shape[1] == 1
        posterior = batch_filters.updated(self.settings, BatchState(moved.x[indices], moved.P[indices],
                                                                    moved.mu[indices]),
                                          plots.position[rows], plots.covariance[rows],
                                          inverse[indices][:, None] if single else None)
        self._store(slots, posterior, plots.time[rows])
        return batch_filters.position_estimates(posterior)
