"""The network-scaled Kalman filter: a small network scales Singer's manoeuvre frequency, Q and R at every step.

The recurrent Kalman network of the seed paper (`shared/spec/related-work.md` section C; reference
003): the Kalman filter keeps its structure, and before each step a small network (a GRU cell, or
an MLP without memory of its own) reads four normalised features of the track and outputs, through
sigmoids times amplitudes, the step's scale of
- the transition parameter: Singer's manoeuvre frequency alpha = 1 / tau (F(alpha) and Q(alpha),
  `torch_filters.motion`); for a CV or CA base the transition has no parameter of its own and its
  noise Q is the one thing to scale, so the network has no separate output for it;
- the process noise, Q = q * Q0, Q0 the base filter's (`KalmanNetConfig.noise_std`);
- the measurement noise, R = r * R0, R0 = the plot's converted-measurement covariance times
  `r0_scale` (so R0 follows the radar's range-dependent cross-range error).

Features (the seed's eqs 31-33, norms instead of per-axis values so that they do not depend on
where in ECEF the track is), each 0 where it is not defined yet (a track's first steps, a restart):
1. state increment |x_{t-1} - x_{t-2}| / (v dt_{t-1}), x the filtered positions;
2. measurement increment |z_t - z_{t-1}| / (v dt_t);
3. their disagreement |(z_t - z_{t-1}) / dt_t - (x_{t-1} - x_{t-2}) / dt_{t-1}| / v, a manoeuvre cue;
4. the normalised innovation squared d' S^-1 d of z_t against the base filter's prediction
   (scales 1), over `nis_scale`, at most 1 (the seed: its maximum set to 10).
v is `velocity_scale_mps` (the seed's 400 m/s: no aircraft here is faster).

The output layer starts with zero weights and the bias that gives every scale 1: an untrained
network is the base filter with Q0 and R0, and the amplitudes are the largest factors it can learn.

`KalmanNet.step_scales` is the per-step interface (state, plot, memory -> scales, memory) a
tracker's estimator can call for one track or many; `KalmanNet.forward` runs it over a batch of
sequences (`torch_filters.filter_sequences`) with truncated BPTT; `load` reads it back
(`model_store.save_network` writes it; `kalman_net_training` trains it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import torch
from torch import Tensor, nn

from pipeline.filters import torch_filters
from pipeline.filters.torch_filters import Filtered, FilterSpec, SequenceBatch, State, Step, StepScales
from pipeline.learning import model_store

FEATURES = 4
BASES = ("cv", "ca", "singer")
CELLS = ("gru", "mlp")


@dataclass(frozen=True)
class KalmanNetConfig:
    """The network-scaled filter's design values (params.yaml `kalman_net`, which documents them)."""

    base: str                      # cv, ca or singer
    cell: str                      # gru or mlp
    hidden: int
    noise_std: float               # Q0: cv m/s^2, ca m/s^3, singer's acceleration sigma_m m/s^2
    manoeuvre_time_s: float        # Q0 and F of singer: tau, s (unused by cv and ca)
    velocity_std_mps: float        # a new track's velocity spread
    acceleration_std_mps2: float   # ... and acceleration spread (ca, singer)
    r0_scale: float                # R0 = plot covariance * this
    q_amplitude: float             # the largest Q scale
    r_amplitude: float             # the largest R scale
    manoeuvre_amplitude: float     # the largest manoeuvre-frequency scale (singer)
    velocity_scale_mps: float      # v of the increment features
    nis_scale: float               # divides the innovation feature

    def __post_init__(self) -> None:
        if self.base not in BASES:
            raise ValueError(f"kalman_net.base = {self.base!r}: must be one of {BASES}")
        if self.cell not in CELLS:
            raise ValueError(f"kalman_net.cell = {self.cell!r}: must be one of {CELLS}")

    @property
    def outputs(self) -> tuple[str, ...]:
        """The scales the network outputs, in order."""
        return ("manoeuvre", "q", "r") if self.base == "singer" else ("q", "r")

    def amplitude(self, name: str) -> float:
        return {"manoeuvre": self.manoeuvre_amplitude, "q": self.q_amplitude, "r": self.r_amplitude}[name]

    def spec(self) -> FilterSpec:
        """The base filter with Q0."""
        tau = self.manoeuvre_time_s if self.base == "singer" else None
        return FilterSpec(self.base, (self.noise_std,), self.velocity_std_mps, self.acceleration_std_mps2,
                          manoeuvre_time_s=tau)


@dataclass(frozen=True)
class Memory:
    """What the scaler keeps of B tracks between steps: the network's `hidden` (B, H), the filtered
    position `estimate` (B, 3) m after the step before the last, the last plot `measurement` (B, 3) m,
    the last step's `dt` (B,) s and the track's `age` (B,): plots since its (re)start, that one included."""

    hidden: Tensor
    estimate: Tensor
    measurement: Tensor
    dt: Tensor
    age: Tensor

    def detached(self) -> Memory:
        """Cut from the graph, with the filter's state (truncated BPTT)."""
        return replace(self, hidden=self.hidden.detach(), estimate=self.estimate.detach(),
                       measurement=self.measurement.detach())


class ScaleNetwork(nn.Module):
    """features (B, 4) and hidden (B, H) -> raw outputs (B, K) and the next hidden (B, H): a GRU cell,
    or one tanh layer (then `hidden` is returned unchanged), then a linear head."""

    def __init__(self, cell: str, hidden: int, outputs: int) -> None:
        super().__init__()
        self.recurrent = cell == "gru"
        self.body = nn.GRUCell(FEATURES, hidden) if self.recurrent else nn.Sequential(nn.Linear(FEATURES, hidden),
                                                                                     nn.Tanh())
        self.head = nn.Linear(hidden, outputs)

    def forward(self, features: Tensor, hidden: Tensor) -> tuple[Tensor, Tensor]:
        if self.recurrent:
            hidden = self.body(features, hidden)
            return self.head(hidden), hidden
        return self.head(self.body(features)), hidden


class KalmanNet(nn.Module):
    """The base filter of `config` with its Q, R (and singer's manoeuvre frequency) scaled by a network."""

    def __init__(self, config: KalmanNetConfig, dtype: torch.dtype = torch_filters.DTYPE) -> None:
        super().__init__()
        self.config = config
        self.base = config.spec()
        self.network = ScaleNetwork(config.cell, config.hidden, len(config.outputs)).to(dtype)
        with torch.no_grad():  # every scale 1 until trained: sigmoid(b) * A = 1
            self.network.head.weight.zero_()
            self.network.head.bias.copy_(torch.tensor([-math.log(config.amplitude(name) - 1.0)
                                                       for name in config.outputs], dtype=dtype))
        self.register_buffer("amplitudes", torch.tensor([config.amplitude(n) for n in config.outputs], dtype=dtype))

    def memory(self, tracks: int) -> Memory:
        """The memory of `tracks` tracks before their first plot, on the model's device."""
        like = dict(dtype=self.amplitudes.dtype, device=self.amplitudes.device)
        return Memory(torch.zeros(tracks, self.config.hidden, **like), torch.zeros(tracks, 3, **like),
                      torch.zeros(tracks, 3, **like), torch.zeros(tracks, **like),
                      torch.zeros(tracks, dtype=torch.long, device=self.amplitudes.device))

    def features(self, memory: Memory, state: State, z: Tensor, R: Tensor, dt: Tensor) -> Tensor:
        """The network's input (B, 4) before the step with plot z (B, 3) of nominal covariance R (B, 3, 3)
        after dt (B,) s, from the posterior `state` after the previous step (module docstring)."""
        v = self.config.velocity_scale_mps
        estimate, _ = torch_filters.position_estimates(state)
        dt = dt.to(z.dtype)
        moving = (dt > 0) & (memory.age >= 1)
        known = moving & (memory.age >= 2) & (memory.dt > 0)
        safe_dt, safe_previous = torch.where(moving, dt, 1.0), torch.where(known, memory.dt, 1.0)
        state_rate = (estimate - memory.estimate) / safe_previous[:, None]
        plot_rate = (z - memory.measurement) / safe_dt[:, None]
        prior = torch_filters.predicted(self.base, state, *torch_filters.motion(self.base, dt))
        position, covariance = torch_filters.position_estimates(prior)
        innovation = z - position
        inverse, _ = torch_filters.inverse3(covariance + R)
        nis = (innovation[:, None, :] @ inverse @ innovation[:, :, None])[:, 0, 0]
        zero = torch.zeros((), dtype=z.dtype, device=z.device)
        return torch.stack([torch.where(known, state_rate.norm(dim=-1) / v, zero),
                            torch.where(moving, plot_rate.norm(dim=-1) / v, zero),
                            torch.where(known, (plot_rate - state_rate).norm(dim=-1) / v, zero),
                            torch.where(moving, (nis / self.config.nis_scale).clamp(max=1.0), zero)], 1)

    def step_scales(self, memory: Memory, step: Step, fresh: Tensor, moving: Tensor) -> tuple[StepScales, Memory]:
        """The scales of one step of B tracks and the memory after it. `fresh` (B,) bool: the track
        (re)starts at this plot (its network memory is cleared); `moving` (B,): it is updated with it;
        tracks that are neither (padding) keep their memory."""
        memory = replace(memory, hidden=torch.where(fresh[:, None], 0.0, memory.hidden),
                         age=torch.where(fresh, 0, memory.age))
        raw, hidden = self.network(self.features(memory, step.state, step.z, step.R, step.dt), memory.hidden)
        scales = dict(zip(self.config.outputs, (torch.sigmoid(raw) * self.amplitudes).unbind(1)))
        used = fresh | moving
        estimate, _ = torch_filters.position_estimates(step.state)
        after = Memory(torch.where(used[:, None], hidden, memory.hidden),
                       torch.where(moving[:, None], estimate, memory.estimate),
                       torch.where(used[:, None], step.z, memory.measurement),
                       torch.where(used, step.dt.to(memory.dt.dtype), memory.dt), memory.age + used.long())
        return StepScales(**scales), after

    def forward(self, batch: SequenceBatch, detach_every: int | None = None) -> Filtered:
        """The batch filtered (`torch_filters.filter_sequences`, R0 = its covariances * r0_scale), the
        network's memory cut with the filter's state every `detach_every` steps."""
        scaler = SequenceScaler(self, batch.valid & batch.restart, batch.valid & ~batch.restart, detach_every)
        return torch_filters.filter_sequences(self.base, batch.times, batch.positions,
                                              batch.covariances * self.config.r0_scale, batch.valid, batch.restart,
                                              scaler, detach_every)


class SequenceScaler:
    """`KalmanNet.step_scales` as `filter_sequences`' per-step callback over B padded sequences (fresh
    and moving (B, T) bool), keeping the memory between calls and cutting it where the filter's state
    is cut."""

    def __init__(self, model: KalmanNet, fresh: Tensor, moving: Tensor, detach_every: int | None) -> None:
        self.model, self.fresh, self.moving, self.detach_every = model, fresh, moving, detach_every
        self.memory = model.memory(len(fresh))

    def __call__(self, step: Step) -> StepScales:
        if self.detach_every is not None and step.t and step.t % self.detach_every == 0:
            self.memory = self.memory.detached()
        scales, self.memory = self.model.step_scales(self.memory, step, self.fresh[:, step.t], self.moving[:, step.t])
        return scales


def load(path: Path) -> KalmanNet:
    """A saved network-scaled filter, ready to filter (eval mode); InputError naming a missing, unreadable or
    foreign file (`model_store.load_network`)."""
    return model_store.load_network(path, lambda config: KalmanNet(KalmanNetConfig(**config)), "train_kalman_net")
