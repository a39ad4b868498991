"""The classical filters of `pipeline.classical_filters`, stepped for many tracks at once.

Why our own code next to filterpy: the tuner evaluates its cost about a hundred times over
the ~100,000 target plots of the training routes, and the hold-out comparison runs tens of
thousands of windows. filterpy's objects step one track at a time (~0.3 ms per Kalman step,
~0.9 ms per IMM step here), which would make tuning take hours; the same equations written
over a batch axis take seconds. The tests check this module against filterpy, step by step.

A batch state holds, for M motion models and B tracks, the states x (M, B, n), covariances
P (M, B, n, n) and mode probabilities mu (B, M) (M = 1 for a single Kalman filter). The
update is filterpy's: Joseph-form covariance and Gaussian likelihoods for the IMM, here in
log space so a far-off plot cannot underflow every model at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline import motion_models
from pipeline.classical_filters import FilterSettings


@dataclass
class BatchState:
    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray


def start(settings: FilterSettings, positions: np.ndarray, covariances: np.ndarray) -> BatchState:
    """Tracks started at one measurement each: positions (B, 3), covariances (B, 3, 3)."""
    pairs = [motion_models.initial_state(model, positions, covariances, settings.velocity_std_mps,
                                         settings.acceleration_std_mps2) for model in settings.models]
    probabilities = settings.initial_probabilities() if settings.kind == "imm" else np.ones(1)
    return BatchState(np.stack([x for x, _ in pairs]), np.stack([p for _, p in pairs]),
                      np.tile(probabilities, (len(positions), 1)))


def _mixed(settings: FilterSettings, state: BatchState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IMM mixing: each model's starting state and covariance, and the predicted mode probabilities."""
    if settings.kind != "imm":
        return state.x, state.P, state.mu
    transition = settings.transition_probabilities()
    cbar = state.mu @ transition                                        # (B, M)
    omega = transition[None] * state.mu[:, :, None] / cbar[:, None, :]  # (B, i, j)
    x = np.einsum("bij,ibn->jbn", omega, state.x)
    offset = state.x[:, None] - x[None]                                 # (i, j, B, n)
    P = np.einsum("bij,ijbnm->jbnm", omega, state.P[:, None] + offset[..., :, None] * offset[..., None, :])
    return x, P, cbar


def predict(settings: FilterSettings, state: BatchState, dt: np.ndarray) -> BatchState:
    """Each track dt (B,) seconds ahead; mu becomes the predicted mode probabilities."""
    x, P, probabilities = _mixed(settings, state)
    xs, Ps = [], []
    for index, (model, noise) in enumerate(zip(settings.models, settings.noise_std)):
        F = motion_models.transition(model, dt)
        xs.append(np.einsum("bnm,bm->bn", F, x[index]))
        Ps.append(F @ P[index] @ np.swapaxes(F, -1, -2) + motion_models.process_noise(model, dt, noise))
    return BatchState(np.stack(xs), np.stack(Ps), probabilities)


def update(settings: FilterSettings, state: BatchState, z: np.ndarray, R: np.ndarray) -> BatchState:
    """Each track updated with its measurement z (B, 3) of covariance R (B, 3, 3)."""
    H = motion_models.measurement_matrix(settings.models[0])
    measured = settings.measured
    innovation = z[None] - state.x[..., measured]                                  # (M, B, 3)
    S = state.P[..., measured, :][..., :, measured] + R[None]                      # (M, B, 3, 3)
    gain = np.swapaxes(np.linalg.solve(S, state.P[..., measured, :]), -1, -2)      # P H' S^-1
    x = state.x + np.einsum("mbnk,mbk->mbn", gain, innovation)
    identity = np.eye(H.shape[1])
    joseph = identity - gain @ H
    P = joseph @ state.P @ np.swapaxes(joseph, -1, -2) + gain @ R[None] @ np.swapaxes(gain, -1, -2)
    mu = state.mu
    if settings.kind == "imm":
        distance = np.einsum("mbk,mbk->mb", innovation, np.linalg.solve(S, innovation[..., None])[..., 0])
        log_likelihood = -0.5 * (distance + np.linalg.slogdet(S)[1] + 3 * np.log(2 * np.pi))
        log_weight = np.log(state.mu.T) + log_likelihood
        log_weight -= log_weight.max(axis=0)
        weight = np.exp(log_weight)
        mu = (weight / weight.sum(axis=0)).T
    return BatchState(x, P, mu)


def combined(state: BatchState) -> tuple[np.ndarray, np.ndarray]:
    """The mode-weighted state (B, n) and covariance (B, n, n)."""
    x = np.einsum("bm,mbn->bn", state.mu, state.x)
    offset = state.x - x[None]
    P = np.einsum("bm,mbnk->bnk", state.mu, state.P + offset[..., :, None] * offset[..., None, :])
    return x, P


def select(mask: np.ndarray, chosen: BatchState, other: BatchState) -> BatchState:
    """Per track: `chosen` where mask (B,) is true, else `other`."""
    return BatchState(np.where(mask[None, :, None], chosen.x, other.x),
                      np.where(mask[None, :, None, None], chosen.P, other.P),
                      np.where(mask[:, None], chosen.mu, other.mu))


def filter_sequences(settings: FilterSettings, times: np.ndarray, positions: np.ndarray, covariances: np.ndarray,
                     valid: np.ndarray, restart: np.ndarray) -> tuple[np.ndarray, np.ndarray, BatchState]:
    """Filter B measurement sequences side by side: times (B, T), positions (B, T, 3),
    covariances (B, T, 3, 3). Invalid steps (padding) are skipped; at `restart` steps a track
    starts afresh from the measurement. Returns the filtered positions (B, T, 3) and their
    covariances (B, T, 3, 3), NaN at invalid steps, and the state after each track's last step."""
    B, T = times.shape
    measured = settings.measured
    state = start(settings, positions[:, 0], covariances[:, 0])
    last_time = times[:, 0].copy()
    out_x = np.full((B, T, 3), np.nan)
    out_P = np.full((B, T, 3, 3), np.nan)
    for step in range(T):
        fresh = valid[:, step] & restart[:, step]
        moving = valid[:, step] & ~restart[:, step]
        started = start(settings, positions[:, step], covariances[:, step])
        dt = np.where(moving, times[:, step] - last_time, 0.0)
        updated = update(settings, predict(settings, state, dt), positions[:, step], covariances[:, step])
        state = select(fresh, started, select(moving, updated, state))
        last_time = np.where(valid[:, step], times[:, step], last_time)
        x, P = combined(state)
        out_x[valid[:, step], step] = x[valid[:, step]][:, measured]
        out_P[valid[:, step], step] = P[valid[:, step]][:, measured][:, :, measured]
    return out_x, out_P, state


def predict_positions(settings: FilterSettings, state: BatchState, dt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted positions (B, 3) and covariances (B, 3, 3) dt seconds ahead."""
    x, P = combined(predict(settings, state, dt))
    measured = settings.measured
    return x[:, measured], P[:, measured][:, :, measured]
