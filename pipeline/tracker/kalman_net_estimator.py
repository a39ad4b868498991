"""The network-scaled Kalman filter (`pipeline.learning.kalman_net`, seed 003) as the tracker's estimator, an `Estimator`.

Every live track runs the trained model's base filter (cv, ca or singer) in PyTorch
(`pipeline.filters.torch_filters`, float64, no gradients), with the network's recurrent memory kept
beside it. A batched step (the network's scales with the prediction, `step_runtime.KalmanNetPlotStep`;
the update, `KalmanNetUpdate`) runs traced to TorchScript, the same numbers as eager PyTorch in a
fraction of its dispatch, or eagerly (`tracker.learned_runtime`, `pipeline.learning.step_runtime`),
on the CPU or a CUDA device (`tracker.device`, `pipeline.learning.devices`: the states, the memory
and the network live there, numpy arrays come back from every role). Both sit in tensors by slot,
as `pipeline.tracker.kalman.KalmanEstimator` keeps its filters: the posterior state x (S, M, n),
P (S, M, n, n), mu (S, M), the time it is at (S,), the network's `kalman_net.Memory` (hidden (S, H)
and the increments' last values), and the scales the network gave at the track's last plot (q, and
singer's manoeuvre scale) (S,).

A step is `KalmanNet.step_scales` then the scaled filter step, exactly as in training
(`torch_filters.filter_sequences`): the network reads the track's memory, its posterior and the
new plot (z, R0 = the plot's covariance x `r0_scale`, dt), and scales Q (and singer's manoeuvre
frequency) of the prediction and R of the update. A track's filter starts, as in training, at its
first plot with the network's first (`fresh`) step: position measured, covariance R0 x r, the
velocity unknown up to the model's spread. It starts when the track is first predicted or
updated (clutter tracks, most of them, never are).

The network's features need the plot (its increment and its innovation), so the network runs per
(track, plot) pair: `PlotScaledGate` (the method's gate) has the estimator step the candidate tracks
to their plots (`predict_plot`: the network called once for all the pairs it is given, a plot's K
candidates or, the roles being `pairwise`, every pair of an antenna scan or of nearest neighbour's
look-ahead, `pipeline.tracker.run`), and scores them with the chi-square gate
(`pipeline.tracker.gate.ChiSquareGate`) on the scaled filter's own innovation covariance S = P(q) +
r R0; the chosen track's `update` resumes from that step, and `update_pairs` makes a scan's updates
in one call. Measured on the test split (issue 17), this beats gating with the scales each track's
network gave at its previous plot (`predict`, the protocol's prediction without a plot): GOSPA 203 m
against 211 m, ROCA 0.978 against 0.968. The covariance `update` returns is the scaled filter's
posterior, which the consistency metrics (ANEES) read.

A pair's numbers do not depend on the pairs stepped with it: the network (and the prediction with
its scales, in the same call) runs on rows padded as `pipeline.learning.batch_rows` says (MKL's
matrix products and torch's sigmoid otherwise give a row of a small call other last bits), and the
filter's own steps are elementwise or 3 x 3 to 9 x 9 products, each the same alone as in a batch.
So a scan stepped at once gives the updates of stepping it plot by plot, to the bit
(`tests/test_learned_scans.py`, both runtimes); since the padding (issue 29) a plot's rows differ
from the unpadded per-plot calls before it in the last bits. TorchScript runs the same kernels:
the tracks are those of eager PyTorch, to the bit.
"""

from __future__ import annotations

from dataclasses import fields
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from pipeline.filters import batch_filters, motion_models, torch_filters
from pipeline.filters.batch_filters import BatchState
from pipeline.filters.torch_filters import State, StepScales
from pipeline.learning import batch_rows, devices, step_runtime
from pipeline.learning.kalman_net import KalmanNet, Memory
from pipeline.tracker.assigner import Hypotheses
from pipeline.tracker.estimator import Prediction
from pipeline.tracker.gate import ChiSquareGate, Scores
from pipeline.tracker.tracks import LiveTracks


class KalmanNetEstimator:
    """One network-scaled filter per live track, of the trained `model` (eval mode, no gradients)."""

    gives_covariance = True
    gives_velocity = True
    pairwise = True
    latest_plots = 0  # a track's first plot starts its filter; the filter keeps the rest

    def __init__(self, model: KalmanNet, capacity: int = 64, runtime: str = "script", device: str = "cpu") -> None:
        self.device = devices.resolve(device)
        self.model = model = devices.placed(model, self.device)
        self.spec = model.base
        self.r0_scale = model.config.r0_scale
        self.singer = model.config.base == "singer"
        models, size = len(self.spec.models), motion_models.state_size(self.spec.models[0])
        like = dict(dtype=self.spec.dtype, device=self.device)
        self.x = torch.zeros((capacity, models, size), **like)
        self.P = torch.zeros((capacity, models, size, size), **like)
        self.mu = torch.ones((capacity, models), **like)
        self.q = torch.ones(capacity, **like)
        self.manoeuvre = torch.ones(capacity, **like)
        self.memory = model.memory(capacity)
        self.time = np.full(capacity, np.nan)  # NaN: the slot's filter is not started
        self._plot_step = step_runtime.traced(model, step_runtime.KalmanNetPlotStep, runtime, self._example)
        self._update = step_runtime.traced(model, step_runtime.KalmanNetUpdate, runtime,
                                           lambda rows: (*self._example(rows)[:3], *self._example(rows)[8:10]))

    def _example(self, rows: int) -> tuple[Tensor, ...]:
        """Inputs of `rows` tracks' plot step (`step_runtime.KalmanNetPlotStep`) to trace it with: started
        tracks, their memory, plots 1 km on after 4 s."""
        z = torch.full((rows, 3), 6.4e6, dtype=self.spec.dtype, device=self.device)
        R0 = torch.eye(3, dtype=self.spec.dtype, device=self.device).expand(rows, 3, 3) * 1e4
        state, memory = torch_filters.start(self.spec, z, R0), self.model.memory(rows)
        moving = torch.ones(rows, dtype=torch.bool, device=self.device)
        return (state.x, state.P, state.mu, memory.hidden, memory.estimate, memory.measurement, memory.dt, memory.age,
                z + 1e3, R0, torch.full((rows,), 4.0, dtype=torch.float64, device=self.device), ~moving, moving)

    def _grow(self, capacity: int) -> None:
        extra = capacity - len(self.time)

        def grown(values: Tensor, fill: float = 0.0) -> Tensor:
            return torch.cat([values, torch.full((extra, *values.shape[1:]), fill, dtype=values.dtype,
                                                 device=values.device)])
        self.x, self.P, self.mu = grown(self.x), grown(self.P), grown(self.mu, 1.0)
        self.q, self.manoeuvre = grown(self.q, 1.0), grown(self.manoeuvre, 1.0)
        self.memory = Memory(**{f.name: grown(getattr(self.memory, f.name)) for f in fields(Memory)})
        self.time = np.concatenate([self.time, np.full(extra, np.nan)])

    def start(self, tracks: LiveTracks, slot: int) -> None:
        """The track at `slot` is new: its filter starts when it is first stepped."""
        if slot >= len(self.time):
            self._grow(len(tracks.tracks))
        self.time[slot] = np.nan

    def _index(self, rows: np.ndarray) -> Tensor:
        """Indices (numpy) as a tensor on the device."""
        return torch.from_numpy(np.ascontiguousarray(rows)).to(self.device)

    def _state(self, slots: np.ndarray) -> State:
        index = self._index(slots)
        return State(self.x[index], self.P[index], self.mu[index])

    def _store(self, slots: np.ndarray, state: State, scales: StepScales, memory: Memory, time: np.ndarray) -> None:
        index = self._index(slots)
        self.x[index], self.P[index], self.mu[index] = state.x, state.P, state.mu
        self.q[index] = scales.q
        if self.singer:
            self.manoeuvre[index] = scales.manoeuvre
        for f in fields(Memory):
            getattr(self.memory, f.name)[index] = getattr(memory, f.name)
        self.time[slots] = time

    def velocities(self, tracks: LiveTracks, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The velocities (K, 3) m/s and their covariances (K, 3, 3) of the tracks at `slots` after their
        latest update, their models combined as the classical filters' (`batch_filters.velocity_estimates`)."""
        index = self._index(slots)
        return batch_filters.velocity_estimates(BatchState(*(values[index].cpu().numpy()
                                                              for values in (self.x, self.P, self.mu))))

    def _measured(self, tracks: LiveTracks, rows: list[int] | np.ndarray) -> tuple[Tensor, Tensor]:
        """The plots' positions z (K, 3) m and R0 = their covariances x r0_scale (K, 3, 3) m^2."""
        plots = tracks.plots
        return (torch.as_tensor(plots.position[rows], dtype=self.spec.dtype, device=self.device),
                torch.as_tensor(plots.covariance[rows], dtype=self.spec.dtype, device=self.device) * self.r0_scale)

    def _network(self, slots: np.ndarray, before: State, z: Tensor, R0: Tensor, dt: Tensor, fresh: bool
                 ) -> tuple[StepScales, Memory, State]:
        """The network's scales for the step of the tracks at `slots` (K,) from posterior `before` to plots
        z (K, 3) of nominal covariance R0 (K, 3, 3) after dt (K,) s, the track's first step if `fresh`,
        its memory after the step (`KalmanNet.step_scales`; the stored memory is left unchanged) and
        the prior predicted with the scales (`step_runtime.KalmanNetPlotStep`). Run on the rows of
        `batch_rows.padding` (the scales, sigmoids, a row apiece), so that a row's numbers are those of
        any other call."""
        count = len(slots)
        rows = batch_rows.padding(count, elements_each=len(self.model.config.outputs))
        at = self._index(rows)
        memory = _rows(self.memory, self._index(slots[rows]))
        flags = (torch.full((len(rows),), fresh, device=self.device),
                 torch.full((len(rows),), not fresh, device=self.device))
        scales, *after, x, P, mu = self._plot_step(before.x[at], before.P[at], before.mu[at],
                                                   *(getattr(memory, f.name) for f in fields(Memory)), z[at], R0[at],
                                                   dt[at], *flags)
        named = dict(zip(self.model.config.outputs, scales[:count].unbind(1)))
        return (StepScales(named["q"], named["r"], named.get("manoeuvre")),
                Memory(*(value[:count] for value in after)), State(x[:count], P[:count], mu[:count]))

    def _start_filters(self, tracks: LiveTracks, slots: np.ndarray) -> None:
        """Start the filters of the tracks at `slots` not started yet at their first plots, with the
        network's first step (fresh: no features yet) giving R's scale."""
        fresh = np.unique(slots[np.isnan(self.time[slots])])  # a scan's pairs hold a track once per plot
        if not len(fresh):
            return
        rows = [tracks.tracks[slot].rows[0] for slot in fresh]
        z, R0 = self._measured(tracks, rows)
        with torch.no_grad():
            scales, memory, _ = self._network(fresh, torch_filters.start(self.spec, z, R0), z, R0,
                                              torch.zeros(len(fresh), dtype=torch.float64, device=self.device),
                                              fresh=True)
            started = torch_filters.start(self.spec, z, R0 * scales.r[:, None, None])
        self._store(fresh, started, scales, memory, tracks.plots.time[rows])

    def predict(self, tracks: LiveTracks, slots: np.ndarray, time: float | np.ndarray) -> Prediction:
        """The tracks' filters moved to `time` (one, or one per track: `pairwise`) with the Q scales their
        networks gave at their last plots, unchanged: positions (K, 3) and covariances (K, 3, 3), no
        state (no plot: no network step)."""
        self._start_filters(tracks, slots)
        index = self._index(slots)
        dt = torch.as_tensor(time - self.time[slots], dtype=torch.float64, device=self.device)
        with torch.no_grad():
            motion = torch_filters.motion(self.spec, dt, self.q[index], self.manoeuvre[index] if self.singer else None)
            position, covariance = torch_filters.position_estimates(
                torch_filters.predicted(self.spec, self._state(slots), *motion))
        return Prediction(position.cpu().numpy(), covariance.cpu().numpy())

    def predict_plot(self, tracks: LiveTracks, slots: np.ndarray, row: int | np.ndarray) -> Prediction:
        """The tracks at `slots` (K,) stepped towards plot `row` (one, or one per track: `pairwise`) in
        one batch, unchanged: the network's scales from the plot, and each filter predicted with its Q
        scale. Positions (K, 3); covariances (K, 3, 3): the predicted position covariance plus the scaled
        measurement noise beyond the plot's own, r R0 - R, so that a gate adding the plot's R to them has
        S = P + r R0; the state a `PlotStep` for the update."""
        self._start_filters(tracks, slots)
        rows = np.broadcast_to(row, slots.shape)
        z, R0 = self._measured(tracks, rows)
        dt = torch.as_tensor(tracks.plots.time[rows] - self.time[slots], dtype=torch.float64, device=self.device)
        with torch.no_grad():
            scales, memory, prior = self._network(slots, self._state(slots), z, R0, dt, fresh=False)
            R = R0 * scales.r[:, None, None]
            position, covariance = torch_filters.position_estimates(prior)
        extra = R.cpu().numpy() - tracks.plots.covariance[rows]
        return Prediction(position.cpu().numpy(), covariance.cpu().numpy() + extra, PlotStep(prior, R, scales, memory))

    def update(self, tracks: LiveTracks, slot: int, row: int, prediction: Prediction | None, index: int
               ) -> tuple[np.ndarray, np.ndarray]:
        """The track's filter updated with plot `row` from its `predict_plot` step (made here when the
        gate made none: a young track): the new position (3,) and its covariance (3, 3)."""
        if prediction is None or prediction.state is None:
            prediction, index = self.predict_plot(tracks, np.array([slot]), row), 0
        position, covariance = self.update_pairs(tracks, np.array([slot]), np.array([row]), prediction,
                                                 np.array([index]))
        return position[0], covariance[0]

    def update_pairs(self, tracks: LiveTracks, slots: np.ndarray, rows: np.ndarray, prediction: Prediction | None,
                     indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The filters of the tracks at `slots` (P,), each a different track, updated each with its plot
        of `rows` (P,) from row `indices` (P,) of a `predict_plot` step (made here, one call for all, when
        `prediction` is None or carries none: young tracks): the new positions (P, 3) and covariances
        (P, 3, 3)."""
        if prediction is None or prediction.state is None:
            prediction, indices = self.predict_plot(tracks, slots, rows), np.arange(len(slots))
        step: PlotStep = prediction.state
        at = self._index(np.asarray(indices))
        z, _ = self._measured(tracks, rows)
        with torch.no_grad():
            x, P, mu, position, covariance = self._update(step.prior.x[at], step.prior.P[at], step.prior.mu[at], z,
                                                          step.R[at])
        scales = StepScales(*(None if value is None else value[at] for value in
                              (step.scales.q, step.scales.r, step.scales.manoeuvre)))
        self._store(slots, State(x, P, mu), scales, _rows(step.memory, at), tracks.plots.time[rows])
        return position.cpu().numpy(), covariance.cpu().numpy()

    def update_mixtures(self, tracks: LiveTracks, hypotheses: Hypotheses) -> tuple[np.ndarray, np.ndarray]:
        """The filters of the T tracks of `hypotheses` updated with all their plots at once, each weighted by
        its probability (a soft assigner's: `pipeline.tracker.jpda`). All of a track's hypotheses resume from
        the `predict_plot` step towards its reference plot: that prior, the network's R scale (applied to each
        plot's own R0) and its memory, which the track keeps; each hypothesis's update is merged per model
        as the classical filters' are (`batch_filters.collapsed`), stored at the reference plot's time.
        Returns the new positions (T, 3) and covariances (T, 3, 3)."""
        step: PlotStep = hypotheses.prediction.state
        at = self._index(hypotheses.reference_index)
        each = self._index(hypotheses.reference_index[hypotheses.track])
        z, R0 = self._measured(tracks, hypotheses.rows)
        with torch.no_grad():
            x, P, mu, _, _ = self._update(step.prior.x[each], step.prior.P[each], step.prior.mu[each], z,
                                          R0 * step.scales.r[each][:, None, None])
        prior = BatchState(*(values[at].cpu().numpy() for values in (step.prior.x, step.prior.P, step.prior.mu)))
        merged = batch_filters.collapsed(prior, BatchState(x.cpu().numpy(), P.cpu().numpy(), mu.cpu().numpy()),
                                         hypotheses.track, hypotheses.weights, hypotheses.missed)
        scales = StepScales(*(None if value is None else value[at] for value in
                              (step.scales.q, step.scales.r, step.scales.manoeuvre)))
        state = State(*(torch.as_tensor(values, dtype=self.spec.dtype, device=self.device)
                        for values in (merged.x, merged.P, merged.mu)))
        self._store(hypotheses.slots, state, scales, _rows(step.memory, at), tracks.plots.time[hypotheses.reference])
        return batch_filters.position_estimates(merged)


def _rows(memory: Memory, index: Tensor | slice) -> Memory:
    """The memory of the tracks at `index`."""
    return Memory(**{f.name: getattr(memory, f.name)[index] for f in fields(Memory)})


class PlotStep(NamedTuple):
    """K candidate tracks stepped towards their plots: the predicted `prior` (a State of K), the scaled
    measurement covariance `R` (K, 3, 3) m^2, the network's `scales` and its `memory` after the step."""

    prior: State
    R: Tensor
    scales: StepScales
    memory: Memory


class PlotScaledGate:
    """The chi-square gate (`ChiSquareGate`, gate probability `probability`) on the network-scaled
    filter's own innovation covariance: the estimator steps the candidates to the plot itself (each
    pair to its own plot: `pairwise`)."""

    uses_prediction = False
    pairwise = True
    latest_plots = 0

    def __init__(self, estimator: KalmanNetEstimator, probability: float) -> None:
        self.estimator, self.chi_square = estimator, ChiSquareGate(probability)

    def __call__(self, tracks: LiveTracks, slots: np.ndarray, row: int | np.ndarray, prediction: Prediction | None
                 ) -> Scores:
        return self.chi_square(tracks, slots, row, self.estimator.predict_plot(tracks, slots, row))
