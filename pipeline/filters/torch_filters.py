"""The Kalman core of `pipeline.filters.batch_filters` in PyTorch: differentiable, batched, scaled per step.

The same filters (CV, CA, and the IMM of CV9 and CA, as `pipeline.filters.classical_filters` defines
them), plus Singer's model (`pipeline.filters.motion_models`), written over tensors so that a loss on the
filtered positions can be differentiated with respect to the filter's noise, its start spreads,
and per-step scale factors of Q, R and Singer's manoeuvre frequency that a network supplies (the
recurrent Kalman network of the seed paper, `shared/spec/related-work.md` section C). The
equations are `batch_filters`' line for line (Joseph-form update, IMM mixing, Gaussian
log-likelihoods, the models' combined estimate), and the tests check them against it and
against filterpy step by step.

Shapes follow `batch_filters`: a `State` of B tracks and M motion models holds x (B, M, n),
P (B, M, n, n) and mu (B, M). One step is `predicted` (`mixed`, then `moved` by F and Q) and
`updated` (with z and R); F, Q and R are arguments of every call, per track, so a caller can scale
them. `filter_sequences` runs B padded sequences of T plots (the tuner's material,
`tuning.target_sequences`), with optional per-step scales and truncated backpropagation through
time. Everything is float64 unless the inputs say otherwise; times stay float64 whatever the
working dtype (Unix seconds need it). The steps run on the device of their data (dt, z, the state:
`tracker.device`, issue 29), the spec's values and the constant tables moved there as they are used
(on the CPU, where the spec is, the moves are no-ops).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from pipeline.filters import motion_models

if TYPE_CHECKING:
    from pipeline.filters.classical_filters import FilterSettings
    from pipeline.filters.tuning import Sequences

DTYPE = torch.float64
MODELS = {"cv": ("cv",), "ca": ("ca",), "singer": ("singer",), "imm": ("cv9", "ca")}
LOG_NORMALISER = 3 * math.log(2 * math.pi)  # of a 3-dimensional Gaussian density

# Cofactor C[r, c] = S[r+1, c+1] S[r+2, c+2] - S[r+1, c+2] S[r+2, c+1] (indices mod 3), as in batch_filters.
_COFACTOR_INDEX = torch.tensor([[3 * ((r + a) % 3) + (c + b) % 3 for r in range(3) for c in range(3)]
                                for a, b in ((1, 1), (2, 2), (1, 2), (2, 1))])


# ----------------------------------------------------------------------------- the filter

@dataclass(frozen=True)
class FilterSpec:
    """One filter: its kind, and its values as tensors (0-dimensional unless said), which may
    require grad (the gradient-tuned baselines learn them).

    `noise_std` (M,): per motion model, as in `FilterSettings` (cv m/s^2, ca m/s^3, imm both in that
    order); for singer the acceleration's standard deviation sigma_m (m/s^2). `manoeuvre_time_s`:
    singer's tau (s). `switch_probability` and `initial_cv_probability`: the IMM's."""

    kind: str
    noise_std: Tensor
    velocity_std_mps: Tensor
    acceleration_std_mps2: Tensor
    manoeuvre_time_s: Tensor | None = None
    switch_probability: Tensor | None = None
    initial_cv_probability: Tensor | None = None

    def __post_init__(self) -> None:
        if self.kind not in MODELS:
            raise ValueError(f"filter kind {self.kind!r}: must be one of {tuple(MODELS)}")
        for field in fields(self)[1:]:
            value = getattr(self, field.name)
            if value is not None:
                object.__setattr__(self, field.name, torch.as_tensor(value, dtype=_dtype_of(value)))
        if self.noise_std.shape != (len(self.models),):
            raise ValueError(f"{self.kind}: needs {len(self.models)} process-noise values, got {self.noise_std}")
        if self.kind == "singer" and self.manoeuvre_time_s is None:
            raise ValueError("singer: needs manoeuvre_time_s")
        if self.kind == "imm" and (self.switch_probability is None or self.initial_cv_probability is None):
            raise ValueError("imm: needs switch_probability and initial_cv_probability")

    @property
    def models(self) -> tuple[str, ...]:
        return MODELS[self.kind]

    @property
    def dtype(self) -> torch.dtype:
        return self.noise_std.dtype

    @classmethod
    def from_settings(cls, settings: FilterSettings, dtype: torch.dtype = DTYPE) -> FilterSpec:
        """The classical filter of `settings` (cv, ca or imm), its values as constant tensors."""
        def value(number: float) -> Tensor:
            return torch.tensor(number, dtype=dtype)
        return cls(settings.kind, torch.tensor(settings.noise_std, dtype=dtype), value(settings.velocity_std_mps),
                   value(settings.acceleration_std_mps2), None, value(settings.switch_probability),
                   value(settings.initial_cv_probability))

    def transition_probabilities(self) -> Tensor:
        """The IMM's Markov switching matrix (2, 2)."""
        switch = self.switch_probability
        return torch.stack([torch.stack([1 - switch, switch]), torch.stack([switch, 1 - switch])])

    def initial_probabilities(self) -> Tensor:
        """A new track's mode probabilities (M,): the IMM's CV then CA, [1] for one model."""
        if self.kind != "imm":
            return torch.ones(1, dtype=self.dtype)
        return torch.stack([self.initial_cv_probability, 1 - self.initial_cv_probability])


def _dtype_of(value: object) -> torch.dtype:
    return value.dtype if isinstance(value, Tensor) and value.is_floating_point() else DTYPE


@dataclass(frozen=True)
class State:
    """States x (B, M, n), covariances P (B, M, n, n) and mode probabilities mu (B, M) of B tracks."""

    x: Tensor
    P: Tensor
    mu: Tensor

    def detached(self) -> State:
        """The same state cut from the graph: gradients stop here (truncated BPTT)."""
        return State(self.x.detach(), self.P.detach(), self.mu.detach())


def _where(rows: Tensor, chosen: State, other: State) -> State:
    """Per track (rows (B,) bool): `chosen`'s state where true, `other`'s elsewhere."""
    return State(torch.where(rows[:, None, None], chosen.x, other.x),
                 torch.where(rows[:, None, None, None], chosen.P, other.P),
                 torch.where(rows[:, None], chosen.mu, other.mu))


@lru_cache
def _measurement_matrix(model: str, dtype: torch.dtype, device: torch.device) -> Tensor:
    return torch.as_tensor(motion_models.measurement_matrix(model), dtype=dtype, device=device)


def start(spec: FilterSpec, z: Tensor, R: Tensor) -> State:
    """Tracks started at one measurement each, z (B, 3) metres of covariance R (B, 3, 3) m^2: position
    measured, velocity (and acceleration) zero with spreads `velocity_std_mps` (`acceleration_std_mps2`;
    cv9 starts with none). `motion_models.initial_state`, differentiable: x = H' z, P = H' R H + D."""
    xs, Ps = [], []
    for model in spec.models:
        H = _measurement_matrix(model, spec.dtype, z.device)
        size = motion_models.DIMENSIONS[model]
        spread = [torch.zeros((), dtype=spec.dtype), spec.velocity_std_mps ** 2,
                  spec.acceleration_std_mps2 ** 2 * (model in ("ca", "singer"))][:size]
        xs.append(z @ H)
        Ps.append(H.T @ R @ H + torch.diag(torch.stack(spread).repeat(3).to(z.device)))
    return State(torch.stack(xs, 1), torch.stack(Ps, 1),
                 spec.initial_probabilities().to(z.device).expand(len(z), -1))


# ----------------------------------------------------------------------------- motion

def _per_axis(block: Tensor) -> Tensor:
    """The same (..., d, d) block on each of the three axes: (..., 3d, 3d) (`motion_models._per_axis`)."""
    d = block.shape[-1]
    eye = torch.eye(3, dtype=block.dtype, device=block.device)
    return torch.einsum("ab,...ij->...aibj", eye, block).reshape(*block.shape[:-2], 3 * d, 3 * d)


# Per axis, every entry of cv's, ca's and cv9's F and Q (the latter without its variance) is one
# monomial c dt^k (`motion_models.transition` and `process_noise`): (coefficients, powers) of F, then of Q.
_MONOMIALS = {
    "cv": (([[1, 1], [0, 1]], [[0, 1], [0, 0]]),
           ([[1 / 4, 1 / 2], [1 / 2, 1]], [[4, 3], [3, 2]])),
    "ca": (([[1, 1, 1 / 2], [0, 1, 1], [0, 0, 1]], [[0, 1, 2], [0, 0, 1], [0, 0, 0]]),
           ([[1 / 4, 1 / 2, 1 / 2], [1 / 2, 1, 1], [1 / 2, 1, 1]], [[4, 3, 2], [3, 2, 1], [2, 1, 0]])),
    "cv9": (([[1, 1, 0], [0, 1, 0], [0, 0, 0]], [[0, 1, 0], [0, 0, 0], [0, 0, 0]]),
            ([[1 / 4, 1 / 2, 0], [1 / 2, 1, 0], [0, 0, 0]], [[4, 3, 0], [3, 2, 0], [0, 0, 0]])),
}


@lru_cache
def _monomial_tables(models: tuple[str, ...], dtype: torch.dtype, device: torch.device) -> tuple[Tensor, ...]:
    """Coefficients and powers of F, then of Q, on all three axes: four tensors (M, n, n) on `device`."""
    tables = [[np.kron(np.eye(3), _MONOMIALS[model][matrix][part]) for model in models]
              for matrix in (0, 1) for part in (0, 1)]
    return tuple(torch.tensor(np.array(table), dtype=dtype, device=device) for table in tables)


def motion(spec: FilterSpec, dt: Tensor, q_scale: Tensor | None = None, manoeuvre_scale: Tensor | None = None
           ) -> tuple[Tensor, Tensor]:
    """Each track's transition F and process noise Q (B, M, n, n) over dt (B,) seconds
    (`motion_models.transition` and `process_noise`: cv, ca and cv9 from their monomial tables,
    singer from `motion_models.singer_blocks`).

    Q is multiplied by `q_scale` ((B,) for all models, or (B, M)); singer's manoeuvre frequency
    1 / manoeuvre_time_s by `manoeuvre_scale` (B,), which changes both F and Q (the seed's F(alpha))."""
    dt = dt.to(spec.dtype)
    if manoeuvre_scale is not None and spec.kind != "singer":
        raise ValueError(f"{spec.kind}: a manoeuvre scale only applies to singer")
    if spec.kind == "singer":
        alpha = (1.0 if manoeuvre_scale is None else manoeuvre_scale) / spec.manoeuvre_time_s * torch.ones_like(dt)
        F, Q = motion_models.singer_blocks(dt, alpha, spec.noise_std[0].to(dt.device) ** 2, torch)
        F, Q = _per_axis(F)[:, None], _per_axis(Q)[:, None]
    else:
        F_coefficients, F_powers, Q_coefficients, Q_powers = _monomial_tables(spec.models, spec.dtype, dt.device)
        dt = dt[:, None, None, None]
        F = F_coefficients * dt ** F_powers
        Q = spec.noise_std.to(dt.device)[:, None, None] ** 2 * Q_coefficients * dt ** Q_powers
    if q_scale is not None:
        Q = Q * q_scale.reshape(dt.shape[0], -1, 1, 1)  # shape[0], not len(): traced as the batch size
    return F, Q


# ----------------------------------------------------------------------------- one step

def mixed(spec: FilterSpec, state: State) -> State:
    """IMM mixing (`batch_filters.mixed`): each model's starting state and covariance, and the predicted
    mode probabilities cbar in `mu`; a single filter starts from its posterior (the same object).

    x0_j = sum_i w_ij x_i, P0_j = sum_i w_ij P_i + w_0j w_1j (x_0 - x_1)(x_0 - x_1)' with
    w_ij = T_ij mu_i / cbar_j (filterpy's IMMEstimator, two models in closed form)."""
    if spec.kind != "imm":
        return state
    transition = spec.transition_probabilities()
    cbar = state.mu @ transition                                                    # (B, M)
    weight = transition.T * state.mu[:, None, :] / cbar[:, :, None]                 # w_ij at [b, j, i]
    spread = state.x[:, 0] - state.x[:, 1]                                          # (B, n)
    B, M, n = state.x.shape
    P = (weight @ state.P.reshape(B, M, n * n)).reshape(state.P.shape) + \
        (weight[:, :, 0] * weight[:, :, 1])[:, :, None, None] * (spread[:, None, :, None] * spread[:, None, None, :])
    return State(weight @ state.x, P, cbar)


def moved(state: State, F: Tensor, Q: Tensor) -> State:
    """x' = F x, P' = F P F' + Q with F, Q (B, M, n, n) (filterpy's `KalmanFilter.predict`); mu is kept."""
    return State((F @ state.x[..., None])[..., 0], F @ state.P @ F.transpose(-1, -2) + Q, state.mu)


def predicted(spec: FilterSpec, state: State, F: Tensor, Q: Tensor) -> State:
    """Posteriors mixed and moved by F and Q (B, M, n, n); mu becomes the predicted mode probabilities."""
    return moved(mixed(spec, state), F, Q)


def inverse3(S: Tensor) -> tuple[Tensor, Tensor]:
    """Inverse (..., 3, 3) and determinant (...) of 3 x 3 matrices by cofactors (`batch_filters.inverse3`)."""
    flat = S.reshape(*S.shape[:-2], 9)
    factors = flat[..., _COFACTOR_INDEX.to(S.device)]                               # (..., 4, 9)
    cofactor = factors[..., 0, :] * factors[..., 1, :] - factors[..., 2, :] * factors[..., 3, :]
    determinant = (flat[..., :3] * cofactor[..., :3]).sum(-1)
    return cofactor.reshape(S.shape).transpose(-1, -2) / determinant[..., None, None], determinant


def updated(spec: FilterSpec, state: State, z: Tensor, R: Tensor) -> State:
    """Each track updated with z (B, 3) of covariance R (B, 3, 3) (`batch_filters.updated`): Joseph form
    (I - K H) P (I - K H)' + K R K' as J P + (K R - J P H') K' with J P = P - K H P; for the IMM the
    mode probabilities from the models' Gaussian log-likelihoods
    -(d' S^-1 d + ln det S + 3 ln 2 pi) / 2, normalised (a softmax)."""
    position = slice(None, None, state.x.shape[-1] // 3)
    R = R[:, None]                                                                  # (B, 1, 3, 3)
    HP = state.P[..., position, :]                                                  # (B, M, 3, n)
    innovation = z[:, None] - state.x[..., position]                                # (B, M, 3)
    S_inverse, S_determinant = inverse3(HP[..., position] + R)
    gain_T = S_inverse @ HP                                                         # K' (B, M, 3, n)
    gain = gain_T.transpose(-1, -2)
    x = state.x + (innovation[..., None, :] @ gain_T)[..., 0, :]
    JP = state.P - gain @ HP
    P = JP + (gain @ R - JP[..., :, position]) @ gain_T
    mu = state.mu
    if spec.kind == "imm":
        distance = (innovation[..., None, :] @ S_inverse @ innovation[..., :, None])[..., 0, 0]
        mu = torch.softmax(torch.log(state.mu) - 0.5 * (distance + torch.log(S_determinant) + LOG_NORMALISER), 1)
    return State(x, P, mu)


def combined(mu: Tensor, x: Tensor, P: Tensor) -> tuple[Tensor, Tensor]:
    """Mode-weighted mean (..., k) and covariance (..., k, k) of means x (..., M, k) and covariances
    P (..., M, k, k) with probabilities mu (..., M) (filterpy's `IMMEstimator._compute_state_estimate`)."""
    mean = (mu[..., None] * x).sum(-2)
    offset = x - mean[..., None, :]
    return mean, (mu[..., None, None] * (P + offset[..., :, None] * offset[..., None, :])).sum(-3)


def position_estimates(state: State) -> tuple[Tensor, Tensor]:
    """The tracks' positions (B, 3) and position covariances (B, 3, 3), their models combined."""
    position = slice(None, None, state.x.shape[-1] // 3)
    return combined(state.mu, state.x[..., position], state.P[..., position, position])


# ----------------------------------------------------------------------------- sequences

@dataclass(frozen=True)
class StepScales:
    """One step's scale factors, each None (1) or per track: `q` (B,) or (B, M) multiplies Q, `r` (B,)
    multiplies R, `manoeuvre` (B,) multiplies singer's manoeuvre frequency."""

    q: Tensor | None = None
    r: Tensor | None = None
    manoeuvre: Tensor | None = None


@dataclass(frozen=True)
class Scales:
    """Scale factors for every step, computed beforehand: `q` (B, T) or (B, T, M), `r` (B, T),
    `manoeuvre` (B, T); None means 1."""

    q: Tensor | None = None
    r: Tensor | None = None
    manoeuvre: Tensor | None = None

    def at(self, step: int) -> StepScales:
        return StepScales(*(None if value is None else value[:, step]
                            for value in (self.q, self.r, self.manoeuvre)))


@dataclass(frozen=True)
class Step:
    """What a scaler sees before step `t`: the posterior `state` after step t - 1, the step's
    measurement z (B, 3), its nominal covariance R (B, 3, 3) and time step dt (B,) (0 where a track
    restarts or idles)."""

    t: int
    state: State
    z: Tensor
    R: Tensor
    dt: Tensor


Scaler = Callable[[Step], StepScales]


@dataclass(frozen=True)
class Filtered:
    """What `filter_sequences` gives for B sequences of T steps (NaN where not defined).

    `position` (B, T, 3) m and `covariance` (B, T, 3, 3) m^2: the filtered positions (NaN at
    padding). `probabilities` (B, T, M): the mode probabilities after each step (NaN at padding).
    `innovation` (B, T, 3) m, `innovation_covariance` (B, T, 3, 3) m^2 and `innovation_distance`
    (B, T): d = z - x_pred, S = P_pred + R (the scaled R) and d' S^-1 d against the combined
    predicted density (`batch_filters.FilteredSequences`), NaN where a track (re)starts or idles.
    `last`: the state after the last step."""

    position: Tensor
    covariance: Tensor
    probabilities: Tensor
    innovation: Tensor
    innovation_covariance: Tensor
    innovation_distance: Tensor
    last: State


def time_steps(times: Tensor, valid: Tensor, restart: Tensor) -> Tensor:
    """Each step's time (B, T) since the row's previous valid step, 0 where the row restarts or idles;
    float64 (`batch_filters.filter_sequences`)."""
    B, T = times.shape
    steps = torch.arange(T).expand(B, T)
    previous = torch.cummax(torch.where(valid, steps, 0), 1).values
    previous = torch.cat([torch.zeros((B, 1), dtype=previous.dtype), previous[:, :-1]], 1)
    times = times.to(torch.float64)
    return torch.where(valid & ~restart, times - times.gather(1, previous), 0.0)


def filter_sequences(spec: FilterSpec, times: Tensor, positions: Tensor, covariances: Tensor, valid: Tensor,
                     restart: Tensor, scales: Scales | Scaler | None = None, detach_every: int | None = None
                     ) -> Filtered:
    """Filter B measurement sequences side by side (`batch_filters.filter_sequences`): times (B, T)
    seconds, positions (B, T, 3) metres, covariances (B, T, 3, 3) m^2, valid and restart (B, T) bool.
    Padding is skipped (the state stays); at restarts a track starts afresh from the measurement and
    its scaled covariance.

    `scales`: per-step factors of Q, R and singer's manoeuvre frequency, as tensors for all steps
    (`Scales`) or from a function called before each step with the filter's state (`Scaler`: the
    network-scaled filter); None: all 1. `detach_every` = k: the state is cut from the graph before
    steps k, 2k, ..., so a loss at a step reaches back at most k steps (truncated BPTT)."""
    if detach_every is not None and detach_every < 1:
        raise ValueError(f"detach_every = {detach_every}: must be at least 1 step (or None)")
    B, T = times.shape
    scaler = _scaler(scales, B, T)
    positions, covariances = positions.to(spec.dtype), covariances.to(spec.dtype)
    dt = time_steps(times, valid, restart)
    moving = valid & ~restart
    fresh_steps = (valid & restart).any(0).tolist()
    idle_steps = (~valid).any(0).tolist()
    position = slice(None, None, motion_models.state_size(spec.models[0]) // 3)

    state = start(spec, positions[:, 0], covariances[:, 0])
    model_x, model_P, mu, prior_x, prior_P, prior_mu, used_R = [], [], [], [], [], [], []
    for t in range(T):
        if detach_every is not None and t and t % detach_every == 0:
            state = state.detached()
        z = positions[:, t]
        step = scaler(Step(t, state, z, covariances[:, t], dt[:, t]))
        R = covariances[:, t] if step.r is None else covariances[:, t] * step.r[:, None, None]
        prior = predicted(spec, state, *motion(spec, dt[:, t], step.q, step.manoeuvre))
        after = updated(spec, prior, z, R)
        if fresh_steps[t]:
            after = _where(valid[:, t] & restart[:, t], start(spec, z, R), after)
        if idle_steps[t]:
            after = _where(~valid[:, t], state, after)
        state = after
        prior_x.append(prior.x[..., position])
        prior_P.append(prior.P[..., position, position])
        prior_mu.append(prior.mu)
        model_x.append(state.x[..., position])
        model_P.append(state.P[..., position, position])
        mu.append(state.mu)
        used_R.append(R)
    x, P = combined(torch.stack(mu, 1), torch.stack(model_x, 1), torch.stack(model_P, 1))
    prior_position, prior_covariance = combined(torch.stack(prior_mu, 1), torch.stack(prior_x, 1),
                                                torch.stack(prior_P, 1))
    innovation = positions - prior_position
    S = prior_covariance + torch.stack(used_R, 1)
    distance = (innovation[..., None, :] @ inverse3(S)[0] @ innovation[..., :, None])[..., 0, 0]
    return Filtered(_blank(x, valid), _blank(P, valid), _blank(torch.stack(mu, 1), valid),
                    _blank(innovation, moving), _blank(S, moving), _blank(distance, moving), state)


def _blank(values: Tensor, keep: Tensor) -> Tensor:
    """`values` (B, T, ...) with NaN where `keep` (B, T) is false (no gradient flows there)."""
    return torch.where(keep.reshape(*keep.shape, *[1] * (values.dim() - 2)), values, torch.nan)


def _scaler(scales: Scales | Scaler | None, B: int, T: int) -> Scaler:
    """Any form of `filter_sequences`' scales as a function of the step, tensors' shapes checked."""
    if scales is None:
        return lambda step: StepScales()
    if not isinstance(scales, Scales):
        return scales
    for name in ("q", "r", "manoeuvre"):
        value = getattr(scales, name)
        if value is not None and (tuple(value.shape[:2]) != (B, T) or value.dim() > 2 + (name == "q")):
            raise ValueError(f"scales.{name}: shape {tuple(value.shape)}, must be ({B}, {T})"
                             + (" or (B, T, M)" if name == "q" else ""))
    return lambda step: scales.at(step.t)


# ----------------------------------------------------------------------------- training material

@dataclass(frozen=True)
class SequenceBatch:
    """The tuner's material (`tuning.Sequences`) as tensors, rows selectable: times (B, T) s (float64),
    positions and truth (B, T, 3) m, covariances (B, T, 3, 3) m^2, valid, restart and scored (B, T)."""

    times: Tensor
    positions: Tensor
    covariances: Tensor
    truth: Tensor
    valid: Tensor
    restart: Tensor
    scored: Tensor

    @classmethod
    def from_sequences(cls, material: Sequences, dtype: torch.dtype = DTYPE) -> SequenceBatch:
        return cls(torch.as_tensor(material.times, dtype=torch.float64),
                   torch.as_tensor(material.positions, dtype=dtype), torch.as_tensor(material.covariances, dtype=dtype),
                   torch.as_tensor(material.truth, dtype=dtype), torch.as_tensor(material.valid),
                   torch.as_tensor(material.restart), torch.as_tensor(material.scored))

    def rows(self, index: Tensor | slice) -> SequenceBatch:
        """The batch of rows `index` (a training batch)."""
        return replace(self, **{field.name: getattr(self, field.name)[index] for field in fields(self)})

    def filtered(self, spec: FilterSpec, scales: Scales | Scaler | None = None, detach_every: int | None = None
                 ) -> Filtered:
        return filter_sequences(spec, self.times, self.positions, self.covariances, self.valid, self.restart,
                                scales, detach_every)

    def position_error(self, filtered: Filtered) -> Tensor:
        """Mean distance (m) of the filtered positions from the truth over the scored steps (a loss)."""
        return (filtered.position[self.scored] - self.truth[self.scored]).norm(dim=-1).mean()
