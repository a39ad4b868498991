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

Uncertainty (Gal and Ghahramani 2016, MC dropout): the dropout masks stay on, and N =
`mc_samples` copies of each track run as one batch (B N rows), each with its own masks at every
step and its own state and memory: an ensemble. The estimate is the ensemble mean, its covariance
the ensemble's sample covariance of the position times a calibration factor, plus `floor_m`^2 I;
the prediction's likewise (the gate's). The two factors are fitted after training on training
material (`calibrate`): the estimate's so that its mean NEES is 3, the prediction's so that the
mean NIS against S = c C + R is 3. With dropout 0 the copies coincide and the spread is zero.

Shapes: B tracks, N samples, T steps, H hidden units; float64 like `torch_filters`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from scipy.optimize import brentq
from torch import Tensor, nn

from pipeline import torch_filters
from pipeline.torch_filters import Filtered, FilterSpec, SequenceBatch, State

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

    def __post_init__(self) -> None:
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"lstm_update.dropout = {self.dropout!r}: must be in [0, 1)")
        if self.mc_samples < 1:
            raise ValueError(f"lstm_update.mc_samples = {self.mc_samples!r}: must be at least 1")


@dataclass(frozen=True)
class Ensemble:
    """N copies of B tracks: states x (B, N, 9) ECEF [p, v, a] per axis, LSTM memory h and c (B, N, H)."""

    x: Tensor
    h: Tensor
    c: Tensor

    def detached(self) -> Ensemble:
        return Ensemble(self.x.detach(), self.h.detach(), self.c.detach())

    def where(self, rows: Tensor, other: Ensemble) -> Ensemble:
        """Per track (rows (B,) bool): this ensemble where true, `other` elsewhere."""
        keep = rows[:, None, None]
        return Ensemble(torch.where(keep, self.x, other.x), torch.where(keep, self.h, other.h),
                        torch.where(keep, self.c, other.c))


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


def spread(samples: Tensor) -> tuple[Tensor, Tensor]:
    """Mean (B, k) and sample covariance (B, k, k) over the N samples of (B, N, k); zero for N = 1."""
    mean = samples.mean(1)
    offset = samples - mean[:, None]
    return mean, offset.transpose(1, 2) @ offset / max(samples.shape[1] - 1, 1)


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
        self.register_buffer("calibration", torch.ones(2, dtype=dtype))  # estimate's, prediction's

    @property
    def dtype(self) -> torch.dtype:
        return self.output.weight.dtype

    def started(self, z: Tensor, samples: int) -> Ensemble:
        """`samples` copies of tracks started at plots z (B, 3): at the plot, still, memory empty."""
        x = torch.zeros(len(z), samples, STATES, dtype=self.dtype)
        x[..., ::3] = z[:, None]
        memory = torch.zeros(len(z), samples, self.config.hidden, dtype=self.dtype)
        return Ensemble(x, memory, memory)

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

    def step(self, ensemble: Ensemble, z: Tensor, R: Tensor, dt: Tensor, sample: bool
             ) -> tuple[Ensemble, Tensor]:
        """One plot z (B, 3), covariance R (B, 3, 3), dt (B,) s after the ensemble's estimates:
        the new ensemble and the predictions x~ (B, N, 9). `sample`: dropout masks on (training,
        MC dropout), off for the deterministic estimate."""
        prior = self.predicted(ensemble.x, dt)
        f, frame = self.features(prior, z, R, dt)
        B, N, _ = f.shape
        h, c = self.cell(f.reshape(B * N, -1), (ensemble.h.reshape(B * N, -1), ensemble.c.reshape(B * N, -1)))
        read = nn.functional.dropout(torch.cat([f.reshape(B * N, -1), h], 1), self.config.dropout, sample)
        correction = (self.output(read) * self.output_scale).reshape(B, N, 3, 3)  # [axis, p/v/a] in the frame
        correction = (frame.transpose(-1, -2) @ correction).reshape(B, N, STATES)
        return Ensemble(prior + correction, h.reshape(B, N, -1), c.reshape(B, N, -1)), prior

    def covariance(self, samples: Tensor, which: int) -> tuple[Tensor, Tensor]:
        """Mean (B, 3) and calibrated covariance (B, 3, 3) of sample positions (B, N, 3); `which`:
        0 the estimate's calibration, 1 the prediction's."""
        mean, covariance = spread(samples)
        floor = self.config.floor_m ** 2 * torch.eye(3, dtype=self.dtype)
        return mean, self.calibration[which] * covariance + floor

    def ensemble(self) -> tuple[int, bool]:
        """How many copies of a track run and whether their dropout masks are on: in training one
        copy with dropout (the loss); else the MC-dropout ensemble of `mc_samples` copies, or one
        copy without dropout when dropout is 0 or `mc_samples` 1."""
        if self.training:
            return 1, True
        samples = 1 if self.config.dropout == 0 else self.config.mc_samples
        return samples, samples > 1

    def forward(self, batch: SequenceBatch, detach_every: int | None = None) -> Filtered:
        """B sequences of T plots filtered (padding skipped, restarts started afresh) by the ensemble
        of `ensemble()`, its state cut from the graph every `detach_every` steps (truncated BPTT)."""
        samples, sample = self.ensemble()
        return run_sequences(self, batch, samples, sample, detach_every).filtered(self, batch)

    def deterministic(self, batch: SequenceBatch) -> Filtered:
        """The sequences with dropout off (one copy): the estimator's point estimates."""
        return run_sequences(self, batch, 1, sample=False).filtered(self, batch)


@dataclass(frozen=True)
class Run:
    """An ensemble run over B sequences of T steps: estimates and predictions (B, T, N, 3) ECEF m
    (NaN-free; padding repeats the state), and the last ensemble."""

    estimates: Tensor
    predictions: Tensor
    last: Ensemble

    def filtered(self, model: LSTMUpdate, batch: SequenceBatch) -> Filtered:
        """As `torch_filters.Filtered`: positions and covariances (calibrated, `LSTMUpdate.covariance`),
        innovations against the ensemble's mean prediction with S = its covariance + R, NaN where not
        defined; one mode of probability 1."""
        B, T, N, _ = self.estimates.shape
        position, covariance = model.covariance(self.estimates.reshape(B * T, N, 3), 0)
        predicted, predicted_covariance = model.covariance(self.predictions.reshape(B * T, N, 3), 1)
        innovation = batch.positions.reshape(B * T, 3) - predicted
        S = predicted_covariance + batch.covariances.reshape(B * T, 3, 3)
        distance = (innovation[:, None] @ torch_filters.inverse3(S)[0] @ innovation[:, :, None])[:, 0, 0]
        moving = batch.valid & ~batch.restart
        blank = torch_filters._blank
        mean = self.last.x.mean(1)
        return Filtered(blank(position.reshape(B, T, 3), batch.valid), blank(covariance.reshape(B, T, 3, 3), batch.valid),
                        blank(torch.ones(B, T, 1, dtype=model.dtype), batch.valid),
                        blank(innovation.reshape(B, T, 3), moving), blank(S.reshape(B, T, 3, 3), moving),
                        blank(distance.reshape(B, T), moving),
                        State(mean[:, None], torch.zeros(B, 1, STATES, STATES, dtype=model.dtype),
                              torch.ones(B, 1, dtype=model.dtype)))


def run_sequences(model: LSTMUpdate, batch: SequenceBatch, samples: int, sample: bool,
                  detach_every: int | None = None) -> Run:
    """`samples` copies of each of the batch's B sequences through the estimator, step by step."""
    if detach_every is not None and detach_every < 1:
        raise ValueError(f"detach_every = {detach_every}: must be at least 1 step (or None)")
    positions, covariances = batch.positions.to(model.dtype), batch.covariances.to(model.dtype)
    dt = torch_filters.time_steps(batch.times, batch.valid, batch.restart)
    ensemble = model.started(positions[:, 0], samples)
    estimates, predictions = [], []
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
        ensemble = after
    return Run(torch.stack(estimates, 1), torch.stack(predictions, 1), ensemble)


def calibrate(model: LSTMUpdate, batch: SequenceBatch) -> tuple[float, float]:
    """Fit the two covariance factors on `batch`'s scored steps (module docstring): the estimate's
    c = mean NEES of the uncalibrated ensemble covariance / 3 (NEES scales as 1 / c), the
    prediction's the root of mean d' (c C + R)^-1 d = 3 (decreasing in c, scipy's brentq on
    [1e-6, 1e6], clipped there). Sets and returns them. Without spread (dropout 0) both stay 1."""
    if model.config.dropout == 0 or model.config.mc_samples < 2:
        return 1.0, 1.0
    with torch.no_grad():
        model.calibration.fill_(1.0)
        run = run_sequences(model, batch, model.config.mc_samples, sample=True)
        scored = batch.scored & ~batch.restart
        estimates, predictions = run.estimates[scored], run.predictions[scored]
        floor = model.config.floor_m ** 2 * torch.eye(3, dtype=model.dtype)
        mean, C = spread(estimates)
        error = mean - batch.truth[scored]
        nees = (error[:, None] @ torch.linalg.solve(C + floor, error[:, :, None]))[:, 0, 0]
        estimate_factor = float(nees.mean() / 3)
        mean, C = spread(predictions)
        innovation, R = batch.positions[scored] - mean, batch.covariances[scored]

        def excess(c: float) -> float:
            S = c * C + floor + R
            return float((innovation[:, None] @ torch.linalg.solve(S, innovation[:, :, None])).mean()) - 3.0
        low, high = 1e-6, 1e6
        prediction_factor = low if excess(low) < 0 else high if excess(high) > 0 else brentq(excess, low, high,
                                                                                                rtol=1e-4)
        model.calibration.copy_(torch.tensor([estimate_factor, prediction_factor], dtype=model.dtype))
    return estimate_factor, prediction_factor


def load(path: Path) -> LSTMUpdate:
    """An estimator saved by `kalman_net.save` (config, weights, calibration), ready to estimate (eval mode)."""
    stored = torch.load(path, weights_only=True)
    model = LSTMUpdate(LSTMUpdateConfig(**stored["config"]))
    model.load_state_dict(stored["state_dict"])
    return model.eval()
