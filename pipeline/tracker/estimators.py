"""State estimators of the neural tracker: the predictor and filter networks (thesis 4.6).

Every call takes a batch (all candidate tracks of a plot, or all MIA samples) and runs one
forward pass. Inputs are built from the tracks' histories as the training windows were:

- predictor: the last (up to) 5 states [t, dt, x, y, z, r], dt = time to the next state
  and, for the last state, to the time being predicted. A track with fewer states is
  padded by repeating its first state (dt = 0) in front, as the thesis does.
- filter: the last 10 plots [t, x, y, z, r]; the last row of its output is the new state.

A different estimator (a Kalman filter, say) only has to offer `update`, and what its gate needs.
"""

from __future__ import annotations

import numpy as np

from pipeline.model_eval import output_scaler
from pipeline.tracker.models import Models
from pipeline.tracker.tracks import Track


class NetworkEstimator:
    """Predictor and filter networks with their scalers."""

    def __init__(self, models: Models) -> None:
        self.predictor, self.filter = models.predictor, models.filter
        self._run_predictor, self._run_filter = models.runnable["predictor"], models.runnable["filter"]
        self.inputs = self.predictor.config.input_steps
        self.filter_plots = self.filter.config.input_steps
        self._predictor_out = output_scaler(self.predictor.scaler)
        self._filter_out = output_scaler(self.filter.scaler)

    def state_windows(self, tracks: list[Track], times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predictor input windows (N x 5 x 6, unscaled) and the number of padded states of each."""
        windows = np.empty((len(tracks), self.inputs, 6))
        padded = np.empty(len(tracks), dtype=np.int64)
        for n, (track, time) in enumerate(zip(tracks, times)):
            states = np.asarray(track.states[-self.inputs:])
            padded[n] = self.inputs - len(states)
            window = windows[n]
            window[:padded[n], 0] = states[0, 0]
            window[:padded[n], 2:] = states[0, 1:]
            window[:padded[n], 1] = 0.0
            window[padded[n]:, 0] = states[:, 0]
            window[padded[n]:, 2:] = states[:, 1:]
            window[padded[n]:, 1] = np.diff(np.append(states[:, 0], time))
        return windows, padded

    def predict_windows(self, windows: np.ndarray) -> np.ndarray:
        """Predicted [t, x, y, z, r] at the end of each state window (N x 5)."""
        scaler = self.predictor.scaler
        origin = scaler.origin(windows)
        outputs = self._run_predictor(scaler.transform(windows, origin)).astype(float)
        return self._predictor_out.inverse(outputs, origin)[:, -1]

    def predict(self, tracks: list[Track], times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted [t, x, y, z, r] of each track at its time, and the number of padded states."""
        windows, padded = self.state_windows(tracks, times)
        return self.predict_windows(windows), padded

    def update(self, track: Track, plot: np.ndarray, predicted: np.ndarray | None) -> np.ndarray:
        """New state after associating `plot` (not yet added to the track's plots).

        With `filter_plots` plots, the new one included, the filter network denoises the last
        ones; before that the state is the mean of the prediction and the plot (position and range).
        `predicted` is the gate's prediction at the plot's time, or None when the gate made none
        (the young-track radius), then the predictor runs here if needed.
        """
        if len(track.plots) + 1 < self.filter_plots:
            if predicted is None:
                predicted = self.predict([track], np.array([plot[0]]))[0][0]
            state = 0.5 * (predicted + plot)
            state[0] = plot[0]
            return state
        window = np.vstack([*track.plots[-(self.filter_plots - 1):], plot])[None]
        origin = self.filter.scaler.origin(window)
        outputs = self._run_filter(self.filter.scaler.transform(window, origin)).astype(float)
        output = self._filter_out.inverse(outputs, origin)[0, -1]
        output[0] = plot[0]
        return output
