"""The LSTM update on a Kalman prediction (`pipeline.learning.lstm_update`, issue 18) as the tracker's `Estimator`.

Every live track keeps, by slot, its MC-dropout ensemble (N copies of the 9-state CA estimate and
of the LSTM's memory, `lstm_update.Ensemble`; copy 0 the point estimate) and the time it is at.
A track's ensemble starts at its first plot (at the plot, still, memory empty) when the track is first predicted, as the
Kalman estimator's filter does. `predict` moves the candidate tracks' ensembles to the plot's time
in one batch (K N rows): the position is the point estimate's prediction and its covariance the
calibrated spread of the copies about it (`LSTMUpdate.prediction_covariance`, the factors for the
track's age and the scan periods predicted over), which the
chi-square gate adds to the plot's covariance. `update` runs the LSTM step on the track's copies
with the plot and its measurement covariance, and gives the point estimate and its calibrated
covariance (`LSTMUpdate.estimate_covariance`: the copies' spread and the plot's covariance). Works in ECEF metres, seconds, like every estimator. The MC copies' dropout masks come
from the estimator's own generator, seeded from the run's seed (the scenario's), so a scenario's
tracks do not depend on what ran before it in the process (torch's global generator is left as it was).
The prediction (`step_runtime.LSTMPredict`) and the LSTM step with its calibrated covariance
(`step_runtime.LSTMStep`) run traced to TorchScript, the same numbers as eager PyTorch in a fraction
of its dispatch, or eagerly (`tracker.learned_runtime`), on the CPU or a CUDA device (`tracker.device`,
`pipeline.learning.devices`: the ensembles and the network live there, the masks are drawn on the CPU
and moved, numpy arrays come back from every role).

The estimator is `pairwise`: `predict` moves the tracks of a whole scan's (track, plot) pairs (or
of nearest neighbour's look-ahead) in one call, each to its own plot's time, and `update_pairs`
steps several tracks through the LSTM in one call, the masks drawn track by track in the order of
the pairs (`LSTMUpdate.dropout_masks`: the draws `nn.functional.dropout` makes for one track, from
the same generator). A pair's numbers do not depend on the pairs beside it (a call of at least
`batch_rows.GEMM_ROWS` rows: a track's copies make them), so with nearest neighbour, the method's
assigner, which updates one plot at a time in time order, the updates are those of scoring one plot
at a time, to the bit (`tests/test_learned_scans.py`). Under global nearest neighbour the loop
updates a scan's mature tracks in one call before its young ones: the masks then go to the updates
in another order than plot by plot (as valid a draw, not the same bits). In that mature call the rows
past the last multiple of `batch_rows.GEMM_ROWS` (tracks x copies, modulo 4) go through MKL's tail
kernel, so the last track's last copies may differ in the last bits from a call with other tracks beside
it: the same recording gives the same bytes, but a track's numbers there depend on the scan's other
mature tracks (padding the call to whole blocks would remove it, and change today's outputs' last bits).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from pipeline.learning import batch_rows, devices, step_runtime
from pipeline.learning.lstm_update import FEATURES, Ensemble, LSTMUpdate
from pipeline.tracker.estimator import Prediction
from pipeline.tracker.tracks import LiveTracks


class Moved(NamedTuple):
    """A prediction's state: the candidates' ensembles (K tracks) before the step, and their time steps (K,) s."""

    ensemble: Ensemble
    dt: torch.Tensor


def _parts(ensemble: Ensemble) -> tuple[torch.Tensor, ...]:
    return ensemble.x, ensemble.h, ensemble.c, ensemble.age


class LSTMUpdateEstimator:
    """One MC-dropout ensemble of the LSTM-update estimator per live track."""

    gives_covariance = True
    gives_velocity = True
    pairwise = True
    latest_plots = 0  # a track's first plot starts its ensemble; the ensemble keeps the rest

    def __init__(self, model: LSTMUpdate, seed: int | list[int], capacity: int = 64, runtime: str = "script",
                 device: str = "cpu") -> None:
        self.device = devices.resolve(device)
        self.model = model = devices.placed(model.eval(), self.device)
        self.generator = torch.Generator().manual_seed(
            int(np.random.SeedSequence(seed).generate_state(1)[0]))  # the dropout masks', drawn on the CPU
        self.samples, self.sample = model.ensemble()
        self.dtype = model.dtype
        self.ensemble = Ensemble(*(torch.zeros(capacity, self.samples, size, dtype=self.dtype, device=self.device)
                                   for size in (9, model.config.hidden, model.config.hidden)),
                                 torch.zeros(capacity, dtype=torch.long, device=self.device))
        self.time = np.zeros(capacity)
        self.velocity = np.zeros((capacity, 3))  # the point estimates' (copy 0's), kept as stored: read per update
        self.started = np.zeros(capacity, dtype=bool)
        self._predict = step_runtime.traced(model, step_runtime.LSTMPredict, runtime,
                                            lambda rows: self._example(rows)[0])
        self._step = step_runtime.traced(model, step_runtime.LSTMStep if self.sample else step_runtime.LSTMStepUnmasked,
                                         runtime, lambda rows: self._example(rows)[1])
        self._step_alone = step_runtime.traced(model, step_runtime.LSTMStepAlone, runtime,
                                               lambda rows: self._example(rows)[1]) if self.sample else None

    def _tensor(self, values: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(values, dtype=self.dtype, device=self.device)

    def _example(self, rows: int) -> tuple[tuple[torch.Tensor, ...], tuple[torch.Tensor, ...]]:
        """Inputs of `rows` tracks' prediction and LSTM step (`step_runtime.LSTMPredict`, `LSTMStep`) to trace
        them with: tracks started at a plot, the next plots 1 km on after 4 s, masks of ones."""
        z = self._tensor(np.full((rows, 3), 6.4e6))
        ensemble, dt = self.model.started(z, self.samples), self._tensor(np.full(rows, 4.0))
        R = self._tensor(np.repeat(np.eye(3)[None] * 1e4, rows, 0))
        masks = torch.ones(rows, self.samples, FEATURES + self.model.config.hidden, dtype=self.dtype,
                           device=self.device)
        return ((ensemble.x, ensemble.age, dt),
                (*_parts(ensemble), z + 1e3, R, dt) + (masks,) * self.sample)

    def start(self, tracks: LiveTracks, slot: int) -> None:
        if slot >= len(self.time):
            extra = len(tracks.tracks) - len(self.time)
            self.ensemble = Ensemble(*(torch.cat([part, part.new_zeros((extra, *part.shape[1:]))])
                                       for part in _parts(self.ensemble)))
            self.time = np.concatenate([self.time, np.zeros(extra)])
            self.velocity = np.concatenate([self.velocity, np.zeros((extra, 3))])
            self.started = np.concatenate([self.started, np.zeros(extra, dtype=bool)])
        self.started[slot] = False

    def _store(self, slots: np.ndarray, ensemble: Ensemble, time: np.ndarray | float) -> None:
        index = torch.as_tensor(slots, device=self.device)
        for part, value in zip(_parts(self.ensemble), _parts(ensemble)):
            part[index] = value
        self.time[slots] = time
        self.velocity[slots] = ensemble.x[:, 0, 1::3].cpu().numpy()

    def _start_ensembles(self, tracks: LiveTracks, slots: np.ndarray) -> None:
        """Start the ensembles of the tracks at `slots` not started yet, at their first plots."""
        fresh = np.unique(slots[~self.started[slots]])  # a scan's pairs hold a track once per plot
        if len(fresh):
            rows = [tracks.tracks[slot].rows[0] for slot in fresh]
            z = self._tensor(tracks.plots.position[rows])
            self._store(fresh, self.model.started(z, self.samples), tracks.plots.time[rows])
            self.started[fresh] = True

    def predict(self, tracks: LiveTracks, slots: np.ndarray, time: float | np.ndarray) -> Prediction:
        """The tracks' ensembles moved to `time` (one, or one per track: `pairwise`), unchanged: predicted
        positions (K, 3), calibrated covariances (K, 3, 3), and the ensembles with their time steps as
        the state (`Moved`)."""
        self._start_ensembles(tracks, slots)
        index = torch.as_tensor(slots, device=self.device)
        ensemble = Ensemble(*(part[index] for part in _parts(self.ensemble)))
        dt = self._tensor(time - self.time[slots])
        with torch.no_grad():
            position, covariance = self._predict(ensemble.x, ensemble.age, dt)
        return Prediction(position.cpu().numpy(), covariance.cpu().numpy(), Moved(ensemble, dt))

    def update(self, tracks: LiveTracks, slot: int, row: int, prediction: Prediction | None, index: int
               ) -> tuple[np.ndarray, np.ndarray]:
        """The track's ensemble stepped with plot `row` (its position and measurement covariance): the
        point estimate's position (3,) and its calibrated covariance (3, 3)."""
        if prediction is None:
            prediction, index = self.predict(tracks, np.array([slot]), tracks.plots.time[row]), 0
        position, covariance = self.update_pairs(tracks, np.array([slot]), np.array([row]), prediction,
                                                 np.array([index]))
        return position[0], covariance[0]

    def velocities(self, tracks: LiveTracks, slots: np.ndarray) -> tuple[np.ndarray, None]:
        """The velocities (K, 3) m/s of the tracks at `slots` after their latest update: the point
        estimate's (copy 0, undropped), state per axis [p, v, a], kept on the CPU as each update stores it.
        No covariance: the network calibrates only the position's (`LSTMUpdate.estimate_covariance`)."""
        return self.velocity[slots], None

    def update_pairs(self, tracks: LiveTracks, slots: np.ndarray, rows: np.ndarray, prediction: Prediction | None,
                     indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The ensembles of the tracks at `slots` (P,), each a different track, stepped each with its plot
        of `rows` (P,) from row `indices` (P,) of `prediction`, in one LSTM call: the point estimates'
        positions (P, 3) and calibrated covariances (P, 3, 3). The masks are drawn pair by pair; a call
        of fewer than `batch_rows.GEMM_ROWS` rows (a track of 1 to 3 copies alone) runs on repeated
        pairs, whose masks are ones (no draws).

        With `prediction` None (a scan's young tracks) the tracks are predicted here in one call (a
        track's prediction is the same in any call) and stepped as `update` steps each alone, plot by
        plot: in one call of `step_runtime.LSTMStepAlone`, whose matrix products give each track the
        rows of a call of its own (MKL's dgemm computes a call's last rows, its row count modulo
        `batch_rows.GEMM_ROWS`, in other last bits), or, without dropout, one call per track."""
        plots, count = tracks.plots, len(slots)
        step = self._step
        if prediction is None:
            prediction, indices = self.predict(tracks, slots, plots.time[rows]), np.arange(count)
            if not self.sample:
                stepped = [self.update_pairs(tracks, slots[k:k + 1], rows[k:k + 1], prediction, indices[k:k + 1])
                           for k in range(count)]
                return np.concatenate([p for p, _ in stepped]), np.concatenate([c for _, c in stepped])
            step = self._step_alone
        moved = prediction.state
        padded = batch_rows.padding(count, self.samples)
        at = torch.as_tensor(np.asarray(indices)[padded], device=self.device)
        z, R = self._tensor(plots.position[rows[padded]]), self._tensor(plots.covariance[rows[padded]])
        masks = ()
        if self.sample:
            drawn = self.model.dropout_masks(self.samples, self.generator, tracks=count)
            if len(padded) > count:
                drawn = torch.cat([drawn, drawn.new_ones((len(padded) - count, *drawn.shape[1:]))])
            masks = (drawn.to(self.device),)
        with torch.no_grad():
            *after, position, covariance = step(*(part[at] for part in _parts(moved.ensemble)), z, R,
                                                moved.dt[at], *masks)
        self._store(slots, Ensemble(*(part[:count] for part in after)), plots.time[rows])
        return position[:count].cpu().numpy(), covariance[:count].cpu().numpy()
