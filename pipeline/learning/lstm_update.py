"""The LSTM update on a Kalman prediction (seed 001), with Monte-Carlo-dropout uncertainty.

The seed (`shared/reference/001_0406b49a545f4b16.txt`, restated in `shared/spec/related-work.md`
section A) keeps the constant-acceleration Kalman filter's prediction x~_t = F(dt) x_{t-1} (9
states, per axis [p, v, a], `torch_filters.motion` "ca") from the previous estimate and replaces
the measurement update by an LSTM cell whose hidden state h_t, with the prediction, gives the new
state through a linear layer, x_t = W [x~_t, h_t] + b. Here the linear layer gives a correction
added to the prediction, x_t = x~_t + D(W_o dropout([f_t, h_t]) + b_o): the seed's layer with the
identity on x~_t taken out, so that zero output weights give the Kalman prediction (the
tests' check), and the prediction enters through the features f_t.

Frame and normalisation (the seed's shift, rotate, normalise): every step is seen from the
prediction, in a level frame turned to the predicted heading: axes forward (the horizontal part of
the predicted velocity; east while the track has none), left, up (the geocentric vertical at the
predicted position, within 0.2 degrees of the geodetic one). The features f_t (16):
1. the innovation z_t - p~_t in that frame / `position_scale_m` (3) (shift to the origin);
2. the innovation over dt / `velocity_scale_mps` (3): the velocity it implies;
3. the plot's standard deviations on the frame's axes, sqrt(diag(A R A')) / `position_scale_m` (3);
4. the predicted velocity / `velocity_scale_mps` and acceleration / `acceleration_scale_mps2` in
   the frame (3 + 3): forward speed, climb, and the manoeuvre;
5. dt / `time_scale_s` (1).
The correction comes out in the same frame, D scales its position, velocity and acceleration parts
by the same scales, and it is turned back to ECEF. The output layer starts as an alpha-beta filter
(Kalata 1984): position += alpha innovation, velocity += beta innovation / dt, i.e. weight alpha on
feature 1 and beta on feature 2, everything else zero.

`detach_prediction` (the seed: the prediction is not differentiated through) cuts the previous
estimate from the graph before F; otherwise gradients flow through the whole recursion up to the
truncation.

Uncertainty (Gal and Ghahramani 2016, MC dropout): each track runs as N = 1 + `mc_samples`
copies in one batch (B N rows), each with its own state and memory: copy 0 without dropout, the
point estimate (as trained: it starts still at the track's first plot), and `mc_samples` copies
with their own dropout masks at every step, started with velocities spread by
`start_velocity_std_mps` (antithetic, mean zero), so that the prediction at the second plot
carries the unknown velocity as the Kalman filter's start covariance does. The covariance is the
copies' second moment C = sum_k (x_k - x_0)(x_k - x_0)' / `mc_samples` about the point estimate
(spread and bias of the copies). The estimate's covariance is a C + b R + `floor_m`^2 I, R the plot's
covariance: the MC spread is the model's (epistemic) uncertainty and the plot noise that stays in
the estimate the data's (aleatoric) one, summed as Kendall and Gal (2017, "What uncertainties do
we need in Bayesian deep learning", eq. 9) sum the MC variance and the predicted noise variance;
the spread alone gave NEES far heavier-tailed than chi-square with 3 degrees of freedom (median
0.95 against 2.37 on the hold-out) and so an ANEES that moved with each draw of the masks. The
prediction's covariance (the gate's) is c C + `floor_m`^2 I. The factors a, b, c depend on the
track's age (plots since its start: the start spread fades with it) up to `calibration_ages`,
older tracks taking the last. They are fitted after training on validation material the
estimator never trained on (the stage's `validation_fraction` of the split's segments, as
windows of the stage's `segment_plots` plots started at every plot, as the hold-out's windows are:
windows of `calibration_ages` + 1 plots gave the gate of old tracks a factor of 22 where those give
30, and the tracker split each aircraft into 2.1 tracks, issue 18, test split), age by
age (`calibrate`): the estimate's a, b by maximum likelihood of the errors under N(0, a C + b R +
floor), then scaled together so that their mean NEES is 3, the dimension (the ML optimum is there
already up to the floor); the prediction's for the gate, so that the chi-square gate of probability
p with S = c C + R lets through the share p of the training plots (its definition), fitted on the
predictions over one scan period (dt / `time_scale_s` rounds to 1). The prediction's factor is
then multiplied by one for the scan periods k the prediction spans (2 .. `calibration_gaps`, longer
gaps taking the last; 1 for k = 1), fitted the same way on all ages' predictions over k periods:
the copies' spread grows linearly with dt (their velocities differ) while the error of a
prediction over missed scans grows faster (the unmodelled acceleration's dt^2 / 2, and no LSTM
correction in between), so one factor for every dt let 4-6 % of a tracked aircraft's plots out of
the gate after a missed scan (issue 18, test split). A mean NIS of 3
would not do: the LSTM's innovations have heavier tails than a Gaussian's, and such a gate rejects
about 1 % of a track's own plots at every scan, where p = 0.999 promises 0.1 %. With dropout 0 one
copy runs and the covariance is the floor.

Shapes: B tracks, N samples, T steps, H hidden units; float64 like `torch_filters`.
"""

from __future__ import annotations

import functools

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.optimize import minimize
from scipy.stats import chi2
from torch import Tensor, nn

from pipeline.filters import torch_filters
from pipeline.filters.torch_filters import Filtered, FilterSpec, SequenceBatch, State
from pipeline.learning import model_store

FEATURES = 16
STATES = 9
_CA = FilterSpec("ca", (1.0,), 1.0, 1.0)  # its F only: the noise values do not enter the prediction


@dataclass(frozen=True)
class LSTMUpdateConfig:
    """The estimator's design values (params.yaml `lstm_update`, which documents them)."""

    hidden: int
    dropout: float
    mc_samples: int
    detach_prediction: bool
    position_scale_m: float
    velocity_scale_mps: float
    acceleration_scale_mps2: float
    time_scale_s: float
    initial_alpha: float
    initial_beta: float
    floor_m: float
    start_velocity_std_mps: float
    calibration_ages: int
    calibration_gaps: int

    def __post_init__(self) -> None:
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"lstm_update.dropout = {self.dropout!r}: must be in [0, 1)")
        if self.mc_samples < 1:
            raise ValueError(f"lstm_update.mc_samples = {self.mc_samples!r}: must be at least 1")
        if self.calibration_gaps < 1:
            raise ValueError(f"lstm_update.calibration_gaps = {self.calibration_gaps!r}: must be at least 1")


@dataclass(frozen=True)
class Ensemble:
    """N copies of B tracks: states x (B, N, 9) ECEF [p, v, a] per axis, LSTM memory h and c (B, N, H),
    and each track's age (B,) (plots since its start, that one included)."""

    x: Tensor
    h: Tensor
    c: Tensor
    age: Tensor

    def detached(self) -> Ensemble:
        return Ensemble(self.x.detach(), self.h.detach(), self.c.detach(), self.age)

    def where(self, rows: Tensor, other: Ensemble) -> Ensemble:
        """Per track (rows (B,) bool): this ensemble where true, `other` elsewhere."""
        keep = rows[:, None, None]
        return Ensemble(torch.where(keep, self.x, other.x), torch.where(keep, self.h, other.h),
                        torch.where(keep, self.c, other.c), torch.where(rows, self.age, other.age))


def transition(dt: Tensor) -> Tensor:
    """The constant-acceleration F (B, 9, 9) over dt (B,) s (`torch_filters.motion`, the seed's F)."""
    return torch_filters.motion(_CA, dt)[0][:, 0]


def level_frames(position: Tensor, velocity: Tensor) -> Tensor:
    """Rows forward, left, up (..., 3, 3) at ECEF `position` (..., 3) m heading along `velocity`
    (..., 3) m/s (module docstring); east where the horizontal velocity is below 1e-6 m/s."""
    up = position / position.norm(dim=-1, keepdim=True)
    east = torch.stack([-position[..., 1], position[..., 0], torch.zeros_like(position[..., 0])], -1)
    east = east / east.norm(dim=-1, keepdim=True)
    level = velocity - (velocity * up).sum(-1, keepdim=True) * up
    speed = level.norm(dim=-1, keepdim=True)
    forward = torch.where(speed > 1e-6, level / speed.clamp(min=1e-6), east)
    return torch.stack([forward, torch.linalg.cross(up, forward), up], -2)


@functools.lru_cache(maxsize=16)
def _start_velocities(samples: int, dtype: torch.dtype, std_mps: float) -> Tensor:
    """`LSTMUpdate.start_velocities`, made once per (samples, dtype, std): callers get a copy."""
    draws = torch.randn((samples - 1) // 2, 3, generator=torch.Generator().manual_seed(0), dtype=dtype)
    still = torch.zeros(1 + (samples - 1) % 2, 3, dtype=dtype)
    return torch.cat([still, draws, -draws]) * std_mps


def spread(samples: Tensor) -> tuple[Tensor, Tensor]:
    """The point estimate (B, k), copy 0 of (B, N, k), and the other copies' second moment about it
    (B, k, k) (module docstring); zero for N = 1."""
    centre = samples[:, 0]
    offset = samples[:, 1:] - centre[:, None]
    return centre, offset.transpose(1, 2) @ offset / max(samples.shape[1] - 1, 1)


class LSTMUpdate(nn.Module):
    """The CA Kalman prediction corrected by an LSTM cell (module docstring)."""

    def __init__(self, config: LSTMUpdateConfig, dtype: torch.dtype = torch_filters.DTYPE) -> None:
        super().__init__()
        self.config = config
        self.cell = nn.LSTMCell(FEATURES, config.hidden).to(dtype)
        self.output = nn.Linear(FEATURES + config.hidden, STATES).to(dtype)
        with torch.no_grad():  # an alpha-beta filter until trained
            self.output.weight.zero_()
            self.output.bias.zero_()
            for axis in range(3):
                self.output.weight[3 * axis, axis] = config.initial_alpha
                self.output.weight[3 * axis + 1, 3 + axis] = config.initial_beta
        scales = (config.position_scale_m, config.velocity_scale_mps, config.acceleration_scale_mps2)
        self.register_buffer("output_scale", torch.tensor(scales * 3, dtype=dtype))
        self.register_buffer("calibration", torch.ones(2, config.calibration_ages, dtype=dtype))  # estimate's a,
        # prediction's c, by age 1 .. calibration_ages
        self.register_buffer("plot_calibration", torch.zeros(config.calibration_ages, dtype=dtype))  # the
        # estimate's b (of the plot's R), by age
        self.register_buffer("gap_calibration", torch.ones(config.calibration_gaps, dtype=dtype))  # the
        # prediction's, by scan periods 1 .. calibration_gaps

    @property
    def dtype(self) -> torch.dtype:
        return self.output.weight.dtype

    def start_velocities(self, samples: int) -> Tensor:
        """The copies' start velocities (samples, 3) m/s: copy 0 still, the others antithetic pairs of
        normal draws (a fixed generator: the same for every track and run) times
        `start_velocity_std_mps`, an odd one out still, so their mean is zero. A new tensor each call
        (`_start_velocities` keeps them: the tracker starts tracks one at a time, and a generator's
        making and seeding cost more than the rest of a start)."""
        return _start_velocities(samples, self.dtype, self.config.start_velocity_std_mps).clone()

    def started(self, z: Tensor, samples: int) -> Ensemble:
        """`samples` copies of tracks started at plots z (B, 3): at the plot, velocities
        `start_velocities` (the copies' prior, as an ensemble Kalman filter draws one), memory empty;
        on z's device."""
        x = torch.zeros(len(z), samples, STATES, dtype=self.dtype, device=z.device)
        x[..., ::3] = z[:, None]
        x[..., 1::3] = self.start_velocities(samples).to(z.device)
        memory = torch.zeros(len(z), samples, self.config.hidden, dtype=self.dtype, device=z.device)
        return Ensemble(x, memory, memory, torch.ones(len(z), dtype=torch.long, device=z.device))

    def predicted(self, x: Tensor, dt: Tensor) -> Tensor:
        """x~ = F x (B, N, 9) over dt (B,) s, the previous estimate cut from the graph if
        `detach_prediction`."""
        if self.config.detach_prediction:
            x = x.detach()
        return x @ transition(dt.to(self.dtype)).transpose(1, 2)

    def features(self, prior: Tensor, z: Tensor, R: Tensor, dt: Tensor) -> tuple[Tensor, Tensor]:
        """The features f (B, N, 16) of plot z (B, 3) of covariance R (B, 3, 3) after dt (B,) s
        against the predictions `prior` (B, N, 9), and the frames (B, N, 3, 3) they are in."""
        c = self.config
        frame = level_frames(prior[..., ::3], prior[..., 1::3])
        to_frame = lambda v: (frame @ v[..., None])[..., 0]  # noqa: E731
        innovation = to_frame(z[:, None] - prior[..., ::3])
        safe_dt = torch.where(dt > 0, dt, 1.0).to(self.dtype)[:, None, None]
        deviation = torch.diagonal(frame @ R[:, None] @ frame.transpose(-1, -2), dim1=-2, dim2=-1).sqrt()
        time = (dt.to(self.dtype) / c.time_scale_s)[:, None, None].expand(*prior.shape[:2], 1)
        return torch.cat([innovation / c.position_scale_m, innovation / safe_dt / c.velocity_scale_mps,
                          deviation / c.position_scale_m, to_frame(prior[..., 1::3]) / c.velocity_scale_mps,
                          to_frame(prior[..., 2::3]) / c.acceleration_scale_mps2, time], -1), frame

    def step(self, ensemble: Ensemble, z: Tensor, R: Tensor, dt: Tensor, sample: bool, masks: Tensor | None = None
             ) -> tuple[Ensemble, Tensor]:
        """One plot z (B, 3), covariance R (B, 3, 3), dt (B,) s after the ensemble's estimates:
        the new ensemble and the predictions x~ (B, N, 9). `sample`: dropout masks on (training,
        MC dropout; copy 0 of several has none), off for a deterministic estimate. `masks` (B, N, 16 + H):
        the dropout masks to use, scaled as dropout scales them (`dropout_masks`), instead of drawing
        them from torch's generator (the tracker draws each track's from its own sequence)."""
        prior = self.predicted(ensemble.x, dt)
        f, frame = self.features(prior, z, R, dt)
        B, N, _ = f.shape
        h, c = self.cell(f.reshape(B * N, -1), (ensemble.h.reshape(B * N, -1), ensemble.c.reshape(B * N, -1)))
        read = torch.cat([f.reshape(B * N, -1), h], 1)
        if masks is None:
            dropped = nn.functional.dropout(read, self.config.dropout, sample)
        else:
            dropped = read * masks.reshape(B * N, -1)
        if N > 1:  # copy 0: the point estimate
            dropped = torch.cat([read.reshape(B, N, -1)[:, :1], dropped.reshape(B, N, -1)[:, 1:]], 1)
        read = dropped.reshape(B * N, -1)
        correction = (self.output(read) * self.output_scale).reshape(B, N, 3, 3)  # [axis, p/v/a] in the frame
        correction = (frame.transpose(-1, -2) @ correction).reshape(B, N, STATES)
        return Ensemble(prior + correction, h.reshape(B, N, -1), c.reshape(B, N, -1), ensemble.age + 1), prior

    def dropout_masks(self, copies: int, generator: torch.Generator, tracks: int | None = None) -> Tensor:
        """One track's dropout masks (copies, 16 + H), as `nn.functional.dropout` draws them for the
        `step` of that one track: Bernoulli(1 - p) over 1 - p, drawn from `generator` in the same
        order, so that masks drawn track by track give the numbers of stepping the tracks one at a time.
        With `tracks`, that many tracks' (tracks, copies, 16 + H), each track's drawn in turn as a call
        for it alone draws them (a draw into a track's contiguous rows is the draw of a tensor of its
        own), scaled in one division: the same numbers for one tensor operation per track, not four."""
        keep = 1.0 - self.config.dropout
        if tracks is None:
            masks = torch.empty((copies, FEATURES + self.config.hidden), dtype=self.dtype)
            return masks.bernoulli_(keep, generator=generator).div_(keep)
        masks = torch.empty((tracks, copies, FEATURES + self.config.hidden), dtype=self.dtype)
        for track in masks:
            track.bernoulli_(keep, generator=generator)
        return masks.div_(keep)

    def scan_periods(self, dt: Tensor) -> Tensor:
        """The scan periods (B,) a prediction over dt (B,) s spans: dt / `time_scale_s` rounded, in
        [1, `calibration_gaps`] (the index + 1 of its `gap_calibration`)."""
        return torch.round(dt.to(self.dtype) / self.config.time_scale_s).long().clamp(1, self.config.calibration_gaps)

    def estimate_covariance(self, samples: Tensor, age: Tensor, R: Tensor) -> tuple[Tensor, Tensor]:
        """Point estimate (B, 3) and calibrated covariance a C + b R + floor (B, 3, 3) of the copies'
        positions (B, N, 3) of tracks of `age` (B,) (after the plot) updated with plots of covariance R
        (B, 3, 3) (module docstring)."""
        centre, covariance = spread(samples)
        at = age.clamp(1, self.config.calibration_ages) - 1
        return centre, (self.calibration[0, at][:, None, None] * covariance
                        + self.plot_calibration[at][:, None, None] * R + self._floor())

    def prediction_covariance(self, samples: Tensor, age: Tensor, dt: Tensor) -> tuple[Tensor, Tensor]:
        """Point prediction (B, 3) and calibrated covariance c C + floor (B, 3, 3) of the copies'
        predicted positions (B, N, 3) of tracks of `age` (B,) (before the plot) over dt (B,) s."""
        centre, covariance = spread(samples)
        factor = (self.calibration[1, age.clamp(1, self.config.calibration_ages) - 1]
                  * self.gap_calibration[self.scan_periods(dt) - 1])
        return centre, factor[:, None, None] * covariance + self._floor()

    def _floor(self) -> Tensor:
        return self.config.floor_m ** 2 * torch.eye(3, dtype=self.dtype, device=self.output.weight.device)

    def ensemble(self) -> tuple[int, bool]:
        """How many copies of a track run and whether their dropout masks are on: in training one
        copy with dropout (the loss); else the point estimate and `mc_samples` MC-dropout copies, or
        the point estimate alone when dropout is 0."""
        if self.training:
            return 1, True
        return (1, False) if self.config.dropout == 0 else (1 + self.config.mc_samples, True)

    def forward(self, batch: SequenceBatch, detach_every: int | None = None) -> Filtered:
        """B sequences of T plots filtered (padding skipped, restarts started afresh) by the ensemble
        of `ensemble()`, its state cut from the graph every `detach_every` steps (truncated BPTT)."""
        samples, sample = self.ensemble()
        return run_sequences(self, batch, samples, sample, detach_every).filtered(self, batch)


@dataclass(frozen=True)
class Run:
    """An ensemble run over B sequences of T steps: estimates and predictions (B, T, N, 3) ECEF m
    (NaN-free; padding repeats the state), the tracks' ages (B, T) after and before each step, the
    time steps predicted over (B, T) s, and the last ensemble."""

    estimates: Tensor
    predictions: Tensor
    ages: Tensor
    prior_ages: Tensor
    dt: Tensor
    last: Ensemble

    def filtered(self, model: LSTMUpdate, batch: SequenceBatch) -> Filtered:
        """As `torch_filters.Filtered`: positions and covariances (calibrated, `LSTMUpdate.estimate_covariance`),
        innovations against the point estimate's prediction with S = its covariance + R, NaN where not
        defined; one mode of probability 1."""
        B, T, N, _ = self.estimates.shape
        R = batch.covariances.reshape(B * T, 3, 3).to(model.dtype)
        position, covariance = model.estimate_covariance(self.estimates.reshape(B * T, N, 3), self.ages.reshape(-1), R)
        predicted, predicted_covariance = model.prediction_covariance(self.predictions.reshape(B * T, N, 3),
                                                                      self.prior_ages.reshape(-1), self.dt.reshape(-1))
        innovation = batch.positions.reshape(B * T, 3) - predicted
        S = predicted_covariance + R
        distance = (innovation[:, None] @ torch_filters.inverse3(S)[0] @ innovation[:, :, None])[:, 0, 0]
        moving = batch.valid & ~batch.restart
        blank = torch_filters._blank
        point = self.last.x[:, 0]
        return Filtered(blank(position.reshape(B, T, 3), batch.valid),
                        blank(covariance.reshape(B, T, 3, 3), batch.valid),
                        blank(torch.ones(B, T, 1, dtype=model.dtype), batch.valid),
                        blank(innovation.reshape(B, T, 3), moving), blank(S.reshape(B, T, 3, 3), moving),
                        blank(distance.reshape(B, T), moving),
                        State(point[:, None], torch.zeros(B, 1, STATES, STATES, dtype=model.dtype),
                              torch.ones(B, 1, dtype=model.dtype)))


def run_sequences(model: LSTMUpdate, batch: SequenceBatch, samples: int, sample: bool,
                  detach_every: int | None = None) -> Run:
    """`samples` copies of each of the batch's B sequences through the estimator, step by step."""
    if detach_every is not None and detach_every < 1:
        raise ValueError(f"detach_every = {detach_every}: must be at least 1 step (or None)")
    positions, covariances = batch.positions.to(model.dtype), batch.covariances.to(model.dtype)
    dt = torch_filters.time_steps(batch.times, batch.valid, batch.restart)
    ensemble = model.started(positions[:, 0], samples)
    estimates, predictions, ages, prior_ages = [], [], [], []
    for t in range(batch.times.shape[1]):
        if detach_every is not None and t and t % detach_every == 0:
            ensemble = ensemble.detached()
        z = positions[:, t]
        after, prior = model.step(ensemble, z, covariances[:, t], dt[:, t], sample)
        fresh = batch.valid[:, t] & batch.restart[:, t]
        moving = batch.valid[:, t] & ~batch.restart[:, t]
        after = model.started(z, samples).where(fresh, after.where(moving, ensemble))
        predictions.append(torch.where(moving[:, None, None], prior[..., ::3], after.x[..., ::3]))
        estimates.append(after.x[..., ::3])
        prior_ages.append(ensemble.age)
        ages.append(after.age)
        ensemble = after
    return Run(torch.stack(estimates, 1), torch.stack(predictions, 1), torch.stack(ages, 1), torch.stack(prior_ages, 1),
               dt, ensemble)


def calibrate(model: LSTMUpdate, batch: SequenceBatch, gate_probability: float) -> tuple[Tensor, Tensor, Tensor]:
    """Fit the covariance factors on `batch`'s updates (validation material, module docstring), age by
    age up to `calibration_ages` (the last takes every older update): the estimate's a, b
    (`_estimate_factors`), the prediction's c (`_gate_factor`) on the predictions over one scan
    period; then the prediction's factor for each longer gap, over all ages with their factors
    applied; where there are no updates (a start's estimate) a = 1, b = 0, c = 1. Sets and returns
    them ((2, calibration_ages) a and c, (calibration_ages,) b, (calibration_gaps,)). Without copies
    (dropout 0) left as they are."""
    if model.config.dropout == 0:
        return model.calibration, model.plot_calibration, model.gap_calibration
    with torch.no_grad():
        model.calibration.fill_(1.0)
        model.plot_calibration.fill_(0.0)
        model.gap_calibration.fill_(1.0)
        run = run_sequences(model, batch, *model.eval().ensemble())
        moving = batch.valid & ~batch.restart
        periods = model.scan_periods(run.dt)
        floor = model._floor()
        top = model.config.calibration_ages
        for age in range(1, top + 1):
            rows = moving & ((run.ages == age) if age < top else (run.ages >= age))
            if rows.any():
                centre, C = spread(run.estimates[rows])
                model.calibration[0, age - 1], model.plot_calibration[age - 1] = _estimate_factors(
                    batch.truth[rows] - centre, C, batch.covariances[rows], floor)
            rows = moving & ((run.prior_ages == age) if age < top else (run.prior_ages >= age)) & (periods == 1)
            if rows.any():
                centre, C = spread(run.predictions[rows])
                model.calibration[1, age - 1] = _gate_factor(batch.positions[rows] - centre, C,
                                                             floor + batch.covariances[rows], gate_probability)
        for gap in range(2, model.config.calibration_gaps + 1):
            rows = moving & (periods == gap)
            if rows.any():
                centre, C = spread(run.predictions[rows])
                by_age = model.calibration[1, run.prior_ages[rows].clamp(1, top) - 1]
                model.gap_calibration[gap - 1] = _gate_factor(batch.positions[rows] - centre, by_age[:, None, None] * C,
                                                              floor + batch.covariances[rows], gate_probability)
    return model.calibration, model.plot_calibration, model.gap_calibration


def _distance(d: Tensor, S: Tensor) -> Tensor:
    """d' S^-1 d (n,) of d (n, 3) and S (n, 3, 3)."""
    return (d[:, None] @ torch.linalg.solve(S, d[:, :, None]))[:, 0, 0]


def _estimate_factors(error: Tensor, C: Tensor, R: Tensor, floor: Tensor) -> tuple[float, float]:
    """The a, b >= 0 of the estimate's covariance P = a C + b R + floor for the errors `error` (n, 3),
    MC spreads C and plot covariances R (n, 3, 3): the Gaussian maximum likelihood, min over log a,
    log b of the mean of log det P + e' P^-1 e (scipy's Nelder-Mead from a = b = 1), then a and b
    scaled together (bisection on the scale) so that the mean NEES e' P^-1 e is 3, the dimension
    (Bar-Shalom, Li and Kirubarajan 2001, section 5.4.2: a consistent estimator's ANEES)."""
    def covariance(log_a: float, log_b: float) -> Tensor:
        return math.exp(log_a) * C + math.exp(log_b) * R + floor

    def loss(logs: np.ndarray) -> float:
        P = covariance(*logs)
        return float((torch.logdet(P) + _distance(error, P)).mean())
    log_a, log_b = minimize(loss, np.zeros(2), method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-6}).x
    low, high = -20.0, 20.0  # log of the common scale: the mean NEES falls as it grows
    while high - low > 1e-6:
        middle = (low + high) / 2
        too_small = float(_distance(error, covariance(log_a + middle, log_b + middle)).mean()) > 3
        low, high = (middle, high) if too_small else (low, middle)
    return math.exp(log_a + high), math.exp(log_b + high)


def _gate_factor(innovation: Tensor, C: Tensor, rest: Tensor, probability: float) -> float:
    """The smallest c (within a factor 1e-4, in [1e-6, 1e6]) for which the chi-square gate of
    `probability` (3 degrees of freedom) with S = c C + rest lets through that share of the
    `innovation`s (n, 3); the share rejected falls as c grows (C positive semidefinite): bisection on
    log c."""
    threshold, allowed = chi2.ppf(probability, 3), 1.0 - probability

    def rejected(log_c: float) -> float:
        return float((_distance(innovation, math.exp(log_c) * C + rest) > threshold).double().mean())
    low, high = math.log(1e-6), math.log(1e6)
    if rejected(high) > allowed:
        return 1e6
    if rejected(low) <= allowed:
        return 1e-6
    while high - low > 1e-4:
        middle = (low + high) / 2
        low, high = (middle, high) if rejected(middle) > allowed else (low, middle)
    return math.exp(high)


def load(path: Path) -> LSTMUpdate:
    """An estimator saved by `model_store.save_network` (config, weights, calibration), ready to estimate (eval
    mode); InputError naming a missing, unreadable or foreign file (`model_store.load_network`)."""
    return model_store.load_network(path, lambda config: LSTMUpdate(LSTMUpdateConfig(**config)),
                                    "train_lstm_update")
