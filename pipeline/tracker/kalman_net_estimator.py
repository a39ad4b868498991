"""The network-scaled Kalman filter (`pipeline.kalman_net`, seed 003) as the tracker's estimator, an `Estimator`.

Every live track runs the trained model's base filter (cv, ca or singer) in PyTorch
(`pipeline.torch_filters`, float64, no gradients), with the network's recurrent memory kept
beside it; both sit in tensors by slot, as `pipeline.tracker.kalman.KalmanEstimator` keeps its
filters: the posterior state x (S, 1, n), P (S, 1, n, n), mu (S, 1), the time it is at (S,), the
network's `kalman_net.Memory` (hidden (S, H) and the increments' last values), and the scales the
network gave at the track's last plot (q, and singer's manoeuvre scale) (S,).

A step is `KalmanNet.step_scales` then the scaled filter step, exactly as in training
(`torch_filters.filter_sequences`): the network reads the track's memory, its posterior and the
new plot (z, R0 = the plot's covariance x `r0_scale`, dt), and scales Q (and singer's manoeuvre
frequency) of the prediction and R of the update. A track's filter starts, as in training, at its
first plot with the network's first (`fresh`) step: position measured, covariance R0 x r, the
velocity unknown up to the model's spread. It starts when the track is first predicted or
updated (clutter tracks, most of them, never are).

`predict` cannot run the network: its features need the plot (its increment and its innovation),
and the loop predicts the candidate tracks of a plot before choosing one. It moves the K
candidates' filters in one batch with the Q scale each track's network gave at its last plot, so
the chi-square gate scores with the filter's own predicted covariance (plus the plot's nominal
measurement covariance, the gate's), and a distant clutter plot, whose innovation would make the
network widen Q and R, cannot widen the gate that judges it. `update` runs the network on the
associated plot (one track) and makes the step with its scales; the covariance it returns is the
scaled filter's posterior, which the consistency metrics (ANEES) read.
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import torch
from torch import Tensor

from pipeline import motion_models, torch_filters
from pipeline.kalman_net import KalmanNet, Memory
from pipeline.torch_filters import State, Step
from pipeline.tracker.estimator import Prediction
from pipeline.tracker.tracks import LiveTracks


class KalmanNetEstimator:
    """One network-scaled filter per live track, of the trained `model` (eval mode, no gradients)."""

    gives_covariance = True

    def __init__(self, model: KalmanNet, capacity: int = 64) -> None:
        self.model, self.spec = model, model.base
        self.r0_scale = model.config.r0_scale
        self.singer = model.config.base == "singer"
        size, dtype = motion_models.state_size(self.spec.models[0]), self.spec.dtype
        self.x = torch.zeros((capacity, 1, size), dtype=dtype)
        self.P = torch.zeros((capacity, 1, size, size), dtype=dtype)
        self.mu = torch.ones((capacity, 1), dtype=dtype)
        self.q = torch.ones(capacity, dtype=dtype)
        self.manoeuvre = torch.ones(capacity, dtype=dtype)
        self.memory = model.memory(capacity)
        self.time = np.zeros(capacity)
        self.started = np.zeros(capacity, dtype=bool)

    def _grow(self, capacity: int) -> None:
        extra = capacity - len(self.time)

        def grown(values: Tensor, fill: float = 0.0) -> Tensor:
            return torch.cat([values, torch.full((extra, *values.shape[1:]), fill, dtype=values.dtype)])
        self.x, self.P, self.mu = grown(self.x), grown(self.P), grown(self.mu, 1.0)
        self.q, self.manoeuvre = grown(self.q, 1.0), grown(self.manoeuvre, 1.0)
        self.memory = Memory(**{f.name: grown(getattr(self.memory, f.name)) for f in fields(Memory)})
        self.time = np.concatenate([self.time, np.zeros(extra)])
        self.started = np.concatenate([self.started, np.zeros(extra, dtype=bool)])

    def start(self, tracks: LiveTracks, slot: int) -> None:
        if slot >= len(self.time):
            self._grow(len(tracks.tracks))
        self.started[slot] = False

    def _state(self, slots: np.ndarray) -> State:
        index = torch.from_numpy(slots)
        return State(self.x[index], self.P[index], self.mu[index])

    def _step(self, tracks: LiveTracks, slots: np.ndarray, rows: list[int], fresh: bool) -> State:
        """One network-scaled step of the tracks at `slots` with plots `rows`, stored: the track's
        first (`fresh`: the filter starts at the plot) or an update. Returns the posterior."""
        plots, index = tracks.plots, torch.from_numpy(slots)
        z = torch.as_tensor(plots.position[rows], dtype=self.spec.dtype)
        R0 = torch.as_tensor(plots.covariance[rows], dtype=self.spec.dtype) * self.r0_scale
        dt = torch.as_tensor(0.0 if fresh else plots.time[rows] - self.time[slots], dtype=torch.float64)
        dt = dt.expand(len(slots))
        with torch.no_grad():
            before = torch_filters.start(self.spec, z, R0) if fresh else self._state(slots)
            memory = Memory(**{f.name: getattr(self.memory, f.name)[index] for f in fields(Memory)})
            flags = torch.full((len(slots),), fresh), torch.full((len(slots),), not fresh)
            scales, memory = self.model.step_scales(memory, Step(0, before, z, R0, dt), *flags)
            R = R0 * scales.r[:, None, None]
            if fresh:
                after = torch_filters.start(self.spec, z, R)
            else:
                prior = torch_filters.predicted(self.spec, before, *torch_filters.motion(self.spec, dt, scales.q,
                                                                                         scales.manoeuvre))
                after = torch_filters.updated(self.spec, prior, z, R)
        self.x[index], self.P[index], self.mu[index] = after.x, after.P, after.mu
        self.q[index] = scales.q
        if self.singer:
            self.manoeuvre[index] = scales.manoeuvre
        for f in fields(Memory):
            getattr(self.memory, f.name)[index] = getattr(memory, f.name)
        self.time[slots] = plots.time[rows]
        self.started[slots] = True
        return after

    def _start_filters(self, tracks: LiveTracks, slots: np.ndarray) -> None:
        """Start the filters of the tracks at `slots` not started yet, at their first plots."""
        fresh = slots[~self.started[slots]]
        if len(fresh):
            self._step(tracks, fresh, [tracks.tracks[slot].rows[0] for slot in fresh], fresh=True)

    def predict(self, tracks: LiveTracks, slots: np.ndarray, time: float) -> Prediction:
        """The tracks' filters moved to `time` with their last Q scales, unchanged: positions (K, 3) and
        covariances (K, 3, 3); no state (the update steps afresh with the plot's own scales)."""
        self._start_filters(tracks, slots)
        index = torch.from_numpy(slots)
        dt = torch.as_tensor(time - self.time[slots], dtype=torch.float64)
        with torch.no_grad():
            motion = torch_filters.motion(self.spec, dt, self.q[index], self.manoeuvre[index] if self.singer else None)
            position, covariance = torch_filters.position_estimates(
                torch_filters.predicted(self.spec, self._state(slots), *motion))
        return Prediction(position.numpy(), covariance.numpy())

    def update(self, tracks: LiveTracks, slot: int, row: int, prediction: Prediction | None, index: int
               ) -> tuple[np.ndarray, np.ndarray]:
        """The track's filter stepped with plot `row`, the network's scales from it: the new position (3,)
        and its covariance (3, 3). `prediction` is not used (module docstring)."""
        slots = np.array([slot])
        self._start_filters(tracks, slots)
        position, covariance = torch_filters.position_estimates(self._step(tracks, slots, [row], fresh=False))
        return position[0].numpy(), covariance[0].numpy()

