"""The one Kalman core: the classical filters of `pipeline.filters.classical_filters` (CV, CA, IMM) for
many tracks at once. The tuner (`pipeline.filters.tuning`), the hold-out comparison
(`pipeline.stages.compare_stage`) and the tracker (`pipeline.tracker.kalman`) all step their filters here.

Why our own code next to filterpy: the tuner evaluates its cost about a hundred times over
the ~100,000 target plots of the training routes, the hold-out comparison runs tens of
thousands of windows, and the tracker gates and updates tracks at tens of thousands of plots
per second. filterpy's objects step one track at a time (~0.3 ms per Kalman step, ~0.9 ms per
IMM step here), which would make tuning take hours and the tracker ten times slower; the same
equations written over a batch axis take seconds. filterpy stays the reference: the tests check
this module against it, step by step.

A batch state holds, for B tracks and M motion models, the states x (B, M, n), covariances
P (B, M, n, n) and mode probabilities mu (B, M) (M = 1 for a single Kalman filter, 2 for the
IMM, 3 for the IMM with turns). The update is filterpy's: Joseph-form covariance and Gaussian
likelihoods for the IMM, here in log space so a far-off plot cannot underflow every model at once.

One step is `mixed` (the IMM's mixing: each model's starting state and the predicted mode
probabilities; nothing for a single filter), `moved` (x' = F x, P' = F P F' + Q) and `updated`
(with a measurement z and its covariance R). F and Q (from `motion`, and `turned` for a model that
turns about each track's own vertical) and R are arguments of every call and given per track, so each
track can have its own time step, process noise and measurement covariance (the radar a plot comes
from; a network scaling the noise later).

Why it is written the way it is: tuning steps ~90 rows through ~1200 steps about a hundred
times per filter, so a step works on ~90 small matrices per model and its cost is overhead (per
NumPy call, and per matrix in a stacked product), not arithmetic. `filter_sequences` therefore
steps every row with one set of calls and repairs the few rows that restart or idle at a step
afterwards, builds F and Q once per distinct time step (plot times are quantised, so a few dozen
per evaluation) and gathers them, inverts the 3 x 3 innovation covariances by cofactors, mixes
the IMM's two models in closed form (more in the general form), and combines the models' estimates
for all steps at once after the loop. The results equal the step-by-step formulation (the tests' filterpy) to
floating-point rounding.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from pipeline.filters import motion_models, turn_model
from pipeline.filters.classical_filters import FilterSettings

CHUNK_CELLS = 2 ** 14  # F and Q are tabulated for the distinct time steps of about this many (step, row) cells at once
LOG_NORMALISER = 3 * np.log(2 * np.pi)  # of a 3-dimensional Gaussian density

# Cofactor C[r, c] = S[r+1, c+1] S[r+2, c+2] - S[r+1, c+2] S[r+2, c+1] (indices mod 3) of a 3 x 3 matrix,
# as four gathers from the flattened matrix (rows: the four factors; columns: r * 3 + c).
_COFACTOR_INDEX = np.array([[3 * ((r + a) % 3) + (c + b) % 3 for r in range(3) for c in range(3)]
                            for a, b in ((1, 1), (2, 2), (1, 2), (2, 1))])


@dataclass
class BatchState:
    """States x (B, M, n), covariances P (B, M, n, n) and mode probabilities mu (B, M) of B tracks."""

    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray


def start(settings: FilterSettings, positions: np.ndarray, covariances: np.ndarray) -> BatchState:
    """Tracks started at one measurement each: positions (B, 3), covariances (B, 3, 3)."""
    pairs = [motion_models.initial_state(model, positions, covariances, settings.velocity_std_mps,
                                         settings.acceleration_std_mps2) for model in settings.motion_bases]
    probabilities = settings.initial_probabilities() if settings.is_imm else np.ones(1)
    return BatchState(np.stack([x for x, _ in pairs], axis=1), np.stack([p for _, p in pairs], axis=1),
                      np.tile(probabilities, (len(positions), 1)))


def motion(settings: FilterSettings, dt: np.ndarray) -> np.ndarray:
    """Each model's transition F and process noise Q over dt of any shape: (*dt.shape, 2, M, n, n), F then Q.
    A turning model's F is its straight base's here (`FilterSettings.motion_bases`); `turned` turns it per track."""
    return np.stack([np.stack([motion_models.transition(model, dt) for model in settings.motion_bases], axis=-3),
                     np.stack([motion_models.process_noise(model, dt, noise)
                               for model, noise in zip(settings.motion_bases, settings.model_noise_std)], axis=-3)],
                    axis=-4)


def verticals(settings: FilterSettings, state: BatchState) -> np.ndarray | None:
    """The local vertical (B, 3) at each track's first model's position in `state` (`turn_model.local_vertical`),
    about which its turning models turn over the next step; None when no model turns. One per track and
    step: the models' positions differ by metres, their verticals by 1e-6 rad. Taken from the posterior,
    as filterpy's reference does (`classical_filters.advance`)."""
    if not settings.turn_rates().any():
        return None
    return turn_model.local_vertical(state.x[:, 0, ::state.x.shape[-1] // 3])


def turned(settings: FilterSettings, F: np.ndarray, dt: np.ndarray, up: np.ndarray | None) -> np.ndarray:
    """F (B, M, n, n) of B tracks stepping dt (B,) seconds, with each turning model's transition made about
    the track's vertical up (B, 3) (`verticals`; `turn_model.turning_transitions`); F itself when no
    model turns."""
    rates = settings.turn_rates()
    turning = np.flatnonzero(rates)
    if not len(turning):
        return F
    F = F.copy()
    F[:, turning] = turn_model.turning_transitions(dt, rates[turning], up)
    return F


def _motion_per_step(settings: FilterSettings, dt: np.ndarray) -> Iterator[np.ndarray]:
    """F and Q (B, 2, M, n, n) for each step of dt (T, B) seconds, in step order.

    Tabulated for the distinct values of dt over chunks of steps and gathered per step: building
    them per step would cost ~20 NumPy calls per step, tabulating them all at once as much memory
    as (T, B) matrices."""
    steps = max(1, CHUNK_CELLS // dt.shape[1])
    for first in range(0, len(dt), steps):
        values, codes = np.unique(dt[first:first + steps], return_inverse=True)
        table = motion(settings, values)
        for code in codes.reshape(-1, dt.shape[1]):
            yield table[code]


def mixed(settings: FilterSettings, state: BatchState, each_alone: bool = False) -> BatchState:
    """IMM mixing of posteriors: each model's starting state and covariance, and the predicted mode
    probabilities cbar in `mu`; a single filter starts from its posterior (the same object).
    `each_alone`: cbar of each track by its own (1, M) product, the numbers it gets when mixed
    alone (the tracker's updates, one track or a scan's at once, must not depend on which tracks
    share the call); otherwise one product for the batch, whose BLAS call may round differently.

    IMMEstimator's mixing, x0_j = sum_i w_ij x_i and P0_j = sum_i w_ij (P_i + d_ij d_ij') with
    d_ij = x_i - x0_j, where w_ij = T_ij mu_i / cbar_j; for two models, whose weights w_0j + w_1j
    are 1, the second sum is sum_i w_ij P_i + w_0j w_1j (x_0 - x_1)(x_0 - x_1)' (fewer products),
    for more the general form."""
    if not settings.is_imm:
        return state
    transition = settings.transition_probabilities()
    cbar = (state.mu[:, None, :] @ transition)[:, 0] if each_alone else state.mu @ transition  # (B, M)
    weight = transition.T * state.mu[:, None, :] / cbar[:, :, None]                 # w_ij at [b, j, i]
    B, M, n = state.x.shape
    P = (weight @ state.P.reshape(B, M, n * n)).reshape(state.P.shape)
    x = weight @ state.x
    if M == 2:
        spread = state.x[:, 0] - state.x[:, 1]                                      # (B, n)
        P = P + (weight[:, :, 0] * weight[:, :, 1])[:, :, None, None] * (spread[:, None, :, None]
                                                                          * spread[:, None, None, :])
    else:
        offset = state.x[:, None, :, :] - x[:, :, None, :]                         # d_ij at [b, j, i]
        P = P + np.einsum("bji,bjik,bjil->bjkl", weight, offset, offset)
    return BatchState(x, P, cbar)


def moved(state: BatchState, F: np.ndarray, Q: np.ndarray) -> BatchState:
    """Each track's models moved by their transition F and process noise Q (B, M, n, n):
    x' = F x, P' = F P F' + Q (filterpy's `KalmanFilter.predict`); mu is kept."""
    return BatchState((F @ state.x[..., None])[..., 0], F @ state.P @ F.swapaxes(-1, -2) + Q, state.mu)


def predicted(settings: FilterSettings, state: BatchState, F: np.ndarray, Q: np.ndarray) -> BatchState:
    """Posteriors mixed and moved by F and Q (B, M, n, n); mu becomes the predicted mode probabilities."""
    return moved(mixed(settings, state), F, Q)


def inverse3(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse (..., 3, 3) and determinant (...) of 3 x 3 matrices S (..., 3, 3) by cofactors:
    one gather and a few products instead of a LAPACK call per matrix, which costs more than the
    arithmetic at this size. Singular matrices give inf or NaN entries, no error."""
    flat = S.reshape(S.shape[:-2] + (9,))
    factors = flat[..., _COFACTOR_INDEX]                                            # (..., 4, 9)
    cofactor = factors[..., 0, :] * factors[..., 1, :] - factors[..., 2, :] * factors[..., 3, :]
    determinant = np.add.reduce(flat[..., :3] * cofactor[..., :3], axis=-1)
    return cofactor.reshape(S.shape).swapaxes(-1, -2) / determinant[..., None, None], determinant


def updated(settings: FilterSettings, state: BatchState, z: np.ndarray, R: np.ndarray,
            S_inverse: np.ndarray | None = None) -> BatchState:
    """Each track updated with its measurement z (B, 3) of covariance R (B, 3, 3): Joseph form, and
    for the IMM the mode probabilities from the models' log-likelihoods.

    `S_inverse` (B, M, 3, 3): the inverse of the innovation covariance S = H P H' + R when the
    caller has it already (the tracker's chi-square gate computed it for a single filter), else
    computed here; the IMM's mode probabilities need S's determinant too, so it is not taken there
    (ValueError).

    H only picks x, y, z out of the state, so H P is rows of P, and the Joseph form
    (I - K H) P (I - K H)' + K R K' is evaluated as J P + (K R - J P H') K' with J P = P - K (H P)."""
    position = slice(None, None, state.x.shape[-1] // 3)  # x, y, z lead their axis's block of the state
    R = R[:, None]                                                                  # (B, 1, 3, 3)
    HP = state.P[..., position, :]                                                  # (B, M, 3, n)
    innovation = z[:, None] - state.x[..., position]                                # (B, M, 3)
    if S_inverse is None:
        S_inverse, S_determinant = inverse3(HP[..., position] + R)                 # (B, M, 3, 3), (B, M)
    elif settings.is_imm:
        raise ValueError("updated: the IMM needs the innovation covariance's determinant; give no S_inverse")
    gain_T = S_inverse @ HP                                                         # K' = S^-1 H P: (B, M, 3, n)
    gain = gain_T.swapaxes(-1, -2)
    x = state.x + (innovation[..., None, :] @ gain_T)[..., 0, :]
    JP = state.P - gain @ HP
    P = JP + (gain @ R - JP[..., :, position]) @ gain_T
    mu = state.mu
    if settings.is_imm:
        distance = (innovation[..., None, :] @ S_inverse @ innovation[..., :, None])[..., 0, 0]  # (B, M)
        log_weight = np.log(state.mu) - 0.5 * (distance + np.log(S_determinant) + LOG_NORMALISER)
        weight = np.exp(log_weight - log_weight.max(axis=1, keepdims=True))
        mu = weight / weight.sum(axis=1, keepdims=True)
    return BatchState(x, P, mu)


def collapsed(prior: BatchState, posteriors: BatchState, track: np.ndarray, weights: np.ndarray,
              missed: np.ndarray) -> BatchState:
    """The probabilistic data association update of T tracks: each track's hypotheses, none of its
    plots its own (`prior`, T tracks, probability `missed` (T,)) or plot h its own (`posteriors`, H
    updates, each of track `track[h]` with probability `weights[h]`), merged per motion model into
    one Gaussian by moment matching.

    The mixture over (hypothesis, model) pairs has weights beta_h mu_{h,r}, mu_{h,r} being model r's
    probability after hypothesis h's update (`updated`); model r's merged mean and covariance are
    its hypotheses' weighted mean and spread, and its probability their summed weight. For a
    single filter this is the PDA update (Bar-Shalom, Daum & Huang, "The probabilistic data
    association filter", IEEE Control Systems 29(6), 2009, eqs. 36-41: x = sum_h beta_h x_h,
    P = beta_0 P^- + sum_h beta_h P_h + the spread of the means); for the IMM, the hypotheses of
    each model merged as the IMM-PDAF's model-conditioned PDA updates are (Bar-Shalom, Willett &
    Tian, "Tracking and Data Fusion", YBS 2011, 3.4), the hypotheses' probabilities being common to
    the models (computed from the combined prediction: `pipeline.tracker.jpda`). Shapes as
    BatchState's; the result holds T tracks."""
    tracks, hypotheses = len(missed), len(track)
    of_track = np.zeros((tracks, hypotheses))  # sums over each track's hypotheses as one product: np.add.at is slower
    of_track[track, np.arange(hypotheses)] = 1.0

    def summed(prior_part: np.ndarray, posterior_part: np.ndarray) -> np.ndarray:
        """Each track's `prior_part` (T, M, ...) plus the sum of its hypotheses' `posterior_part` (H, M, ...)."""
        return prior_part + (of_track @ posterior_part.reshape(hypotheses, -1)).reshape(prior_part.shape)

    weight = weights[:, None] * posteriors.mu                                       # (H, M)
    prior_weight = missed[:, None] * prior.mu                                       # (T, M)
    total = summed(prior_weight, weight)
    held = total > 0.0  # a model no hypothesis leaves any weight keeps its prior (mu underflowed to 0)
    safe = np.where(held, total, 1.0)
    x = np.where(held[..., None], summed(prior_weight[..., None] * prior.x, weight[..., None] * posteriors.x)
                 / safe[..., None], prior.x)
    prior_offset = prior.x - x
    posterior_offset = posteriors.x - x[track]
    P_sum = summed(prior_weight[..., None, None] * (prior.P + prior_offset[..., :, None] * prior_offset[..., None, :]),
                   weight[..., None, None] * (posteriors.P + posterior_offset[..., :, None]
                                              * posterior_offset[..., None, :]))
    P = np.where(held[..., None, None], P_sum / safe[..., None, None], prior.P)
    return BatchState(x, P, total / total.sum(axis=1, keepdims=True))


def combined(mu: np.ndarray, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mode-weighted mean (..., k) and covariance (..., k, k) of the models' means x (..., M, k)
    and covariances P (..., M, k, k) with probabilities mu (..., M) (filterpy's
    `IMMEstimator._compute_state_estimate`). The sums over models are reductions over the model
    axis rather than a loop over models: the same additions in the same order, a few NumPy calls
    whatever M (the tracker calls this twice per associated plot). A single model (mu = 1) is its
    own estimate: x as is, and P + 0.0, what the general form gives it (its spread is 0)."""
    if mu.shape[-1] == 1:
        return x[..., 0, :], P[..., 0, :, :] + 0.0
    mean = np.add.reduce(mu[..., None] * x, axis=-2)
    offset = x - mean[..., None, :]
    return mean, np.add.reduce(mu[..., None, None] * (P + offset[..., :, None] * offset[..., None, :]), axis=-3)


def position_estimates(state: BatchState) -> tuple[np.ndarray, np.ndarray]:
    """The tracks' positions (B, 3) and position covariances (B, 3, 3), their models combined (a
    single model's as `combined` gives them, picked directly: the tracker asks twice per plot)."""
    step = state.x.shape[-1] // 3
    if state.mu.shape[-1] == 1:
        return state.x[..., 0, ::step], state.P[..., 0, ::step, ::step] + 0.0
    return combined(state.mu, state.x[..., ::step], state.P[..., ::step, ::step])


def velocity_estimates(state: BatchState) -> tuple[np.ndarray, np.ndarray]:
    """The tracks' velocities (B, 3) m/s and their covariances (B, 3, 3) m^2/s^2, their models combined
    (`combined`; state per axis [p, v] or [p, v, a]). Of an IMM's mixed state as the tracker stores it
    after an update (`mixed`) they are the posterior's: mixing keeps the mixture's mean and covariance
    (Bar-Shalom, Li & Kirubarajan 2001, 11.6.6, the mixing probabilities summed over the models)."""
    step = state.x.shape[-1] // 3
    return combined(state.mu, state.x[..., 1::step], state.P[..., 1::step, 1::step])


def _overwrite(state: BatchState, rows: np.ndarray | slice, source: BatchState, tracks: np.ndarray | slice) -> None:
    """Tracks `rows` of `state` become the tracks `tracks` of `source` (in place)."""
    state.x[rows], state.P[rows], state.mu[rows] = source.x[tracks], source.P[tracks], source.mu[tracks]


@dataclass(frozen=True)
class FilteredSequences:
    """What `filter_sequences` gives for B sequences of T steps.

    `position` (B, T, 3) metres and `covariance` (B, T, 3, 3) m^2: the filtered positions, NaN
    at invalid steps. `innovation_distance` (B, T): each measurement's normalised innovation
    squared against the predicted density the tracker gates with, d' S^-1 d with d = z - x_pred
    and S = P_pred + R (the IMM's models combined with the predicted mode probabilities), NaN
    where the track (re)starts or the step is padding; chi-square with 3 degrees of freedom for a
    consistent filter (Bar-Shalom, Li & Kirubarajan 2001, 5.4.2). `last`: the state after each
    row's last step."""

    position: np.ndarray
    covariance: np.ndarray
    innovation_distance: np.ndarray
    last: BatchState


def filter_sequences(settings: FilterSettings, times: np.ndarray, positions: np.ndarray, covariances: np.ndarray,
                     valid: np.ndarray, restart: np.ndarray) -> FilteredSequences:
    """Filter B measurement sequences side by side: times (B, T) seconds, positions (B, T, 3) metres,
    covariances (B, T, 3, 3) m^2. Invalid steps (padding) are skipped; at `restart` steps a track
    starts afresh from the measurement."""
    B, T = times.shape
    moving = valid & ~restart
    # Each step's time since the row's previous valid step (times[:, 0] when there is none).
    previous = np.maximum.accumulate(np.where(valid, np.arange(T), 0), axis=1)
    previous = np.concatenate([np.zeros((B, 1), dtype=previous.dtype), previous[:, :-1]], axis=1)
    dt = np.where(moving, times - np.take_along_axis(times, previous, axis=1), 0.0).T          # (T, B)
    z, R = np.ascontiguousarray(np.swapaxes(positions, 0, 1)), np.ascontiguousarray(np.swapaxes(covariances, 0, 1))
    # Steps where some row does not predict and update: it restarts, or keeps its state (padding).
    repaired = ~moving.all(axis=0)
    fresh_steps, fresh_rows = np.nonzero((valid & restart).T)
    started = start(settings, z[fresh_steps, fresh_rows], R[fresh_steps, fresh_rows])   # every restart, in step order
    fresh_bounds = np.searchsorted(fresh_steps, np.arange(T + 1))

    state = start(settings, z[0], R[0])
    M, n = state.mu.shape[1], state.x.shape[-1]
    position = slice(None, None, n // 3)
    model_x, model_P, model_mu = np.empty((T, B, M, 3)), np.empty((T, B, M, 3, 3)), np.empty((T, B, M))
    prior_x, prior_P, prior_mu = np.empty_like(model_x), np.empty_like(model_P), np.empty_like(model_mu)
    for step, step_motion in enumerate(_motion_per_step(settings, dt)):
        F = turned(settings, step_motion[:, 0], dt[step], verticals(settings, state))
        prior = predicted(settings, state, F, step_motion[:, 1])
        prior_x[step], prior_P[step], prior_mu[step] = prior.x[..., position], prior.P[..., position, position], \
            prior.mu
        after = updated(settings, prior, z[step], R[step])
        if repaired[step]:
            idle, cells = ~valid[:, step], slice(fresh_bounds[step], fresh_bounds[step + 1])
            _overwrite(after, idle, state, idle)                                    # padding: the state stays
            _overwrite(after, fresh_rows[cells], started, cells)
        state = after
        model_x[step], model_P[step], model_mu[step] = state.x[..., position], state.P[..., position, position], \
            state.mu
    x, P = combined(model_mu, model_x, model_P)                                     # (T, B, 3), (T, B, 3, 3)
    invalid = ~valid.T
    x[invalid], P[invalid] = np.nan, np.nan
    prior_position, prior_covariance = combined(prior_mu, prior_x, prior_P)
    innovation = z - prior_position
    S_inverse, _ = inverse3(prior_covariance + R)
    distance = np.einsum("tbi,tbij,tbj->tb", innovation, S_inverse, innovation)
    distance[~moving.T] = np.nan
    return FilteredSequences(np.ascontiguousarray(np.swapaxes(x, 0, 1)), np.ascontiguousarray(np.swapaxes(P, 0, 1)),
                             np.ascontiguousarray(distance.T), state)


def predict_positions(settings: FilterSettings, state: BatchState, dt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted positions (B, 3) and covariances (B, 3, 3) of posteriors dt (B,) seconds ahead."""
    F_and_Q = motion(settings, dt)
    F = turned(settings, F_and_Q[:, 0], dt, verticals(settings, state))
    return position_estimates(predicted(settings, state, F, F_and_Q[:, 1]))
