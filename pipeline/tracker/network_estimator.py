"""The networks' state estimator: the predictor and filter networks (thesis 4.6), an `Estimator`.

Every call takes a batch and runs one forward pass: the candidate tracks of a plot, or, the
estimator being `pairwise`, every (track, plot) pair of an antenna scan or of nearest neighbour's
look-ahead (`pipeline.tracker.run`), MIA's samples included; `update_pairs` runs the filter network
once for a scan's updates. A row's outputs do not depend on the rows run with it (ONNX Runtime's
kernels and NumPy's elementwise arithmetic give a row the same bits in a call of one row or of
thousands; checked by `tests/test_learned_scans.py`), so a scan at once gives the updates of
stepping it plot by plot, to the bit. Inputs are built from the tracks' histories as the training windows were:

- predictor: the last (up to) 5 states [t, dt, x, y, z, r], dt = time to the next state
  and, for the last state, to the time being predicted. A track with fewer states is
  padded by repeating its first state (dt = 0) in front, as the thesis does.
- filter: the last 10 plots [t, x, y, z, r] (r the plot's measured range to its radar); the
  last row of its output is the new state.

The networks read and write a range r beside the position, so each track keeps its latest
network states [t, x, y, z, r] in its `memory` (the predictor's 5; a track's first state is its
first plot); the track itself shows the loop only the position. Of a track's plots the estimator
reads the filter's window (its input less the new plot) and the latest one's radar:
`latest_plots`. The networks give no covariance.
"""

from __future__ import annotations

import numpy as np

from pipeline.learning.model_eval import output_scaler
from pipeline.tracker.estimator import Prediction
from pipeline.tracker.models import Models
from pipeline.tracker.tracks import LiveTracks


class NetworkEstimator:
    """Predictor and filter networks with their scalers."""

    gives_covariance = False
    gives_velocity = False  # the networks give positions only
    pairwise = True

    def __init__(self, models: Models) -> None:
        self.predictor, self.filter = models["predictor"], models["filter"]
        self._run_predictor, self._run_filter = models.runnable["predictor"], models.runnable["filter"]
        self.inputs = self.predictor.config.input_steps
        self.filter_plots = self.filter.config.input_steps
        self._predictor_out = output_scaler(self.predictor.scaler)
        self._filter_out = output_scaler(self.filter.scaler)
        self.latest_plots = max(self.filter_plots - 1, 1)

    def start(self, tracks: LiveTracks, slot: int) -> None:
        track = tracks.tracks[slot]
        track.memory = [tracks.plots.features[track.rows[0]]]

    def state_windows(self, tracks: LiveTracks, slots: np.ndarray, time: float | np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Predictor input windows (K x 5 x 6, unscaled) of the tracks at `slots` predicting to
        `time` (one, or one per track (K,)), the number of padded states of each (K,), and the ECEF
        position of the radar of each track's last plot (K x 3), for the window frame."""
        windows = np.empty((len(slots), self.inputs, 6))
        padded = np.empty(len(slots), dtype=np.int64)
        times = np.broadcast_to(time, slots.shape)
        for n, slot in enumerate(slots):
            states = np.asarray(tracks.tracks[slot].memory[-self.inputs:])
            padded[n] = self.inputs - len(states)
            window = windows[n]
            window[:padded[n], 0] = states[0, 0]
            window[:padded[n], 2:] = states[0, 1:]
            window[:padded[n], 1] = 0.0
            window[padded[n]:, 0] = states[:, 0]
            window[padded[n]:, 2:] = states[:, 1:]
            window[padded[n]:, 1] = np.diff(np.append(states[:, 0], times[n]))
        radar = tracks.plots.radar_position[[tracks.tracks[slot].rows[-1] for slot in slots]]
        return windows, padded, radar

    def predict_windows(self, windows: np.ndarray, radar_ecef: np.ndarray) -> np.ndarray:
        """Predicted [t, x, y, z, r] at the end of each state window (K x 5), seen by radars at `radar_ecef` (K x 3)."""
        scaler = self.predictor.scaler
        origin = scaler.origin(windows, radar_ecef)
        outputs = self._run_predictor(scaler.transform(windows, origin)).astype(float)
        return self._predictor_out.inverse(outputs, origin)[:, -1]

    def predict(self, tracks: LiveTracks, slots: np.ndarray, time: float | np.ndarray) -> Prediction:
        """The predictor's [t, x, y, z, r] of each track at `time` (one, or one per track (K,)): the
        Prediction's state, K x 5."""
        windows, _, radar = self.state_windows(tracks, slots, time)
        rows = self.predict_windows(windows, radar)
        return Prediction(rows[:, 1:4], None, rows)

    def update(self, tracks: LiveTracks, slot: int, row: int, prediction: Prediction | None, index: int
               ) -> tuple[np.ndarray, None]:
        """The state after associating plot `row` (`update_pairs`), the predictor running here when the
        gate made no prediction (the young-track radius)."""
        if prediction is None:
            prediction, index = self.predict(tracks, np.array([slot]), tracks.plots.time[row]), 0
        positions, _ = self.update_pairs(tracks, np.array([slot]), np.array([row]), prediction, np.array([index]))
        return positions[0], None

    def update_pairs(self, tracks: LiveTracks, slots: np.ndarray, rows: np.ndarray, prediction: Prediction | None,
                     indices: np.ndarray) -> tuple[np.ndarray, None]:
        """The states after the tracks at `slots` (P,), each a different track, take their plots `rows` (P,),
        from rows `indices` (P,) of `prediction` (None: the predictor runs here, each track to its plot's
        time): positions (P, 3). A track with `filter_plots` plots, the
        new one included, is denoised by the filter network (one call for all such pairs) on its last
        plots; a younger one takes the mean of its predicted state and the plot (position and range)."""
        if prediction is None:
            prediction, indices = self.predict(tracks, slots, tracks.plots.time[rows]), np.arange(len(slots))
        features = tracks.plots.features
        states = 0.5 * (prediction.state[indices] + features[rows])
        filtered = tracks.plot_count[slots] + 1 >= self.filter_plots
        if filtered.any():
            windows = np.array([[*tracks.tracks[slot].rows[-(self.filter_plots - 1):], row]
                                for slot, row in zip(slots[filtered], rows[filtered])])
            plots = features[windows]
            origin = self.filter.scaler.origin(plots, tracks.plots.radar_position[windows[:, 0]])
            outputs = self._run_filter(self.filter.scaler.transform(plots, origin)).astype(float)
            states[filtered] = self._filter_out.inverse(outputs, origin)[:, -1]
        states[:, 0] = features[rows, 0]
        for slot, state in zip(slots, states):
            memory = tracks.tracks[slot].memory
            memory.append(state)
            del memory[:-self.inputs]
        return states[:, 1:4], None
